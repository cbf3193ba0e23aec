/* A pixel's sums across launches: a launch renders samples s0 .. s1-1 of spp and
   continues the sums the launch before left in out (rgb, alpha) and, with VR_DEPTH, in
   depth (sum, weight); the last launch divides. Any split gives the same image. */
#ifndef VR_ACCUM_H
#define VR_ACCUM_H

typedef struct {
    float3 rgb;
    float alpha, depth, depth_w;
} VrAccum;

inline VrAccum vr_accum_load(__global const float4* out, __global const float* depth,
                             uint pixel, int s0)
{
    VrAccum a = { (float3)(0.0f), 0.0f, 0.0f, 0.0f };
    if (s0 > 0) {
        a.rgb = out[pixel].xyz;
        a.alpha = out[pixel].w;
#if VR_DEPTH
        a.depth = depth[2 * pixel];
        a.depth_w = depth[2 * pixel + 1];
#endif
    }
    (void)depth;
    return a;
}

inline void vr_accum_store(__global float4* out, __global float* depth, uint pixel,
                           VrAccum a, int s1, int spp)
{
#if VR_DEPTH
    depth[2 * pixel + 1] = a.depth_w;
#endif
    (void)depth;
    if (s1 < spp) {                    /* more samples follow in a later launch */
        out[pixel] = (float4)(a.rgb, a.alpha);
#if VR_DEPTH
        depth[2 * pixel] = a.depth;
#endif
        return;
    }
    float inv = 1.0f / (float)spp;
    out[pixel] = (float4)(a.rgb * inv, a.alpha * inv);
#if VR_DEPTH
    depth[2 * pixel] = a.depth_w > 0.0f ? a.depth / a.depth_w : INFINITY;
#endif
}

#endif
