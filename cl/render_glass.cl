/* Molten-glass point clouds: one work-item per pixel follows one path per sample through
   up to `bounces` surface events of the smooth union of spheres (render frame).
   Inputs: Camera, GlassParams, lights, spheres (tree order), tree nodes, environment,
   per-sphere colours, support cells (bricks, cells, lists, entries: cl/cells.h). Output:
   rgba, alpha = coverage of the primary ray.
   Flags: VR_TREE, VR_GRID, VR_N_SUNS, VR_N_POINTS, VR_SHADOWS, VR_REFRACTION, VR_ABSORPTION,
          VR_GLOW, VR_ENV_MAP, VR_COLORS, VR_FULL (both Fresnel branches, shade_glass.h), VR_TILED (+ VR_TILE_W, VR_TILE_H, VR_TILE_CAP),
          VR_UBER (every feature compiled in, chosen at run time by GlassParams.uber and
          the light counts in GlassParams: the kernel-specialisation baseline),
          VR_STATS (diagnostics: rgb holds the field evaluations, node tests and sphere
          tests per pixel, summed over its samples). */
#if !defined(VR_TREE) || !defined(VR_GRID) || !defined(VR_N_SUNS) || !defined(VR_N_POINTS) || \
    !defined(VR_SHADOWS) || !defined(VR_REFRACTION) || !defined(VR_ABSORPTION) || \
    !defined(VR_GLOW) || !defined(VR_ENV_MAP) || !defined(VR_COLORS) || \
    !defined(VR_TILED) || !defined(VR_UBER) || !defined(VR_STATS) || !defined(VR_FULL)
#error "render_glass.cl: a VR_* feature flag is missing (see volrender/features.py)"
#endif

#include "common.h"
#include "structs.h"
#include "camera.h"
#include "sdf.h"
#include "glass.h"
#include "shade_glass.h"
#include "glass_tile.h"
#include "accum.h"


#if VR_TILED
__kernel __attribute__((reqd_work_group_size(VR_TILE_W, VR_TILE_H, 1)))
#else
__kernel
#endif
void render_glass(__constant Camera* cam, __constant GlassParams* gp,
                  __constant Light* lights, __global const float4* restrict spheres,
                  __global const TreeNode* restrict nodes, __global const float4* env,
                  __global const float4* restrict colors, __global const int2* restrict bricks,
                  __global const int2* restrict cells, __global const int4* restrict lists,
                  __global const int2* restrict entries, __global float4* out, int y0, int s0,
                  int s1)
{
    int x = get_global_id(0), y = y0 + get_global_id(1);
#if VR_TILED
    /* every work-item of the group takes part in building the list, even past the edge */
    __local float4 tile[VR_TILE_CAP];
    __local int tile_idx[VR_TILE_CAP];      /* a power of two: sorted in place */
    __local int tile_count;
    float3 pl[4];
    int tile_n = glass_build_tile(cam, gp, spheres, nodes, tile, tile_idx, &tile_count,
                                  get_group_id(0) * VR_TILE_W, y0 + get_group_id(1) * VR_TILE_H, pl);
#endif
    if (x >= cam->width || y >= cam->height)
        return;
    uint pixel = (uint)(y * cam->width + x);
    SdfScene sc = sdf_scene(gp, spheres, nodes, colors, bricks, cells, lists, entries);
#if VR_TILED
    sc.tile = tile;
    sc.tile_idx = tile_idx;
    sc.tile_n = tile_n;
    sc.tile_margin = gp->tile_margin;
    sc.tile_eye = cam->origin.xyz;
    for (int i = 0; i < 4; ++i)
        sc.tile_pl[i] = pl[i];
#endif
#if VR_STATS
    int3 stats = (int3)(0);
    sc.stats = &stats;
#endif
    /* samples s0 .. s1-1 of cam->spp: a launch continues the sums of the one before */
    VrAccum acc = vr_accum_load(out, 0, pixel, s0);
#if VR_STATS
    float3 before = acc.rgb;
#endif
    for (int s = s0; s < s1; ++s) {
        float2 j = vr_pixel_jitter(cam, pixel, (uint)s);
        float3 d = vr_camera_dir(cam, x, y, j.x, j.y);
        int covered;
        acc.rgb += vr_safe_sample(glass_path(&sc, gp, lights, env, cam->origin.xyz, d, cam->seed,
                                             pixel, (uint)s, &covered));
        acc.alpha += (float)covered;
    }
#if VR_STATS
    acc.rgb = before + convert_float3(stats);        /* the totals so far */
    if (s1 >= cam->spp)
        acc.rgb *= (float)cam->spp;                  /* so that the division gives the totals */
#endif
    vr_accum_store(out, 0, pixel, acc, s1, cam->spp);
}
