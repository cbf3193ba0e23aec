/* The environment: an equirectangular map looked up bilinearly, shared by glass
   (glass.h) and volumes, and the importance sampling of a map by the volume kernels.
   Convention: u = 0.5 + atan2(x, -z) / 2pi (the image centre looks along -z),
   v = acos(y) / pi (the top row looks up); texel (i, j) covers u in [j, j+1)/W,
   v in [i, i+1)/H. Directions are world directions. The volume helpers at the end
   read VR_ENV (0 none, 1 uniform, 2 a map). */
#ifndef VR_ENV_H
#define VR_ENV_H

#include "structs.h"

inline float3 vr_env_map(__global const float4* env, int w, int h, float3 d)
{
    float u = 0.5f + atan2(d.x, -d.z) * (0.5f / VR_PI);
    float v = acos(clamp(d.y, -1.0f, 1.0f)) * (1.0f / VR_PI);
    if (!(isfinite(u) && isfinite(v)))
        return (float3)(0.0f);
    float fx = u * (float)w - 0.5f, fy = clamp(v * (float)h - 0.5f, 0.0f, (float)(h - 1));
    float x0f = floor(fx), y0f = floor(fy);
    float ax = fx - x0f, ay = fy - y0f;
    int x0 = ((int)x0f % w + w) % w, x1 = (x0 + 1) % w;
    int y0 = (int)y0f, y1 = min(y0 + 1, h - 1);
    float3 a = mix(env[y0 * w + x0].xyz, env[y0 * w + x1].xyz, ax);
    float3 b = mix(env[y1 * w + x0].xyz, env[y1 * w + x1].xyz, ax);
    return mix(a, b, ay);
}

/* Importance sampling of a map: texels are drawn with probability proportional to
   their weight (volrender/volume.py env_weights: the largest luminance of the texel and
   its neighbours, which bounds the bilinear map over the cell, x sin(theta) at the row
   centre, so per solid angle the density follows the luminance), then uniformly in
   (u, v) within the texel. cdf: H + 1 row CDF values, then H rows of W + 1 column CDF
   values (each from 0 to 1). The density per solid angle at a direction is
   p_texel W H / (2 pi^2 sin theta). Directions in texels of weight 0 have density 0:
   the kernels combine this with phase sampling by multiple importance sampling, so
   nothing is lost where the bilinear map is brighter than its texel's weight. */

/* Index i with cdf[i] <= u < cdf[i + 1] among n + 1 values (cdf[0] = 0, cdf[n] = 1). */
inline int vr_cdf_find(__global const float* cdf, int n, float u)
{
    int lo = 0, hi = n;              /* invariant: cdf[lo] <= u < cdf[hi] */
    while (hi - lo > 1) {
        int mid = (lo + hi) >> 1;
        if (cdf[mid] <= u)
            lo = mid;
        else
            hi = mid;
    }
    return lo;
}

inline float3 vr_env_dir(float u, float v)
{
    float phi = (u - 0.5f) * (2.0f * VR_PI), theta = v * VR_PI;
    float st = sin(theta);
    return (float3)(st * sin(phi), cos(theta), -st * cos(phi));
}

/* Density per solid angle of vr_env_sample at world direction d. */
inline float vr_env_pdf(__global const float* cdf, int w, int h, float3 d)
{
    float u = 0.5f + atan2(d.x, -d.z) * (0.5f / VR_PI);
    float v = acos(clamp(d.y, -1.0f, 1.0f)) * (1.0f / VR_PI);
    float st = sqrt(fmax(1.0f - d.y * d.y, 0.0f));
    if (!(isfinite(u) && isfinite(v)) || st <= 0.0f)
        return 0.0f;
    int i = clamp((int)(v * (float)h), 0, h - 1), j = clamp((int)(u * (float)w), 0, w - 1);
    __global const float* row = cdf + (h + 1) + i * (w + 1);
    float p = (cdf[i + 1] - cdf[i]) * (row[j + 1] - row[j]);
    return p * (float)(w * h) / (2.0f * VR_PI * VR_PI * st);
}

/* A direction drawn from the map's distribution from two uniforms (each picks its texel
   row or column, and its position within it once rescaled to that texel's interval:
   still uniform); *pdf its density per solid angle (0: the map has no weight there). */
inline float3 vr_env_sample(__global const float* cdf, int w, int h, float u0, float u1,
                            float* pdf)
{
    int i = vr_cdf_find(cdf, h, u0);
    __global const float* row = cdf + (h + 1) + i * (w + 1);
    int j = vr_cdf_find(row, w, u1);
    float fv = (u0 - cdf[i]) / fmax(cdf[i + 1] - cdf[i], 1e-30f);
    float fu = (u1 - row[j]) / fmax(row[j + 1] - row[j], 1e-30f);
    float3 d = vr_env_dir(((float)j + clamp(fu, 0.0f, 1.0f)) / (float)w,
                          ((float)i + clamp(fv, 0.0f, 1.0f)) / (float)h);
    *pdf = vr_env_pdf(cdf, w, h, d);
    return d;
}

/* Volumes: the environment's radiance along world direction w (towards it), and what
   a ray leaving the medium sees: the background, plus the environment where it is
   visible (VolumeParams.env_visible). */
inline float3 vr_env_radiance(__constant VolumeParams* vp, __global const float4* env, float3 w)
{
#if defined(VR_ENV) && VR_ENV == 1
    (void)env; (void)w;
    return vp->env_radiance.xyz;
#else
    return vr_env_map(env, vp->env_width, vp->env_height, w);
#endif
}

inline float3 vr_volume_behind(__constant VolumeParams* vp, __global const float4* env,
                               float3 w)
{
#if defined(VR_ENV) && VR_ENV
    return vp->background.xyz + vp->env_visible * vr_env_radiance(vp, env, w);
#else
    (void)env; (void)w;
    return vp->background.xyz;
#endif
}

#endif
