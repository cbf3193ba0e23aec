/* Path-traced volumes: multiple scattering, unbiased (the reference), on the brick
   majorants (track.h). One work-item per pixel; `--estimator track` is this kernel at
   max_depth 1, the single-scattering estimand of render_volume.cl (DESIGN.md).

   Per sample, a path of segments. Each segment is one walk over tentative collisions
   (a Poisson process of rate mu, the brick's majorant, crossed brick by brick) that
   serves two estimators at once:
   - ratio tracking to the box exit: the weight w = prod (1 - sigma_t/mu) has
     E[w] = T, so w times what lies beyond (the background and the visible environment
     for the camera segment; the environment for a scattered one) and sum w e C/mu
     (the emission along the segment) are unbiased;
   - delta tracking: the first real collision (probability sigma_t/mu at each point) is
     distributed as T sigma_t dt, so it is the next scattering vertex, carrying the
     throughput factor sigma_s/sigma_t = albedo (per channel: track.h).
   At vertex k (1 <= k <= max_depth), with throughput beta:
   - next-event estimation toward every light: phase x radiance x a ratio-tracked
     shadow ray;
   - toward the environment: a uniform one is gathered by the continuation's own ratio
     walk (phase sampling: phase/pdf = 1); a map also by a direction drawn from the map
     with a ratio-tracked shadow ray, the two combined by multiple importance sampling
     (power heuristic);
   - the continuation: a direction drawn from the phase (phase.h), then the next
     segment; its ratio walk collects the environment (MIS-weighted for a map) and,
     for k < max_depth, the emission it crosses. At k = max_depth the path ends (for an
     environment, the last segment walks only to collect it). So light from the lights
     and the environment is scattered 1..max_depth times, emitted light 0..max_depth-1
     times (emission has no next-event estimation: the paths find it).
   - Russian roulette from vertex rr_depth + 1 on: the path survives with probability
     q = min(max_c beta_c, 0.95) and beta is divided by q.
   The camera segment also gives alpha = 1 - mean_c w and the depth (first collision).

   Random numbers: dims 0 and 1 of sample 0 place the sub-pixel samples
   (vr_pixel_jitter); everything else draws from one running counter per sample
   starting at 2 (`dim`): each draw takes the next dimension, so no two draws of a
   sample share one, whatever the bounces, lights and walk lengths.

   Flags: VR_N_SUNS, VR_N_POINTS, VR_SHADOWS, VR_PHASE_MIXED, VR_EMISSION, VR_DEPTH,
   VR_CHROMATIC, VR_ENV, VR_TEMPERATURE (VR_SKIP_EMPTY is implied: empty bricks have
   mu = 0). */
#if !defined(VR_N_SUNS) || !defined(VR_N_POINTS) || !defined(VR_SHADOWS) || \
    !defined(VR_PHASE_MIXED) || !defined(VR_EMISSION) || !defined(VR_DEPTH) || \
    !defined(VR_CHROMATIC) || !defined(VR_ENV) || !defined(VR_TEMPERATURE)
#error "path_volume.cl: a VR_* feature flag is missing (see volrender/features.py)"
#endif

#include "common.h"
#include "structs.h"
#include "camera.h"
#include "phase.h"
#include "volume.h"
#include "lights.h"
#include "env.h"
#include "track.h"
#include "accum.h"

#define VR_RR_MAX 0.95f             /* survival probability cap of the path roulette */

__kernel void path_volume(__constant Camera* cam, __constant VolumeParams* vp,
                          __constant Light* lights,
                          __global const int* table, __global const float* data,
                          __global const float* emission,
                          __global const float* temperature, __global const float4* bb,
                          __global const float4* env, __global const float* cdf,
                          __global const float* majorant,
                          __global float4* out, __global float* depth, int y0, int s0,
                          int s1)
{
    int x = get_global_id(0), y = y0 + get_global_id(1);
    if (x >= cam->width || y >= cam->height)
        return;
    uint pixel = (uint)(y * cam->width + x);
    uint seed = cam->seed;
    VrGrid g = { vp->dims, table, data };
    float3 o = cam->origin.xyz;
    /* what a scattering vertex can gather (else the camera segment needs no delta walk) */
#if VR_N_SUNS + VR_N_POINTS > 0 || VR_ENV || VR_DEPTH
    int scatters = 1;
#else
    int scatters = VR_EMISSION ? vp->max_depth > 1 : 0;
#endif
    (void)cdf;

    /* samples s0 .. s1-1 of cam->spp: a launch continues the sums of the one before */
    VrAccum acc = vr_accum_load(out, depth, pixel, s0);
    for (int s = s0; s < s1; ++s) {
        uint us = (uint)s, dim = 2u;
        float2 j = vr_pixel_jitter(cam, pixel, us);
        float3 dir = vr_camera_dir(cam, x, y, j.x, j.y);
        float3 d = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, dir);
        float2 tt = vr_ray_box(o, 1.0f / d, (float3)(0.0f), vp->box_hi.xyz);
        VrSegment sg;
        vr_segment(&g, majorant, emission, temperature, bb, vp, o, d, fmax(tt.x, 0.0f), tt.y,
                   1, 1, scatters, 1.0f, seed, pixel, us, &dim, &sg);
        float3 L = sg.le;
        L += sg.w * vr_volume_behind(vp, env, dir);
        acc.alpha += 1.0f - vr_spec_mean(sg.w);
#if VR_DEPTH
        if (sg.hit) {
            acc.depth += sg.tc;
            acc.depth_w += 1.0f;
        }
#endif
        VrSpec beta = sg.wt;
        float3 xp = sg.x;           /* the vertex, local */
        float3 din = dir;           /* the world direction the path arrived along */
        for (int k = 1; sg.hit; ++k) {
            if (k > vp->rr_depth) {
                float q = fmin(vr_spec_max(beta), VR_RR_MAX);
                if (!(vr_rand(seed, pixel, us, dim++) < q))
                    break;
                beta /= q;
            }
            float3 Lk = (float3)(0.0f);
#if VR_N_SUNS + VR_N_POINTS > 0
            for (int i = 0; i < VR_N_SUNS + VR_N_POINTS; ++i) {
                float3 dl, prop;
                float tmax, atten;
                if (!vr_light_at(vp, lights, i, xp, &dl, &tmax, &prop, &atten))
                    continue;
#if VR_SHADOWS
                VrSpec tr = vr_shadow_ratio(&g, majorant, vp, xp, dl, tmax, seed, pixel, us, &dim);
#else
                float tr = 1.0f;      /* --no-shadows: the lights only; the environment is
                                         gathered by walks, so it stays attenuated */
#endif
                Lk += vr_phase(dot(prop, -din), vp->phase) * tr * lights[i].radiance.xyz / atten;
            }
#endif
#if VR_ENV == 2
            {   /* the map, by its own distribution */
                float pe;
                float u0 = vr_rand(seed, pixel, us, dim++), u1 = vr_rand(seed, pixel, us, dim++);
                float3 we = vr_env_sample(cdf, vp->env_width, vp->env_height, u0, u1, &pe);
                if (pe > 0.0f) {
                    float ph = vr_phase(dot(we, din), vp->phase);
                    float3 dl = vr_mat3(vp->world_to_local0, vp->world_to_local1,
                                        vp->world_to_local2, we);
                    VrSpec tr = vr_shadow_ratio(&g, majorant, vp, xp, dl, INFINITY, seed, pixel,
                                                us, &dim);
                    float r = ph / pe;              /* power heuristic, overflow-safe */
                    Lk += (r / (1.0f + r * r)) * tr * vr_env_radiance(vp, env, we);
                }
            }
#endif
            int last = k >= vp->max_depth;
            int walk = VR_ENV ? 1 : !last;       /* the last walk only gathers the environment */
            if (walk) {
                float u0 = vr_rand(seed, pixel, us, dim++), u1 = vr_rand(seed, pixel, us, dim++);
                float u2 = vr_rand(seed, pixel, us, dim++);
                float3 wn = vr_phase_sample(vp->phase, din, u0, u1, u2);
                float3 dl = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, wn);
                float2 tb = vr_ray_box(xp, 1.0f / dl, (float3)(0.0f), vp->box_hi.xyz);
                VrSpec b = beta;
                vr_segment(&g, majorant, emission, temperature, bb, vp, xp, dl, 0.0f, tb.y,
                           VR_ENV || VR_EMISSION ? 1 : 0, !last, !last, beta, seed, pixel, us,
                           &dim, &sg);
                Lk += sg.le;
#if VR_ENV
                float mis = 1.0f;
#if VR_ENV == 2
                float ph = vr_phase(dot(wn, din), vp->phase);
                float pe = vr_env_pdf(cdf, vp->env_width, vp->env_height, wn);
                float r = pe / ph;
                mis = 1.0f / (1.0f + r * r);
#endif
                Lk += mis * sg.w * vr_env_radiance(vp, env, wn);
#endif
                L += b * Lk;
                if (last)
                    break;
                beta = b * sg.wt;
                xp = sg.x;
                din = wn;
            } else {
                L += beta * Lk;
                break;
            }
        }
        acc.rgb += vr_safe_sample(L);
    }
    vr_accum_store(out, depth, pixel, acc, s1, cam->spp);
}
