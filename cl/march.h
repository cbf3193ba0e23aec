/* Ray marching helpers of the marcher (render_volume.cl): the shadow march, the
   in-scattered light at a sample with its multiple-scattering octaves, and the
   environment's share. Include after volume.h, phase.h, lights.h and env.h. Reads
   VR_N_SUNS, VR_N_POINTS, VR_SHADOWS, VR_CHROMATIC, VR_MS_OCTAVES, VR_ENV.

   Octaves (issue #22; after Wrenninge, Kulla and Lundqvist 2013, "Oz: the great and
   volumetric", made energy-conserving): the light that reaches a sample from a source
   through shadow optical depth tau is split into N bands k = 0..N-1 at depth scales
   A_k = A_inf^(u_k), u_k = k / (N - 1):
       band 0:  p(mu; g) exp(-tau)                         (single scattering)
       band k:  w p_k(mu) [exp(-A_k tau) - exp(-A_{k-1} tau)],
   p_k the phase with g scaled by C^((u_{k-1} + u_k) / 2) and w = G albedo for lights,
   p_k = p and w = albedo for the environment (the band's light scattered once more),
   A_inf = min(1, D sqrt(3 (1 - albedo) (1 - g_mean))) the
   diffusion-theory decay of light deep in the medium (per channel). The environment's
   bands telescope: with albedo 1 (A_inf = 0, w = 1) they sum to p exactly, so a white furnace
   returns its radiance at any N, D, G, C. A light's bands stand for its blocked light
   reaching the sample by scattering, which near a lit surface builds up above the
   single-scattered light (G > 1; fitted, docs/error_time.md); without scattering
   (albedo 0) the bands vanish; where the medium is thin (tau -> 0) the extra bands vanish, and with
   A_inf = 1 (albedo <= 0.43 at g 0.42) they are single scattering. One shadow march gives
   tau for every band. The bands are a midpoint quadrature over u of one continuous model
   (its phase varies with u), so more octaves converge to it; with C = 0 or 1 every N
   gives the same image (the sum telescopes). VR_MS_OCTAVES 1 is plain single
   scattering, bit for bit as before. */
#ifndef VR_MARCH_H
#define VR_MARCH_H

#define VR_ENV_DIMS 0x80000000u    /* random dims of the environment samples, per step */

/* Optical depth (grey: density_scale x the grid integral; the channels scale it by
   VR_EXTINCTION) from local p along dl (local per world unit) over world length tmax,
   clipped to the box, marched at the shadow step. Stops once it passes tau_stop. */
inline float vr_march_tau(const VrGrid* g, __constant VolumeParams* vp, float3 p, float3 dl,
                          float tmax, float u, float tau_stop)
{
    float2 tt = vr_ray_box(p, 1.0f / dl, (float3)(0.0f), vp->box_hi.xyz);
    float t1 = fmin(tt.y, tmax);
    if (t1 <= 0.0f)
        return 0.0f;
    return vr_optical_depth(g, p, dl, 0.0f, t1, vp->shadow_step, u, vp->density_scale, tau_stop);
}

/* A light's shadow optical depth: vr_march_tau, or 0 without shadows (--no-shadows
   leaves the lights unattenuated; the environment always is). */
inline float vr_shadow_tau(const VrGrid* g, __constant VolumeParams* vp, float3 p, float3 dl,
                           float tmax, float u, float tau_stop)
{
#if VR_SHADOWS
    return vr_march_tau(g, vp, p, dl, tmax, u, tau_stop);
#else
    return 0.0f;
#endif
}

/* Transmittance from local point p towards light `dl` (local per world unit) over
   world length tmax, clipped to the volume box. */
inline float vr_shadow(const VrGrid* g, __constant VolumeParams* vp, float3 p, float3 dl,
                       float tmax, float u)
{
    return vr_transmit(vr_shadow_tau(g, vp, p, dl, tmax, u, VR_SHADOW_TAU_STOP));
}

#if VR_MS_OCTAVES > 1 || VR_CHROMATIC
#if VR_MS_OCTAVES > 1
/* Band k's transmittance through the channels' optical depth ext_tau: exp(-A_k ext_tau),
   A_k = A_inf^(k / (N - 1)), ms_decay holding ln A_inf per channel. */
inline VrSpec vr_band_transmit(__constant VolumeParams* vp, VrSpec ext_tau, int k)
{
#if VR_CHROMATIC
    float3 ln_a = vp->ms_decay.xyz;
#else
    float ln_a = vp->ms_decay.x;
#endif
    return vr_spec_transmit(exp((float)k * (1.0f / (float)(VR_MS_OCTAVES - 1)) * ln_a) * ext_tau);
}
#endif

/* The band sum at cosine mu over shadow optical depth tau (see the top; one octave: p T).
   `light` 1: a light's bands (gain G, phase broadened), 0: the environment's (gain 1,
   the phase kept). */
inline VrSpec vr_octaves(__constant VolumeParams* vp, float mu, float tau, int light)
{
    VrSpec ext_tau = tau * VR_EXTINCTION(vp);
    VrSpec prev = vr_spec_transmit(ext_tau);
    VrSpec sum = vr_phase(mu, vp->phase) * prev;
#if VR_MS_OCTAVES > 1
    VrSpec gain = (light ? vp->ms.x : 1.0f) * VR_ALBEDO(vp);   /* scattered once more */
    float du = 1.0f / (float)(VR_MS_OCTAVES - 1);
    for (int k = 1; k < VR_MS_OCTAVES; ++k) {
        float u = (float)k * du;
        VrSpec tk = vr_band_transmit(vp, ext_tau, k);
        float ph = vr_phase(mu, vp->phase);
        if (light) {            /* the phase at the band's middle: N -> inf converges */
            float ck = pow(vp->ms.y, u - 0.5f * du);
            ph = vr_phase(mu, (float4)(vp->phase.x * ck, vp->phase.y * ck, vp->phase.z, 0.0f));
        }
        sum += gain * ph * (tk - prev);
        prev = tk;
    }
#else
    (void)light;
#endif
    return sum;
}
/* The environment's bands without the phase (they keep it: vr_octaves(vp, mu, tau, 0)
   = p(mu) x this): the transmittance the bands give through shadow depth tau, per
   channel; exp(-tau) with one octave. The light cache bakes it (cl/bake_light.cl). */
inline VrSpec vr_env_bands(__constant VolumeParams* vp, float tau)
{
    VrSpec ext_tau = tau * VR_EXTINCTION(vp);
    VrSpec prev = vr_spec_transmit(ext_tau);
    VrSpec sum = prev;
#if VR_MS_OCTAVES > 1
    VrSpec gain = VR_ALBEDO(vp);
    for (int k = 1; k < VR_MS_OCTAVES; ++k) {
        VrSpec tk = vr_band_transmit(vp, ext_tau, k);
        sum += gain * (tk - prev);
        prev = tk;
    }
#endif
    return sum;
}

/* where the shadow march may stop: every band's (and channel's) light below 1e-4 */
#define VR_TAU_STOP(vp) ((vp)->ms.w)
#endif

#if VR_N_SUNS + VR_N_POINTS > 0
/* Sum over lights of phase * irradiance * light transmittance at local point p (with
   octaves: the octave sum). `wo` is the world direction towards the camera. */
inline float3 vr_inscatter(const VrGrid* g, __constant VolumeParams* vp,
                           __constant Light* lights, float3 p, float3 wo,
                           uint seed, uint pixel, uint s, uint step)
{
    float3 sum = (float3)(0.0f);
    /* shadow jitter keyed by (step, light index): adding a light leaves the others' */
    uint dim = 16u + step * VR_MAX_LIGHTS;
    for (int i = 0; i < VR_N_SUNS + VR_N_POINTS; ++i) {
        float3 dl, prop;
        float tmax, atten;
        if (!vr_light_at(vp, lights, i, p, &dl, &tmax, &prop, &atten))
            continue;
#if VR_MS_OCTAVES > 1 || VR_CHROMATIC
        float tau = vr_shadow_tau(g, vp, p, dl, tmax, vr_rand(seed, pixel, s, dim++),
                                  VR_TAU_STOP(vp));
        sum += vr_octaves(vp, dot(prop, wo), tau, 1) * lights[i].radiance.xyz / atten;
#else
        float tr = vr_shadow(g, vp, p, dl, tmax, vr_rand(seed, pixel, s, dim++));
        sum += vr_phase(dot(prop, wo), vp->phase) * tr * lights[i].radiance.xyz / atten;
#endif
    }
    return sum;
}
#endif

#if VR_ENV
/* The environment's single-scattered light at local p, `d` the camera ray's world
   direction, from one direction per step: drawn from the phase (octave 0), or (a map)
   from the phase or the map with probability 1/2 each, weighted by the mixture density
   (one-sample multiple importance sampling, balance heuristic). Octaves as for lights. */
inline float3 vr_env_inscatter(const VrGrid* g, __constant VolumeParams* vp,
                               __global const float4* env, __global const float* cdf,
                               float3 p, float3 d, uint seed, uint pixel, uint s, uint step)
{
    uint dim = VR_ENV_DIMS + step * 8u;
    float u0 = vr_rand(seed, pixel, s, dim), u1 = vr_rand(seed, pixel, s, dim + 1u);
    float u2 = vr_rand(seed, pixel, s, dim + 2u), u3 = vr_rand(seed, pixel, s, dim + 3u);
    float3 w;
    float pdf_mix = 1.0f;
#if VR_ENV == 2
    float pdf_env;
    if (u0 < 0.5f) {
        w = vr_phase_sample(vp->phase, d, 2.0f * u0, u1, u2);
        pdf_env = vr_env_pdf(cdf, vp->env_width, vp->env_height, w);
    } else {
        w = vr_env_sample(cdf, vp->env_width, vp->env_height, u1, u2, &pdf_env);
    }
    float p0 = vr_phase(dot(w, d), vp->phase);
    pdf_mix = 0.5f * (p0 + pdf_env);
    if (!(pdf_mix > 0.0f))
        return (float3)(0.0f);
#else
    (void)cdf;
    w = vr_phase_sample(vp->phase, d, u0, u1, u2);
    float p0 = vr_phase(dot(w, d), vp->phase);
#endif
    float3 dl = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, w);
#if VR_MS_OCTAVES > 1 || VR_CHROMATIC
    float tau = vr_march_tau(g, vp, p, dl, INFINITY, u3, VR_TAU_STOP(vp));
    VrSpec f = vr_octaves(vp, dot(w, d), tau, 0);
#else
    VrSpec f = p0 * vr_transmit(vr_march_tau(g, vp, p, dl, INFINITY, u3, VR_SHADOW_TAU_STOP));
#endif
#if VR_ENV == 1
    f = f / p0;                 /* phase sampling: p / pdf = 1 for octave 0 */
#else
    f = f / pdf_mix;
    (void)p0;
#endif
    return f * vr_env_radiance(vp, env, w);
}
#endif

#endif
