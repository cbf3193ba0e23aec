/* Smooth union of spheres, its acceleration (tree walk or support cells) and sphere tracing.
   Field: d_i = |x - c_i| - r_i, m = min_i d_i, h_i = max(0, 1 - (d_i - m)/k),
   S = sum_i h_i^2 (the nearest sphere gives 1), F = m - (k/2) ln S: a plain sum, so
   independent of visiting order. For two spheres F is C1 across the seam (slopes 1/2 and
   1/2 where d_a = d_b); the bulge over the plain union is at most (k/2) ln N (N spheres
   at equal distance), instead of growing linearly with N as a sum of pairwise smins does.
   Support: sphere i matters only where d_i < m + k.
   Flags: VR_TREE (walk the partition tree), VR_GRID (fold the point's support-cell list,
   cl/cells.h; rays skip cells away from the surface), neither: brute force; VR_TILED (a
   work-group's sphere list in local memory, exact wherever m + k <= its margin, see
   render_glass.cl); VR_COLORS (per-sphere colours, blended with the weights h_i^2 / S). */
#ifndef VR_SDF_H
#define VR_SDF_H

#if !defined(VR_TREE) || !defined(VR_GRID) || !defined(VR_TILED) || !defined(VR_COLORS)
#error "sdf.h: VR_TREE, VR_GRID, VR_TILED or VR_COLORS is missing (see volrender/features.py)"
#endif
#if VR_TREE && VR_GRID
#error "sdf.h: VR_TREE and VR_GRID exclude each other"
#endif

#ifndef VR_TREE_STACK
#define VR_TREE_STACK VR_MAX_TREE_STACK   /* tree depth + 1; the host sets it (layout.tree_stack) */
#endif
#ifndef VR_ADAPTIVE_RELAX
#define VR_ADAPTIVE_RELAX 1   /* the relaxation factor from r's slope (sdf_march); 0: fixed */
#endif
#ifndef VR_RELAX_MARGIN
#define VR_RELAX_MARGIN 0.95f /* times the factor that just keeps the balls overlapping on a
                                 plane: 0.85 and 1.0 took 2-16% more evaluations (PoCL) */
#endif
#ifndef VR_LIST_PREFETCH
#define VR_LIST_PREFETCH 2    /* VR_GRID: a cell's list is walked with its loads issued
                                 ahead (SDF_WALK_LIST): 0 none, 1 the next entry, 2 the next
                                 entry's sphere and the entry after it */
#endif
#ifndef VR_STATS
#define VR_STATS 0            /* count the field's work (diagnostics; glass.GlassSettings.stats) */
#endif

typedef struct {
    __global const float4* spheres;   /* centre xyz, radius w; render frame, tree order */
    __global const TreeNode* nodes;   /* heap layout, root 1 (unused when VR_TREE == 0) */
    int n_spheres;
    int first_leaf;
    float k;                          /* blend, world units */
    float hit_len;                    /* the hit threshold eps (base + t) stops growing here */
#if VR_COLORS
    __global const float4* colors;    /* rgb per sphere, tree order */
#endif
#if VR_TILED
    __local const float4* tile;       /* spheres that can matter inside this tile's frustum */
    __local const int* tile_idx;      /* their indices in `spheres` */
    int tile_n;                       /* list length; -1: do not use the list */
    float tile_margin;                /* spheres left out have d_i > margin in the frustum */
    float3 tile_eye;                  /* the frustum: x - eye on the inner side of 4 planes */
    float3 tile_pl[4];
#endif
#if VR_GRID
    __global const int2* bricks;      /* cl/cells.h */
    __global const int2* cells;
    __global const int4* lists;       /* (start, count, -, core count) into entries */
    __global const int2* entries;     /* (sphere, key bits), ascending key per list */
    float3 grid_lo;                   /* min corner of cell (0, 0, 0) */
    float cell, inv_cell;             /* cell edge and its inverse */
    float nudge;                      /* step past a skipped cell's exit face */
    int3 dims, bdims;                 /* cells and bricks per axis */
    int max_skips;                    /* skips per ray segment */
#endif
#if VR_STATS
    int3* stats;                      /* counters: evaluations, node tests (cell lookups with
                                         VR_GRID), sphere tests */
#endif
} SdfScene;

typedef struct {
    float f;      /* field value */
    float lip;    /* bound on |grad F| at the point: max(1, 2 sum_{i != argmin} h_i / S - 1) */
    float3 grad;  /* analytic gradient (not normalised) */
#if VR_COLORS
    float3 color; /* sum_i h_i^2 c_i / S */
#endif
} SdfSample;

#if VR_GRID
#include "cells.h"
#endif

/* The field of a glass kernel's arguments (render_glass.cl, and the tests' probes: one
   place, so they never drift); the tile fields (VR_TILED) are the caller's. */
inline SdfScene sdf_scene(__constant GlassParams* gp, __global const float4* spheres,
                          __global const TreeNode* nodes, __global const float4* colors,
                          __global const int2* bricks, __global const int2* cells,
                          __global const int4* lists, __global const int2* entries)
{
    SdfScene sc;
    sc.spheres = spheres;
    sc.nodes = nodes;
    sc.n_spheres = gp->n_spheres;
    sc.first_leaf = gp->first_leaf;
    sc.k = gp->blend;
    sc.hit_len = gp->hit_len;
#if VR_COLORS
    sc.colors = colors;
#endif
#if VR_GRID
    sc.bricks = bricks;
    sc.cells = cells;
    sc.lists = lists;
    sc.entries = entries;
    sc.grid_lo = gp->grid_lo.xyz;
    sc.cell = gp->grid_lo.w;
    sc.inv_cell = gp->grid_inv;
    sc.nudge = gp->grid_nudge;
    sc.dims = gp->grid_dims.xyz;
    sc.bdims = gp->brick_dims.xyz;
    sc.max_skips = gp->grid_skips;
#endif
    return sc;
}

/* sqrt(dot) rather than length(): length() guards against overflow by rescaling, which
   made the field ~1.5x slower on the H200 and PoCL; the host refuses scenes large enough
   to overflow (glass.MAX_EXTENT). */
inline float sdf_sphere(float4 s, float3 x)
{
    float3 v = x - s.xyz;
    return sqrt(dot(v, v)) - s.w;
}

inline float3 sdf_sphere_normal(float4 s, float3 x)
{
    float3 v = x - s.xyz;
    float q = dot(v, v);
    return q > 0.0f ? v * rsqrt(q) : (float3)(0.0f);
}

/* Lower bound of d_i over a node's spheres: distance to its box, -inf inside it. The node
   is read as two float4 loads (lo xyz + start, hi xyz + count; cl/structs.h), not six
   scalar ones: lanes of a warp visit different nodes, so each load is its own transaction. */
inline float sdf_node_bound(const SdfScene* sc, int node, float3 x)
{
    __global const float4* nd = (__global const float4*)(sc->nodes + node);
    float3 lo = nd[0].xyz, hi = nd[1].xyz;
    float3 g = fmax(fmax(lo - x, x - hi), (float3)(0.0f));
    float q = dot(g, g);
#if VR_STATS
    ++sc->stats->y;
#endif
    return q > 0.0f ? sqrt(q) * 0.999999f : -INFINITY;   /* shrunk: rounding-safe */
}

#if VR_STATS
#define SDF_COUNT_SPHERE ++sc->stats->z;
#else
#define SDF_COUNT_SPHERE
#endif

/* Walk a cell's list (VR_GRID) by ascending key up to the first key >= stop (re-read each
   step: pass 1's running m), running BODY with the sphere s4 and its index idx. The loads
   are chained (an entry, then its sphere), so with VR_LIST_PREFETCH they are issued ahead:
   the next entry (1), or the next entry's sphere and the entry after that (2), while this
   sphere is tested. Reads ahead are clamped to the list's last entry. */
#if VR_LIST_PREFETCH == 2
#define SDF_WALK_LIST(sc, list, stop, BODY)                                   \
    {                                                                         \
        int j_ = (list).x, end_ = (list).x + (list).y;                        \
        if (j_ < end_) {                                                      \
            int2 e_ = (sc)->entries[j_];                                      \
            int2 en_ = (sc)->entries[min(j_ + 1, end_ - 1)];                  \
            float4 s4 = (sc)->spheres[e_.x];                                  \
            for (;;) {                                                        \
                if (as_float(e_.y) >= (stop))                                 \
                    break;                                                    \
                float4 sn_ = (sc)->spheres[en_.x];                            \
                int2 enn_ = (sc)->entries[min(j_ + 2, end_ - 1)];             \
                int idx = e_.x;                                               \
                BODY                                                          \
                if (++j_ >= end_)                                             \
                    break;                                                    \
                e_ = en_; en_ = enn_; s4 = sn_;                               \
            }                                                                 \
        }                                                                     \
    }
#elif VR_LIST_PREFETCH == 1
#define SDF_WALK_LIST(sc, list, stop, BODY)                                   \
    {                                                                         \
        int j_ = (list).x, end_ = (list).x + (list).y;                        \
        int2 e_ = j_ < end_ ? (sc)->entries[j_] : (int2)(0);                  \
        for (; j_ < end_; ++j_) {                                             \
            int2 en_ = (sc)->entries[min(j_ + 1, end_ - 1)];                  \
            if (as_float(e_.y) >= (stop))                                     \
                break;                                                        \
            float4 s4 = (sc)->spheres[e_.x];                                  \
            int idx = e_.x;                                                   \
            BODY                                                              \
            e_ = en_;                                                         \
        }                                                                     \
    }
#else
#define SDF_WALK_LIST(sc, list, stop, BODY)                                   \
    for (int j_ = (list).x; j_ < (list).x + (list).y; ++j_) {                 \
        int2 e_ = (sc)->entries[j_];                                          \
        if (as_float(e_.y) >= (stop))                                         \
            break;                                                            \
        float4 s4 = (sc)->spheres[e_.x];                                      \
        int idx = e_.x;                                                       \
        BODY                                                                  \
    }
#endif

/* Pass 1: the nearest sphere, m = min_i d_i (returned) and its index *arg (-1: none).
   The traversal visits the nearer child first and prunes against the running m; with
   VR_GRID it walks the cell's list by key up to the first key >= m (within the core). */
inline float sdf_nearest(const SdfScene* sc, float3 x, int use_tile, int4 list, int* arg)
{
    float m = INFINITY;
    int a = -1;
#define SDF_NEAREST(s4, i)                         \
    {                                             \
        float d = sdf_sphere(s4, x);              \
        SDF_COUNT_SPHERE                          \
        if (d < m) { m = d; a = i; }              \
    }
#if VR_TILED
    if (use_tile) {
        for (int j = 0; j < sc->tile_n; ++j)
            SDF_NEAREST(sc->tile[j], sc->tile_idx[j])
        *arg = a;
        return m;
    }
#endif
#if VR_GRID
    SDF_WALK_LIST(sc, list, m, SDF_NEAREST(s4, idx))     /* by key: stop at key >= m */
#elif VR_TREE
    int stack[VR_TREE_STACK];
    float sb[VR_TREE_STACK];
    int sp = 0;
    int node = 1;
    while (node) {
        if (node >= sc->first_leaf) {
            __global const TreeNode* nd = sc->nodes + node;
            int end = nd->start + nd->count;
            for (int i = nd->start; i < end; ++i)
                SDF_NEAREST(sc->spheres[i], i)
            node = 0;
        } else {
            int c0 = 2 * node, c1 = c0 + 1;
            float b0 = sdf_node_bound(sc, c0, x), b1 = sdf_node_bound(sc, c1, x);
            if (b1 < b0) { int cs = c0; c0 = c1; c1 = cs; float bt = b0; b0 = b1; b1 = bt; }
            node = 0;
            if (b0 < m) {
                node = c0;
                if (b1 < m) { stack[sp] = c1; sb[sp] = b1; ++sp; }
            }
        }
        while (!node && sp > 0) {
            --sp;
            if (sb[sp] < m)
                node = stack[sp];
        }
    }
#else
    for (int i = 0; i < sc->n_spheres; ++i)
        SDF_NEAREST(sc->spheres[i], i)
#endif
#undef SDF_NEAREST
    *arg = a;
    return m;
}

/* One sphere's blend terms for d < thr = m + k: h, h^2, h * normal (and colour). */
#if VR_COLORS
#define SDF_COLOR_ADD(w, idx) col += (w) * sc->colors[idx].xyz;
#else
#define SDF_COLOR_ADD(w, idx)
#endif
#define SDF_ACCUMULATE(s4, idx)                                          \
    {                                                                 \
        float d = sdf_sphere(s4, x);                                  \
        SDF_COUNT_SPHERE                                              \
        if (d < thr) {                                                \
            float h = fmax(1.0f - (d - m) * inv_k, 0.0f);             \
            s1 += h; s2 += h * h; g += h * sdf_sphere_normal(s4, x);  \
            SDF_COLOR_ADD(h * h, idx)                                 \
        }                                                             \
    }

typedef struct {
    float s1, s2;     /* sum of h_i and of h_i^2 */
    float3 g, col;    /* sum of h_i n_i and of h_i^2 c_i */
} SdfSums;

/* Pass 2: sums over all spheres with d_i < m + k (the argmin included, h = 1). The
   threshold is fixed, so the visiting order does not matter and no list is kept: on the
   H200 two passes ran x1.4 faster than one gathering a private candidate list (which
   spilled to local memory). Starting pass 2 from the previous step's nearest sphere
   instead of pass 1 cost more: along a ray the nearest sphere changes at 80% of steps. */
inline SdfSums sdf_blend_sums(const SdfScene* sc, float3 x, float m, int use_tile, int4 list)
{
    float thr = m + sc->k, inv_k = 1.0f / sc->k;
    float s1 = 0.0f, s2 = 0.0f;
    float3 g = (float3)(0.0f), col = (float3)(0.0f);
#if VR_TILED
    if (use_tile) {
        for (int j = 0; j < sc->tile_n; ++j)
            SDF_ACCUMULATE(sc->tile[j], sc->tile_idx[j])
    } else
#endif
    {
#if VR_GRID
    SDF_WALK_LIST(sc, list, thr, SDF_ACCUMULATE(s4, idx))     /* stop at key >= m + k */
#elif VR_TREE
    int stack[VR_TREE_STACK];
    int sp = 0;
    int node = sdf_node_bound(sc, 1, x) < thr ? 1 : 0;
    while (node) {
        if (node >= sc->first_leaf) {
            __global const TreeNode* nd = sc->nodes + node;
            int end = nd->start + nd->count;
            for (int i = nd->start; i < end; ++i)
                SDF_ACCUMULATE(sc->spheres[i], i)
            node = 0;
        } else {
            int c0 = 2 * node, c1 = c0 + 1;
            int in0 = sdf_node_bound(sc, c0, x) < thr;
            int in1 = sdf_node_bound(sc, c1, x) < thr;
            node = in0 ? c0 : (in1 ? c1 : 0);
            if (in0 && in1)
                stack[sp++] = c1;
        }
        if (!node && sp > 0)
            node = stack[--sp];
    }
#else
    for (int i = 0; i < sc->n_spheres; ++i)
        SDF_ACCUMULATE(sc->spheres[i], i)
#endif
    }
    SdfSums r = { s1, s2, g, col };
    return r;
}

/* Can x use the tile's list (inside the tile's frustum)? */
#if VR_TILED
#define SDF_TILE_MARGIN(sc) ((sc)->tile_margin)
#else
#define SDF_TILE_MARGIN(sc) 0.0f
#endif

inline int sdf_in_tile(const SdfScene* sc, float3 x)
{
#if VR_TILED
    float3 xe = x - sc->tile_eye;
    return sc->tile_n >= 0 && dot(sc->tile_pl[0], xe) >= 0.0f && dot(sc->tile_pl[1], xe) >= 0.0f &&
           dot(sc->tile_pl[2], xe) >= 0.0f && dot(sc->tile_pl[3], xe) >= 0.0f;
#else
    return 0;
#endif
}

/* F, its gradient bound at the point and its analytic gradient at x (render frame); with
   VR_GRID from the lists of x's cell (cl/cells.h). */
inline SdfSample sdf_eval_in(const SdfScene* sc, float3 x, int4 list)
{
    SdfSample r;
    r.lip = 1.0f;
    r.grad = (float3)(0.0f);
#if VR_COLORS
    r.color = (float3)(0.0f);
#endif
#if VR_STATS
    ++sc->stats->x;
#endif
    int a, in_tile = sdf_in_tile(sc, x);
#if VR_GRID && VR_TILED
    /* with cells the tile's list serves only where it is the shorter */
    in_tile = in_tile && sc->tile_n < list.y;
#endif
    float m;
    /* the list serves when every sphere off it (d_i > margin) is beyond m + k */
    if (in_tile)
        m = sdf_nearest(sc, x, 1, list, &a);
    int use_tile = in_tile && m + sc->k <= SDF_TILE_MARGIN(sc);
    if (!use_tile)
        m = sdf_nearest(sc, x, 0, list, &a);
    r.f = m;
    if (a < 0)
        return r;
    float3 na = sdf_sphere_normal(sc->spheres[a], x);
    r.grad = na;
#if VR_COLORS
    r.color = sc->colors[a].xyz;
#endif
    /* k -> 0, or k below m's precision: the plain union */
    if (!(sc->k > VR_BLEND_MIN) || !(m + sc->k > m))
        return r;
    SdfSums u = sdf_blend_sums(sc, x, m, use_tile, list);
    float s1 = u.s1, s2 = u.s2;
    float3 g = u.g, col = u.col;
    s2 = fmax(s2, 1.0f);                   /* the argmin's h = 1 is in the sums */
    float s1o = fmax(s1 - 1.0f, 0.0f);     /* sum of h over the other spheres */
    float inv_s = 1.0f / s2;
    r.f = m - 0.5f * sc->k * log(s2);
    /* S grad F = (S - s1o) grad m + sum' h_i grad d_i (unit gradients): |grad F| <= 1
       while S >= s1o (a convex combination), else <= 2 s1o / S - 1. The older bound
       1 + 2 s1o / S took x1.5 more steps (H200, 3000 spheres). */
    r.lip = fmax(1.0f, 2.0f * s1o * inv_s - 1.0f);
    /* grad F = grad m + (1/S) sum_i h_i (n_i - n_a) */
    r.grad = na + (g - s1 * na) * inv_s;
#if VR_COLORS
    r.color = col * inv_s;
#endif
    return r;
}

/* A skippable cell's sample: only the bound (its sign is F's), no gradient. */
inline SdfSample sdf_bound_sample(float bound)
{
    SdfSample r;
    r.f = bound;
    r.lip = 1.0f;
    r.grad = (float3)(0.0f);
#if VR_COLORS
    r.color = (float3)(0.0f);
#endif
    return r;
}

/* F at any point x (render frame): see sdf_eval_in; in a skippable cell, its bound. */
inline SdfSample sdf_eval(const SdfScene* sc, float3 x)
{
#if VR_GRID
    SdfCell c = sdf_cell(sc, x);
    if (c.code < 0)
        return sdf_bound_sample(c.bound);
    return sdf_eval_in(sc, x, sc->lists[c.code]);
#else
    return sdf_eval_in(sc, x, (int4)(0));
#endif
}

/* With VR_GRID: the sample at o + t d for a march on `side`, or a skip. Returns 1 with *s
   set; 0 when the cell is skipped (*t moved past its exit, *skips counted). A cell of the
   other side means the surface lies behind: its bound sample (side * F < 0) is a hit. */
#if VR_GRID
inline int sdf_step_sample(const SdfScene* sc, float3 o, float3 d, float3 inv_d, float side,
                           float* t, int* skips, SdfSample* s, float* bound, float* t_exit)
{
    SdfCell c = sdf_cell(sc, o + *t * d);
    if (c.code >= 0) {
        *s = sdf_eval_in(sc, o + *t * d, sc->lists[c.code]);
        return 1;
    }
    if (!sdf_cell_skips(&c, side)) {
        *s = sdf_bound_sample(c.bound);
        return 1;
    }
    ++*skips;
    *bound = c.bound;
    *t = sdf_cell_exit(sc, &c, o, inv_d, *t);
    *t_exit = *t;
    return 0;
}
#endif

/* Sphere-trace o + t d over [t0, t1] against side * F (side -1: inside glass).
   Hit when side * F < eps * min(base + t, hit_len); safe step r = (side * F) / lip.
   With relax > 1 the step is w r, 1 <= w <= relax (over-relaxed sphere tracing), w
   chosen from the slope of r along the ray (VR_ADAPTIVE_RELAX; Balint and Valasek,
   "Accelerating Sphere Tracing", 2018): near relax where r hardly falls (grazing), near
   1 head-on. A relaxed step reaches beyond the last safe ball, so it is checked before
   it is kept: when the safe balls of two consecutive points do not overlap (r + r_prev <
   step), when it ends past t1 (the box exit) or when it ends in a cell the ray would
   skip, neither of which is evaluated, the march goes back to the plain step (w = 1 for
   that step). No surface is skipped either way. With VR_GRID, cells of the ray's side
   are crossed without evaluations (they hold no hit: |F| > tau there); a skip restarts
   the relaxation and counts against max_skips, not max_steps. cone > 0 (shadow rays):
   *vis also keeps the minimum of side * F / (cone t) over the evaluated points, and of
   a skipped cell's bound at its exit.
   Returns 1 on a hit with *t and *s at the hit; else 0 with *t where marching stopped
   (<= t1). */
inline int sdf_march(const SdfScene* sc, float3 o, float3 d, float t0, float t1, float side,
                     float eps, float base, int max_steps, float relax, float cone,
                     float* vis, float* t_out, SdfSample* s_out)
{
    float t = t0, w = relax, step = 0.0f, r_prev = 0.0f;
#if VR_GRID
    float3 inv_d = 1.0f / d;
    int skips = 0;
#endif
    for (int i = 0; i < max_steps;) {
        int past = !(t <= t1);
        SdfSample s;
#if VR_GRID
        float bound = 0.0f, t_exit = t, t_next = t;
        int skip = !past && !sdf_step_sample(sc, o, d, inv_d, side, &t_next, &skips, &s,
                                             &bound, &t_exit);
#else
        int skip = 0;
#endif
        if ((past || skip) && w > 1.0f && step > 0.0f) {
            t -= step - step / w;              /* back to the plain step: safe */
            step /= w;
            w = 1.0f;
#if VR_GRID
            skips -= skip;
#endif
            continue;
        }
        if (past)
            break;
#if VR_GRID
        if (skip) {
            if (cone > 0.0f)
                *vis = fmin(*vis, bound / (cone * fmin(t_exit, t1)));
            t = t_next;
            step = 0.0f;
            r_prev = 0.0f;
            if (skips > sc->max_skips)
                break;
            continue;
        }
#else
        s = sdf_eval(sc, o + t * d);
#endif
        ++i;
        float f = side * s.f;
        float r = f / s.lip;
        if (w > 1.0f && r + r_prev < step) {
            t -= step - step / w;              /* back to the plain step: safe */
            step /= w;
            w = 1.0f;
            continue;
        }
        if (f < eps * fmin(base + t, sc->hit_len)) {
            *t_out = t;
            *s_out = s;
            return 1;
        }
        if (cone > 0.0f)
            *vis = fmin(*vis, f / (cone * fmax(t, 1e-30f)));
#if VR_ADAPTIVE_RELAX
        /* the next factor from the slope c of r along the ray (its fall over the last
           step): a plane met at slope c ends the next step's ball exactly at the last
           one's edge for w = 2 / (1 + c), the largest the check keeps */
        if (step > 0.0f && relax > 1.0f) {
            float c = clamp((r_prev - r) / step, 0.0f, 1.0f);
            w = clamp(VR_RELAX_MARGIN * 2.0f / (1.0f + c), 1.0f, relax);
        }
#endif
        step = w * r;
        r_prev = r;
        t += step;
    }
    *t_out = fmin(t, t1);
    return 0;
}

/* sdf_march without the penumbra: primary, reflected and refracted rays. */
inline int sdf_trace(const SdfScene* sc, float3 o, float3 d, float t0, float t1, float side,
                     float eps, float base, int max_steps, float relax, float* t_out,
                     SdfSample* s_out)
{
    float vis = 1.0f;
    return sdf_march(sc, o, d, t0, t1, side, eps, base, max_steps, relax, 0.0f, &vis, t_out,
                     s_out);
}

#endif
