/* The light cache (volrender/light_cache.py): the light reaching each point of the
   medium, baked once per scene and lights (cl/bake_light.cl) on nodes spaced
   VR_LIGHT_CACHE voxels apart inside every occupied brick (8 / VR_LIGHT_CACHE + 1 nodes
   per axis, the brick's faces included, so neighbours share their face values), and read
   trilinearly by the marcher instead of a shadow march per sample per light.
   Channels per node (VR_CACHE_CH):
     0 .. n_lights-1   each light's shadow optical depth (grey, as vr_shadow_tau gives it);
                       the octave bands and the channels' extinction apply when it is read
     then, with VR_ENV, 12 floats: the environment's light, L1 spherical harmonics of
                       L_env(w) F(tau(w)) over VR_CACHE_DIRS fixed directions (a0 rgb, then
                       a1 = 3 mean(w f) as x rgb, y rgb, z rgb), F the bands' transmittance
                       (exp(-tau) with one octave). The phase folds in exactly
                       (Funk-Hecke: a0 + g_mean a1 . d for a Henyey-Greenstein mixture).
   Layout: cache[(slot * nodes + (i * n + j) * n + k) * VR_CACHE_CH + ch].
   Include after volume.h and lights.h. */
#ifndef VR_LIGHT_CACHE_H
#define VR_LIGHT_CACHE_H

#if VR_LIGHT_CACHE
#define VR_CACHE_N (VR_BRICK / VR_LIGHT_CACHE + 1)      /* nodes per axis per brick */
#define VR_CACHE_NODES (VR_CACHE_N * VR_CACHE_N * VR_CACHE_N)
#define VR_CACHE_LIGHTS (VR_N_SUNS + VR_N_POINTS)
#define VR_CACHE_ENV_CH 12
#define VR_CACHE_CH (VR_CACHE_LIGHTS + (VR_ENV ? VR_CACHE_ENV_CH : 0))
#define VR_CACHE_DIRS 14

/* The fixed environment directions: the 6 axes and the 8 cube diagonals, each a
   spherical 3-design, so equal weights integrate the L1 harmonics exactly. */
__constant float4 vr_cache_dirs[VR_CACHE_DIRS] = {
    (float4)(1, 0, 0, 0), (float4)(-1, 0, 0, 0), (float4)(0, 1, 0, 0),
    (float4)(0, -1, 0, 0), (float4)(0, 0, 1, 0), (float4)(0, 0, -1, 0),
    (float4)(0.57735027f, 0.57735027f, 0.57735027f, 0),
    (float4)(0.57735027f, 0.57735027f, -0.57735027f, 0),
    (float4)(0.57735027f, -0.57735027f, 0.57735027f, 0),
    (float4)(0.57735027f, -0.57735027f, -0.57735027f, 0),
    (float4)(-0.57735027f, 0.57735027f, 0.57735027f, 0),
    (float4)(-0.57735027f, 0.57735027f, -0.57735027f, 0),
    (float4)(-0.57735027f, -0.57735027f, 0.57735027f, 0),
    (float4)(-0.57735027f, -0.57735027f, -0.57735027f, 0)};

/* The eight nodes around local point (cell c, fraction f) of brick `slot` and their
   trilinear weights: *base the first node's offset (in floats), node offsets
   base + off[n], weights w[n]. */
typedef struct {
    int base;
    int off[8];
    float w[8];
} VrCacheTap;

inline void vr_cache_tap(int slot, int3 c, float3 f, VrCacheTap* t)
{
    float3 q = (convert_float3(c & (VR_BRICK - 1)) + f) * (1.0f / (float)VR_LIGHT_CACHE);
    int3 i = min(convert_int3(q), (int3)(VR_CACHE_N - 2));
    float3 r = clamp(q - convert_float3(i), 0.0f, 1.0f);
    t->base = (slot * VR_CACHE_NODES + (i.x * VR_CACHE_N + i.y) * VR_CACHE_N + i.z) * VR_CACHE_CH;
    for (int n = 0; n < 8; ++n) {
        int dx = n >> 2, dy = (n >> 1) & 1, dz = n & 1;
        t->off[n] = ((dx * VR_CACHE_N + dy) * VR_CACHE_N + dz) * VR_CACHE_CH;
        t->w[n] = (dx ? r.x : 1.0f - r.x) * (dy ? r.y : 1.0f - r.y) * (dz ? r.z : 1.0f - r.z);
    }
}

/* Channel ch of the cache at the tap. */
inline float vr_cache_read(__global const float* cache, const VrCacheTap* t, int ch)
{
    __global const float* v = cache + t->base + ch;
    float s = 0.0f;
    for (int n = 0; n < 8; ++n)
        s += t->w[n] * v[t->off[n]];
    return s;
}

#if VR_CACHE_LIGHTS > 0
/* vr_inscatter (march.h) with each light's shadow optical depth read from the cache. */
inline float3 vr_cached_inscatter(__constant VolumeParams* vp, __constant Light* lights,
                                  __global const float* cache, const VrCacheTap* t,
                                  float3 p, float3 wo)
{
    float3 sum = (float3)(0.0f);
    for (int i = 0; i < VR_CACHE_LIGHTS; ++i) {
        float3 dl, prop;
        float tmax, atten;
        if (!vr_light_at(vp, lights, i, p, &dl, &tmax, &prop, &atten))
            continue;
        float tau = vr_cache_read(cache, t, i);
#if VR_MS_OCTAVES > 1 || VR_CHROMATIC
        sum += vr_octaves(vp, dot(prop, wo), tau, 1) * lights[i].radiance.xyz / atten;
#else
        sum += vr_phase(dot(prop, wo), vp->phase) * vr_transmit(tau) * lights[i].radiance.xyz / atten;
#endif
    }
    return sum;
}
#endif

#if VR_ENV
/* The environment's in-scattered light towards the camera ray's world direction d. */
inline float3 vr_cached_env(__constant VolumeParams* vp, __global const float* cache,
                            const VrCacheTap* t, float3 d)
{
    float a[VR_CACHE_ENV_CH];
    for (int ch = 0; ch < VR_CACHE_ENV_CH; ++ch)
        a[ch] = vr_cache_read(cache, t, VR_CACHE_LIGHTS + ch);
    float g = vp->phase.z * vp->phase.x + (1.0f - vp->phase.z) * vp->phase.y;   /* mean cosine */
    float3 a0 = (float3)(a[0], a[1], a[2]);
    float3 a1 = d.x * (float3)(a[3], a[4], a[5]) + d.y * (float3)(a[6], a[7], a[8])
              + d.z * (float3)(a[9], a[10], a[11]);
    return fmax(a0 + g * a1, (float3)(0.0f));
}
#endif

#endif
#endif
