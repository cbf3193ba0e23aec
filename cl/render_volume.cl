/* Ray-marching volume renderer, one work-item per pixel: single scattering (DESIGN.md
   estimand) with VR_MS_OCTAVES 1, or its multiple-scattering octaves (march.h); lit by
   the lights and the environment (VR_ENV 1 uniform, 2 a map: one direction per step).
   Flags: VR_N_SUNS, VR_N_POINTS, VR_SHADOWS, VR_PHASE_MIXED, VR_SKIP_EMPTY,
          VR_EMISSION, VR_DEPTH, VR_TILED, VR_TILE_W, VR_TILE_H, VR_TILE_CAP,
          VR_CHROMATIC, VR_ENV, VR_MS_OCTAVES, VR_TEMPERATURE, VR_LIGHT_CACHE,
          VR_MS_CACHE (scattering orders 2+ read from the light cache).

   Dispatch (volrender/dispatch.py):
   fragment (VR_TILED 0): independent work-items, any local size, no local memory.
   tiled    (VR_TILED 1): a work-group of VR_TILE_W x VR_TILE_H work-items owns one screen
            tile. With VR_SKIP_EMPTY it first culls the occupied bricks against the tile's
            frustum into a local list (vr_tile_cull); each ray then marches only between
            the first entry into and the last exit from the listed bricks it crosses, on
            the same sample lattice t0 + (k + u) dt as the fragment variant, so both give
            the same image. A list over VR_TILE_CAP entries makes the whole tile march the
            full box. Without VR_SKIP_EMPTY (the plain-marching reference) nothing is
            culled. */
#if !defined(VR_N_SUNS) || !defined(VR_N_POINTS) || !defined(VR_SHADOWS) || \
    !defined(VR_PHASE_MIXED) || !defined(VR_SKIP_EMPTY) || !defined(VR_SKIP_RUNS) || \
    !defined(VR_EMISSION) || \
    !defined(VR_DEPTH) || !defined(VR_TILED) || !defined(VR_TILE_W) || \
    !defined(VR_TILE_H) || !defined(VR_TILE_CAP) || !defined(VR_CHROMATIC) || \
    !defined(VR_ENV) || !defined(VR_MS_OCTAVES) || !defined(VR_TEMPERATURE) || \
    !defined(VR_LIGHT_CACHE) || !defined(VR_MS_CACHE)
#error "render_volume.cl: a VR_* feature flag is missing (see volrender/features.py)"
#endif

#include "common.h"
#include "structs.h"
#include "camera.h"
#include "phase.h"
#include "volume.h"
#include "volume_tile.h"
#include "lights.h"
#include "env.h"
#include "march.h"
#include "light_cache.h"
#include "accum.h"

#define VR_T_CUTOFF 1e-5f          /* stop marching once the view transmittance is below */

/* occ: the occupied bricks' coordinates (n_occ of them), read only by tiled culling.
   temperature: the temperature grid (VR_TEMPERATURE), bb: the blackbody table; env, cdf:
   the environment map and its sampling CDFs (VR_ENV 2); light_cache: the baked light
   (VR_LIGHT_CACHE > 0, light_cache.h), read instead of the shadow marches. */
#if VR_TILED
__attribute__((reqd_work_group_size(VR_TILE_W, VR_TILE_H, 1)))
#endif
__kernel void render_volume(__constant Camera* cam, __constant VolumeParams* vp,
                            __constant Light* lights,
                            __global const int* table, __global const float* data,
                            __global const float* emission,
                            __global const float* temperature, __global const float4* bb,
                            __global const float4* env, __global const float* cdf,
                            __global float4* out, __global float* depth,
                            __global const float* light_cache,
                            __global const int4* occ, int n_occ, int y0, int s0, int s1)
{
    int x = get_global_id(0), y = y0 + get_global_id(1);
    float3 o = cam->origin.xyz;
#if VR_CULL
    __local float4 list[VR_TILE_CAP];
    __local volatile int n_list;
    /* bricks are inflated by pad voxels: far above the rounding of local points and
       ray-box parameters, so no sample in an occupied brick falls outside its box */
    float3 ao = fabs(o);
    float pad = 1.0f / 64.0f + 1e-5f * (fmax(fmax(ao.x, ao.y), ao.z) +
                                        fmax(fmax(vp->box_hi.x, vp->box_hi.y), vp->box_hi.z));
    vr_tile_cull(cam, vp, occ, n_occ, y0, pad, list, &n_list);
    int n_listed = n_list;
    int overflow = n_listed > VR_TILE_CAP;     /* uniform over the group */
#endif
    /* work-items past the image edge only helped the group cull */
    if (x >= cam->width || y >= cam->height)
        return;
    uint pixel = (uint)(y * cam->width + x);
    VrGrid g = { vp->dims, table, data };
    float dt = vp->step;

    /* samples s0 .. s1-1 of cam->spp: a launch continues the sums of the one before */
    VrAccum acc = vr_accum_load(out, depth, pixel, s0);
    for (int s = s0; s < s1; ++s) {
        float2 j = vr_pixel_jitter(cam, pixel, (uint)s);
        float3 dir = vr_camera_dir(cam, x, y, j.x, j.y);    /* world */
        float3 d = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, dir);
        float3 inv_d = 1.0f / d;
        float2 tt = vr_ray_box(o, inv_d, (float3)(0.0f), vp->box_hi.xyz);
        float t0 = fmax(tt.x, 0.0f), t1 = tt.y;
        float u = vr_rand(cam->seed, pixel, (uint)s, 2u);

        /* samples k = k0, k0 + 1, ... while t < t_end: the full box, or (tiled) the
           span of the listed bricks this ray crosses, widened by one sample in front */
        int k0 = 0;
        float t_end = t1;
#if VR_CULL
        if (!overflow) {
            float2 span = vr_listed_span(list, n_listed, o, inv_d, VR_BRICK + 2.0f * pad);
            t_end = span.x <= span.y ? fmin(t1, span.y) : -INFINITY;
            float kf = floor((span.x - t0) / dt - u) - 1.0f;
            k0 = (int)fmin(fmax(kf, 0.0f), 1e9f);
        }
#endif

        /* VrSpec: one float for grey media, float3 per channel (VR_CHROMATIC, volume.h) */
        float3 L = (float3)(0.0f);
        VrSpec T = 1.0f;
        float dsum = 0.0f, dw = 0.0f;
        for (int k = k0; t0 < t_end && k < VR_MAX_RAY_SAMPLES; ++k) {
            float t = t0 + ((float)k + u) * dt;
            if (t >= t_end || vr_spec_max(T) < VR_T_CUTOFF)
                break;
            float3 p = o + t * d;
            float3 cf = floor(p);
            int3 c = convert_int3(cf);
            int slot = vr_brick_slot(&g, c);
            if (slot < 0) {            /* empty brick: density and emission are zero */
#if VR_SKIP_EMPTY
                float te = VR_EMPTY_EXIT(&g, o, inv_d, p);
                k = max(k, (int)ceil((te - t0) / dt - u) - 1);
#endif
                continue;
            }
            float3 f = p - cf;
            float sigma = vp->density_scale * vr_trilinear(data, slot, c, f);
            VrSpec sigma_t = sigma * VR_EXTINCTION(vp);
            VrSpec tau = sigma_t * dt;
            VrSpec a = 1.0f - vr_spec_transmit(tau);      /* opacity of this step */
#if VR_EMISSION
            float e = vr_trilinear(emission, slot, c, f);
            if (e > 0.0f) {
                /* integral of T(s) over the step, per unit emission: (1-e^-tau)/sigma_t */
                VrSpec len = select(a / sigma_t, (VrSpec)(dt), tau <= 1e-4f);
                L += T * e * len * vr_emission_color(vp, temperature, bb, slot, c, f);
            }
#endif
            if (vr_spec_max(a) > 0.0f) {
#if VR_N_SUNS + VR_N_POINTS > 0 || VR_ENV
                float3 S = (float3)(0.0f);
#if VR_LIGHT_CACHE
                VrCacheTap tap;
                vr_cache_tap(slot, c, f, &tap);
#if VR_N_SUNS + VR_N_POINTS > 0
                S = vr_cached_inscatter(&g, vp, lights, light_cache, &tap, p, -dir, cam->seed, pixel,
                                        (uint)s, (uint)k);
#endif
#if VR_MS_CACHE             /* the orders with the sky's light added (bake_light.cl ms_finish) */
                S += vr_cached_ms(vp, light_cache, &tap, dir);
#elif VR_ENV
                S += vr_cached_env(vp, light_cache, &tap, dir);
#endif
#else
#if VR_N_SUNS + VR_N_POINTS > 0
                S = vr_inscatter(&g, vp, lights, p, -dir, cam->seed, pixel, (uint)s, (uint)k);
#endif
#if VR_ENV
                S += vr_env_inscatter(&g, vp, env, cdf, p, dir, cam->seed, pixel, (uint)s, (uint)k);
#endif
#endif
                L += T * a * VR_ALBEDO(vp) * S;
#endif
#if VR_DEPTH
                float w = vr_spec_mean(T * a);
                dsum += w * t;
                dw += w;
#endif
                T *= 1.0f - a;
            }
        }
        L += T * vr_volume_behind(vp, env, dir);
        acc.rgb += vr_safe_sample(L);
        acc.alpha += 1.0f - vr_spec_mean(T);
        acc.depth += dsum;
        acc.depth_w += dw;
    }
    vr_accum_store(out, depth, pixel, acc, s1, cam->spp);
}
