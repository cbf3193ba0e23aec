/* Tracking on the brick majorants: a DDA walk over tentative collisions (delta and
   ratio tracking share it), stiff-media bulk intervals, Russian roulette, the
   ratio-tracked shadow ray and a path segment's walk (path_volume.cl explains the
   estimators). Include after volume.h, phase.h and lights.h. Reads VR_N_SUNS,
   VR_N_POINTS, VR_SHADOWS, VR_EMISSION, VR_CHROMATIC.

   Per-channel media (VR_CHROMATIC): the majorant bounds the largest channel
   (density_scale x max s x the brick maximum). Ratio tracking keeps one weight per
   channel, prod (1 - sigma_c / mu), unbiased for each channel's transmittance. Delta
   tracking decides real or null with the throughput-weighted mean probability
   P = sum_c beta_c sigma_c / (mu sum_c beta_c) (Kutz et al. 2017, "spectral tracking"
   with the history-aware average) and multiplies each channel's throughput by its own
   ratio to it: sigma_s,c / (mu P) at a real collision, (1 - sigma_c / mu) / (1 - P) at
   a null one. P is positive wherever any channel has sigma_c > 0 and below 1 wherever
   one has sigma_c < mu, so every channel stays unbiased; grey media give P = sigma/mu
   and the weights albedo and 1, plain delta tracking. */
#ifndef VR_TRACK_H
#define VR_TRACK_H

#define VR_RR_W 0.1f                 /* roulette ratio weights below this */
#define VR_TRACK_MAX_POINTS (1 << 20) /* safety cap on tentative points per walk */
#define VR_LIGHT_DIMS (1u << 24)     /* random dims per shadow walk */
/* Stiff media. Where a brick's rate would put more than VR_BULK_POINTS tentative
   points into an interval of length max(VR_BULK_RES |t|, VR_BULK_VOXEL voxel) (2^-16
   |t| is 128 float ulps: below it a float t cannot resolve the points; 1/512 voxel
   keeps the cost per voxel bounded), the walk takes such intervals whole ("bulk"),
   with the density linear across each (its values at both ends): the ratio weight gets
   its expectation exp(-tau), tau = (sigma0 + sigma1) len / 2, a collision happens with
   probability 1 - exp(-tau) at the offset where the linear optical depth reaches
   -ln(1 - u), and cells whose eight values are all zero are crossed in one step. The
   trilinear density along a ray is a cubic in t, so the linear model is off by
   ~1e-6 of its variation over 1/512 voxel. Only majorant optical depths above
   64 x 512 = 32768 per voxel (or mean free paths under 2^-22 |t|) get there; ordinary
   media keep the unbiased point process. */
#define VR_BULK_RES (1.0f / 65536.0f)
#define VR_BULK_VOXEL (1.0f / 512.0f)
#define VR_BULK_POINTS 64.0f

/* Walk over tentative collisions along o + t d (local o, d local per world unit),
   t in [t, t1): a brick DDA with the brick's majorant as the rate. */
typedef struct {
    float3 o, d;         /* the ray, local */
    float vox;           /* world length of one local unit (voxel) along the ray */
    int3 b, step;        /* current brick, axis steps */
    float3 tnext, tdelta;/* t of the next brick face per axis, t per brick */
    float t, te, t1, mu; /* current t, end of this brick's segment, end of the ray, rate */
    float bulk;          /* > 0: the walk stands on the interval [t, t + bulk) (see above) */
    int slot;            /* slot of the current brick (-1: empty) */
    int n;               /* tentative points so far */
} VrTrack;

inline void vr_track_segment(VrTrack* k, const VrGrid* g, __global const float* maj)
{
    k->te = fmin(fmin(k->tnext.x, k->tnext.y), fmin(k->tnext.z, k->t1));
    k->slot = g->table[(k->b.x * g->dims.y + k->b.y) * g->dims.z + k->b.z];
    k->mu = k->slot >= 0 ? maj[k->slot] : 0.0f;
}

/* Starts a walk over [t0, t1) (t0 inside the box, t1 at or before the box exit). */
inline void vr_track_init(VrTrack* k, const VrGrid* g, __global const float* maj,
                          float3 o, float3 d, float t0, float t1)
{
    float3 inv_d = 1.0f / d;
    float3 p = o + t0 * d;
    k->o = o;
    k->d = d;
    k->vox = 1.0f / length(d);
    k->b = clamp(convert_int3(floor(p * (1.0f / VR_BRICK))), (int3)(0), g->dims.xyz - 1);
    k->step = select((int3)(-1), (int3)(1), d > 0.0f);
    float3 face = convert_float3((k->b + select((int3)(0), (int3)(1), d > 0.0f)) * VR_BRICK);
    k->tnext = select((face - o) * inv_d, (float3)(INFINITY), d == 0.0f);
    k->tdelta = select(fabs((float)VR_BRICK * inv_d), (float3)(INFINITY), d == 0.0f);
    k->t = t0;
    k->t1 = t1;
    k->bulk = 0.0f;
    k->n = 0;
    vr_track_segment(k, g, maj);
}

/* Cell and fraction of local point p, held inside the walk's brick so that the
   trilinear value is a convex combination of that brick's values (<= its majorant). */
inline int3 vr_track_cell(const VrTrack* k, float3 p, float3* f)
{
    int3 lo = k->b * VR_BRICK;
    int3 c = clamp(convert_int3(floor(p)), lo, lo + (VR_BRICK - 1));
    *f = clamp(p - convert_float3(c), 0.0f, 1.0f);
    return c;
}

/* Largest of the eight values around cell c of brick `slot` (see vr_trilinear). */
inline float vr_cell_max(__global const float* data, int slot, int3 c)
{
    int3 l = c & (VR_BRICK - 1);
    __global const float* v = data + slot * VR_BRICK_VALUES + (l.x * 9 + l.y) * 9 + l.z;
    return fmax(fmax(fmax(v[0], v[1]), fmax(v[9], v[10])),
                fmax(fmax(v[81], v[82]), fmax(v[90], v[91])));
}

/* Next tentative collision (k->t, in brick k->slot, rate k->mu), or with k->bulk > 0
   the next unresolvable interval [k->t, k->t + k->bulk); 0 once the walk leaves
   [t0, t1). The exponential draw is memoryless, so a draw that overshoots the brick is
   dropped and the walk restarts at the next brick with its own rate. `emission` (0
   when there is none) keeps emitting cells from being crossed as empty. */
inline int vr_track_next(VrTrack* k, const VrGrid* g, __global const float* maj,
                         __global const float* emission, uint seed, uint pixel, uint s,
                         uint* dim)
{
    if (++k->n > VR_TRACK_MAX_POINTS)
        return 0;
    if (k->bulk > 0.0f) {
        k->t += k->bulk;
        k->bulk = 0.0f;
    }
    for (;;) {
        if (k->mu > 0.0f && k->t < k->te) {
            float res = fmax(VR_BULK_RES * fmax(fabs(k->t), fabs(k->te)),
                             VR_BULK_VOXEL * k->vox);
            if (k->mu * res > VR_BULK_POINTS) {
                float3 f;
                int3 c = vr_track_cell(k, k->o + k->t * k->d, &f);
                if (vr_cell_max(g->data, k->slot, c) <= 0.0f
                    && (!emission || vr_cell_max(emission, k->slot, c) <= 0.0f)) {
                    float3 lo = convert_float3(c);
                    float tx = fmin(vr_ray_box(k->o, 1.0f / k->d, lo, lo + 1.0f).y, k->te);
                    if (tx > k->t) {          /* an empty cell: cross it */
                        k->t = tx;
                        continue;
                    }
                }
                k->bulk = fmin(res, k->te - k->t);
                return 1;
            }
            float u = vr_rand(seed, pixel, s, (*dim)++);
            float tn = k->t - log(1.0f - u) / k->mu;
            if (tn < k->te) {
                k->t = tn;
                return 1;
            }
        }
        k->t = fmax(k->t, k->te);
        if (k->te >= k->t1)
            return 0;
        /* step into the next brick across the nearest face */
        if (k->tnext.x <= k->tnext.y && k->tnext.x <= k->tnext.z) {
            k->b.x += k->step.x; k->tnext.x += k->tdelta.x;
        } else if (k->tnext.y <= k->tnext.z) {
            k->b.y += k->step.y; k->tnext.y += k->tdelta.y;
        } else {
            k->b.z += k->step.z; k->tnext.z += k->tdelta.z;
        }
        if (any(k->b < 0) || any(k->b >= g->dims.xyz))
            return 0;
        vr_track_segment(k, g, maj);
    }
}

/* sigma_t at walk parameter t (local ray o + t d), in the walk's brick. */
inline float vr_track_sigma(const VrTrack* k, const VrGrid* g, float scale, float t)
{
    float3 f;
    int3 c = vr_track_cell(k, k->o + t * k->d, &f);
    return scale * vr_trilinear(g->data, k->slot, c, f);
}

/* Offset into a bulk interval of length len, sigma linear from s0 to s1, where the
   optical depth reaches E (E below the interval's): the root of s0 s + a s^2/2 = E in
   the cancellation-free form; 0 for infinite sigma. */
inline float vr_bulk_hit(float s0, float s1, float len, float E)
{
    float a = (s1 - s0) / len;
    float disc = fmax(s0 * s0 + 2.0f * a * E, 0.0f);
    float s = 2.0f * E / (s0 + sqrt(disc));
    return s >= 0.0f ? fmin(s, len) : 0.0f;      /* NaN (inf - inf) reads as 0 */
}

/* Russian roulette on a ratio-tracking weight: unbiased, ends walks that no longer
   matter. */
inline float vr_roulette(float w, float u)
{
    if (w >= VR_RR_W)
        return w;
    return u * VR_RR_W < w ? VR_RR_W : 0.0f;
}

/* Ratio-tracked transmittance (per channel) from local point p along dl (local per
   world unit) over world length tmax, clipped to the volume box, drawing from the
   running dimension counter *dim; rouletted below VR_RR_W on its largest channel. */
inline VrSpec vr_shadow_ratio(const VrGrid* g, __global const float* maj,
                              __constant VolumeParams* vp, float3 p, float3 dl, float tmax,
                              uint seed, uint pixel, uint s, uint* dim)
{
    float2 tt = vr_ray_box(p, 1.0f / dl, (float3)(0.0f), vp->box_hi.xyz);
    float t0 = fmax(tt.x, 0.0f), t1 = fmin(tt.y, tmax);
    if (!(t1 > t0))
        return 1.0f;
    VrTrack k;
    vr_track_init(&k, g, maj, p, dl, t0, t1);
    VrSpec w = 1.0f;
    while (vr_track_next(&k, g, maj, 0, seed, pixel, s, dim)) {
        float sigma = vr_track_sigma(&k, g, vp->density_scale, k.t);
        if (k.bulk > 0.0f)
            w *= vr_spec_transmit(0.5f * (sigma + vr_track_sigma(&k, g, vp->density_scale,
                                                                  k.t + k.bulk)) * k.bulk
                                  * VR_EXTINCTION(vp));
        else
            w *= 1.0f - fmin(sigma * VR_EXTINCTION(vp) / k.mu, 1.0f);
        float m = vr_spec_max(w);
        float r = vr_roulette(m, vr_rand(seed, pixel, s, (*dim)++));
        if (r <= 0.0f)
            return 0.0f;
        w *= r / m;
    }
    return w;
}

/* What one path segment o + t d, t in [t0, t1), gathers (path_volume.cl). */
typedef struct {
    VrSpec w;        /* ratio-tracking weight at t1: E[w] = T(t0, t1) per channel */
    float3 le;       /* ratio-weighted emission: E[le] = int T e C dt */
    int hit;         /* delta tracking found a real collision */
    float tc;        /* its parameter (world distance) */
    float3 x;        /* its local position */
    VrSpec wt;       /* the throughput factor it carries: E[wt; hit in dt] = T sigma_s dt */
} VrSegment;

/* One walk over the segment's tentative collisions serving both estimators: ratio
   tracking (`ratio`: the weight w to t1 and, with `emit`, the emission along the way;
   w is rouletted below VR_RR_W) and delta tracking (`delta`: the first real collision,
   chosen with the spectral-tracking probability for throughput `beta`; see the top of
   this file). The walk ends when neither needs more points. Stiff media: bulk
   intervals (VR_BULK_*) give the ratio weight exp(-tau) and a collision with
   probability 1 - exp(-tau), at the offset where the channel-mean optical depth
   reaches its share. */
inline void vr_segment(const VrGrid* g, __global const float* maj,
                       __global const float* emission, __global const float* temperature,
                       __global const float4* bb, __constant VolumeParams* vp,
                       float3 o, float3 d, float t0, float t1, int ratio, int emit, int delta,
                       VrSpec beta, uint seed, uint pixel, uint s, uint* dim, VrSegment* out)
{
    out->w = 1.0f;
    out->le = (float3)(0.0f);
    out->hit = 0;
    out->tc = 0.0f;
    out->x = o;
    out->wt = 0.0f;
    if (!(t1 > t0))
        return;
    VrSpec wnull = 1.0f;         /* delta tracking's null-collision weights so far */
    int live = 1;                /* the ratio weight is still > 0 */
    VrTrack k;
    vr_track_init(&k, g, maj, o, d, t0, t1);
    while ((delta || (ratio && live))
           && vr_track_next(&k, g, maj, VR_EMISSION ? emission : 0, seed, pixel, s, dim)) {
        float3 p = o + k.t * d;
        float3 f;
        int3 c = vr_track_cell(&k, p, &f);
        float sigma = vp->density_scale * vr_trilinear(g->data, k.slot, c, f);
        /* ratio: the chance this point is a real collision (per channel); len: the
           emission estimator's length (1/mu at a point; over a bulk interval, the
           integral of T within it) */
        VrSpec ratio_c, len;
        float sigma1 = 0.0f;
        if (k.bulk > 0.0f) {
            sigma1 = vr_track_sigma(&k, g, vp->density_scale, k.t + k.bulk);
            VrSpec tau = 0.5f * (sigma + sigma1) * k.bulk * VR_EXTINCTION(vp);
            ratio_c = 1.0f - vr_spec_transmit(tau);
#if VR_CHROMATIC
            len = select(ratio_c * (k.bulk / tau), (float3)(k.bulk), tau <= 1e-4f);
#else
            len = tau > 1e-4f ? ratio_c * (k.bulk / tau) : k.bulk;
#endif
        } else {
            ratio_c = fmin(sigma * VR_EXTINCTION(vp) / k.mu, 1.0f);
            len = 1.0f / k.mu;
        }
#if VR_EMISSION
        if (emit && ratio && live) {
            float e = vr_trilinear(emission, k.slot, c, f);
            if (k.bulk > 0.0f) {
                /* the emission linear across the interval like the density: its mean
                   there times the integral of T, exact where e is proportional to
                   sigma (the start alone reads ~0 at a stiff medium's edge, where the
                   first interval already holds all the optical depth) */
                float3 f1;
                int3 c1 = vr_track_cell(&k, o + (k.t + k.bulk) * d, &f1);
                e = 0.5f * (e + vr_trilinear(emission, k.slot, c1, f1));
            }
            if (e > 0.0f)
                out->le += out->w * e * len * vr_emission_color(vp, temperature, bb, k.slot, c, f);
        }
#else
        (void)len; (void)emit; (void)temperature; (void)bb;
#endif
        if (delta) {
            float u = vr_rand(seed, pixel, s, (*dim)++);
#if VR_CHROMATIC
            float3 h = beta * wnull;
            float hs = h.x + h.y + h.z;
            float P = hs > 0.0f ? dot(h, ratio_c) / hs : vr_spec_mean(ratio_c);
#else
            float P = ratio_c;
#endif
            if (u < P) {
                delta = 0;
                out->hit = 1;
                out->tc = k.t;
                if (k.bulk > 0.0f) {     /* where in the interval */
                    float share = fmin(u / P, 1.0f) * vr_spec_mean(ratio_c);
                    float m = vr_spec_mean(VR_EXTINCTION(vp));
                    out->tc = k.t + vr_bulk_hit(sigma * m, sigma1 * m, k.bulk, -log(1.0f - share));
                }
                out->x = o + out->tc * d;
#if VR_CHROMATIC
                out->wt = wnull * ratio_c * VR_ALBEDO(vp) / P;
#else
                out->wt = VR_ALBEDO(vp);
#endif
            } else {
#if VR_CHROMATIC
                wnull *= (1.0f - ratio_c) / (1.0f - P);
#endif
            }
        }
        if (ratio && live) {
            out->w *= 1.0f - ratio_c;
            float m = vr_spec_max(out->w);
            float r = vr_roulette(m, vr_rand(seed, pixel, s, (*dim)++));
            if (r <= 0.0f) {
                out->w = 0.0f;
                live = 0;
            } else {
                out->w *= r / m;
            }
        }
    }
}

#endif
