/* Dielectric Fresnel and refraction, and the environment (procedural sky or an
   equirectangular map). No flags: the kernel picks what it calls. */
#ifndef VR_GLASS_H
#define VR_GLASS_H

#include "env.h"

/* Exact unpolarised dielectric Fresnel reflectance. cos_i in [0, 1] on the incident
   side, eta = n_incident / n_transmitted. Total internal reflection -> 1; eta 1 -> 0. */
inline float glass_fresnel(float cos_i, float eta)
{
    if (eta == 1.0f)
        return 0.0f;
    float s2 = eta * eta * (1.0f - cos_i * cos_i);
    if (s2 >= 1.0f)
        return 1.0f;
    float cos_t = sqrt(1.0f - s2);
    float rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    float rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    return 0.5f * (rs * rs + rp * rp);
}

/* Refract unit d at unit normal n facing the incident side (dot(d, n) <= 0). Returns 0
   on total internal reflection; eta 1 passes d through unchanged. */
inline int glass_refract(float3 d, float3 n, float eta, float3* t)
{
    if (eta == 1.0f) {
        *t = d;
        return 1;
    }
    float cos_i = fmin(-dot(d, n), 1.0f);
    float s2 = eta * eta * (1.0f - cos_i * cos_i);
    if (s2 >= 1.0f)
        return 0;
    *t = normalize(eta * d + (eta * cos_i - sqrt(1.0f - s2)) * n);
    return 1;
}

inline float3 glass_reflect(float3 d, float3 n)
{
    return d - 2.0f * dot(d, n) * n;
}

/* Procedural environment: sky from a bright horizon to a blue zenith, a grey checker
   ground (unit squares on the plane one unit below the eye) fading into haze. */
inline float3 glass_sky(float3 d)
{
    float3 horizon = (float3)(0.85f, 0.9f, 1.0f);
    if (d.y >= 0.0f) {
        float3 zenith = (float3)(0.2f, 0.4f, 0.85f);
        return mix(horizon, zenith, sqrt(fmin(d.y, 1.0f)));
    }
    float dn = -d.y;
    float2 q = clamp(d.xz / fmax(dn, 1e-6f), -1e6f, 1e6f);
    float c = fabs(fmod(floor(q.x) + floor(q.y), 2.0f));
    float3 ground = c > 0.5f ? (float3)(0.35f, 0.33f, 0.3f) : (float3)(0.12f, 0.11f, 0.1f);
    return mix(horizon, ground, 1.0f - exp(-12.0f * dn));
}

/* Equirectangular map, bilinear (env.h, shared with the volume kernels). */
inline float3 glass_env_map(__global const float4* env, int w, int h, float3 d)
{
    return vr_env_map(env, w, h, d);
}

#endif
