/* Support-cell builder (volrender/cells.py drives it; cl/cells.h reads the result).
   A box B (a cell, or a brick of CELL_BRICK^3 cells) is classified from the spheres, found
   through the partition tree (render frame, tree order). For sphere i:
     lo_i = min_{x in B} |x - c_i| - r_i,   hi_i = max_{x in B} |x - c_i| - r_i.
   M = min_i lo_i <= m(x) <= U = min_i hi_i for every x in B (m = min_i d_i).
   List: every i with lo_i <= U + k. Sphere i matters at x only where d_i(x) < m(x) + k, and
   then lo_i <= d_i(x) < m(x) + k <= U + k: the list holds every sphere that can matter
   anywhere in B (the nearest one included), so folding it gives the brute-force field.
   Core list: every i with lo_i <= U. The nearest sphere at x has lo_a <= d_a(x) = m(x) <= U,
   so the core alone gives m (the field's first pass), and is much shorter.
   Field bounds over B (F = m - (k/2) ln S, S = sum_i h_i^2, h_i = (1 - (d_i - m)/k)_+):
     since lo_i <= d_i <= hi_i, for the m of any x in B:
       S <= Shi(m) = sum_list (1 - (lo_i - m)/k)_+^2   (>= 1 for m >= M),
       S >= Slo(m) = max(1, sum_list (1 - (hi_i - m)/k)_+^2),
     both non-decreasing in m. On a partition M = t_0 < ... < t_J = U, for m in [t_j, t_j+1]:
       F >= t_j - (k/2) ln Shi(t_j+1)   and   F <= t_j+1 - (k/2) ln Slo(t_j),
     so L = min_j (t_j - (k/2) ln Shi(t_j+1)) <= F <= max_j (t_j+1 - (k/2) ln Slo(t_j)) = UF.
   B is skippable outside when L > tau and inside when UF < -tau (tau: above every hit
   threshold and rounding error). A cheap first test for bricks: S <= N (list length),
   so L0 = M - (k/2) ln N is a bound too, and N is counted from whole subtrees.
   k <= VR_BLEND_MIN (plain union): L = M, UF = U.
   Lists are stored as runs (first, count) of consecutive sphere indices, ascending (the
   walk visits the leaves left to right; spheres are in tree order, so neighbours are runs).
   Kernels: build_classify (class, run counts, bound, U per box: bricks, then the octants of
   the boxes left unclassified, down to single cells), build_fill (the runs), build_expand
   (a level's octants), build_paint_* and build_mark_* (the tables the renderer reads). The
   counts' prefix sums and the compaction of unclassified boxes are pyopencl scans
   (volrender/cells.py): a level reads back only its kept count and its run total. */
#include "common.h"
#include "structs.h"

#ifndef VR_TREE_STACK
#error "build_cells.cl: VR_TREE_STACK is missing (see volrender/cells.py)"
#endif
#define CB_J VR_CELL_BOUNDS_J   /* sub-intervals of [M, U] for the field bounds (layout.py) */

/* distance between boxes a and b (0 when they meet) */
inline float cb_gap(float3 alo, float3 ahi, float3 blo, float3 bhi)
{
    float3 g = fmax(fmax(blo - ahi, alo - bhi), (float3)(0.0f));
    return sqrt(dot(g, g));
}

/* an upper bound of dist(c, B) over the points c of node box N */
inline float cb_far_gap(float3 blo, float3 bhi, float3 nlo, float3 nhi)
{
    float3 g = fmax(fmax(blo - nlo, nhi - bhi), (float3)(0.0f));
    return sqrt(dot(g, g));
}

inline void cb_sphere(float4 s, float3 lo, float3 hi, float* dlo, float* dhi)
{
    float3 c = s.xyz;
    float3 g = fmax(fmax(lo - c, c - hi), (float3)(0.0f));
    float3 f = fmax(fabs(c - lo), fabs(c - hi));
    *dlo = sqrt(dot(g, g)) - s.w;
    *dhi = sqrt(dot(f, f)) - s.w;
}

inline void cb_node(__global const TreeNode* nodes, int node, float3* lo, float3* hi)
{
    __global const float4* nd = (__global const float4*)(nodes + node);
    *lo = nd[0].xyz;
    *hi = nd[1].xyz;
}

/* lower bound of lo_i (and hi_i) over a node's spheres: the box gap, -inf when they meet */
inline float cb_bound(__global const TreeNode* nodes, int node, float3 lo, float3 hi)
{
    float3 nlo, nhi;
    cb_node(nodes, node, &nlo, &nhi);
    float g = cb_gap(lo, hi, nlo, nhi);
    return g > 0.0f ? g * 0.999999f : -INFINITY;
}

/* M = min lo_i and U = min hi_i over all spheres (nearest first, pruned against U >= M) */
inline void cb_nearest(__global const float4* sp, __global const TreeNode* nodes, int first_leaf,
                       float3 lo, float3 hi, float* M, float* U)
{
    float m = INFINITY, u = INFINITY;
    int stack[VR_TREE_STACK];
    float sb[VR_TREE_STACK];
    int top = 0, node = 1;
    while (node) {
        if (node >= first_leaf) {
            __global const TreeNode* nd = nodes + node;
            for (int i = nd->start; i < nd->start + nd->count; ++i) {
                float a, b;
                cb_sphere(sp[i], lo, hi, &a, &b);
                m = fmin(m, a);
                u = fmin(u, b);
            }
            node = 0;
        } else {
            int c0 = 2 * node, c1 = c0 + 1;
            float b0 = cb_bound(nodes, c0, lo, hi), b1 = cb_bound(nodes, c1, lo, hi);
            if (b1 < b0) { int cs = c0; c0 = c1; c1 = cs; float bt = b0; b0 = b1; b1 = bt; }
            node = 0;
            if (b0 < u) {
                node = c0;
                if (b1 < u) { stack[top] = c1; sb[top] = b1; ++top; }
            }
        }
        while (!node && top > 0) {
            --top;
            if (sb[top] < u)
                node = stack[top];
        }
    }
    *M = m;
    *U = u;
}

/* Number of spheres with lo_i <= thr, over-counted: whole subtrees within thr are added
   without visiting them (an upper bound of the list length). */
inline int cb_count(__global const TreeNode* nodes, int first_leaf, float3 lo, float3 hi, float thr)
{
    int stack[VR_TREE_STACK];
    int top = 0, node = 1, n = 0;
    while (node) {
        float3 nlo, nhi;
        cb_node(nodes, node, &nlo, &nhi);
        int next = 0;
        if (cb_bound(nodes, node, lo, hi) <= thr) {
            if (node >= first_leaf || cb_far_gap(lo, hi, nlo, nhi) <= thr) {
                n += nodes[node].count;
            } else {
                stack[top++] = 2 * node + 1;
                next = 2 * node;
            }
        }
        node = next ? next : (top > 0 ? stack[--top] : 0);
    }
    return n;
}

typedef struct {
    float k, inv_k, thr;        /* blend (0: plain union), its inverse, list threshold */
    float t[CB_J + 1];          /* the partition of [M, U] */
    float shi[CB_J], slo[CB_J]; /* Shi(t_j+1), Slo(t_j) */
    float core;                 /* core threshold U + pad */
    int n, nc;                  /* runs on the list and on the core */
    int first, last;            /* the list's open run */
    int firstc, lastc;          /* the core's open run */
} CbAcc;

inline CbAcc cb_start(__constant CellBuild* cb, float M, float U)
{
    CbAcc a;
    int blended = cb->blend > VR_BLEND_MIN;
    a.k = blended ? cb->blend : 0.0f;
    a.inv_k = blended ? 1.0f / cb->blend : 0.0f;
    a.thr = U + a.k + cb->pad;
    a.core = U + cb->pad;
    for (int j = 0; j <= CB_J; ++j)
        a.t[j] = j == CB_J ? U : M + (U - M) * ((float)j / (float)CB_J);
    for (int j = 0; j < CB_J; ++j) { a.shi[j] = 0.0f; a.slo[j] = 0.0f; }
    a.n = 0;
    a.nc = 0;
    a.first = a.last = -2;
    a.firstc = a.lastc = -2;
    return a;
}

/* Where cb_add writes: the list's runs at runs[0, cap) and the core's at core[0, core_cap).
   A run (first, count) is consecutive sphere indices; spheres arrive in ascending order. */
typedef struct {
    __global int2* runs;
    int cap;
    __global int2* core;
    int core_cap;
} CbOut;

/* Count (and with runs, write) sphere i into a run list: *n runs so far, the last one
   starting at *first and ending at *last (written when the next run starts) */
inline void cb_run(__global int2* runs, int cap, int* n, int* first, int* last, int i)
{
    if (i == *last + 1 && *n > 0) {
        *last = i;
        return;
    }
    if (runs && *n > 0 && *n <= cap)
        runs[*n - 1] = (int2)(*first, *last - *first + 1);
    ++*n;
    *first = i;
    *last = i;
}

inline void cb_run_end(__global int2* runs, int cap, int n, int first, int last)
{
    if (runs && n > 0 && n <= cap)
        runs[n - 1] = (int2)(first, last - first + 1);
}

/* one candidate sphere i: on the list when lo_i <= thr, on the core when lo_i <= U + pad;
   the bounds' sums only when counting (w == 0: the fill pass needs the runs alone) */
inline void cb_add(CbAcc* a, float4 s, int i, float3 lo, float3 hi, const CbOut* w)
{
    float dlo, dhi;
    cb_sphere(s, lo, hi, &dlo, &dhi);
    if (dlo <= a->thr) {
        cb_run(w ? w->runs : 0, w ? w->cap : 0, &a->n, &a->first, &a->last, i);
        if (dlo <= a->core)
            cb_run(w ? w->core : 0, w ? w->core_cap : 0, &a->nc, &a->firstc, &a->lastc, i);
        if (w)
            return;
        for (int j = 0; j < CB_J; ++j) {
            float ha = fmax(1.0f - (dlo - a->t[j + 1]) * a->inv_k, 0.0f);
            float hb = fmax(1.0f - (dhi - a->t[j]) * a->inv_k, 0.0f);
            a->shi[j] += ha * ha;
            a->slo[j] += hb * hb;
        }
    }
}

/* L and UF from the sums; empty runs fill written lists' unused tails */
inline float2 cb_finish(__constant CellBuild* cb, CbAcc* a, float M, float U, const CbOut* w)
{
    if (w) {
        cb_run_end(w->runs, w->cap, a->n, a->first, a->last);
        cb_run_end(w->core, w->core_cap, a->nc, a->firstc, a->lastc);
        for (int j = a->n; j < w->cap; ++j)
            w->runs[j] = (int2)(0, 0);
        for (int j = a->nc; j < w->core_cap; ++j)
            w->core[j] = (int2)(0, 0);
    }
    if (a->k == 0.0f)
        return (float2)(M, U);
    float lower = INFINITY, upper = -INFINITY;
    for (int j = 0; j < CB_J; ++j) {
        lower = fmin(lower, a->t[j] - 0.5f * a->k * log(fmax(a->shi[j], 1.0f)));
        upper = fmax(upper, a->t[j + 1] - 0.5f * a->k * log(fmax(a->slo[j], 1.0f)));
    }
    return (float2)(lower, upper);
}

/* The list of box [lo, hi] from the tree: (n, bounds) with cb_finish's bounds */
inline CbAcc cb_list_tree(__constant CellBuild* cb, __global const float4* sp,
                          __global const TreeNode* nodes, float3 lo, float3 hi, float M, float U,
                          const CbOut* w)
{
    CbAcc a = cb_start(cb, M, U);
    int stack[VR_TREE_STACK];
    int top = 0;
    int node = cb_bound(nodes, 1, lo, hi) <= a.thr ? 1 : 0;
    while (node) {
        if (node >= cb->first_leaf) {
            __global const TreeNode* nd = nodes + node;
            for (int i = nd->start; i < nd->start + nd->count; ++i)
                cb_add(&a, sp[i], i, lo, hi, w);
            node = 0;
        } else {
            int c0 = 2 * node, c1 = c0 + 1;
            int in0 = cb_bound(nodes, c0, lo, hi) <= a.thr;
            int in1 = cb_bound(nodes, c1, lo, hi) <= a.thr;
            node = in0 ? c0 : (in1 ? c1 : 0);
            if (in0 && in1)
                stack[top++] = c1;
        }
        if (!node && top > 0)
            node = stack[--top];
    }
    return a;
}

/* M and U, then the list, from candidate runs: a parent box P's list holds every sphere
   that can be on a sub-box C's list (lo_i(P) <= lo_i(C) <= U(C) + k <= U(P) + k), and P's
   core the minimisers of M(C) and U(C) (lo_j(P) <= lo_j(C) <= hi_j(C) = U(C) <= U(P)) */
inline void cb_nearest_of(__global const float4* sp, __global const int2* cand, int nc, float3 lo,
                          float3 hi, float* M, float* U)
{
    float m = INFINITY, u = INFINITY;
    for (int j = 0; j < nc; ++j) {
        int2 r = cand[j];
        for (int i = r.x; i < r.x + r.y; ++i) {
            float a, b;
            cb_sphere(sp[i], lo, hi, &a, &b);
            m = fmin(m, a);
            u = fmin(u, b);
        }
    }
    *M = m;
    *U = u;
}

inline CbAcc cb_list_of(__constant CellBuild* cb, __global const float4* sp,
                        __global const int2* cand, int nc, float3 lo, float3 hi, float M, float U,
                        const CbOut* w)
{
    CbAcc a = cb_start(cb, M, U);
    for (int j = 0; j < nc; ++j) {
        int2 r = cand[j];
        for (int i = r.x; i < r.x + r.y; ++i)
            cb_add(&a, sp[i], i, lo, hi, w);
    }
    return a;
}

/* box of work-item gid: origins[gid] (in cells), box_cells cells on a side */
inline void cb_box(__constant CellBuild* cb, __global const int4* origins, int gid, float3* lo,
                   float3* hi)
{
    int4 o = origins[gid];
    float h = cb->grid_lo.w;
    *lo = cb->grid_lo.xyz + convert_float3(o.xyz) * h;
    *hi = cb->grid_lo.xyz + convert_float3(o.xyz + cb->box_cells) * h;
}

/* class of a box from M, U, the list's and core's run counts and the bounds:
   VR_CELL_OUTSIDE (bound = L), VR_CELL_INSIDE (bound = UF) or 0 (the list is needed) */
inline int4 cb_classify(__constant CellBuild* cb, float M, float U, int n, int nc, float2 b)
{
    int cls = 0;
    float bound = 0.0f;
    if (b.x > cb->tau) {
        cls = VR_CELL_OUTSIDE;
        bound = b.x;
    } else if (b.y < -cb->tau) {
        cls = VR_CELL_INSIDE;
        bound = b.y;
    }
    return (int4)(cls, n, cls ? as_int(bound) : nc, as_int(U));
}

/* out[gid] = (class, list runs, bound bits or (class 0) core runs, U bits) of box
   origins[gid], from the tree */
__kernel void build_classify(__constant CellBuild* cb, __global const float4* restrict sp,
                             __global const TreeNode* restrict nodes,
                             __global const int4* restrict origins, __global int4* out, int n_boxes)
{
    int gid = get_global_id(0);
    if (gid >= n_boxes)
        return;
    float3 lo, hi;
    cb_box(cb, origins, gid, &lo, &hi);
    float M, U;
    cb_nearest(sp, nodes, cb->first_leaf, lo, hi, &M, &U);
    float k = cb->blend > VR_BLEND_MIN ? cb->blend : 0.0f;
    if (U < -cb->tau) {                      /* inside one sphere */
        out[gid] = (int4)(VR_CELL_INSIDE, 0, as_int(U), as_int(U));
        return;
    }
    if (cb->box_cells > 1) {                 /* larger boxes: the counting bound first */
        int nc = cb_count(nodes, cb->first_leaf, lo, hi, U + k + cb->pad);
        float l0 = M - 0.5f * k * log((float)max(nc, 1));
        if (l0 > cb->tau) {
            out[gid] = (int4)(VR_CELL_OUTSIDE, nc, as_int(l0), as_int(U));
            return;
        }
    }
    CbAcc a = cb_list_tree(cb, sp, nodes, lo, hi, M, U, 0);
    out[gid] = cb_classify(cb, M, U, a.n, a.nc, cb_finish(cb, &a, M, U, 0));
}

/* The same for sub-boxes origins[gid], the octants of box gid >> 3 of the level above
   (build_expand), from that parent's list and core: cand[lists[gid >> 3]] */
__kernel void build_classify_sub(__constant CellBuild* cb, __global const float4* restrict sp,
                                 __global const int2* restrict cand,
                                 __global const int4* restrict lists,
                                 __global const int4* restrict origins, __global int4* out,
                                 int n_boxes)
{
    int gid = get_global_id(0);
    if (gid >= n_boxes)
        return;
    float3 lo, hi;
    cb_box(cb, origins, gid, &lo, &hi);
    int4 pl = lists[gid >> 3];
    float M, U;
    cb_nearest_of(sp, cand + pl.z, pl.w, lo, hi, &M, &U);
    if (U < -cb->tau) {
        out[gid] = (int4)(VR_CELL_INSIDE, 0, as_int(U), as_int(U));
        return;
    }
    CbAcc a = cb_list_of(cb, sp, cand + pl.x, pl.y, lo, hi, M, U, 0);
    out[gid] = cb_classify(cb, M, U, a.n, a.nc, cb_finish(cb, &a, M, U, 0));
}

/* The list and core of each kept box k, box sel[k] of its level (thresholds U + k + pad
   and U + pad, U from its classification out[sel[k]].w), written as runs at runs[l.x,
   l.x + l.y) and runs[l.z, l.z + l.w), l = lists[k]; from the tree (from_tree), or from
   the list of its parent, box sel[k] >> 3 of the level above: cand[cand_lists[sel[k] >> 3]] */
__kernel void build_fill(__constant CellBuild* cb, __global const float4* restrict sp,
                         __global const TreeNode* restrict nodes,
                         __global const int2* restrict cand,
                         __global const int4* restrict cand_lists,
                         __global const int* restrict sel,
                         __global const int4* restrict origins,
                         __global const int4* restrict out,
                         __global const int4* restrict lists, __global int2* runs, int n_kept,
                         int from_tree)
{
    int k = get_global_id(0);
    if (k >= n_kept)
        return;
    int j = sel[k];
    float3 lo, hi;
    cb_box(cb, origins, j, &lo, &hi);
    float U = as_float(out[j].w);       /* membership needs U only (M sets the bounds) */
    int4 l = lists[k];
    CbOut w = { runs + l.x, l.y, runs + l.z, l.w };
    CbAcc a;
    if (from_tree) {
        a = cb_list_tree(cb, sp, nodes, lo, hi, U, U, &w);
    } else {
        int4 pl = cand_lists[j >> 3];
        a = cb_list_of(cb, sp, cand + pl.x, pl.y, lo, hi, U, U, &w);
    }
    cb_finish(cb, &a, U, U, &w);
}

/* The octants of the kept boxes: box 8 k + o of the next level is octant o (x, y, z bits)
   of box sel[k] (edge: the octants' edge in cells), in the same brick's block blk */
__kernel void build_expand(__global const int4* restrict origins, __global const int* restrict blk,
                           __global const int* restrict sel, int n_kept, int edge,
                           __global int4* next, __global int* next_blk)
{
    int i = get_global_id(0);
    if (i >= 8 * n_kept)
        return;
    int k = i >> 3, o = i & 7, j = sel[k];
    next[i] = origins[j] + edge * (int4)(o & 1, (o >> 1) & 1, o >> 2, 0);
    next_blk[i] = blk[j];
}

/* Classified boxes of edge size cells (bricks' multiples) into the brick table: every
   brick of the box inside the grid takes (class, bound bits) */
__kernel void build_paint_bricks(__global const int4* restrict origins,
                                 __global const int4* restrict out, int n_boxes, int size,
                                 int4 bdims, __global int2* table)
{
    int j = get_global_id(0);
    if (j >= n_boxes || out[j].x == 0)
        return;
    int4 b0 = origins[j] / VR_CELL_BRICK;
    int nb = size / VR_CELL_BRICK;
    for (int z = b0.z; z < min(b0.z + nb, bdims.z); ++z)
        for (int y = b0.y; y < min(b0.y + nb, bdims.y); ++y)
            for (int x = b0.x; x < min(b0.x + nb, bdims.x); ++x)
                table[(z * bdims.y + y) * bdims.x + x] = (int2)(out[j].x, out[j].z);
}

/* The mixed bricks (kept at brick size): brick table entry (block k, 0), the block of
   CELL_BRICK^3 cells the cell levels fill */
__kernel void build_mark_mixed(__global const int4* restrict origins,
                               __global const int* restrict sel, int n_kept, int4 bdims,
                               __global int2* table, __global int* blk)
{
    int k = get_global_id(0);
    if (k >= n_kept)
        return;
    int4 b = origins[sel[k]] / VR_CELL_BRICK;
    table[(b.z * bdims.y + b.y) * bdims.x + b.x] = (int2)(k, 0);
    blk[sel[k]] = k;
}

/* Classified boxes of edge size cells inside one brick into its block of the cell table;
   with lists (the last level: size 1, every kept box), kept box k writes (k, 0) */
__kernel void build_paint_cells(__global const int4* restrict origins,
                                __global const int* restrict blk,
                                __global const int4* restrict out, int n_boxes, int size,
                                __global int2* cells)
{
    int j = get_global_id(0);
    if (j >= n_boxes || out[j].x == 0)
        return;
    int4 l = origins[j] % VR_CELL_BRICK;
    __global int2* block = cells + blk[j] * VR_CELL_BRICK * VR_CELL_BRICK * VR_CELL_BRICK;
    for (int z = l.z; z < l.z + size; ++z)
        for (int y = l.y; y < l.y + size; ++y)
            for (int x = l.x; x < l.x + size; ++x)
                block[(z * VR_CELL_BRICK + y) * VR_CELL_BRICK + x] = (int2)(out[j].x, out[j].z);
}

/* the listed cells (the last level's kept boxes k): cell entry (k, 0) */
__kernel void build_mark_listed(__global const int4* restrict origins,
                                __global const int* restrict blk,
                                __global const int* restrict sel, int n_kept,
                                __global int2* cells)
{
    int k = get_global_id(0);
    if (k >= n_kept)
        return;
    int j = sel[k];
    int4 l = origins[j] % VR_CELL_BRICK;
    cells[blk[j] * VR_CELL_BRICK * VR_CELL_BRICK * VR_CELL_BRICK +
          (l.z * VR_CELL_BRICK + l.y) * VR_CELL_BRICK + l.x] = (int2)(k, 0);
}

/* The walk order the renderer reads (cl/cells.h): list k's spheres one by one, entries
   (sphere, key bits) at entries[walk[k].x, + walk[k].y), in non-decreasing key, each key
   at most lo_i - pad (below the sphere's distance from any point of the cell, rounding
   included). A walk can then stop at the first key >= m (pass 1) or >= m + k (pass 2): no
   later sphere is nearer, or within the blend. counts[k] = (list spheres, core spheres)
   for the offsets' scan. */
__kernel void build_walk_count(__global const int4* restrict lists,
                               __global const int2* restrict runs, int n_lists,
                               __global int2* counts)
{
    int k = get_global_id(0);
    if (k >= n_lists)
        return;
    int4 l = lists[k];
    int n = 0, nc = 0;
    for (int j = l.x; j < l.x + l.y; ++j)
        n += runs[j].y;
    for (int j = l.z; j < l.z + l.w; ++j)
        nc += runs[j].y;
    counts[k] = (int2)(n, nc);
}

#define CB_WALK_BINS 64

/* list k (cell sel[k] of the last level, classified as out[sel[k]]) into its entries by a
   counting sort on CB_WALK_BINS bins: bin 0 has lower edge -inf, bins 1.. split [U - diag
   - pad, U + k + pad] evenly, where every key lies (lo_i <= U + k + pad on the list; the
   sphere j with lo_j = M has U <= hi_j <= M + diag). A sphere goes to the last bin whose
   edge is at most its key, and the entry keeps that edge as its key (a lower bound, so the
   walk's stops stay exact; any key lands somewhere, rounding included). Two passes over
   the list and no sort in global memory (a Shell sort there cost the bunny's build on
   PoCL x1.6 in kernel time). */
__kernel void build_walk_fill(__constant CellBuild* cb, __global const float4* restrict sp,
                              __global const int* restrict sel,
                              __global const int4* restrict origins,
                              __global const int4* restrict out,
                              __global const int4* restrict lists,
                              __global const int2* restrict runs,
                              __global const int4* restrict walk, __global int2* entries,
                              int n_lists)
{
    int k = get_global_id(0);
    if (k >= n_lists)
        return;
    float3 lo, hi;
    cb_box(cb, origins, sel[k], &lo, &hi);
    int4 l = lists[k];
    __global int2* e = entries + walk[k].x;
    float U = as_float(out[sel[k]].w), blend = cb->blend > VR_BLEND_MIN ? cb->blend : 0.0f;
    float diag = length(hi - lo), base = U - diag - cb->pad;
    float width = (diag + blend + 2.0f * cb->pad) * (1.0f / (CB_WALK_BINS - 1));
    float edge[CB_WALK_BINS];
    int start[CB_WALK_BINS];
    for (int b = 0; b < CB_WALK_BINS; ++b) {
        edge[b] = b == 0 ? -INFINITY : base + (float)(b - 1) * width;
        start[b] = 0;
    }
    for (int pass = 0; pass < 2; ++pass) {
        for (int j = l.x; j < l.x + l.y; ++j)
            for (int i = runs[j].x; i < runs[j].x + runs[j].y; ++i) {
                float dlo, dhi;
                cb_sphere(sp[i], lo, hi, &dlo, &dhi);
                float key = dlo - cb->pad;
                float f = width > 0.0f ? fmin((key - base) / width, (float)CB_WALK_BINS) : 0.0f;
                int b = f >= 0.0f ? min((int)f + 1, CB_WALK_BINS - 1) : 0;   /* NaN: 0 */
                while (b > 0 && !(edge[b] <= key))
                    --b;
                while (b < CB_WALK_BINS - 1 && edge[b + 1] <= key)
                    ++b;
                if (pass == 0)
                    ++start[b];                       /* counts, then offsets */
                else
                    e[start[b]++] = (int2)(i, as_int(edge[b]));
            }
        if (pass == 0) {
            int sum = 0;
            for (int b = 0; b < CB_WALK_BINS; ++b) {
                int c = start[b];
                start[b] = sum;
                sum += c;
            }
        }
    }
}
