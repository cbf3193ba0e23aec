/* Ray marching helpers of the single-scattering marcher (render_volume.cl): the shadow
   march and the in-scattered light at a sample. Include after volume.h, phase.h and
   lights.h. Reads VR_N_SUNS, VR_N_POINTS, VR_SHADOWS. */
#ifndef VR_MARCH_H
#define VR_MARCH_H

#define VR_SHADOW_TAU_STOP 25.0f   /* exp(-25) ~ 1e-11: light fully blocked */

#if VR_N_SUNS + VR_N_POINTS > 0
/* Transmittance from local point p towards light `dl` (local per world unit) over
   world length tmax, clipped to the volume box. */
inline float vr_shadow(const VrGrid* g, __constant VolumeParams* vp, float3 p, float3 dl,
                       float tmax, float u)
{
#if VR_SHADOWS
    float2 tt = vr_ray_box(p, 1.0f / dl, (float3)(0.0f), vp->box_hi.xyz);
    float t1 = fmin(tt.y, tmax);
    if (t1 <= 0.0f)
        return 1.0f;
    float tau = vr_optical_depth(g, p, dl, 0.0f, t1, vp->shadow_step, u, vp->density_scale,
                                 VR_SHADOW_TAU_STOP);
    return vr_transmit(tau);
#else
    return 1.0f;
#endif
}

/* Sum over lights of phase * irradiance * light transmittance at local point p.
   `wo` is the world direction towards the camera. */
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
        float tr = vr_shadow(g, vp, p, dl, tmax, vr_rand(seed, pixel, s, dim++));
        sum += vr_phase(dot(prop, wo), vp->phase) * tr * lights[i].radiance.xyz / atten;
    }
    return sum;
}
#endif

#endif
