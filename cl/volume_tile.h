/* Tiled dispatch for volumes: a work-group culls the occupied bricks against its tile's
   frustum into local memory (render_volume.cl). Include after volume.h; everything here
   is compiled only with VR_CULL (VR_TILED && VR_SKIP_EMPTY). */
#ifndef VR_VOLUME_TILE_H
#define VR_VOLUME_TILE_H

#define VR_CULL (VR_TILED && VR_SKIP_EMPTY)
#if VR_CULL && VR_TILE_CAP < 1
#error "volume_tile.h: tiled culling needs VR_TILE_CAP >= 1"
#endif

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

#endif
