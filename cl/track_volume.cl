/* Unbiased tracking estimator of the single-scattering estimand of render_volume.cl
   (DESIGN.md): L = int T(0,t) sigma_s(t) sum_lights p E T_light dt
                  + int T(0,t) e(t) C dt + T(0,tmax) L_background,   alpha = 1 - T(0,tmax).
   One work-item per pixel, same arguments as render_volume plus `majorant`.

   Tentative collisions are a Poisson process of rate mu (the brick's majorant) along
   the ray, walked brick by brick with a DDA over the 8^3 bricks (empty bricks have
   mu = 0 and cost one table read). On those points, per sample:
   - scattering: delta (Woodcock) tracking. A point is a real collision with
     probability sigma_t/mu; the first real collision is distributed as
     T(0,t) sigma_t(t) dt, so albedo * (in-scattered light there) estimates the
     scattering integral. One shadow ray per light at that collision.
   - transmittance, background and emission: ratio tracking over the same points.
     W(t) = prod (1 - sigma_t/mu) over the points before t has E[W(t)] = T(0,t), so
     W(tmax) estimates T (alpha = 1 - W, background W * L_bg) and sum W e/mu over the
     points estimates int T e dt. W is Russian-rouletted below VR_RR_W (unbiased).
   - shadow rays: ratio tracking to the light (or the box), also rouletted.
   - stiff media (majorant optical depth above ~3e4 per voxel): intervals are taken
     whole, with the density linear across each (VR_BULK_* below).
   mu = density_scale * brick maximum (host side, volrender/render.py
   track_majorants), raised to 1/voxel in bricks that emit, so emission in bricks
   of zero density is still sampled.

   Variance: the scattering term is a collision estimator: per sample it is either 0
   or albedo * S(x), so its relative noise is large where alpha is small (thin media)
   and where S varies along the ray; the transmittance term is a product of factors in
   [0, 1] whose noise grows with the majorant's looseness (a tight majorant makes it a
   0/1 track-length estimate, variance T (1 - T)); roulette adds a little. Noise falls
   as 1/sqrt(spp). The cost per sample is ~ the majorant optical depth along the
   ray up to the collision plus that of one shadow ray per light: no step size.
   bench/error.py measures both against marching (docs/error_time.md).

   Random numbers: dims 0, 1 pixel jitter; 2.. the primary walk; (light + 1) << 24 ..
   that light's shadow walk. Flags as render_volume.cl (VR_SKIP_EMPTY is implied). */
#if !defined(VR_N_SUNS) || !defined(VR_N_POINTS) || !defined(VR_SHADOWS) || \
    !defined(VR_PHASE_MIXED) || !defined(VR_SKIP_EMPTY) || !defined(VR_EMISSION) || \
    !defined(VR_DEPTH)
#error "track_volume.cl: a VR_* feature flag is missing (see volrender/features.py)"
#endif

#include "common.h"
#include "structs.h"
#include "camera.h"
#include "phase.h"
#include "volume.h"
#include "lights.h"
#include "track.h"

__kernel void track_volume(__constant Camera* cam, __constant VolumeParams* vp,
                           __constant Light* lights,
                           __global const int* table, __global const float* data,
                           __global const float* emission, __global const float* majorant,
                           __global float4* out, __global float* depth, int y0, int s0,
                           int s1)
{
    int x = get_global_id(0), y = y0 + get_global_id(1);
    if (x >= cam->width || y >= cam->height)
        return;
    uint pixel = (uint)(y * cam->width + x);
    VrGrid g = { vp->dims, table, data };
    float3 o = cam->origin.xyz;

    /* samples s0 .. s1-1 of cam->spp: a launch continues the sums of the one before */
    float3 acc = (float3)(0.0f);
    float acc_alpha = 0.0f, acc_depth = 0.0f, acc_depth_w = 0.0f;
    if (s0 > 0) {
        acc = out[pixel].xyz;
        acc_alpha = out[pixel].w;
#if VR_DEPTH
        acc_depth = depth[2 * pixel];
        acc_depth_w = depth[2 * pixel + 1];
#endif
    }
    for (int s = s0; s < s1; ++s) {
        float2 j = vr_pixel_jitter(cam, pixel, (uint)s);
        float3 dir = vr_camera_dir(cam, x, y, j.x, j.y);
        float3 d = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, dir);
        float2 tt = vr_ray_box(o, 1.0f / d, (float3)(0.0f), vp->box_hi.xyz);
        float t0 = fmax(tt.x, 0.0f), t1 = tt.y;
        float3 L = (float3)(0.0f);
        float w = 1.0f;                  /* ratio-tracking weight: E[w] = T(0, t) */
        if (t1 > t0) {
            uint dim = 2u;
            /* delta tracking is needed only for the in-scattered light (and depth) */
            int collided = !(VR_N_SUNS + VR_N_POINTS > 0 || VR_DEPTH);
            VrTrack k;
            vr_track_init(&k, &g, majorant, o, d, t0, t1);
            while ((!collided || w > 0.0f)
                   && vr_track_next(&k, &g, majorant, VR_EMISSION ? emission : 0,
                                    cam->seed, pixel, (uint)s, &dim)) {
                float tc = k.t;
                float3 p = o + tc * d;
                float3 f;
                int3 c = vr_track_cell(&k, p, &f);
                float sigma = vp->density_scale * vr_trilinear(data, k.slot, c, f);
                /* ratio: the chance that this point is a real collision, and what the
                   ratio weight loses; len: the emission estimator's length (1/mu at a
                   point; over a bulk interval, the integral of T within it) */
                float ratio, len, sigma1 = 0.0f;
                if (k.bulk > 0.0f) {
                    sigma1 = vr_track_sigma(&k, &g, vp->density_scale, k.t + k.bulk);
                    float tau = 0.5f * (sigma + sigma1) * k.bulk;
                    ratio = 1.0f - vr_transmit(tau);
                    len = tau > 1e-4f ? ratio * (k.bulk / tau) : k.bulk;
                } else {
                    ratio = fmin(sigma / k.mu, 1.0f);
                    len = 1.0f / k.mu;
                }
#if VR_EMISSION
                if (w > 0.0f) {
                    float e = vr_trilinear(emission, k.slot, c, f);
                    L += w * e * len * vp->emission_color.xyz;
                }
#else
                (void)len;
#endif
                float u;
                if (!collided && (u = vr_rand(cam->seed, pixel, (uint)s, dim++)) < ratio) {
                    collided = 1;
                    if (k.bulk > 0.0f) {         /* where in the interval */
                        tc = k.t + vr_bulk_hit(sigma, sigma1, k.bulk, -log(1.0f - u));
                        p = o + tc * d;
                    }
#if VR_N_SUNS + VR_N_POINTS > 0
                    L += vp->albedo * vr_track_inscatter(&g, majorant, vp, lights, p, -dir,
                                                         cam->seed, pixel, (uint)s);
#endif
#if VR_DEPTH
                    acc_depth += tc;
                    acc_depth_w += 1.0f;
#endif
                }
                if (w > 0.0f) {
                    w *= 1.0f - ratio;
                    w = vr_roulette(w, vr_rand(cam->seed, pixel, (uint)s, dim++));
                }
            }
        }
        L += w * vp->background.xyz;
        acc += vr_safe_sample(L);
        acc_alpha += 1.0f - w;
    }
#if VR_DEPTH
    depth[2 * pixel + 1] = acc_depth_w;
#endif
    if (s1 < cam->spp) {               /* more samples follow in a later launch */
        out[pixel] = (float4)(acc, acc_alpha);
#if VR_DEPTH
        depth[2 * pixel] = acc_depth;
#endif
        return;
    }
    float inv = 1.0f / (float)cam->spp;
    out[pixel] = (float4)(acc * inv, acc_alpha * inv);
#if VR_DEPTH
    depth[2 * pixel] = acc_depth_w > 0.0f ? acc_depth / acc_depth_w : INFINITY;
#endif
}
