/* Henyey-Greenstein phase, physical sign: mu = cos(light propagation, scattered dir);
   g > 0 scatters forward. Reads VR_PHASE_MIXED. */
#ifndef VR_PHASE_H
#define VR_PHASE_H

/* 1 + g^2 - 2 g mu written as a sum of non-negative terms, so |g| -> 1 near mu = +-1
   does not cancel to zero in float. The host clamps |g| <= 0.999. */
inline float vr_hg(float mu, float g)
{
    float denom = g >= 0.0f ? (1.0f - g) * (1.0f - g) + 2.0f * g * (1.0f - mu)
                            : (1.0f + g) * (1.0f + g) - 2.0f * g * (1.0f + mu);
    denom = fmax(denom, 1e-12f);
    return VR_INV_4PI * (1.0f - g * g) / (denom * sqrt(denom));
}

inline float vr_phase(float mu, float4 ph)
{
#if VR_PHASE_MIXED
    return ph.z * vr_hg(mu, ph.x) + (1.0f - ph.z) * vr_hg(mu, ph.y);
#else
    return vr_hg(mu, ph.x);
#endif
}

/* mu distributed as HG(mu; g) from one uniform u: the inverse of its CDF,
   mu = (1 + g^2 - s^2) / 2g with s = (1 - g^2) / (1 - g + 2 g u); uniform for |g| < 1e-3
   (where that form cancels). u -> 1 gives mu -> +1. */
inline float vr_hg_sample(float g, float u)
{
    if (fabs(g) < 1e-3f)
        return clamp(2.0f * u - 1.0f, -1.0f, 1.0f);
    float s = (1.0f - g * g) / (1.0f - g + 2.0f * g * u);
    return clamp((1.0f + g * g - s * s) / (2.0f * g), -1.0f, 1.0f);
}

/* Unit vector at cosine mu from unit d, azimuth 2 pi u (an orthonormal basis around d,
   Duff et al. 2017, branch-free up to the sign). */
inline float3 vr_around(float3 d, float mu, float u)
{
    float sign = d.z >= 0.0f ? 1.0f : -1.0f;
    float a = -1.0f / (sign + d.z), b = d.x * d.y * a;
    float3 t = (float3)(1.0f + sign * d.x * d.x * a, sign * b, -sign * d.x);
    float3 bt = (float3)(b, sign + d.y * d.y * a, -d.y);
    float st = sqrt(fmax(1.0f - mu * mu, 0.0f)), phi = 2.0f * VR_PI * u;
    return normalize(mu * d + st * (cos(phi) * t + sin(phi) * bt));
}

/* A direction w with cos(w, d) = mu distributed as the phase mixture (lobe 1 with
   probability w, then its HG), from three uniforms; its density per solid angle is
   vr_phase(mu, ph), so phase / pdf = 1. Tracing from the camera, d is the ray's
   direction and w the direction to continue in (towards the light it gathers): the
   light then propagates along -w and scatters into -d, at mu = dot(-w, -d). */
inline float3 vr_phase_sample(float4 ph, float3 d, float u0, float u1, float u2)
{
#if VR_PHASE_MIXED
    float g = u0 < ph.z ? ph.x : ph.y;
#else
    float g = ph.x;
    (void)u0;
#endif
    return vr_around(d, vr_hg_sample(g, u1), u2);
}

#endif
