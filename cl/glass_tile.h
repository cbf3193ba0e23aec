/* Tiled dispatch for glass: a work-group builds the sorted list of spheres that can matter
   inside its tile's frustum (render_glass.cl). Include after sdf.h; compiled only with
   VR_TILED. */
#ifndef VR_GLASS_TILE_H
#define VR_GLASS_TILE_H

#if VR_TILED
/* Frustum of the tile's pixel rectangle [px0, px1] x [py0, py1] (continuous pixel
   coordinates: jitter stays inside): four inward unit plane normals through the eye. Any
   point inside it (on any path: primary, refracted or shadow) can use the tile's list. */
inline void glass_tile_planes(__constant Camera* cam, float px0, float py0, float px1,
                              float py1, float3* pl)
{
    float3 c[4];
    c[0] = cam->pixel00.xyz + px0 * cam->du.xyz + py0 * cam->dv.xyz;
    c[1] = cam->pixel00.xyz + px1 * cam->du.xyz + py0 * cam->dv.xyz;
    c[2] = cam->pixel00.xyz + px1 * cam->du.xyz + py1 * cam->dv.xyz;
    c[3] = cam->pixel00.xyz + px0 * cam->du.xyz + py1 * cam->dv.xyz;
    float3 mid = c[0] + c[1] + c[2] + c[3];
    for (int i = 0; i < 4; ++i) {
        float3 nrm = cross(c[i], c[(i + 1) & 3]);
        float len = length(nrm);
        nrm = len > 0.0f ? nrm / len : (float3)(0.0f);
        pl[i] = dot(nrm, mid) < 0.0f ? -nrm : nrm;
    }
}

/* Could a ball (centre c relative to the eye, radius r) touch the frustum (a convex cone:
   its distance from it is at least the largest distance from one plane)? */
inline int glass_tile_keeps(const float3* pl, float3 c, float r)
{
    return dot(pl[0], c) >= -r && dot(pl[1], c) >= -r && dot(pl[2], c) >= -r &&
           dot(pl[3], c) >= -r;
}

inline int glass_tile_keeps_box(const float3* pl, float3 lo, float3 hi, float margin)
{
    float3 ctr = 0.5f * (lo + hi), ext = 0.5f * (hi - lo);
    for (int i = 0; i < 4; ++i)
        if (dot(pl[i], ctr) + dot(fabs(pl[i]), ext) < -margin)
            return 0;
    return 1;
}

/* The group's list: indices of spheres that can come within tile_margin of the frustum,
   sorted (so sums run in one order whatever the atomics did). Returns the length, or -1
   when more than VR_TILE_CAP spheres qualify. */
inline int glass_build_tile(__constant Camera* cam, __constant GlassParams* gp,
                            __global const float4* spheres, __global const TreeNode* nodes,
                            __local float4* tile, __local int* idx, __local int* count,
                            int px0, int py0, float3* pl)
{
    int lid = get_local_id(1) * get_local_size(0) + get_local_id(0);
    int gsize = get_local_size(0) * get_local_size(1);
    if (lid == 0)
        *count = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    glass_tile_planes(cam, (float)px0, (float)py0, (float)(px0 + VR_TILE_W),
                      (float)(py0 + VR_TILE_H), pl);
    float3 eye = cam->origin.xyz;
    float margin = gp->tile_margin;
#define TILE_TEST(i)                                                          \
    {                                                                         \
        float4 sp = spheres[i];                                               \
        if (glass_tile_keeps(pl, sp.xyz - eye, sp.w + margin)) {              \
            int at = atomic_inc(count);                                       \
            if (at < VR_TILE_CAP)                                             \
                idx[at] = i;                                                  \
        }                                                                     \
    }
#if VR_TREE || VR_GRID
    /* the tree (the cells' builder is there too): one subtree per work-item from the level with about a group's worth of nodes */
    int level = 1;
    while (level < gsize && level < gp->first_leaf)
        level <<= 1;
    for (int root = level + lid; root < 2 * level; root += gsize) {
        int stack[VR_TREE_STACK];
        int sp = 0, node = root;
        while (node) {
            __global const TreeNode* nd = nodes + node;
            float3 lo = (float3)(nd->lo_x, nd->lo_y, nd->lo_z) - eye;
            float3 hi = (float3)(nd->hi_x, nd->hi_y, nd->hi_z) - eye;
            int keep = nd->count > 0 || node < gp->first_leaf ?
                       glass_tile_keeps_box(pl, lo, hi, margin) : 0;
            if (keep && node >= gp->first_leaf) {
                for (int i = nd->start; i < nd->start + nd->count; ++i)
                    TILE_TEST(i)
                keep = 0;
            }
            if (keep) {
                stack[sp++] = 2 * node + 1;
                node = 2 * node;
            } else {
                node = sp > 0 ? stack[--sp] : 0;
            }
        }
    }
#else
    for (int i = lid; i < gp->n_spheres; i += gsize)
        TILE_TEST(i)
#endif
#undef TILE_TEST
    barrier(CLK_LOCAL_MEM_FENCE);
    int n = *count;
    if (n > VR_TILE_CAP)
        return -1;
    /* bitonic sort of idx[0, p2), padded with INT_MAX */
    int p2 = 1;
    while (p2 < n)
        p2 <<= 1;
    for (int i = n + lid; i < p2; i += gsize)
        idx[i] = INT_MAX;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int k = 2; k <= p2; k <<= 1) {
        for (int j = k >> 1; j > 0; j >>= 1) {
            for (int i = lid; i < p2; i += gsize) {
                int l = i ^ j;
                if (l > i) {
                    int a = idx[i], b = idx[l];
                    if (((i & k) == 0) == (a > b)) { idx[i] = b; idx[l] = a; }
                }
            }
            barrier(CLK_LOCAL_MEM_FENCE);
        }
    }
    for (int i = lid; i < n; i += gsize)
        tile[i] = spheres[idx[i]];
    barrier(CLK_LOCAL_MEM_FENCE);
    return n;
}
#endif

#endif
