/* Glass shading: environment, tracing against the field, shadows, highlights and one
   path through up to `bounces` surface events (render_glass.cl). Include after sdf.h and
   glass.h. Reads the flags render_glass.cl lists. */
#ifndef VR_SHADE_GLASS_H
#define VR_SHADE_GLASS_H

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
   estimate; an approximation, exact only for the hard limit). The march is sdf_march's
   (over-relaxed, cells skipped); a skipped cell enters the penumbra estimate with its
   lower bound at its exit (bound / (cone t_exit) <= F / (cone t) there: never brighter
   than the evaluated points would say). */
inline float glass_shadow(const SdfScene* sc, __constant GlassParams* gp, float3 o, float3 d,
                          float base, float tmax)
{
    float2 tt = vr_ray_box(o, 1.0f / d, gp->box_lo.xyz, gp->box_hi.xyz);
    float t0 = fmax(tt.x, 0.0f), t1 = fmin(tt.y, tmax);
    float vis = 1.0f, t;
    SdfSample s;
    if (t0 <= t1 && sdf_march(sc, o, d, t0, t1, 1.0f, gp->epsilon, base, gp->max_steps,
                              gp->relax, gp->shadow_cone, &vis, &t, &s))
        return 0.0f;
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
        tint = gp->eye_color.xyz;              /* the host's blend at the eye (glass.eye_color) */
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

#endif
