/* The light cache (volrender/light_cache.py): the light reaching each point of the
   medium, baked once per scene and lights (cl/bake_light.cl) on nodes spaced
   VR_LIGHT_CACHE voxels apart inside every occupied brick (8 / VR_LIGHT_CACHE + 1 nodes
   per axis, the brick's faces included, so neighbours share their face values), and read
   trilinearly by the marcher instead of a shadow march per sample per light.
   Channels per node (VR_CACHE_CH):
     0 .. n_lights-1   each light's shadow optical depth (grey, as vr_shadow_tau gives it);
                       the octave bands and the channels' extinction apply when it is read
     then, with VR_ENV, 12 floats: the environment's light, the L1 spherical harmonics
                       of L_env(w) F(tau(w)) (a0 rgb, then a1 = 3 mean(w f) as x rgb, y rgb,
                       z rgb), F the bands' transmittance (exp(-tau) with one octave),
                       tau marched along VR_CACHE_DIRS fixed directions and held constant
                       over each one's cell of the sphere (the map integrated over the cell
                       on the host: light_cache.env_quadrature, so F = 1 gives the map's
                       own L1 projection exactly). The phase folds in exactly
                       (Funk-Hecke: a0 + g_mean a1 . d for a Henyey-Greenstein mixture).
     then, with VR_MS_CACHE, 12 floats: the multiply scattered light (scattering orders
                       2 and up, per unit scattering coefficient) as the sky's: a0 rgb, then
                       a1 x rgb, y rgb, z rgb, propagated over the nodes by
                       cl/bake_light.cl's ms_gather (a1: of the orders it gathered, not the
                       geometric tail), with VR_ENV plus the sky's 12 above (ms_finish: the
                       marcher reads this set alone).
   Layout: cache[(slot * nodes + (i * n + j) * n + k) * VR_CACHE_CH + ch].
   Include after volume.h and lights.h. */
#ifndef VR_LIGHT_CACHE_H
#define VR_LIGHT_CACHE_H

#if VR_LIGHT_CACHE
#define VR_CACHE_N (VR_BRICK / VR_LIGHT_CACHE + 1)      /* nodes per axis per brick */
#define VR_CACHE_NODES (VR_CACHE_N * VR_CACHE_N * VR_CACHE_N)
#define VR_CACHE_LIGHTS (VR_N_SUNS + VR_N_POINTS)
#define VR_CACHE_ENV_CH 12
#define VR_CACHE_MS (VR_CACHE_LIGHTS + (VR_ENV ? VR_CACHE_ENV_CH : 0))   /* first ms channel */
#define VR_CACHE_CH (VR_CACHE_MS + (VR_MS_CACHE ? VR_CACHE_ENV_CH : 0))
#define VR_CACHE_DIRS 14

/* The eight nodes around local point (cell c, fraction f) of brick `slot` and their
   trilinear weights: *base the first node's offset (in floats), node offsets
   base + off[n], weights w[n]. */
typedef struct {
    int base;
    int off[8];
    float w[8];
} VrCacheTap;

inline void vr_cache_tap_n(int slot, int3 c, float3 f, int nch, VrCacheTap* t)
{
    float3 q = (convert_float3(c & (VR_BRICK - 1)) + f) * (1.0f / (float)VR_LIGHT_CACHE);
    int3 i = min(convert_int3(q), (int3)(VR_CACHE_N - 2));
    float3 r = clamp(q - convert_float3(i), 0.0f, 1.0f);
    t->base = (slot * VR_CACHE_NODES + (i.x * VR_CACHE_N + i.y) * VR_CACHE_N + i.z) * nch;
    for (int n = 0; n < 8; ++n) {
        int dx = n >> 2, dy = (n >> 1) & 1, dz = n & 1;
        t->off[n] = ((dx * VR_CACHE_N + dy) * VR_CACHE_N + dz) * nch;
        t->w[n] = (dx ? r.x : 1.0f - r.x) * (dy ? r.y : 1.0f - r.y) * (dz ? r.z : 1.0f - r.z);
    }
}

/* The same for the cache's layout (VR_CACHE_CH floats per node). */
inline void vr_cache_tap(int slot, int3 c, float3 f, VrCacheTap* t)
{
    vr_cache_tap_n(slot, c, f, VR_CACHE_CH, t);
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

/* Channel ch of the cache at local point q (-1 where q is in no occupied brick). */
inline float vr_cache_at(const VrGrid* g, __global const float* cache, float3 q, int ch)
{
    float3 cf = floor(q);
    int3 c = convert_int3(cf);
    int slot = vr_brick_slot(g, c);
    if (slot < 0)
        return -1.0f;
    VrCacheTap t;
    vr_cache_tap(slot, c, q - cf, &t);
    return vr_cache_read(cache, &t, ch);
}

#if VR_CACHE_LIGHTS > 0
/* A light's shadow optical depth from local p along dl (local per world unit) over
   tmax: marched exactly for the first vp->cache_near (world; the shadow's sharp part
   near lit surfaces, which trilinear nodes cannot hold in dense media), read from the
   cache at that point for the rest (marched on where that point lies in no occupied
   brick: the cache has no nodes there). */
inline float vr_cached_tau(const VrGrid* g, __constant VolumeParams* vp,
                           __global const float* cache, int i, float3 p, float3 dl,
                           float tmax, float u, float stop)
{
    float near = fmin(vp->cache_near, tmax);
    float tau = near > 0.0f ? vr_shadow_tau(g, vp, p, dl, near, u, stop) : 0.0f;
    if (near >= tmax || tau > stop)
        return tau;
    float3 q = p + near * dl;
    float far = vr_cache_at(g, cache, q, i);
    if (far < 0.0f)
        far = vr_shadow_tau(g, vp, q, dl, tmax - near, u, stop - tau);
    return tau + far;
}

/* vr_inscatter (march.h) with each light's shadow optical depth read from the cache
   (vr_cached_tau). */
inline float3 vr_cached_inscatter(const VrGrid* g, __constant VolumeParams* vp,
                                  __constant Light* lights, __global const float* cache,
                                  const VrCacheTap* t, float3 p, float3 wo,
                                  uint seed, uint pixel, uint s, uint step)
{
    float3 sum = (float3)(0.0f);
    uint dim = 16u + step * VR_MAX_LIGHTS;
#if VR_MS_OCTAVES > 1 || VR_CHROMATIC
    float stop = VR_TAU_STOP(vp);
#else
    float stop = VR_SHADOW_TAU_STOP;
#endif
    for (int i = 0; i < VR_CACHE_LIGHTS; ++i) {
        float3 dl, prop;
        float tmax, atten;
        if (!vr_light_at(vp, lights, i, p, &dl, &tmax, &prop, &atten))
            continue;
        float tau = vp->cache_near > 0.0f
                  ? vr_cached_tau(g, vp, cache, i, p, dl, tmax, vr_rand(seed, pixel, s, dim++), stop)
                  : vr_cache_read(cache, t, i);
#if VR_MS_OCTAVES > 1 || VR_CHROMATIC
        sum += vr_octaves(vp, dot(prop, wo), tau, 1) * lights[i].radiance.xyz / atten;
#else
        sum += vr_phase(dot(prop, wo), vp->phase) * vr_transmit(tau) * lights[i].radiance.xyz / atten;
#endif
    }
    return sum;
}
#endif

#if VR_ENV || VR_MS_CACHE
/* L1 harmonics stored from channel ch (a0 rgb, a1 x/y/z rgb) seen through the phase
   towards the camera ray's world direction d: a0 + g_mean a1 . d, at least 0. */
inline float3 vr_cached_l1(__constant VolumeParams* vp, __global const float* cache,
                           const VrCacheTap* t, int ch, float3 d)
{
    float a[VR_CACHE_ENV_CH];
    for (int c = 0; c < VR_CACHE_ENV_CH; ++c)
        a[c] = vr_cache_read(cache, t, ch + c);
    float g = vp->phase.z * vp->phase.x + (1.0f - vp->phase.z) * vp->phase.y;   /* mean cosine */
    float3 a0 = (float3)(a[0], a[1], a[2]);
    float3 a1 = d.x * (float3)(a[3], a[4], a[5]) + d.y * (float3)(a[6], a[7], a[8])
              + d.z * (float3)(a[9], a[10], a[11]);
    return fmax(a0 + g * a1, (float3)(0.0f));
}
#endif

#if VR_ENV
/* The environment's in-scattered light towards the camera ray's world direction d. */
inline float3 vr_cached_env(__constant VolumeParams* vp, __global const float* cache,
                            const VrCacheTap* t, float3 d)
{
    return vr_cached_l1(vp, cache, t, VR_CACHE_LIGHTS, d);
}
#endif

#if VR_MS_CACHE
/* The multiply scattered light towards the camera ray's world direction d at the tap. */
inline float3 vr_cached_ms(__constant VolumeParams* vp, __global const float* cache,
                           const VrCacheTap* t, float3 d)
{
    return vr_cached_l1(vp, cache, t, VR_CACHE_MS, d);
}
#endif

#endif
#endif
