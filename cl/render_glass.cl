/* Molten-glass point clouds: one work-item per pixel follows one path per sample through
   up to `bounces` surface events of the smooth union of spheres (render frame).
   Inputs: Camera, GlassParams, lights, spheres (tree order), tree nodes, environment,
   per-sphere colours. Output: rgba, alpha = coverage of the primary ray.
   Flags: VR_TREE, VR_N_SUNS, VR_N_POINTS, VR_SHADOWS, VR_REFRACTION, VR_ABSORPTION,
          VR_GLOW, VR_ENV_MAP, VR_COLORS, VR_TILED (+ VR_TILE_W, VR_TILE_H, VR_TILE_CAP),
          VR_UBER (every feature compiled in, chosen at run time by GlassParams.uber and
          the light counts in GlassParams: the kernel-specialisation baseline),
          VR_STATS (diagnostics: rgb holds the field evaluations, node tests and sphere
          tests per pixel, summed over its samples). */
#if !defined(VR_TREE) || !defined(VR_N_SUNS) || !defined(VR_N_POINTS) || \
    !defined(VR_SHADOWS) || !defined(VR_REFRACTION) || !defined(VR_ABSORPTION) || \
    !defined(VR_GLOW) || !defined(VR_ENV_MAP) || !defined(VR_COLORS) || \
    !defined(VR_TILED) || !defined(VR_UBER) || !defined(VR_STATS)
#error "render_glass.cl: a VR_* feature flag is missing (see volrender/features.py)"
#endif

#include "common.h"
#include "structs.h"
#include "camera.h"
#include "sdf.h"
#include "glass.h"

/* Runtime feature bits of the uber-kernel (glass.UBER_BITS). */
#define VR_BIT_SHADOWS 1
#define VR_BIT_REFRACTION 2
#define VR_BIT_ABSORPTION 4
#define VR_BIT_GLOW 8
#define VR_BIT_ENV_MAP 16
#define VR_BIT_COLORS 32

#if VR_UBER
#define VR_ON(bit) (gp->uber & (bit))
#define VR_NSUNS (gp->n_suns)
#define VR_N_LIGHTS (gp->n_suns + gp->n_points)
#define VR_LIT 1
#else
#define VR_ON(bit) 1
#define VR_NSUNS VR_N_SUNS
#define VR_N_LIGHTS (VR_N_SUNS + VR_N_POINTS)
#define VR_LIT (VR_N_SUNS + VR_N_POINTS > 0)
#endif

inline float3 glass_env(__constant GlassParams* gp, __global const float4* env, float3 d)
{
#if VR_ENV_MAP
    if (VR_ON(VR_BIT_ENV_MAP))
        return glass_env_map(env, gp->env_width, gp->env_height, d);
#endif
    return glass_sky(d);
}

/* Trace from o along d, clipped to the scene box and tmax; side -1 marches inside. */
inline int glass_trace(const SdfScene* sc, __constant GlassParams* gp, float3 o, float3 d,
                       float side, float base, float tmax, float* t, SdfSample* s)
{
    float2 tt = vr_ray_box(o, 1.0f / d, gp->box_lo.xyz, gp->box_hi.xyz);
    float t0 = fmax(tt.x, 0.0f), t1 = fmin(tt.y, tmax);
    *t = 0.0f;
    if (!(t0 <= t1))
        return 0;
    return sdf_trace(sc, o, d, t0, t1, side, gp->epsilon, base, gp->max_steps, gp->relax, t, s);
}

#if VR_LIT
#if VR_SHADOWS
/* Visibility of a light along o + t d, t < tmax: 0 when the ray hits glass. Hard with
   shadow_cone 0; else soft: min over the march of F / (cone t), the fraction of a cone
   of half-angle atan(cone) around the ray that the glass leaves open (Quilez's penumbra
   estimate; an approximation, exact only for the hard limit). Over-relaxed like
   sdf_trace, with the same fallback, so thin glass is not stepped over. */
inline float glass_shadow(const SdfScene* sc, __constant GlassParams* gp, float3 o, float3 d,
                          float base, float tmax)
{
    float2 tt = vr_ray_box(o, 1.0f / d, gp->box_lo.xyz, gp->box_hi.xyz);
    float t = fmax(tt.x, 0.0f), t1 = fmin(tt.y, tmax);
    float cone = gp->shadow_cone, vis = 1.0f;
    float w = gp->relax, step = 0.0f, r_prev = 0.0f;
    for (int i = 0; i < gp->max_steps && t <= t1; ++i) {
        SdfSample s = sdf_eval(sc, o + t * d);
        float r = s.f / s.lip;
        if (w > 1.0f && r + r_prev < step) {
            t -= step - step / w;              /* back to the plain step */
            step /= w;
            w = 1.0f;
            continue;
        }
        if (s.f < gp->epsilon * (base + t))
            return 0.0f;
        if (cone > 0.0f)
            vis = fmin(vis, s.f / (cone * fmax(t, 1e-30f)));
        step = w * r;
        r_prev = r;
        t += step;
    }
    /* smooth the ratio into a penumbra weight */
    vis = clamp(vis, 0.0f, 1.0f);
    return vis * vis * (3.0f - 2.0f * vis);
}
#endif

/* Light i seen from p on a surface with normal n: unit direction *l towards it and its
   incident radiance (irradiance on a plane facing it) including the shadow test; zero,
   with no shadow ray, when it is behind the surface. */
inline float3 glass_light(const SdfScene* sc, __constant GlassParams* gp,
                          __constant Light* lights, int i, float3 p, float3 n, float base,
                          float3* l)
{
    float3 e = lights[i].radiance.xyz;
    float dist = INFINITY;
    if (i < VR_NSUNS) {
        *l = -lights[i].vec.xyz;
    } else {
        float3 to = lights[i].vec.xyz - p;
        float r2 = dot(to, to);
        dist = sqrt(r2);
        *l = dist > 0.0f ? to / dist : (float3)(0.0f, 1.0f, 0.0f);
        e /= fmax(r2, 1e-12f * gp->scale * gp->scale);
    }
    if (dot(n, *l) <= 0.0f)
        return (float3)(0.0f);
#if VR_SHADOWS
    if (VR_ON(VR_BIT_SHADOWS))
        e *= glass_shadow(sc, gp, p, *l, base, dist);
#endif
    return e;
}

/* Normalised Blinn-Phong highlights at p (already offset outwards), normal n, towards v. */
inline float3 glass_highlights(const SdfScene* sc, __constant GlassParams* gp,
                               __constant Light* lights, float3 p, float3 n, float3 v,
                               float base)
{
    float3 sum = (float3)(0.0f);
    float norm = (gp->shininess + 8.0f) * (1.0f / (8.0f * VR_PI));
    for (int i = 0; i < VR_N_LIGHTS; ++i) {
        float3 l;
        float3 e = glass_light(sc, gp, lights, i, p, n, base, &l);
        float ndl = dot(n, l);
        if (ndl <= 0.0f)
            continue;
        float3 hv = l + v;
        float hl = length(hv);
        float ndh = hl > 0.0f ? fmax(dot(n, hv / hl), 0.0f) : 0.0f;
        sum += e * ndl * norm * pow(ndh, gp->shininess);
    }
    return sum;
}
#endif

/* Radiance along one primary ray; *covered = the ray starts in or hits glass. */
inline float3 glass_path(const SdfScene* sc, __constant GlassParams* gp,
                         __constant Light* lights, __global const float4* env,
                         float3 o, float3 d, int* covered)
{
    float3 rgb = (float3)(0.0f), thr = (float3)(1.0f);
    float path = 0.0f;                         /* length travelled before o */
    float floor_len = 1e-2f * gp->scale;       /* hit-threshold floor near the eye */
    float eps = gp->epsilon;
    SdfSample s0 = sdf_eval(sc, o);
    int inside = s0.f < 0.0f;                  /* camera inside glass */
    float3 tint = gp->color.xyz;               /* glow colour of the glass we are in */
#if VR_COLORS
    if (VR_ON(VR_BIT_COLORS) && inside)
        tint = s0.color;
#endif
    *covered = inside;
    for (int b = 0;; ++b) {
        if (b >= gp->bounces && !inside)
            break;
        float t;
        SdfSample s;
        int hit = glass_trace(sc, gp, o, d, inside ? -1.0f : 1.0f, path + floor_len,
                              INFINITY, &t, &s);
        if (b == 0)
            *covered |= hit;
#if VR_REFRACTION
        /* Beer-Lambert and emission over the segment inside glass */
        if (inside && VR_ON(VR_BIT_REFRACTION)) {
#if VR_ABSORPTION
            if (VR_ON(VR_BIT_ABSORPTION)) {
                float3 tau = gp->absorption.xyz * t;
#if VR_GLOW
                /* integral of exp(-a s) over [0, t] = t (1 - exp(-a t)) / (a t) */
                if (VR_ON(VR_BIT_GLOW)) {
                    float3 w = select(-expm1(-tau) / tau, (float3)(1.0f), isless(tau, (float3)(1e-6f)));
                    rgb += thr * gp->glow * tint * t * w;
                }
#endif
                thr *= exp(-tau);
            }
#if VR_GLOW
            else if (VR_ON(VR_BIT_GLOW)) {
                rgb += thr * gp->glow * tint * t;
            }
#endif
#elif VR_GLOW
            if (VR_ON(VR_BIT_GLOW))
                rgb += thr * gp->glow * tint * t;
#endif
        }
#endif
        if (!hit || b >= gp->bounces)
            break;
        path += t;
        float3 p = o + t * d;
        float gl = length(s.grad);
        float3 n = gl > 0.0f ? s.grad / gl : -d;          /* outward normal */
        float3 nf = inside ? -n : n;                     /* towards the incident side */
        float eta = inside ? gp->ior : 1.0f / gp->ior;
        float cos_i = clamp(-dot(d, nf), 0.0f, 1.0f);
        float fr = glass_fresnel(cos_i, eta);
        float3 refl = glass_reflect(d, nf);
        float off = 4.0f * eps * fmax(path + floor_len, length(p));
        float3 p_out = p + off * nf;                     /* incident side */
        float3 col = gp->color.xyz;
#if VR_COLORS
        if (VR_ON(VR_BIT_COLORS))
            col = s.color;
#endif
        if (!inside) {
            rgb += thr * (fr * gp->reflectivity) * glass_env(gp, env, refl);
#if VR_LIT
            rgb += thr * fr * glass_highlights(sc, gp, lights, p_out, nf, -d, path + floor_len);
#endif
        }
#if VR_REFRACTION
        if (VR_ON(VR_BIT_REFRACTION)) {
            float3 td;
            if (glass_refract(d, nf, eta, &td)) {
                thr *= 1.0f - fr;
                d = td;
                o = p - off * nf;
                inside = !inside;
                tint = col;                              /* entering: this glass glows */
            } else if (!inside) {
                /* ior < 1, total reflection from outside: F = 1, already counted above */
                return rgb;
            } else {                                     /* total internal reflection */
                d = refl;
                o = p_out;
            }
            continue;
        }
#endif
#if !VR_REFRACTION || VR_UBER
        /* opaque: diffuse tint lit by the environment around n and the lights */
        float3 diffuse = glass_env(gp, env, n);
#if VR_LIT
        for (int i = 0; i < VR_N_LIGHTS; ++i) {
            float3 l;
            float3 e = glass_light(sc, gp, lights, i, p_out, n, path + floor_len, &l);
            diffuse += e * fmax(dot(n, l), 0.0f) * (1.0f / VR_PI);
        }
#endif
        return rgb + thr * (1.0f - fr) * col * diffuse;
#endif
    }
    return rgb + thr * glass_env(gp, env, d);
}

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
#if VR_TREE
    /* one subtree per work-item from the level with about a group's worth of nodes */
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

#if VR_TILED
__kernel __attribute__((reqd_work_group_size(VR_TILE_W, VR_TILE_H, 1)))
#else
__kernel
#endif
void render_glass(__constant Camera* cam, __constant GlassParams* gp,
                  __constant Light* lights, __global const float4* restrict spheres,
                  __global const TreeNode* restrict nodes, __global const float4* env,
                  __global const float4* restrict colors, __global float4* out, int y0)
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
    SdfScene sc;
    sc.spheres = spheres;
    sc.nodes = nodes;
    sc.n_spheres = gp->n_spheres;
    sc.first_leaf = gp->first_leaf;
    sc.k = gp->blend;
#if VR_COLORS
    sc.colors = colors;
#endif
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
    float3 acc = (float3)(0.0f);
    float cover = 0.0f;
    for (int s = 0; s < cam->spp; ++s) {
        float2 j = vr_pixel_jitter(cam, pixel, (uint)s);
        float3 d = vr_camera_dir(cam, x, y, j.x, j.y);
        int covered;
        acc += glass_path(&sc, gp, lights, env, cam->origin.xyz, d, &covered);
        cover += (float)covered;
    }
    float inv = 1.0f / (float)cam->spp;
#if VR_STATS
    acc = convert_float3(stats) * (float)cam->spp;   /* so that * inv gives the totals */
#endif
    out[pixel] = (float4)(acc * inv, cover * inv);
}
