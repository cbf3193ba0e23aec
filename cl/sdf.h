/* Smooth union of spheres, tree traversal and sphere tracing.
   Field: d_i = |x - c_i| - r_i, m = min_i d_i, h_i = max(0, 1 - (d_i - m)/k),
   S = sum_i h_i^2 (the nearest sphere gives 1), F = m - (k/2) ln S: a plain sum, so
   independent of visiting order. For two spheres F is C1 across the seam (slopes 1/2 and
   1/2 where d_a = d_b); the bulge over the plain union is at most (k/2) ln N (N spheres
   at equal distance), instead of growing linearly with N as a sum of pairwise smins does.
   Support: sphere i matters only where d_i < m + k.
   Flags: VR_TREE; VR_TILED (a work-group's sphere list in local memory, exact wherever
   m + k <= its margin, see render_glass.cl); VR_COLORS (per-sphere colours, blended with
   the weights h_i^2 / S). */
#ifndef VR_SDF_H
#define VR_SDF_H

#if !defined(VR_TREE) || !defined(VR_TILED) || !defined(VR_COLORS)
#error "sdf.h: VR_TREE, VR_TILED or VR_COLORS is missing (see volrender/features.py)"
#endif

#ifndef VR_TREE_STACK
#define VR_TREE_STACK 48      /* tree depth + 1 (one push per level); the host sets it */
#endif
#define VR_BLEND_MIN 1e-20f   /* k at or below: plain union */

typedef struct {
    __global const float4* spheres;   /* centre xyz, radius w; render frame, tree order */
    __global const TreeNode* nodes;   /* heap layout, root 1 (unused when VR_TREE == 0) */
    int n_spheres;
    int first_leaf;
    float k;                          /* blend, world units */
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
} SdfScene;

typedef struct {
    float f;      /* field value */
    float lip;    /* local bound on |grad F|: 1 + 2 sum_{i != argmin} h_i / S */
    float3 grad;  /* analytic gradient (not normalised) */
#if VR_COLORS
    float3 color; /* sum_i h_i^2 c_i / S */
#endif
} SdfSample;

inline float sdf_sphere(float4 s, float3 x)
{
    return length(x - s.xyz) - s.w;
}

inline float3 sdf_sphere_normal(float4 s, float3 x)
{
    float3 v = x - s.xyz;
    float len = length(v);
    return len > 0.0f ? v / len : (float3)(0.0f);
}

/* Lower bound of d_i over a node's spheres: distance to its box, -inf inside it. */
inline float sdf_node_bound(__global const TreeNode* nd, float3 x)
{
    float3 lo = (float3)(nd->lo_x, nd->lo_y, nd->lo_z);
    float3 hi = (float3)(nd->hi_x, nd->hi_y, nd->hi_z);
    float3 g = fmax(fmax(lo - x, x - hi), (float3)(0.0f));
    float q = dot(g, g);
    return q > 0.0f ? sqrt(q) * 0.999999f : -INFINITY;   /* shrunk: rounding-safe */
}

/* One sphere's blend terms: h, h^2 and h * normal, for d < thr = m + k. */
#define SDF_ACCUMULATE(s4, idx)                                          \
    {                                                                 \
        float d = sdf_sphere(s4, x);                                  \
        if (d < thr) {                                                \
            float h = fmax(1.0f - (d - m) * inv_k, 0.0f);             \
            s1 += h; s2 += h * h; g += h * sdf_sphere_normal(s4, x);  \
            SDF_COLOR_ADD(h * h, idx)                                 \
        }                                                             \
    }

#if VR_COLORS
#define SDF_COLOR_ADD(w, idx) col += (w) * sc->colors[idx].xyz;
#else
#define SDF_COLOR_ADD(w, idx)
#endif

/* Second pass, only when the candidate list overflows: sums over all spheres with
   d_i < m + k (the argmin included, h = 1). */
inline void sdf_blend_sums(const SdfScene* sc, float3 x, float m, float* s1_out,
                           float* s2_out, float3* g_out, float3* col_out)
{
    float thr = m + sc->k, inv_k = 1.0f / sc->k;
    float s1 = 0.0f, s2 = 0.0f;
    float3 g = (float3)(0.0f), col = (float3)(0.0f);
#if VR_TREE
    int stack[VR_TREE_STACK];
    int sp = 0;
    int node = sdf_node_bound(sc->nodes + 1, x) < thr ? 1 : 0;
    while (node) {
        if (node >= sc->first_leaf) {
            __global const TreeNode* nd = sc->nodes + node;
            int end = nd->start + nd->count;
            for (int i = nd->start; i < end; ++i)
                SDF_ACCUMULATE(sc->spheres[i], i)
            node = 0;
        } else {
            int c0 = 2 * node, c1 = c0 + 1;
            int in0 = sdf_node_bound(sc->nodes + c0, x) < thr;
            int in1 = sdf_node_bound(sc->nodes + c1, x) < thr;
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
    *s1_out = s1;
    *s2_out = s2;
    *g_out = g;
    *col_out = col;
}

/* One pass for the common case: the traversal prunes against the running m + k and
   keeps every sphere with d_i < m + k (at the time it is seen) in a private list; m only
   falls, so nothing dropped can re-enter. The list is compacted when full; if it still
   overflows, the sums come from the second pass instead. Returns the list length, or -1 on
   overflow. */
#ifndef VR_CAND
#define VR_CAND 24            /* private candidate list (the host sets it: glass.CANDIDATES) */
#endif

inline int sdf_candidates(const SdfScene* sc, float3 x, float* m_out, int* arg,
                          float* cd, int* ci, int use_tile)
{
    float m = INFINITY;
    int a = -1, n = 0, over = 0;
    float k = sc->k;
#define SDF_CONSIDER(s4, i)                                                   \
    {                                                                         \
        float d = sdf_sphere(s4, x);                                          \
        if (d < m + k) {                                                      \
            if (d < m) { m = d; a = i; }                                      \
            if (n == VR_CAND) {            /* compact against the current m */ \
                int w = 0;                                                    \
                for (int r = 0; r < VR_CAND; ++r)                             \
                    if (cd[r] < m + k) { cd[w] = cd[r]; ci[w] = ci[r]; ++w; }  \
                n = w;                                                        \
            }                                                                 \
            if (n < VR_CAND) { cd[n] = d; ci[n] = i; ++n; } else over = 1;    \
        }                                                                     \
    }
#if VR_TILED
    if (use_tile) {
        for (int j = 0; j < sc->tile_n; ++j)
            SDF_CONSIDER(sc->tile[j], sc->tile_idx[j])
    } else {
#endif
#if VR_TREE
    int stack[VR_TREE_STACK];
    float sb[VR_TREE_STACK];
    int sp = 0;
    int node = 1;
    while (node) {
        if (node >= sc->first_leaf) {
            __global const TreeNode* nd = sc->nodes + node;
            int end = nd->start + nd->count;
            for (int i = nd->start; i < end; ++i)
                SDF_CONSIDER(sc->spheres[i], i)
            node = 0;
        } else {
            int c0 = 2 * node, c1 = c0 + 1;
            float b0 = sdf_node_bound(sc->nodes + c0, x), b1 = sdf_node_bound(sc->nodes + c1, x);
            if (b1 < b0) { int cs = c0; c0 = c1; c1 = cs; float bt = b0; b0 = b1; b1 = bt; }
            node = 0;
            if (b0 < m + k) {
                node = c0;
                if (b1 < m + k) { stack[sp] = c1; sb[sp] = b1; ++sp; }
            }
        }
        while (!node && sp > 0) {
            --sp;
            if (sb[sp] < m + k)
                node = stack[sp];
        }
    }
#else
    for (int i = 0; i < sc->n_spheres; ++i)
        SDF_CONSIDER(sc->spheres[i], i)
#endif
#if VR_TILED
    }
#endif
#undef SDF_CONSIDER
    *m_out = m;
    *arg = a;
    return over ? -1 : n;
}

/* F, its Lipschitz bound and analytic gradient at x (render frame). */
inline SdfSample sdf_eval(const SdfScene* sc, float3 x)
{
    SdfSample r;
    r.lip = 1.0f;
    r.grad = (float3)(0.0f);
#if VR_COLORS
    r.color = (float3)(0.0f);
#endif
    int a;
    float m;
    float cd[VR_CAND];
    int ci[VR_CAND];
    /* k -> 0: the plain union; the traversal then prunes against m alone */
    if (!(sc->k > VR_BLEND_MIN)) {
        sdf_candidates(sc, x, &m, &a, cd, ci, 0);
        r.f = m;
        if (a >= 0) {
            r.grad = sdf_sphere_normal(sc->spheres[a], x);
#if VR_COLORS
            r.color = sc->colors[a].xyz;
#endif
        }
        return r;
    }
#if VR_TILED
    int n = -1;
    float3 xe = x - sc->tile_eye;
    if (sc->tile_n >= 0 && dot(sc->tile_pl[0], xe) >= 0.0f && dot(sc->tile_pl[1], xe) >= 0.0f &&
        dot(sc->tile_pl[2], xe) >= 0.0f && dot(sc->tile_pl[3], xe) >= 0.0f) {
        n = sdf_candidates(sc, x, &m, &a, cd, ci, 1);
        if (!(m + sc->k <= sc->tile_margin))   /* a sphere off the list may matter */
            n = sdf_candidates(sc, x, &m, &a, cd, ci, 0);
    } else {
        n = sdf_candidates(sc, x, &m, &a, cd, ci, 0);
    }
#else
    int n = sdf_candidates(sc, x, &m, &a, cd, ci, 0);
#endif
    r.f = m;
    if (a < 0)
        return r;
    float3 na = sdf_sphere_normal(sc->spheres[a], x);
    r.grad = na;
#if VR_COLORS
    r.color = sc->colors[a].xyz;
#endif
    /* k below m's precision: the plain union */
    if (!(m + sc->k > m))
        return r;
    float s1 = 0.0f, s2 = 0.0f;
    float3 g = (float3)(0.0f), col = (float3)(0.0f);
    if (n >= 0) {
        float thr = m + sc->k, inv_k = 1.0f / sc->k;
        for (int j = 0; j < n; ++j) {
            float d = cd[j];
            if (d < thr) {
                float h = fmax(1.0f - (d - m) * inv_k, 0.0f);
                s1 += h; s2 += h * h; g += h * sdf_sphere_normal(sc->spheres[ci[j]], x);
                SDF_COLOR_ADD(h * h, ci[j])
            }
        }
    } else {
        sdf_blend_sums(sc, x, m, &s1, &s2, &g, &col);
    }
    s2 = fmax(s2, 1.0f);                   /* the argmin's h = 1 is in the sums */
    float s1o = fmax(s1 - 1.0f, 0.0f);     /* sum of h over the other spheres */
    float inv_s = 1.0f / s2;
    r.f = m - 0.5f * sc->k * log(s2);
    /* |grad F| <= |grad m| + (1/S) sum' h_i |grad d_i - grad m| <= 1 + 2 sum' h_i / S */
    r.lip = 1.0f + 2.0f * s1o * inv_s;
    /* grad F = grad m + (1/S) sum_i h_i (n_i - n_a) */
    r.grad = na + (g - s1 * na) * inv_s;
#if VR_COLORS
    r.color = col * inv_s;
#endif
    return r;
}

/* Sphere-trace o + t d over [t0, t1] against side * F (side -1: inside glass).
   Hit when side * F < eps * (base + t); safe step r = (side * F) / lip. With relax w > 1
   the step is w r (over-relaxed sphere tracing); when the safe balls of two consecutive
   points do not overlap (r + r_prev < step) the step went too far: go back to the plain
   step and stay at w = 1. No surface is skipped either way. Returns 1 on a hit with *t
   and *s at the hit; else 0 with *t where marching stopped (<= t1). */
inline int sdf_trace(const SdfScene* sc, float3 o, float3 d, float t0, float t1, float side,
                     float eps, float base, int max_steps, float relax, float* t_out,
                     SdfSample* s_out)
{
    float t = t0, w = relax, step = 0.0f, r_prev = 0.0f;
    for (int i = 0; i < max_steps && t <= t1; ++i) {
        SdfSample s = sdf_eval(sc, o + t * d);
        float f = side * s.f;
        float r = f / s.lip;
        if (w > 1.0f && r + r_prev < step) {
            t -= step - step / w;              /* back to the plain step: safe */
            step /= w;
            w = 1.0f;
            continue;
        }
        if (f < eps * (base + t)) {
            *t_out = t;
            *s_out = s;
            return 1;
        }
        step = w * r;
        r_prev = r;
        t += step;
    }
    *t_out = fmin(t, t1);
    return 0;
}

#endif
