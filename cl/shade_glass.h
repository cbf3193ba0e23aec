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

inline float glass_max3(float3 v)
{
    return fmax(v.x, fmax(v.y, v.z));
}

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
/* Visibility of a light along o + t d, t < tmax, through opaque glass: 0 when the ray hits
   it. Hard with shadow_cone 0; else soft: min over the march of F / (cone t), the fraction
   of a cone of half-angle atan(cone) around the ray that the glass leaves open (Quilez's
   penumbra estimate; an approximation, exact only for the hard limit). The march is
   sdf_march's (over-relaxed, cells skipped); a skipped cell enters the penumbra estimate
   with its lower bound at its exit (bound / (cone t_exit) <= F / (cone t) there: never
   brighter than the evaluated points would say). */
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

#if VR_FULL && VR_REFRACTION
/* Transmittance of a light along o + t d, t < tmax, through refracting glass (--glass-model
   full): the straight ray crosses each piece of glass it meets, each crossing multiplying
   by the Fresnel transmission 1 - F at its entry and exit (0 on total internal reflection)
   and by Beer-Lambert over its chord. The light is not bent: caustics are left out. A ray
   that meets no glass takes the soft-shadow penumbra, darkened only by the normal-incidence
   transmission (1 - F0)^2 of the glass it passes, so a soft shadow's edge meets its
   transmitted core. More than max(bounces, 8) crossings block the light. */
inline float3 glass_shadow_full(const SdfScene* sc, __constant GlassParams* gp, float3 o,
                                float3 d, float base, float tmax)
{
    float3 trans = (float3)(1.0f), inv_d = 1.0f / d;
    float eps = gp->epsilon, along = 0.0f, vis = 1.0f;
    int crossings = max(gp->bounces, 8);
    for (int k = 0; k <= crossings; ++k) {
        float2 tt = vr_ray_box(o, inv_d, gp->box_lo.xyz, gp->box_hi.xyz);
        float t0 = fmax(tt.x, 0.0f), t1 = fmin(tt.y, tmax - along), t, v = 1.0f;
        SdfSample s;
        if (!(t0 <= t1) || !sdf_march(sc, o, d, t0, t1, 1.0f, eps, base + along, gp->max_steps,
                                      gp->relax, k ? 0.0f : gp->shadow_cone, &v, &t, &s)) {
            if (k == 0) {
                float f0 = glass_fresnel(1.0f, 1.0f / gp->ior), t00 = (1.0f - f0) * (1.0f - f0);
                v = clamp(v, 0.0f, 1.0f);
                vis = 1.0f - (1.0f - v * v * (3.0f - 2.0f * v)) * (1.0f - t00);
            }
            return trans * vis;
        }
        if (k == crossings)
            break;
        float gl = length(s.grad);
        float3 n = gl > 0.0f ? s.grad / gl : -d;
        float3 p = o + t * d;
        along += t;
        trans *= 1.0f - glass_fresnel(clamp(-dot(d, n), 0.0f, 1.0f), 1.0f / gp->ior);
        float off = 4.0f * eps * fmax(base + along, length(p));
        float3 q = p - off * n;                           /* inside */
        tt = vr_ray_box(q, inv_d, gp->box_lo.xyz, gp->box_hi.xyz);
        if (!sdf_march(sc, q, d, 0.0f, fmax(tt.y, 0.0f), -1.0f, eps, base + along,
                       gp->max_steps, gp->relax, 0.0f, &v, &t, &s))
            return (float3)(0.0f);                        /* no exit found */
        along += t;
#if VR_ABSORPTION
        if (VR_ON(VR_BIT_ABSORPTION))
            trans *= exp(-gp->absorption.xyz * t);
#endif
        gl = length(s.grad);
        n = gl > 0.0f ? s.grad / gl : d;
        trans *= 1.0f - glass_fresnel(clamp(dot(d, n), 0.0f, 1.0f), gp->ior);
        if (!(fmax(trans.x, fmax(trans.y, trans.z)) > 1e-6f))
            return (float3)(0.0f);
        p = q + t * d;
        o = p + 4.0f * eps * fmax(base + along, length(p)) * n;
    }
    return (float3)(0.0f);
}
#endif
#endif

/* Light i seen from p: unit direction *l towards it, its distance *dist (INFINITY for a
   sun) and its unshadowed incident radiance (irradiance on a plane facing it). */
inline float3 glass_light_at(__constant GlassParams* gp, __constant Light* lights, int i,
                             float3 p, float3* l, float* dist)
{
    float3 e = lights[i].radiance.xyz;
    *dist = INFINITY;
    if (i < VR_NSUNS) {
        *l = -lights[i].vec.xyz;
    } else {
        float3 to = lights[i].vec.xyz - p;
        float r2 = dot(to, to);
        *dist = sqrt(r2);
        *l = *dist > 0.0f ? to / *dist : (float3)(0.0f, 1.0f, 0.0f);
        e /= fmax(r2, 1e-12f * gp->scale * gp->scale);
    }
    return e;
}

/* The shadow test from p towards a light along l over dist: its transmittance. */
inline float3 glass_light_shadow(const SdfScene* sc, __constant GlassParams* gp, float3 p,
                                 float3 l, float base, float dist)
{
#if VR_SHADOWS
    if (VR_ON(VR_BIT_SHADOWS)) {
#if VR_FULL && VR_REFRACTION
        if (VR_ON(VR_BIT_REFRACTION))
            return glass_shadow_full(sc, gp, p, l, base, dist);
#endif
        return (float3)(glass_shadow(sc, gp, p, l, base, dist));
    }
#endif
    return (float3)(1.0f);
}

/* Light i seen from p on a surface with normal n: unit direction *l towards it and its
   incident radiance including the shadow test; zero, with no shadow ray, when it is
   behind the surface. */
inline float3 glass_light(const SdfScene* sc, __constant GlassParams* gp,
                          __constant Light* lights, int i, float3 p, float3 n, float base,
                          float3* l)
{
    float dist;
    float3 e = glass_light_at(gp, lights, i, p, l, &dist);
    if (dot(n, *l) <= 0.0f)
        return (float3)(0.0f);
    return e * glass_light_shadow(sc, gp, p, *l, base, dist);
}

/* Normalised Blinn-Phong highlights at p (already offset outwards), normal n, towards v,
   times w (the path's weight times F). A light's unshadowed lobe bounds what it adds: one
   whose bound is below gp->roulette (largest channel) is shadow-tested with probability
   bound / roulette, else skipped (and takes that much more weight when tested): unbiased,
   a sample off by at most `roulette` per light, and the shadow rays of the dim part of
   the lobe (most of them at shininess 200) are saved. *dim: vr_rand's next dimension. */
inline float3 glass_highlights(const SdfScene* sc, __constant GlassParams* gp,
                               __constant Light* lights, float3 p, float3 n, float3 v,
                               float base, float3 w, uint seed, uint pixel, uint sample,
                               uint* dim)
{
    float3 sum = (float3)(0.0f);
    float norm = (gp->shininess + 8.0f) * (1.0f / (8.0f * VR_PI));
    for (int i = 0; i < VR_N_LIGHTS; ++i) {
        float3 l;
        float dist;
        float3 e = glass_light_at(gp, lights, i, p, &l, &dist);
        float ndl = dot(n, l);
        if (ndl <= 0.0f)
            continue;
        float3 hv = l + v;
        float hl = length(hv);
        float ndh = hl > 0.0f ? fmax(dot(n, hv / hl), 0.0f) : 0.0f;
        float3 c = w * e * ndl * norm * pow(ndh, gp->shininess);
        float m = glass_max3(c), rr = gp->roulette;
        if (!(m > 0.0f))
            continue;
        if (m < rr) {
            if (vr_rand(seed, pixel, sample, (*dim)++) * rr >= m)
                continue;
            c *= rr / m;
        }
        sum += c * glass_light_shadow(sc, gp, p, l, base, dist);
    }
    return sum;
}
#endif

/* Opaque spheres (--opaque; the uber-kernel decides at run time) */
#if VR_REFRACTION
#define GLASS_OPAQUE(gp) (!VR_ON(VR_BIT_REFRACTION))
#else
#define GLASS_OPAQUE(gp) 1
#endif

/* One segment of a branch from o along d on its side (inside: marching in glass), up to
   the next surface; inside glass it absorbs (Beer-Lambert: *thr) and glows with `tint`
   (into *rgb, the integral of the glow over the segment's transmittance). Returns hit,
   with *t and *s at the surface. */
inline int glass_segment(const SdfScene* sc, __constant GlassParams* gp, float3 o, float3 d,
                         int inside, float base, float3 tint, float3* rgb, float3* thr,
                         float* t, SdfSample* s)
{
    int hit = glass_trace(sc, gp, o, d, inside ? -1.0f : 1.0f, base, INFINITY, t, s);
#if VR_REFRACTION
    if (inside && VR_ON(VR_BIT_REFRACTION)) {
#if VR_ABSORPTION
        if (VR_ON(VR_BIT_ABSORPTION)) {
            float3 tau = gp->absorption.xyz * *t;
#if VR_GLOW
            /* integral of exp(-a s) over [0, t] = t (1 - exp(-a t)) / (a t) */
            if (VR_ON(VR_BIT_GLOW)) {
                float3 w = select(-expm1(-tau) / tau, (float3)(1.0f),
                                  isless(tau, (float3)(1e-6f)));
                *rgb += *thr * gp->glow * tint * *t * w;
            }
#endif
            *thr *= exp(-tau);
            return hit;
        }
#endif
#if VR_GLOW
        if (VR_ON(VR_BIT_GLOW))
            *rgb += *thr * gp->glow * tint * *t;
#endif
    }
#endif
    return hit;
}

/* A surface event: where a branch at o + t d meets the surface, what the two Fresnel
   branches are, and (outer surfaces) the lights' highlights, weighted by F, into *rgb. */
typedef struct {
    float3 p_in, p_out;   /* the hit point, offset to the far and to the incident side */
    float3 n, nf;         /* outward normal; normal towards the incident side */
    float3 refl, td;      /* reflected and refracted directions (td: refl on TIR) */
    float3 col;           /* the glass's colour there */
    float fr;             /* Fresnel reflectance (1 on total internal reflection) */
    int tir;              /* no refracted direction (or opaque) */
} GlassEvent;

inline GlassEvent glass_event(const SdfScene* sc, __constant GlassParams* gp,
                              __constant Light* lights, float3 o, float3 d, float t,
                              const SdfSample* s, int inside, float base, float3 thr,
                              float3* rgb, uint seed, uint pixel, uint sample, uint* dim)
{
    GlassEvent e;
    float3 p = o + t * d;
    float gl = length(s->grad);
    e.n = gl > 0.0f ? s->grad / gl : -d;
    e.nf = inside ? -e.n : e.n;
    float eta = inside ? gp->ior : 1.0f / gp->ior;
    e.fr = glass_fresnel(clamp(-dot(d, e.nf), 0.0f, 1.0f), eta);
    e.refl = glass_reflect(d, e.nf);
    float off = 4.0f * gp->epsilon * fmax(base, length(p));
    e.p_out = p + off * e.nf;
    e.p_in = p - off * e.nf;
    e.col = gp->color.xyz;
#if VR_COLORS
    if (VR_ON(VR_BIT_COLORS))
        e.col = s->color;
#endif
    e.td = e.refl;
    e.tir = GLASS_OPAQUE(gp) || !glass_refract(d, e.nf, eta, &e.td);
#if VR_LIT
    if (!inside)
        *rgb += glass_highlights(sc, gp, lights, e.p_out, e.nf, -d, base, thr * e.fr, seed,
                                 pixel, sample, dim);
#endif
    return e;
}

/* An opaque sphere's diffuse share: its tint lit by the environment around n and the
   lights. */
inline float3 glass_diffuse(const SdfScene* sc, __constant GlassParams* gp,
                            __constant Light* lights, __global const float4* env,
                            const GlassEvent* e, float base)
{
    float3 diffuse = glass_env(gp, env, e->n);
#if VR_LIT
    for (int i = 0; i < VR_N_LIGHTS; ++i) {
        float3 l;
        float3 li = glass_light(sc, gp, lights, i, e->p_out, e->n, base, &l);
        diffuse += li * fmax(dot(e->n, l), 0.0f) * (1.0f / VR_PI);
    }
#endif
    return (1.0f - e->fr) * e->col * diffuse;
}

/* Is the camera in glass? Then *tint is the glow colour there (the host's blend at the
   eye, glass.eye_color). */
inline int glass_eye_inside(const SdfScene* sc, __constant GlassParams* gp, float3 o,
                            float3* tint)
{
    int inside = sdf_eval(sc, o).f < 0.0f;
    *tint = gp->color.xyz;
#if VR_COLORS
    if (VR_ON(VR_BIT_COLORS) && inside)
        *tint = gp->eye_color.xyz;
#endif
    return inside;
}

/* Where a camera path starts (glass_path): the ray, whether it starts in glass and the
   glow tint there, the hit-threshold floor near the eye, and vr_rand's (seed, pixel,
   sample). */
typedef struct {
    float3 o, d, tint;
    float floor_len;
    int inside;
    uint seed, pixel, sample;
} GlassStart;

/* Radiance along one camera ray (render_glass.cl); *covered = the ray starts in or hits
   glass. Inside glass each segment absorbs and glows (glass_segment); at a surface event
   the Fresnel share F is reflected and 1 - F refracted (total internal reflection: all
   reflected; glass_event). A branch that leaves the clip box reads the environment along
   its direction; one that has used its `bounces` events returns 0 if it meets glass or
   is inside it (a path tracer's depth bounces + 1). rng: (seed, pixel, sample) of
   vr_rand. glass_path (below) starts the path, glass_walk (one per model) follows it. */
#if !VR_FULL
/* --glass-model fast: the path follows the refracted branch; the reflection at an outer
   surface reads the environment only, and at an exit it is dropped. */
inline float3 glass_walk(const SdfScene* sc, __constant GlassParams* gp, __constant Light* lights,
                         __global const float4* env, const GlassStart* st, int* covered)
{
    float3 o = st->o, d = st->d, tint = st->tint, rgb = (float3)(0.0f), thr = (float3)(1.0f);
    float path = 0.0f, floor_len = st->floor_len;
    int inside = st->inside;
    uint seed = st->seed, pixel = st->pixel, sample = st->sample, dim = 2u;
    for (int events = 0;; ++events) {
        float t;
        SdfSample s;
        int hit = glass_segment(sc, gp, o, d, inside, path + floor_len, tint, &rgb, &thr, &t, &s);
        if (events == 0)
            *covered |= hit;
        if (!hit)
            return rgb + thr * glass_env(gp, env, d);
        if (events >= gp->bounces)
            return rgb;                                  /* the budget is spent: 0 */
        path += t;
        GlassEvent e = glass_event(sc, gp, lights, o, d, t, &s, inside, path + floor_len, thr,
                                   &rgb, seed, pixel, sample, &dim);
        if (!inside)
            rgb += thr * (e.fr * gp->reflectivity) * glass_env(gp, env, e.refl);
        if (GLASS_OPAQUE(gp))
            return rgb + thr * glass_diffuse(sc, gp, lights, env, &e, path + floor_len);
        if (e.tir) {
            if (!inside)
                return rgb;                              /* ior < 1: F = 1, counted above */
            d = e.refl;
            o = e.p_out;
        } else {
            thr *= 1.0f - e.fr;
            d = e.td;
            o = e.p_in;
            if (!inside)
                tint = e.col;                            /* entering: this glass glows */
            inside = !inside;
        }
    }
}
#else
#ifndef VR_GLASS_STACK
#define VR_GLASS_STACK 4      /* branches waiting to be traced */
#endif
#ifndef VR_GLASS_SPLITS
#define VR_GLASS_SPLITS 8     /* branches split off per camera path; then merged */
#endif

/* A branch of a path waiting to be traced: where it starts, its weight, the length
   travelled before o, its surface events and side (events << 1 | inside), and with
   per-point colours the glow tint of the glass it is in. Kept small: on GPUs the stack
   lives in private memory. */
typedef struct {
    float3 o, d, thr;
    float path;
    int state;
#if VR_COLORS
    float3 tint;
#endif
} GlassBranch;

/* --glass-model full: both branches are traced like camera rays, so glass shows in
   reflections and exits reflect back inside. The path goes on with the larger branch and
   keeps the other (up to VR_GLASS_STACK waiting, VR_GLASS_SPLITS per path); a kept
   branch weaker than gp->roulette (its largest channel) survives Russian roulette with
   probability weight / roulette (and takes that much more weight): unbiased, and a
   sample then differs from its expectation by at most `roulette` of the branch's radiance
   per decision. Past the budget the weaker branch's weight joins the stronger one (it
   sees what that one sees: energy is kept, the direction approximated). Past
   gp->split_events events one branch goes on, chosen in proportion to its weight (and
   divided by that probability): unbiased, and nothing waits. */
inline float3 glass_walk(const SdfScene* sc, __constant GlassParams* gp, __constant Light* lights,
                         __global const float4* env, const GlassStart* st, int* covered)
{
    GlassBranch stack[VR_GLASS_STACK];
    int sp = 0, splits = 0, events = 0, inside = st->inside;
    float3 o = st->o, d = st->d, tint = st->tint, rgb = (float3)(0.0f), thr = (float3)(1.0f);
    float path = 0.0f, floor_len = st->floor_len;
    uint seed = st->seed, pixel = st->pixel, sample = st->sample, dim = 2u;
    for (;;) {
        float t;
        SdfSample s;
        int hit = glass_segment(sc, gp, o, d, inside, path + floor_len, tint, &rgb, &thr, &t, &s);
        if (events == 0)
            *covered |= hit;                             /* the camera ray's segment */
        int alive = hit && events < gp->bounces;         /* a hit past the budget: 0 */
        if (!hit)
            rgb += thr * glass_env(gp, env, d);
        if (alive) {
            ++events;
            path += t;
            GlassEvent e = glass_event(sc, gp, lights, o, d, t, &s, inside, path + floor_len,
                                       thr, &rgb, seed, pixel, sample, &dim);
            if (GLASS_OPAQUE(gp)) {
                rgb += thr * glass_diffuse(sc, gp, lights, env, &e, path + floor_len);
                thr *= e.fr * gp->reflectivity;          /* the reflection, traced */
                d = e.refl;
                o = e.p_out;
                alive = glass_max3(thr) > 0.0f;
            } else if (e.tir) {
                if (!inside)
                    thr *= gp->reflectivity;             /* ior < 1 outside: F = 1 */
                d = e.refl;
                o = e.p_out;
            } else {
                /* the refracted and the reflected branch; go on with the larger */
                GlassBranch tb, rb;
                tb.o = e.p_in;
                tb.d = e.td;
                tb.thr = thr * (1.0f - e.fr);
                tb.path = path;
                tb.state = events << 1 | !inside;
                rb.o = e.p_out;
                rb.d = e.refl;
                rb.thr = thr * (e.fr * gp->reflectivity);
                rb.path = path;
                rb.state = events << 1 | inside;
#if VR_COLORS
                tb.tint = inside ? tint : e.col;
                rb.tint = tint;
#endif
                float wt = glass_max3(tb.thr), wr = glass_max3(rb.thr);
                int keep_t = wt >= wr, split = events <= gp->split_events;
                if (!split && wt + wr > 0.0f) {
                    /* past the split events: one branch, chosen in proportion */
                    float pt = wt / (wt + wr);
                    keep_t = vr_rand(seed, pixel, sample, dim++) < pt;
                    float inv = 1.0f / (keep_t ? pt : 1.0f - pt);
                    tb.thr *= inv;
                    rb.thr *= inv;
                }
                GlassBranch go = keep_t ? tb : rb, other = keep_t ? rb : tb;
                float w = glass_max3(other.thr);
                int keep = split && w > 0.0f;
                float rr = gp->roulette;
                if (keep && w < rr) {
                    keep = vr_rand(seed, pixel, sample, dim++) * rr < w;
                    other.thr *= rr / w;
                    w = rr;
                }
                if (keep && (sp >= VR_GLASS_STACK || splits >= VR_GLASS_SPLITS)) {
                    go.thr += other.thr;                 /* past the budget: merged */
                    keep = 0;
                }
                if (keep) {
                    stack[sp++] = other;
                    ++splits;
                }
                o = go.o;
                d = go.d;
                thr = go.thr;
                inside = go.state & 1;
#if VR_COLORS
                tint = go.tint;
#endif
            }
        }
        if (!alive) {
            if (sp == 0)
                break;
            GlassBranch b = stack[--sp];
            o = b.o;
            d = b.d;
            thr = b.thr;
            path = b.path;
            events = b.state >> 1;
            inside = b.state & 1;
#if VR_COLORS
            tint = b.tint;
#endif
        }
    }
    return rgb;
}
#endif

inline float3 glass_path(const SdfScene* sc, __constant GlassParams* gp,
                         __constant Light* lights, __global const float4* env,
                         float3 o, float3 d, uint seed, uint pixel, uint sample, int* covered)
{
    GlassStart st;
    st.o = o;
    st.d = d;
    st.floor_len = 1e-2f * gp->scale;
    st.inside = glass_eye_inside(sc, gp, o, &st.tint);
    st.seed = seed;
    st.pixel = pixel;
    st.sample = sample;
    *covered = st.inside;
    return glass_walk(sc, gp, lights, env, &st, covered);
}

#endif
