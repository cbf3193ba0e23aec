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

/* bricks: (bx, by, bz, slot) of each occupied brick; cache: its nodes' channels; envq:
   the environment's directions and cell integrals (light_cache.env_quadrature). */
__kernel void bake_light(__constant VolumeParams* vp, __constant Light* lights,
                         __global const int* table, __global const float* data,
                         __global const float4* envq, __global const int4* bricks,
                         __global float* cache, int n_bricks)
{
    int gid = get_global_id(0);
    if (gid >= n_bricks * VR_CACHE_NODES)
        return;
    int4 b = bricks[gid / VR_CACHE_NODES];
    int node = gid % VR_CACHE_NODES;
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
        float tau = vr_march_tau(&g, vp, p, dl, INFINITY, 0.5f, stop);
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
