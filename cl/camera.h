/* Primary rays from the Camera struct (host precomputes pixel00/du/dv: no trig here). */
#ifndef VR_CAMERA_H
#define VR_CAMERA_H

/* World-space unit direction through pixel (x, y) at sub-pixel offset (jx, jy). */
inline float3 vr_camera_dir(__constant Camera* cam, int x, int y, float jx, float jy)
{
    float3 d = cam->pixel00.xyz + ((float)x + jx) * cam->du.xyz + ((float)y + jy) * cam->dv.xyz;
    return normalize(d);
}

/* Sub-pixel offset: the pixel centre with one sample, else box-filter samples that
   stratify the pixel for any count: the R2 sequence (s * (1/phi2, 1/phi2^2) mod 1,
   phi2 the plastic number) shifted by one random offset per pixel (Cranley-Patterson
   rotation: each sample stays uniform, so the estimate stays unbiased). */
inline float2 vr_pixel_jitter(__constant Camera* cam, uint pixel, uint s)
{
    if (cam->spp <= 1)
        return (float2)(0.5f, 0.5f);
    float2 u = (float2)(vr_rand(cam->seed, pixel, 0u, 0u), vr_rand(cam->seed, pixel, 0u, 1u));
    /* s * alpha mod 1 in 32-bit fixed point: exact for every s */
    uint ax = s * 3242174889u, ay = s * 2447445414u;
    float2 q = u + (float2)((float)(ax >> 8), (float)(ay >> 8)) * (1.0f / 16777216.0f);
    return q - floor(q);
}

/* A sample's radiance, safe to sum over 65536 of them: NaN -> 0, each channel at most
   VR_SAMPLE_MAX (volrender/layout.py). The identity for every ordinary value. */
inline float3 vr_safe_sample(float3 L)
{
    return fmin(select(L, (float3)(0.0f), isnan(L)), (float3)(VR_SAMPLE_MAX));
}

#endif
