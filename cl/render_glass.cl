/* Molten-glass point clouds: one work-item per pixel follows one path per sample through
   up to `bounces` surface events of the smooth union of spheres (render frame).
   Inputs: Camera, GlassParams, lights, spheres (tree order), tree nodes, environment.
   Output: rgba, alpha = coverage of the primary ray.
   Flags: VR_TREE, VR_N_SUNS, VR_N_POINTS, VR_SHADOWS, VR_REFRACTION, VR_ABSORPTION,
          VR_GLOW, VR_ENV_MAP. */
#if !defined(VR_TREE) || !defined(VR_N_SUNS) || !defined(VR_N_POINTS) || \
    !defined(VR_SHADOWS) || !defined(VR_REFRACTION) || !defined(VR_ABSORPTION) || \
    !defined(VR_GLOW) || !defined(VR_ENV_MAP)
#error "render_glass.cl: a VR_* feature flag is missing (see volrender/features.py)"
#endif

#include "common.h"
#include "structs.h"
#include "camera.h"
#include "sdf.h"
#include "glass.h"

#define VR_N_LIGHTS (VR_N_SUNS + VR_N_POINTS)

inline float3 glass_env(__constant GlassParams* gp, __global const float4* env, float3 d)
{
#if VR_ENV_MAP
    return glass_env_map(env, gp->env_width, gp->env_height, d);
#else
    return glass_sky(d);
#endif
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
    return sdf_trace(sc, o, d, t0, t1, side, gp->epsilon, base, gp->max_steps, t, s);
}

#if VR_N_LIGHTS > 0
/* Light i seen from p: unit direction towards it, its distance and incident radiance
   (irradiance on a plane facing it), including the shadow test. */
inline float3 glass_light(const SdfScene* sc, __constant GlassParams* gp,
                          __constant Light* lights, int i, float3 p, float base, float3* l)
{
    float3 e = lights[i].radiance.xyz;
    float dist = INFINITY;
    if (i < VR_N_SUNS) {
        *l = -lights[i].vec.xyz;
    } else {
        float3 to = lights[i].vec.xyz - p;
        float r2 = dot(to, to);
        dist = sqrt(r2);
        *l = dist > 0.0f ? to / dist : (float3)(0.0f, 1.0f, 0.0f);
        e /= fmax(r2, 1e-12f * gp->scale * gp->scale);
    }
#if VR_SHADOWS
    float t;
    SdfSample s;
    if (glass_trace(sc, gp, p, *l, 1.0f, base, dist, &t, &s))
        return (float3)(0.0f);
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
        float3 e = glass_light(sc, gp, lights, i, p, base, &l);
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
    int inside = sdf_eval(sc, o).f < 0.0f;     /* camera inside glass */
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
        if (inside) {
#if VR_ABSORPTION
            float3 tau = gp->absorption.xyz * t;
#if VR_GLOW
            /* integral of exp(-a s) over [0, t] = t (1 - exp(-a t)) / (a t) */
            float3 w = select(-expm1(-tau) / tau, (float3)(1.0f), isless(tau, (float3)(1e-6f)));
            rgb += thr * gp->glow * gp->color.xyz * t * w;
#endif
            thr *= exp(-tau);
#elif VR_GLOW
            rgb += thr * gp->glow * gp->color.xyz * t;
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
        if (!inside) {
            rgb += thr * (fr * gp->reflectivity) * glass_env(gp, env, refl);
#if VR_N_LIGHTS > 0
            rgb += thr * fr * glass_highlights(sc, gp, lights, p_out, nf, -d, path + floor_len);
#endif
        }
#if VR_REFRACTION
        float3 td;
        if (glass_refract(d, nf, eta, &td)) {
            thr *= 1.0f - fr;
            d = td;
            o = p - off * nf;
            inside = !inside;
        } else {                                         /* total internal reflection */
            d = refl;
            o = p_out;
        }
#else
        /* opaque: diffuse tint lit by the environment around n and the lights */
        float3 diffuse = glass_env(gp, env, n);
#if VR_N_LIGHTS > 0
        for (int i = 0; i < VR_N_LIGHTS; ++i) {
            float3 l;
            float3 e = glass_light(sc, gp, lights, i, p_out, path + floor_len, &l);
            diffuse += e * fmax(dot(n, l), 0.0f) * (1.0f / VR_PI);
        }
#endif
        return rgb + thr * (1.0f - fr) * gp->color.xyz * diffuse;
#endif
    }
    return rgb + thr * glass_env(gp, env, d);
}

__kernel void render_glass(__constant Camera* cam, __constant GlassParams* gp,
                           __constant Light* lights, __global const float4* spheres,
                           __global const TreeNode* nodes, __global const float4* env,
                           __global float4* out, int y0)
{
    int x = get_global_id(0), y = y0 + get_global_id(1);
    if (x >= cam->width || y >= cam->height)
        return;
    uint pixel = (uint)(y * cam->width + x);
    SdfScene sc = { spheres, nodes, gp->n_spheres, gp->first_leaf, gp->blend };
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
    out[pixel] = (float4)(acc * inv, cover * inv);
}
