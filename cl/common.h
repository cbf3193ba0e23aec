/* Shared math, constants and the counter-based RNG. */
#ifndef VR_COMMON_H
#define VR_COMMON_H

#define VR_PI 3.14159265358979f
#define VR_INV_4PI 0.0795774715459477f
#define VR_TAU_MAX 80.0f          /* exp(-80) ~ 1.8e-35: larger optical depths are opaque */

/* Integer hash (lowbias32-style avalanche). */
inline uint vr_hash(uint x)
{
    x ^= x >> 16; x *= 0x7feb352dU;
    x ^= x >> 15; x *= 0x846ca68bU;
    x ^= x >> 16;
    return x;
}

/* Uniform in [0,1), keyed by (seed, pixel, sample, dimension): no state, so the same
   seed gives the same image whatever the dispatch order. */
inline float vr_rand(uint seed, uint pixel, uint sample, uint dim)
{
    uint h = vr_hash(seed ^ vr_hash(pixel ^ vr_hash(sample ^ vr_hash(dim * 0x9e3779b9U + 0x85ebca6bU))));
    return (float)(h >> 8) * (1.0f / 16777216.0f);
}

/* exp(-tau) with tau clamped to [0, VR_TAU_MAX]; NaN reads as opaque. */
inline float vr_transmit(float tau)
{
    return isnan(tau) ? 0.0f : exp(-clamp(tau, 0.0f, VR_TAU_MAX));
}

/* Ray / axis-aligned box [lo, hi]: entry and exit parameters (t0 > t1 means a miss).
   Uses the IEEE inf from 1/0 for axis-parallel rays, with NaN (0*inf) masked. */
inline float2 vr_ray_box(float3 o, float3 inv_d, float3 lo, float3 hi)
{
    float3 ta = (lo - o) * inv_d;
    float3 tb = (hi - o) * inv_d;
    float3 tn = fmin(ta, tb), tf = fmax(ta, tb);
    tn = select(tn, (float3)(-INFINITY), isnan(tn));
    tf = select(tf, (float3)(INFINITY), isnan(tf));
    return (float2)(fmax(fmax(tn.x, tn.y), tn.z), fmin(fmin(tf.x, tf.y), tf.z));
}

inline float3 vr_mat3(float4 r0, float4 r1, float4 r2, float3 v)
{
    return (float3)(dot(r0.xyz, v), dot(r1.xyz, v), dot(r2.xyz, v));
}

#endif
