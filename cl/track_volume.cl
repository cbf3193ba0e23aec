/* Unbiased tracking estimator of the single-scattering estimand of render_volume.cl
   (DESIGN.md): L = int T(0,t) sigma_s(t) sum_lights p E T_light dt
                  + int T(0,t) e(t) C dt + T(0,tmax) L_background,   alpha = 1 - T(0,tmax).
   One work-item per pixel, same arguments as render_volume plus `majorant`.

   Tentative collisions are a Poisson process of rate mu (the brick's majorant) along
   the ray, walked brick by brick with a DDA over the 8^3 bricks (empty bricks have
   mu = 0 and cost one table read). On those points, per sample:
   - scattering: delta (Woodcock) tracking. A point is a real collision with
     probability sigma_t/mu; the first real collision is distributed as
     T(0,t) sigma_t(t) dt, so albedo * (in-scattered light there) estimates the
     scattering integral. One shadow ray per light at that collision.
   - transmittance, background and emission: ratio tracking over the same points.
     W(t) = prod (1 - sigma_t/mu) over the points before t has E[W(t)] = T(0,t), so
     W(tmax) estimates T (alpha = 1 - W, background W * L_bg) and sum W e/mu over the
     points estimates int T e dt. W is Russian-rouletted below VR_RR_W (unbiased).
   - shadow rays: ratio tracking to the light (or the box), also rouletted.
   - stiff media (majorant optical depth above ~3e4 per voxel): intervals are taken
     whole, with the density linear across each (VR_BULK_* below).
   mu = density_scale * brick maximum (host side, volrender/render.py
   track_majorants), raised to 1/voxel in bricks that emit, so emission in bricks
   of zero density is still sampled.

   Variance: the scattering term is a collision estimator: per sample it is either 0
   or albedo * S(x), so its relative noise is large where alpha is small (thin media)
   and where S varies along the ray; the transmittance term is a product of factors in
   [0, 1] whose noise grows with the majorant's looseness (a tight majorant makes it a
   0/1 track-length estimate, variance T (1 - T)); roulette adds a little. Noise falls
   as 1/sqrt(spp). The cost per sample is ~ the majorant optical depth along the
   ray up to the collision plus that of one shadow ray per light: no step size.
   bench/error.py measures both against marching (docs/error_time.md).

   Random numbers: dims 0, 1 pixel jitter; 2.. the primary walk; (light + 1) << 24 ..
   that light's shadow walk. Flags as render_volume.cl (VR_SKIP_EMPTY is implied). */
#if !defined(VR_N_SUNS) || !defined(VR_N_POINTS) || !defined(VR_SHADOWS) || \
    !defined(VR_PHASE_MIXED) || !defined(VR_SKIP_EMPTY) || !defined(VR_EMISSION) || \
    !defined(VR_DEPTH)
#error "track_volume.cl: a VR_* feature flag is missing (see volrender/features.py)"
#endif

#include "common.h"
#include "structs.h"
#include "camera.h"
#include "phase.h"
#include "volume.h"

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

#if VR_N_SUNS + VR_N_POINTS > 0
/* Ratio-tracked transmittance from local point p along dl (local per world unit)
   over world length tmax, clipped to the volume box. */
inline float vr_track_shadow(const VrGrid* g, __global const float* maj,
                             __constant VolumeParams* vp, float3 p, float3 dl, float tmax,
                             uint seed, uint pixel, uint s, uint dim)
{
#if VR_SHADOWS
    float2 tt = vr_ray_box(p, 1.0f / dl, (float3)(0.0f), vp->box_hi.xyz);
    float t0 = fmax(tt.x, 0.0f), t1 = fmin(tt.y, tmax);
    if (!(t1 > t0))
        return 1.0f;
    VrTrack k;
    vr_track_init(&k, g, maj, p, dl, t0, t1);
    float w = 1.0f;
    while (vr_track_next(&k, g, maj, 0, seed, pixel, s, &dim)) {
        float sigma = vr_track_sigma(&k, g, vp->density_scale, k.t);
        if (k.bulk > 0.0f)
            w *= vr_transmit(0.5f * (sigma + vr_track_sigma(&k, g, vp->density_scale,
                                                             k.t + k.bulk)) * k.bulk);
        else
            w *= 1.0f - fmin(sigma / k.mu, 1.0f);
        w = vr_roulette(w, vr_rand(seed, pixel, s, dim++));
        if (w <= 0.0f)
            return 0.0f;
    }
    return w;
#else
    return 1.0f;
#endif
}

/* Sum over lights of phase * irradiance * ratio-tracked transmittance at local p;
   `wo` is the world direction towards the camera. */
inline float3 vr_track_inscatter(const VrGrid* g, __global const float* maj,
                                 __constant VolumeParams* vp, __constant Light* lights,
                                 float3 p, float3 wo, uint seed, uint pixel, uint s)
{
    float3 sum = (float3)(0.0f);
#if VR_N_SUNS > 0
    for (int i = 0; i < VR_N_SUNS; ++i) {
        float3 d = lights[i].vec.xyz;
        float3 dl = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, -d);
        float tr = vr_track_shadow(g, maj, vp, p, dl, INFINITY, seed, pixel, s,
                                   (uint)(i + 1) * VR_LIGHT_DIMS);
        sum += vr_phase(dot(d, wo), vp->phase) * tr * lights[i].radiance.xyz;
    }
#endif
#if VR_N_POINTS > 0
    for (int i = VR_N_SUNS; i < VR_N_SUNS + VR_N_POINTS; ++i) {
        float3 to_l = lights[i].vec.xyz - p;
        float3 w = vr_mat3(vp->local_to_world0, vp->local_to_world1, vp->local_to_world2, to_l);
        float r2 = dot(w, w);
        float r = sqrt(r2);
        if (r <= 0.0f)
            continue;
        float tr = vr_track_shadow(g, maj, vp, p, to_l / r, r, seed, pixel, s,
                                   (uint)(i + 1) * VR_LIGHT_DIMS);
        float3 prop = -w / r;
        sum += vr_phase(dot(prop, wo), vp->phase) * tr * lights[i].radiance.xyz
               / fmax(r2, vp->point_r2_min);
    }
#endif
    return sum;
}
#endif

__kernel void track_volume(__constant Camera* cam, __constant VolumeParams* vp,
                           __constant Light* lights,
                           __global const int* table, __global const float* data,
                           __global const float* emission, __global const float* majorant,
                           __global float4* out, __global float* depth, int y0)
{
    int x = get_global_id(0), y = y0 + get_global_id(1);
    if (x >= cam->width || y >= cam->height)
        return;
    uint pixel = (uint)(y * cam->width + x);
    VrGrid g = { vp->dims, table, data };
    float3 o = cam->origin.xyz;

    float3 acc = (float3)(0.0f);
    float acc_alpha = 0.0f, acc_depth = 0.0f, acc_depth_w = 0.0f;
    for (int s = 0; s < cam->spp; ++s) {
        float2 j = vr_pixel_jitter(cam, pixel, (uint)s);
        float3 dir = vr_camera_dir(cam, x, y, j.x, j.y);
        float3 d = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, dir);
        float2 tt = vr_ray_box(o, 1.0f / d, (float3)(0.0f), vp->box_hi.xyz);
        float t0 = fmax(tt.x, 0.0f), t1 = tt.y;
        float3 L = (float3)(0.0f);
        float w = 1.0f;                  /* ratio-tracking weight: E[w] = T(0, t) */
        if (t1 > t0) {
            uint dim = 2u;
            /* delta tracking is needed only for the in-scattered light (and depth) */
            int collided = !(VR_N_SUNS + VR_N_POINTS > 0 || VR_DEPTH);
            VrTrack k;
            vr_track_init(&k, &g, majorant, o, d, t0, t1);
            while ((!collided || w > 0.0f)
                   && vr_track_next(&k, &g, majorant, VR_EMISSION ? emission : 0,
                                    cam->seed, pixel, (uint)s, &dim)) {
                float tc = k.t;
                float3 p = o + tc * d;
                float3 f;
                int3 c = vr_track_cell(&k, p, &f);
                float sigma = vp->density_scale * vr_trilinear(data, k.slot, c, f);
                /* ratio: the chance that this point is a real collision, and what the
                   ratio weight loses; len: the emission estimator's length (1/mu at a
                   point; over a bulk interval, the integral of T within it) */
                float ratio, len, sigma1 = 0.0f;
                if (k.bulk > 0.0f) {
                    sigma1 = vr_track_sigma(&k, &g, vp->density_scale, k.t + k.bulk);
                    float tau = 0.5f * (sigma + sigma1) * k.bulk;
                    ratio = 1.0f - vr_transmit(tau);
                    len = tau > 1e-4f ? ratio * (k.bulk / tau) : k.bulk;
                } else {
                    ratio = fmin(sigma / k.mu, 1.0f);
                    len = 1.0f / k.mu;
                }
#if VR_EMISSION
                if (w > 0.0f) {
                    float e = vr_trilinear(emission, k.slot, c, f);
                    L += w * e * len * vp->emission_color.xyz;
                }
#else
                (void)len;
#endif
                float u;
                if (!collided && (u = vr_rand(cam->seed, pixel, (uint)s, dim++)) < ratio) {
                    collided = 1;
                    if (k.bulk > 0.0f) {         /* where in the interval */
                        tc = k.t + vr_bulk_hit(sigma, sigma1, k.bulk, -log(1.0f - u));
                        p = o + tc * d;
                    }
#if VR_N_SUNS + VR_N_POINTS > 0
                    L += vp->albedo * vr_track_inscatter(&g, majorant, vp, lights, p, -dir,
                                                         cam->seed, pixel, (uint)s);
#endif
#if VR_DEPTH
                    acc_depth += tc;
                    acc_depth_w += 1.0f;
#endif
                }
                if (w > 0.0f) {
                    w *= 1.0f - ratio;
                    w = vr_roulette(w, vr_rand(cam->seed, pixel, (uint)s, dim++));
                }
            }
        }
        L += w * vp->background.xyz;
        acc += L;
        acc_alpha += 1.0f - w;
    }
    float inv = 1.0f / (float)cam->spp;
    out[pixel] = (float4)(acc * inv, acc_alpha * inv);
#if VR_DEPTH
    depth[pixel] = acc_depth_w > 0.0f ? acc_depth / acc_depth_w : INFINITY;
#endif
}
