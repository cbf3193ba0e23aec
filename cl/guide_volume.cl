/* Denoising guides of a volume (volrender/guides.py, docs/guide.md "Denoising"): per
   pixel, averaged over the camera's spp jittered sub-pixel rays (guides.SPP, so the
   guides come out noise-free: OIDN's clean_aux):
   - albedo: the medium's single-scattering albedo weighted by the ray's opacity, over
     what lies behind clamped to [0, 1]: (1 - T) albedo + T min(behind, 1), T the ray's
     transmittance through the box (a uniform opaque medium gives its albedo exactly);
   - normal: the world-space unit vector against the density gradient, -grad v / |grad v|
     (central differences of the trilinear density, one voxel apart), at the depth where
     the transmittance first falls to one half; a ray that never gets there takes it at
     its most visible sample (largest T x opacity), scaled by min(1, 2 (1 - T)), so thin
     wisps fade to 0, OIDN's "nothing here".
   The march is render_volume.cl's (the same jitter and empty-brick skipping), grey (the
   channels' mean extinction), without lights, its step VR_GUIDE_STEP x the render's (1) and
   stopped where T < VR_GUIDE_T_STOP (what is behind then moves the albedo by less than
   that: guides.py sets both, bench/guides_spp.py measures them). Inputs are the render
   kernel's, by name. Reads VR_SKIP_EMPTY, VR_SKIP_RUNS, VR_CHROMATIC, VR_ENV
   (features.VolumeFeatures). */
#include "common.h"
#include "structs.h"
#include "camera.h"
#include "volume.h"
#include "env.h"
#include "guide.h"

#ifndef VR_GUIDE_STEP
#define VR_GUIDE_STEP 1.0f
#endif
#ifndef VR_GUIDE_T_STOP
#define VR_GUIDE_T_STOP 1e-4f
#endif

inline float3 vr_guide_gradient(const VrGrid* g, float3 p)
{
    float3 e = (float3)(0.5f);
    return (float3)(vr_lookup(g, g->data, p + (float3)(e.x, 0, 0)) - vr_lookup(g, g->data, p - (float3)(e.x, 0, 0)),
                    vr_lookup(g, g->data, p + (float3)(0, e.y, 0)) - vr_lookup(g, g->data, p - (float3)(0, e.y, 0)),
                    vr_lookup(g, g->data, p + (float3)(0, 0, e.z)) - vr_lookup(g, g->data, p - (float3)(0, 0, e.z)));
}

__kernel void guide_volume(__constant Camera* cam, __constant VolumeParams* vp,
                           __global const int* table, __global const float* data,
                           __global const float4* env,
                           __global float4* albedo_out, __global float4* normal_out,
                           int y0, int s0, int s1)
{
    int x = get_global_id(0), y = y0 + get_global_id(1);
    if (x >= cam->width || y >= cam->height)
        return;
    uint pixel = (uint)(y * cam->width + x);
    VrGrid g = { vp->dims, table, data };
    float3 o = cam->origin.xyz;
    float dt = vp->step * VR_GUIDE_STEP;
    float ext = vr_spec_mean(VR_EXTINCTION(vp));
    float3 alb = vp->albedo_rgb.xyz;
    float4 a_sum = s0 > 0 ? albedo_out[pixel] : (float4)(0.0f);
    float4 n_sum = s0 > 0 ? normal_out[pixel] : (float4)(0.0f);
    for (int s = s0; s < s1; ++s) {
        float2 j = vr_pixel_jitter(cam, pixel, (uint)s);
        float3 dir = vr_camera_dir(cam, x, y, j.x, j.y);
        float3 d = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, dir);
        float3 inv_d = 1.0f / d;
        float2 tt = vr_ray_box(o, inv_d, (float3)(0.0f), vp->box_hi.xyz);
        float t0 = fmax(tt.x, 0.0f), t1 = tt.y;
        float u = vr_rand(cam->seed, pixel, (uint)s, 2u);
        float T = 1.0f, best = 0.0f;
        float3 p_at = (float3)(0.0f);
        int found = 0, crossed = 0;
        for (int k = 0; t0 < t1 && k < VR_MAX_RAY_SAMPLES; ++k) {
            float t = t0 + ((float)k + u) * dt;
            if (t >= t1 || T < VR_GUIDE_T_STOP)
                break;
            float3 p = o + t * d;
            float3 cf = floor(p);
            int3 c = convert_int3(cf);
            int slot = vr_brick_slot(&g, c);
            if (slot < 0) {
#if VR_SKIP_EMPTY
                float te = VR_EMPTY_EXIT(&g, o, inv_d, p);
                k = max(k, (int)ceil((te - t0) / dt - u) - 1);
#endif
                continue;
            }
            float sigma = vp->density_scale * ext * vr_trilinear(data, slot, c, p - cf);
            float a = 1.0f - vr_transmit(sigma * dt);
            if (!crossed && T * a > best) {
                best = T * a;
                p_at = p;
                found = 1;
            }
            T *= 1.0f - a;
            if (!crossed && T <= 0.5f) {
                crossed = 1;
                p_at = p;
                found = 1;
            }
        }
        float3 behind = clamp(vr_volume_behind(vp, env, dir), 0.0f, 1.0f);
        a_sum += (float4)((1.0f - T) * alb + T * behind, 1.0f - T);
        if (found) {
            float3 gl = vr_guide_gradient(&g, p_at);
            /* to world: the gradient takes the transpose of world -> local */
            float3 gw = gl.x * vp->world_to_local0.xyz + gl.y * vp->world_to_local1.xyz
                      + gl.z * vp->world_to_local2.xyz;
            float len = length(gw);
            float w = crossed ? 1.0f : fmin(1.0f, 2.0f * (1.0f - T));
            if (len > 0.0f)
                n_sum.xyz += -gw / len * w;
            n_sum.w += w;
        }
    }
    guide_store(albedo_out, normal_out, pixel, a_sum, n_sum, s1, cam->spp);
}
