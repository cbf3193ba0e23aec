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

#endif
