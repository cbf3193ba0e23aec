/* What the guide kernels share: a pixel's sums stored as they are while samples remain
   (s1 < spp: a later launch adds to them), as means after the last one. */
#ifndef VR_GUIDE_H
#define VR_GUIDE_H

static inline void guide_store(__global float4 *albedo_out, __global float4 *normal_out,
                               uint pixel, float4 a_sum, float4 n_sum, int s1, int spp)
{
    float k = s1 < spp ? 1.0f : 1.0f / (float)spp;
    albedo_out[pixel] = a_sum * k;
    normal_out[pixel] = n_sum * k;
}

#endif
