/* Single-scattering volume renderer (DESIGN.md estimand), one work-item per pixel.
   Flags: VR_N_SUNS, VR_N_POINTS, VR_SHADOWS, VR_PHASE_MIXED, VR_SKIP_EMPTY,
          VR_EMISSION, VR_DEPTH, VR_TILED, VR_TILE_W, VR_TILE_H, VR_TILE_CAP.

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
    !defined(VR_PHASE_MIXED) || !defined(VR_SKIP_EMPTY) || !defined(VR_EMISSION) || \
    !defined(VR_DEPTH) || !defined(VR_TILED) || !defined(VR_TILE_W) || \
    !defined(VR_TILE_H) || !defined(VR_TILE_CAP)
#error "render_volume.cl: a VR_* feature flag is missing (see volrender/features.py)"
#endif
#define VR_CULL (VR_TILED && VR_SKIP_EMPTY)
#if VR_CULL && VR_TILE_CAP < 1
#error "render_volume.cl: tiled culling needs VR_TILE_CAP >= 1"
#endif

#include "common.h"
#include "structs.h"
#include "camera.h"
#include "phase.h"
#include "volume.h"

#define VR_T_CUTOFF 1e-5f          /* stop marching once the view transmittance is below */
#define VR_SHADOW_TAU_STOP 25.0f   /* exp(-25) ~ 1e-11: light fully blocked */
#define VR_MAX_LIGHTS 64u          /* lights.MAX_LIGHTS */

#if VR_CULL
/* Normal of the plane through the camera spanned by corner ray c and edge direction e
   (the tile's side from c along e), oriented towards `inward`, the tile's other side.
   Built from the edge vector, not from two nearly parallel corner rays, so a tile of a
   pixel far away keeps a well-conditioned normal. */
inline float3 vr_side_plane(float3 c, float3 e, float3 inward)
{
    float3 n = cross(c, e);
    return dot(n, inward) < 0.0f ? -n : n;
}

/* Whether some point of box (centre ce relative to the apex, half-size h) may be on the
   positive side of plane n: exact test of the box's farthest corner along n, with a
   slack of 1e-5 of the terms' magnitude for rounding (keeping a brick is always safe). */
inline int vr_box_above(float3 n, float3 ce, float h)
{
    float3 an = fabs(n);
    float v = dot(n, ce) + h * (an.x + an.y + an.z);
    return v >= -1e-5f * (dot(an, fabs(ce)) + h * (an.x + an.y + an.z));
}

/* Cooperative culling of the occupied bricks `occ` (brick coordinates, n_occ of them)
   against the frustum of this work-group's tile: the cone from the camera through the
   tile's pixel footprint [x0, x1] x [ya, yb] (every sub-pixel jitter lies inside it),
   in the grid's local index space. Bricks are inflated by `pad` voxels; a brick holding
   the camera is always kept. Writes the kept bricks' low corners (minus pad) to `list`
   and their count to *n_list (which may exceed VR_TILE_CAP: overflow). Every
   work-item of the group must call it (it holds barriers). */
inline void vr_tile_cull(__constant Camera* cam, __constant VolumeParams* vp,
                         __global const int4* occ, int n_occ, int y0, float pad,
                         __local float4* list, __local volatile int* n_list)
{
    int lid = get_local_id(1) * VR_TILE_W + get_local_id(0);
    if (lid == 0)
        *n_list = 0;
    barrier(CLK_LOCAL_MEM_FENCE);

    float x0 = (float)(get_group_id(0) * VR_TILE_W);
    float x1 = fmin(x0 + (float)VR_TILE_W, (float)cam->width);
    float ya = (float)(y0 + (int)get_group_id(1) * VR_TILE_H);
    float yb = fmin(ya + (float)VR_TILE_H, (float)cam->height);
    /* corner rays (x0, ya) and (x1, yb), pixel steps du, dv: all in local space, where
       the pixel rays are the same linear map of the world ones */
    float3 du = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, cam->du.xyz);
    float3 dv = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, cam->dv.xyz);
    float3 c00 = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2,
                         cam->pixel00.xyz + x0 * cam->du.xyz + ya * cam->dv.xyz);
    float3 c11 = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2,
                         cam->pixel00.xyz + x1 * cam->du.xyz + yb * cam->dv.xyz);
    float3 n0 = vr_side_plane(c00, du, dv), n1 = vr_side_plane(c11, du, -dv);    /* top, bottom */
    float3 n2 = vr_side_plane(c00, dv, du), n3 = vr_side_plane(c11, dv, -du);    /* left, right */

    float3 o = cam->origin.xyz;
    float h = 0.5f * VR_BRICK + pad;
    for (int i = lid; i < n_occ; i += VR_TILE_W * VR_TILE_H) {
        float3 lo = convert_float3(occ[i].xyz * VR_BRICK);
        float3 ce = lo + (float3)(0.5f * VR_BRICK) - o;
        int inside = all(fabs(ce) <= (float3)(h));
        if (inside || (vr_box_above(n0, ce, h) && vr_box_above(n1, ce, h) &&
                       vr_box_above(n2, ce, h) && vr_box_above(n3, ce, h))) {
            int slot = atomic_inc(n_list);
            if (slot < VR_TILE_CAP)
                list[slot] = (float4)(lo - (float3)(pad), 0.0f);
        }
    }
    barrier(CLK_LOCAL_MEM_FENCE);
}

/* First entry into and last exit from the listed bricks (edge 8 + 2 pad) along
   o + t d, t >= 0; x > y when the ray meets none. */
inline float2 vr_listed_span(__local const float4* list, int n, float3 o, float3 inv_d,
                             float size)
{
    float t_in = INFINITY, t_out = -INFINITY;
    for (int i = 0; i < n; ++i) {
        float3 lo = list[i].xyz;
        float2 tt = vr_ray_box(o, inv_d, lo, lo + (float3)(size));
        if (tt.x <= tt.y && tt.y >= 0.0f) {
            t_in = fmin(t_in, tt.x);
            t_out = fmax(t_out, tt.y);
        }
    }
    return (float2)(t_in, t_out);
}
#endif

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

/* occ: the occupied bricks' coordinates (n_occ of them), read only by tiled culling. */
#if VR_TILED
__attribute__((reqd_work_group_size(VR_TILE_W, VR_TILE_H, 1)))
#endif
__kernel void render_volume(__constant Camera* cam, __constant VolumeParams* vp,
                            __constant Light* lights,
                            __global const int* table, __global const float* data,
                            __global const float* emission,
                            __global float4* out, __global float* depth,
                            __global const int4* occ, int n_occ, int y0)
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

        float3 L = (float3)(0.0f);
        float T = 1.0f, dsum = 0.0f, dw = 0.0f;
        for (int k = k0; t0 < t_end; ++k) {
            float t = t0 + ((float)k + u) * dt;
            if (t >= t_end || T < VR_T_CUTOFF)
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
