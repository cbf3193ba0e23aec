/* Bakes the light cache (cl/light_cache.h, volrender/light_cache.py): one work-item per
   node of an occupied brick marches towards every light and along the fixed environment
   directions, with the marcher's own shadow march (march.h) at its sample midpoints
   (u = 1/2: the same node baked from either brick sharing it gives the same value).
   Compiled with the marcher's flags (volrender/features.py) and VR_LIGHT_CACHE, the node
   spacing in voxels. */
#include "common.h"
#include "structs.h"
#include "phase.h"
#include "volume.h"
#include "lights.h"
#include "env.h"
#include "march.h"
#include "light_cache.h"

/* Each kernel runs over the nodes to bake, todo[gid] = (index into bricks, node): a node
   on a face shared by neighbouring bricks is baked once, in the first brick holding it,
   and copied to the others (copy_nodes; light_cache.bake_nodes), the same value either
   way. */
#define VR_BAKE_NODE(bricks, todo, n)                                                 \
    int gid = get_global_id(0);                                                     \
    if (gid >= (n))                                                                 \
        return;                                                                     \
    int2 td = (todo)[gid];                                                          \
    int4 b = (bricks)[td.x];                                                        \
    int node = td.y;

/* buf's nch floats per node: the node dst's are the node src's, (dst, src) = pairs[i]
   (node indices, slot * VR_CACHE_NODES + node). */
__kernel void copy_nodes(__global float* buf, __global const int2* pairs, int n, int nch)
{
    int i = get_global_id(0);
    if (i >= n * nch)
        return;
    int2 pr = pairs[i / nch];
    int c = i % nch;
    buf[pr.x * nch + c] = buf[pr.y * nch + c];
}

/* bricks: (bx, by, bz, slot) of each occupied brick; cache: its nodes' channels; envq:
   the environment's directions and cell integrals (light_cache.env_quadrature). */
__kernel void bake_light(__constant VolumeParams* vp, __constant Light* lights,
                         __global const int* table, __global const float* data,
                         __global const float4* envq, __global const int4* bricks,
                         __global const int2* todo, __global float* cache, int n,
                         float env_step)
{
    VR_BAKE_NODE(bricks, todo, n)
    int3 ijk = (int3)(node / (VR_CACHE_N * VR_CACHE_N), (node / VR_CACHE_N) % VR_CACHE_N,
                      node % VR_CACHE_N);
    float3 p = convert_float3(b.xyz * VR_BRICK + ijk * VR_LIGHT_CACHE);
    VrGrid g = { vp->dims, table, data };
    __global float* out = cache + (b.w * VR_CACHE_NODES + node) * VR_CACHE_CH;
#if VR_MS_OCTAVES > 1 || VR_CHROMATIC
    float stop = VR_TAU_STOP(vp);
#else
    float stop = VR_SHADOW_TAU_STOP;
#endif
#if VR_CACHE_LIGHTS > 0
    for (int i = 0; i < VR_CACHE_LIGHTS; ++i) {
        float3 dl, prop;
        float tmax, atten;
        out[i] = vr_light_at(vp, lights, i, p, &dl, &tmax, &prop, &atten)
               ? vr_shadow_tau(&g, vp, p, dl, tmax, 0.5f, stop) : 0.0f;
    }
#else
    (void)lights;
#endif
#if VR_ENV
    /* envq: per direction j, 5 float4: the direction (world), then the map's integral
       over its cell / 4 pi (rgb) and its first moments / 4 pi (x, y, z: rgb each) */
    float3 a0 = (float3)(0.0f), ax = a0, ay = a0, az = a0;
    for (int j = 0; j < VR_CACHE_DIRS; ++j) {
        __global const float4* q = envq + 5 * j;
        float3 dl = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2,
                            q[0].xyz);
        /* the sky's directions at env_step (light_cache.env_step), not the shadow step */
        float2 tt = vr_ray_box(p, 1.0f / dl, (float3)(0.0f), vp->box_hi.xyz);
        float tau = tt.y > 0.0f ? vr_optical_depth(&g, p, dl, 0.0f, tt.y, env_step, 0.5f,
                                                   vp->density_scale, stop) : 0.0f;
#if VR_MS_OCTAVES > 1 || VR_CHROMATIC
        VrSpec f = vr_env_bands(vp, tau);
#else
        float f = vr_transmit(tau);
#endif
        a0 += f * q[1].xyz;
        ax += f * q[2].xyz;
        ay += f * q[3].xyz;
        az += f * q[4].xyz;
    }
    ax *= 3.0f; ay *= 3.0f; az *= 3.0f;
    __global float* e = out + VR_CACHE_LIGHTS;
    e[0] = a0.x; e[1] = a0.y; e[2] = a0.z;
    e[3] = ax.x; e[4] = ax.y; e[5] = ax.z;
    e[6] = ay.x; e[7] = ay.y; e[8] = ay.z;
    e[9] = az.x; e[10] = az.y; e[11] = az.z;
#else
    (void)envq;
#endif
}

#if VR_MS_CACHE
/* Multiple scattering on the cache's nodes (VR_MS_CACHE; volrender/light_cache.py runs
   these after bake_light). S_1, the once-scattered light per unit scattering coefficient
   averaged over directions (its fluence / 4 pi), comes from the baked channels; each
   ms_gather gives the next order at every node,
       S_{k+1}(x) = (1/4 pi) int dw int_0^inf sigma_s(y) exp(-tau(x, y)) S_k(y) ds,
   y = x + s w, over the VR_CACHE_DIRS directions (weights: their cells' solid angles),
   S_k read trilinearly from the nodes, and sums them, with their first moments over the
   directions (total1: the L1 harmonics' a1 of the light each order gathered, so the
   marcher folds the phase in as for the sky, a0 + g a1 . d); ms_finish adds the geometric tail
   S_K k (k = r / (1 - r), r: the ratio of the last two orders summed over all nodes,
   per channel: volrender/light_cache.py) and writes the cache's ms channels. Orders 2
   and up scatter isotropically (the phase's shape is kept for the first scattering
   only), with the medium's albedo and extinction per channel (alb, ext:
 volume.ms_medium). The gather marches step about half a grey mean free path, between
   the shadow step and dt. src/dst/total: 3 floats per node (rgb). */
#define VR_MS_MFP 0.25f       /* the gather's step, grey mean free paths (docs/error_time.md) */
/* a gather march stops where the transmittance (summed over rgb) is below this, the rest
   of the ray taken as its last sample (docs/error_time.md: smoke's bake -10 %, the error
   as with 3e-3 and no rest) */
#ifndef VR_MS_T_STOP                 /* light_cache.MS_T_STOP passes it */
#define VR_MS_T_STOP 0.03f
#endif
__kernel void ms_source(__constant VolumeParams* vp, __constant Light* lights,
                        __global const int4* bricks, __global const int2* todo,
                        __global const float* cache, __global float* src, int n)
{
    VR_BAKE_NODE(bricks, todo, n)
    int at = b.w * VR_CACHE_NODES + node;
    __global const float* in = cache + at * VR_CACHE_CH;
    float3 s = (float3)(0.0f);
#if VR_CACHE_LIGHTS > 0
    int3 ijk = (int3)(node / (VR_CACHE_N * VR_CACHE_N), (node / VR_CACHE_N) % VR_CACHE_N,
                      node % VR_CACHE_N);
    float3 p = convert_float3(b.xyz * VR_BRICK + ijk * VR_LIGHT_CACHE);
    for (int i = 0; i < VR_CACHE_LIGHTS; ++i) {
        float3 dl, prop;
        float tmax, atten;
        if (vr_light_at(vp, lights, i, p, &dl, &tmax, &prop, &atten))
            s += exp(-in[i] * (float3)(VR_EXTINCTION(vp))) * lights[i].radiance.xyz
               / (4.0f * M_PI_F * atten);
    }
#else
    (void)lights;
#endif
#if VR_ENV
    s += (float3)(in[VR_CACHE_LIGHTS], in[VR_CACHE_LIGHTS + 1], in[VR_CACHE_LIGHTS + 2]);
#endif
    src[3 * at] = s.x; src[3 * at + 1] = s.y; src[3 * at + 2] = s.z;
}

/* The once-scattered light at node `at` (local p) leaving towards -w (w: world), from
   its baked channels as the marcher reads them (the lights' optical depth, the sky's
   harmonics) through the phase. */
inline float3 vr_once_at_node(__constant VolumeParams* vp, __constant Light* lights,
                              __global const float* cache, int at, float3 p, float3 w)
{
    VrCacheTap t;                        /* the node alone */
    t.base = at * VR_CACHE_CH;
    for (int n = 0; n < 8; ++n) {
        t.off[n] = 0;
        t.w[n] = n ? 0.0f : 1.0f;
    }
    float3 s = (float3)(0.0f);
#if VR_CACHE_LIGHTS > 0
    for (int i = 0; i < VR_CACHE_LIGHTS; ++i) {
        float3 l, prop;
        float tmax, atten;
        if (vr_light_at(vp, lights, i, p, &l, &tmax, &prop, &atten))
            s += vr_phase(dot(prop, -w), vp->phase) * lights[i].radiance.xyz / atten
               * exp(-cache[t.base + i] * (float3)(VR_EXTINCTION(vp)));
    }
#else
    (void)lights;
#endif
#if VR_ENV
    s += vr_cached_env(vp, cache, &t, w);
#endif
    return s;
}

/* The once-scattered light at every node towards each of the VR_CACHE_DIRS directions
   (once: 3 floats per direction per node), which the first ms_gather reads trilinearly
   as the later ones read an order: the marcher's reading (the nodes' transmittance and
   sky harmonics interpolated) folded through the phase per direction at the nodes, the
   same where the sky's L1 light is positive at the eight nodes (with point lights their
   phase and falloff are taken at the nodes). */
__kernel void ms_once(__constant VolumeParams* vp, __constant Light* lights,
                      __global const int4* bricks, __global const int2* todo,
                      __global const float* cache, __global const float4* dirs,
                      __global float* once, int n)
{
    VR_BAKE_NODE(bricks, todo, n)
    int at = b.w * VR_CACHE_NODES + node;
    int3 ijk = (int3)(node / (VR_CACHE_N * VR_CACHE_N), (node / VR_CACHE_N) % VR_CACHE_N,
                      node % VR_CACHE_N);
    float3 p = convert_float3(b.xyz * VR_BRICK + ijk * VR_LIGHT_CACHE);
    __global float* out = once + at * 3 * VR_CACHE_DIRS;
    for (int j = 0; j < VR_CACHE_DIRS; ++j) {
        float3 v = vr_once_at_node(vp, lights, cache, at, p, dirs[j].xyz);
        out[3 * j] = v.x; out[3 * j + 1] = v.y; out[3 * j + 2] = v.z;
    }
}

/* One order: dst = the next order of src at every node (see above), total += it (total
   = it with `first`, which gathers S_1 through the phase from ms_once's buffer, src
   then). dirs: per direction its world vector (xyz) and its cell's solid angle / 4 pi
   (w). */
__kernel void ms_gather(__constant VolumeParams* vp, __global const int* table,
                        __global const float* data, __global const float4* dirs,
                        __global const int4* bricks, __global const int2* todo,
                        __global const float* src, __global float* dst,
                        __global float* total, __global float* total1,
                        int n, float4 alb, float4 ext, float dt, int first)
{
    VR_BAKE_NODE(bricks, todo, n)
    int at = b.w * VR_CACHE_NODES + node;
    int3 ijk = (int3)(node / (VR_CACHE_N * VR_CACHE_N), (node / VR_CACHE_N) % VR_CACHE_N,
                      node % VR_CACHE_N);
    float3 o = convert_float3(b.xyz * VR_BRICK + ijk * VR_LIGHT_CACHE);
    VrGrid g = { vp->dims, table, data };
    float3 sum = (float3)(0.0f), mx = sum, my = sum, mz = sum;
    for (int j = 0; j < VR_CACHE_DIRS; ++j) {
        float4 q = dirs[j];
        float3 dl = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, q.xyz);
        float3 inv_d = 1.0f / dl;
        float t1 = vr_ray_box(o, inv_d, (float3)(0.0f), vp->box_hi.xyz).y;
        float3 T = (float3)(1.0f), acc = (float3)(0.0f), sk = acc;
        /* steps of VR_MS_MFP grey mean free paths (from the sample before), between the
           shadow step and dt, sampled at their midpoints */
        float t = 0.0f, h = vp->shadow_step;
        for (int k = 0; k < VR_MAX_RAY_SAMPLES; ++k) {
            if (t + 0.5f * h >= t1 || T.x + T.y + T.z < VR_MS_T_STOP)
                break;
            float3 p = o + (t + 0.5f * h) * dl;
            float3 cf = floor(p);
            int3 c = convert_int3(cf);
            int slot = vr_brick_slot(&g, c);
            if (slot < 0) {
#if VR_SKIP_EMPTY
                t = fmax(VR_EMPTY_EXIT(&g, o, inv_d, p), t + h);
#else
                t += h;
#endif
                h = vp->shadow_step;
                continue;
            }
            float3 f = p - cf;
            float sigma = vp->density_scale * vr_trilinear(data, slot, c, f);
            float3 a = 1.0f - exp(-sigma * ext.xyz * h);
            t += h;
            h = clamp(VR_MS_MFP / fmax(sigma, 1e-30f), vp->shadow_step, dt);
            /* first: S_1 through the phase towards o (ms_once's direction j) */
            int nch = first ? 3 * VR_CACHE_DIRS : 3, ch = first ? 3 * j : 0;
            VrCacheTap tap;
            vr_cache_tap_n(slot, c, f, nch, &tap);
            sk = (float3)(vr_cache_read(src, &tap, ch), vr_cache_read(src, &tap, ch + 1),
                          vr_cache_read(src, &tap, ch + 2));
            acc += T * a * sk;
            T *= 1.0f - a;
        }
        /* stopped at VR_MS_T_STOP: the rest of the ray as its last sample (the medium
           beyond is optically deep; docs/error_time.md) */
        if (T.x + T.y + T.z < VR_MS_T_STOP)
            acc += T * sk;
        sum += q.w * acc;
        mx += q.w * q.x * acc; my += q.w * q.y * acc; mz += q.w * q.z * acc;
    }
    sum *= alb.xyz;
    /* the order's first moment over the directions (L1: a1 = 3 mean(w L)), x, y, z rgb */
    __global float* t1 = total1 + 9 * at;
    float3 m[3] = { 3.0f * alb.xyz * mx, 3.0f * alb.xyz * my, 3.0f * alb.xyz * mz };
    for (int a = 0; a < 3; ++a) {
        float3 v = m[a] + (first ? (float3)(0.0f) : (float3)(t1[3 * a], t1[3 * a + 1], t1[3 * a + 2]));
        t1[3 * a] = v.x; t1[3 * a + 1] = v.y; t1[3 * a + 2] = v.z;
    }
    float3 tot = sum + (first ? (float3)(0.0f)
                              : (float3)(total[3 * at], total[3 * at + 1], total[3 * at + 2]));
    total[3 * at] = tot.x; total[3 * at + 1] = tot.y; total[3 * at + 2] = tot.z;
    dst[3 * at] = sum.x; dst[3 * at + 1] = sum.y; dst[3 * at + 2] = sum.z;
}

/* The cache's ms channels: total plus the geometric tail after the last order S_K
   (plus, with VR_ENV, the sky's channels: both are L1 harmonics read alike, so the
   marcher reads one set of 12 instead of two),
   S_K r / (1 - r) per channel, r the smaller of the last two orders' ratios
   (S_K / S_{K-1}, S_{K-1} / S_{K-2}; the ratio grows with the order where the light's
   shape is still settling, so the smaller is the safer), at most r_max. */
__kernel void ms_finish(__global const int4* bricks, __global const int2* todo,
                        __global const float* total,
                        __global const float* total1, __global const float* s2, __global const float* s1,
                        __global const float* s0, __global float* cache, int n,
                        float4 r_max)
{
    VR_BAKE_NODE(bricks, todo, n)
    int at = 3 * (b.w * VR_CACHE_NODES + node);
    float3 sk = (float3)(s0[at], s0[at + 1], s0[at + 2]);       /* S_K */
    float3 sk1 = (float3)(s1[at], s1[at + 1], s1[at + 2]);      /* S_{K-1} */
    float3 sk2 = (float3)(s2[at], s2[at + 1], s2[at + 2]);      /* S_{K-2} */
    float3 r = fmin(sk / fmax(sk1, 1e-30f), sk1 / fmax(sk2, 1e-30f));
    r = clamp(r, 0.0f, r_max.xyz);
    float3 tot = (float3)(total[at], total[at + 1], total[at + 2]) + sk * r / (1.0f - r);
    __global float* out = cache + (at / 3) * VR_CACHE_CH + VR_CACHE_MS;
    float v[12] = { tot.x, tot.y, tot.z };
    for (int i = 0; i < 9; ++i)
        v[3 + i] = total1[3 * at + i];
#if VR_ENV
    /* the sky's channels added in: the marcher reads the two as one (render_volume.cl) */
    __global const float* e = cache + (at / 3) * VR_CACHE_CH + VR_CACHE_LIGHTS;
    for (int i = 0; i < 12; ++i)
        v[i] += e[i];
#endif
    for (int i = 0; i < 12; ++i)
        out[i] = v[i];
}
#endif

/* The cache's channels as the marcher reads them at local points (tests). */
__kernel void probe_light_cache(__global const float4* pts, __global const int* table,
                                int4 dims, __global const float* cache, __global float* out)
{
    int i = get_global_id(0);
    VrGrid g = { dims, table, 0 };
    float3 p = pts[i].xyz, cf = floor(p);
    int3 c = convert_int3(cf);
    int slot = vr_brick_slot(&g, c);
    VrCacheTap t;
    vr_cache_tap(max(slot, 0), c, p - cf, &t);
    for (int ch = 0; ch < VR_CACHE_CH; ++ch)
        out[i * VR_CACHE_CH + ch] = slot < 0 ? -1.0f : vr_cache_read(cache, &t, ch);
}
