/* Primary rays from the Camera struct (host precomputes pixel00/du/dv: no trig here). */
#ifndef VR_CAMERA_H
#define VR_CAMERA_H

/* World-space unit direction through pixel (x, y) at sub-pixel offset (jx, jy). */
inline float3 vr_camera_dir(__constant Camera* cam, int x, int y, float jx, float jy)
{
    float3 d = cam->pixel00.xyz + ((float)x + jx) * cam->du.xyz + ((float)y + jy) * cam->dv.xyz;
    return normalize(d);
}

/* Sub-pixel offset: the pixel centre with one sample, else box-filter jitter. */
inline float2 vr_pixel_jitter(__constant Camera* cam, uint pixel, uint s)
{
    if (cam->spp <= 1)
        return (float2)(0.5f, 0.5f);
    return (float2)(vr_rand(cam->seed, pixel, s, 0u), vr_rand(cam->seed, pixel, s, 1u));
}

#endif
