/* Denoising guides of molten glass (volrender/guides.py, docs/guide.md "Denoising"): per
   pixel, averaged over the camera's spp jittered sub-pixel rays (guides.SPP: one, the
   pixel's centre; guide_glass_list then takes guides.EDGE_SPP rays on the pixels listed,
   the one-ray guide's edges), noise-free (OIDN's clean_aux):
   - albedo: the first surface's tint, the glass colour (per-point colours blended as the
     field blends them, VR_COLORS) scaled to a brightest channel of 1; where the ray meets
     no glass, the environment it sees, clamped to [0, 1];
   - normal: the first surface's outward unit normal (the field's gradient), world axes
     (the render frame only shifts them); 0 where the ray meets no glass (OIDN's "no
     surface").
   The trace is render_glass.cl's first segment (shade_glass.h, glass_trace). Inputs are the
   render kernel's, by name. Flags: those of render_glass.cl that sdf.h and glass.h read. */
#include "common.h"
#include "structs.h"
#include "camera.h"
#include "sdf.h"
#include "glass.h"
#include "guide.h"

/* the sums of samples [s0, s1) of pixel (x, y) added to a_sum, n_sum */
static void guide_glass_samples(__constant Camera* cam, __constant GlassParams* gp,
                                const SdfScene* sc, __global const float4* env, int x, int y,
                                int s0, int s1, float4* a_sum, float4* n_sum)
{
    uint pixel = (uint)(y * cam->width + x);
    float3 o = cam->origin.xyz;
    float side = sdf_eval(sc, o).f < 0.0f ? -1.0f : 1.0f;
    for (int s = s0; s < s1; ++s) {
        float2 j = vr_pixel_jitter(cam, pixel, (uint)s);
        float3 d = vr_camera_dir(cam, x, y, j.x, j.y);
        float2 tt = vr_ray_box(o, 1.0f / d, gp->box_lo.xyz, gp->box_hi.xyz);
        float t0 = fmax(tt.x, 0.0f), t1 = tt.y, t = 0.0f;
        SdfSample h;
        int hit = t0 <= t1 && sdf_trace(sc, o, d, t0, t1, side, gp->epsilon,
                                        1e-2f * gp->scale, gp->max_steps, gp->relax, &t, &h);
        if (hit) {
            float3 col = gp->color.xyz;
#if VR_COLORS
            col = h.color;
#endif
            float top = fmax(fmax(col.x, col.y), col.z);
            a_sum->xyz += top > 0.0f ? clamp(col / top, 0.0f, 1.0f) : (float3)(0.0f);
            a_sum->w += 1.0f;
            float gl = length(h.grad);
            if (gl > 0.0f)
                n_sum->xyz += h.grad / gl;
            n_sum->w += 1.0f;
        } else {
#if VR_ENV_MAP
            float3 sky = glass_env_map(env, gp->env_width, gp->env_height, d);
#else
            float3 sky = glass_sky(d);
#endif
            a_sum->xyz += clamp(sky, 0.0f, 1.0f);
        }
    }
}

__kernel void guide_glass(__constant Camera* cam, __constant GlassParams* gp,
                          __global const float4* restrict spheres,
                          __global const TreeNode* restrict nodes, __global const float4* env,
                          __global const float4* restrict colors,
                          __global const int2* restrict bricks,
                          __global const int2* restrict cells, __global const int4* restrict lists,
                          __global const int2* restrict entries,
                          __global float4* albedo_out, __global float4* normal_out,
                          int y0, int s0, int s1)
{
    int x = get_global_id(0), y = y0 + get_global_id(1);
    if (x >= cam->width || y >= cam->height)
        return;
    uint pixel = (uint)(y * cam->width + x);
    SdfScene sc = sdf_scene(gp, spheres, nodes, colors, bricks, cells, lists, entries);
    float4 a_sum = s0 > 0 ? albedo_out[pixel] : (float4)(0.0f);
    float4 n_sum = s0 > 0 ? normal_out[pixel] : (float4)(0.0f);
    guide_glass_samples(cam, gp, &sc, env, x, y, s0, s1, &a_sum, &n_sum);
    guide_store(albedo_out, normal_out, pixel, a_sum, n_sum, s1, cam->spp);
}

/* The pixels listed, pixels[0, n): all the camera's spp samples, replacing what the
   outputs held (guides.py: the pixels a one-ray pass found on an edge) */
__kernel void guide_glass_list(__constant Camera* cam, __constant GlassParams* gp,
                               __global const float4* restrict spheres,
                               __global const TreeNode* restrict nodes,
                               __global const float4* env,
                               __global const float4* restrict colors,
                               __global const int2* restrict bricks,
                               __global const int2* restrict cells,
                               __global const int4* restrict lists,
                               __global const int2* restrict entries,
                               __global float4* albedo_out, __global float4* normal_out,
                               __global const int* restrict pixels, int n)
{
    int k = get_global_id(0);
    if (k >= n)
        return;
    int pixel = pixels[k], x = pixel % cam->width, y = pixel / cam->width;
    SdfScene sc = sdf_scene(gp, spheres, nodes, colors, bricks, cells, lists, entries);
    float4 a_sum = (float4)(0.0f), n_sum = (float4)(0.0f);
    guide_glass_samples(cam, gp, &sc, env, x, y, 0, cam->spp, &a_sum, &n_sum);
    guide_store(albedo_out, normal_out, (uint)pixel, a_sum, n_sum, cam->spp, cam->spp);
}
