/* Single-scattering volume renderer (DESIGN.md estimand), one work-item per pixel.
   Flags: VR_N_SUNS, VR_N_POINTS, VR_SHADOWS, VR_PHASE_MIXED, VR_SKIP_EMPTY,
          VR_EMISSION, VR_DEPTH. */
#if !defined(VR_N_SUNS) || !defined(VR_N_POINTS) || !defined(VR_SHADOWS) || \
    !defined(VR_PHASE_MIXED) || !defined(VR_SKIP_EMPTY) || !defined(VR_EMISSION) || \
    !defined(VR_DEPTH)
#error "render_volume.cl: a VR_* feature flag is missing (see volrender/features.py)"
#endif

#include "common.h"
#include "structs.h"
#include "camera.h"
#include "phase.h"
#include "volume.h"

#define VR_T_CUTOFF 1e-5f          /* stop marching once the view transmittance is below */
#define VR_SHADOW_TAU_STOP 25.0f   /* exp(-25) ~ 1e-11: light fully blocked */
#define VR_MAX_LIGHTS 64u          /* lights.MAX_LIGHTS */

#if VR_N_SUNS + VR_N_POINTS > 0
/* Transmittance from local point p towards light `dl` (local per world unit) over
   world length tmax, clipped to the volume box. */
inline float vr_shadow(const VrGrid* g, __constant VolumeParams* vp, float3 p, float3 dl,
                       float tmax, float u)
{
#if VR_SHADOWS
    float2 tt = vr_ray_box(p, 1.0f / dl, (float3)(0.0f), vp->box_hi.xyz);
    float t1 = fmin(tt.y, tmax);
    if (t1 <= 0.0f)
        return 1.0f;
    float tau = vr_optical_depth(g, p, dl, 0.0f, t1, vp->shadow_step, u, vp->density_scale,
                                 VR_SHADOW_TAU_STOP);
    return vr_transmit(tau);
#else
    return 1.0f;
#endif
}

/* Sum over lights of phase * irradiance * light transmittance at local point p.
   `wo` is the world direction towards the camera. */
inline float3 vr_inscatter(const VrGrid* g, __constant VolumeParams* vp,
                           __constant Light* lights, float3 p, float3 wo,
                           uint seed, uint pixel, uint s, uint step)
{
    float3 sum = (float3)(0.0f);
    /* shadow jitter keyed by (step, light index): adding a light leaves the others' */
    uint dim = 16u + step * VR_MAX_LIGHTS;
#if VR_N_SUNS > 0
    for (int i = 0; i < VR_N_SUNS; ++i) {
        float3 d = lights[i].vec.xyz;                       /* propagation, world, unit */
        float3 dl = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, -d);
        float tr = vr_shadow(g, vp, p, dl, INFINITY, vr_rand(seed, pixel, s, dim++));
        sum += vr_phase(dot(d, wo), vp->phase) * tr * lights[i].radiance.xyz;
    }
#endif
#if VR_N_POINTS > 0
    for (int i = VR_N_SUNS; i < VR_N_SUNS + VR_N_POINTS; ++i) {
        float3 to_l = lights[i].vec.xyz - p;                /* local */
        float3 w = vr_mat3(vp->local_to_world0, vp->local_to_world1, vp->local_to_world2, to_l);
        float r2 = dot(w, w);
        float r = sqrt(r2);
        if (r <= 0.0f)
            continue;
        float tr = vr_shadow(g, vp, p, to_l / r, r, vr_rand(seed, pixel, s, dim++));
        float3 prop = -w / r;                               /* from the light through p */
        sum += vr_phase(dot(prop, wo), vp->phase) * tr * lights[i].radiance.xyz
               / fmax(r2, vp->point_r2_min);
    }
#endif
    return sum;
}
#endif

__kernel void render_volume(__constant Camera* cam, __constant VolumeParams* vp,
                            __constant Light* lights,
                            __global const int* table, __global const float* data,
                            __global const float* emission,
                            __global float4* out, __global float* depth, int y0)
{
    int x = get_global_id(0), y = y0 + get_global_id(1);
    if (x >= cam->width || y >= cam->height)
        return;
    uint pixel = (uint)(y * cam->width + x);
    VrGrid g = { vp->dims, table, data };
    float3 o = cam->origin.xyz;
    float dt = vp->step;

    float3 acc = (float3)(0.0f);
    float acc_alpha = 0.0f, acc_depth = 0.0f, acc_depth_w = 0.0f;
    for (int s = 0; s < cam->spp; ++s) {
        float2 j = vr_pixel_jitter(cam, pixel, (uint)s);
        float3 dir = vr_camera_dir(cam, x, y, j.x, j.y);    /* world */
        float3 d = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, dir);
        float3 inv_d = 1.0f / d;
        float2 tt = vr_ray_box(o, inv_d, (float3)(0.0f), vp->box_hi.xyz);
        float t0 = fmax(tt.x, 0.0f), t1 = tt.y;
        float u = vr_rand(cam->seed, pixel, (uint)s, 2u);

        float3 L = (float3)(0.0f);
        float T = 1.0f, dsum = 0.0f, dw = 0.0f;
        for (int k = 0; t0 < t1; ++k) {
            float t = t0 + ((float)k + u) * dt;
            if (t >= t1 || T < VR_T_CUTOFF)
                break;
            float3 p = o + t * d;
            float3 cf = floor(p);
            int3 c = convert_int3(cf);
            int slot = vr_brick_slot(&g, c);
            if (slot < 0) {            /* empty brick: density and emission are zero */
#if VR_SKIP_EMPTY
                float te = vr_brick_exit(o, inv_d, p);
                k = max(k, (int)ceil((te - t0) / dt - u) - 1);
#endif
                continue;
            }
            float3 f = p - cf;
            float sigma_t = vp->density_scale * vr_trilinear(data, slot, c, f);
            float tau = sigma_t * dt;
            float a = 1.0f - vr_transmit(tau);              /* opacity of this step */
#if VR_EMISSION
            float e = vr_trilinear(emission, slot, c, f);
            if (e > 0.0f) {
                /* integral of T(s) over the step, per unit emission: (1-e^-tau)/sigma_t */
                float len = tau > 1e-4f ? a / sigma_t : dt;
                L += T * e * len * vp->emission_color.xyz;
            }
#endif
            if (a > 0.0f) {
#if VR_N_SUNS + VR_N_POINTS > 0
                float3 S = vr_inscatter(&g, vp, lights, p, -dir, cam->seed, pixel, (uint)s, (uint)k);
                L += T * a * vp->albedo * S;
#endif
#if VR_DEPTH
                dsum += T * a * t;
                dw += T * a;
#endif
                T *= 1.0f - a;
            }
        }
        L += T * vp->background.xyz;
        acc += L;
        acc_alpha += 1.0f - T;
        acc_depth += dsum;
        acc_depth_w += dw;
    }
    float inv = 1.0f / (float)cam->spp;
    out[pixel] = (float4)(acc * inv, acc_alpha * inv);
#if VR_DEPTH
    depth[pixel] = acc_depth_w > 0.0f ? acc_depth / acc_depth_w : INFINITY;
#endif
}
