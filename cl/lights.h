/* Lights as seen from a point of a volume (local index space; DESIGN.md conventions),
   shared by the estimators: the marcher (march.h), the tracker (track.h) and what is
   built on them. */
#ifndef VR_LIGHTS_H
#define VR_LIGHTS_H

/* Light i (suns first) seen from local point p: *dl the local direction towards it per
   world unit, *tmax the world distance (INFINITY for a sun), *prop the world propagation
   direction through p; its radiance at p is lights[i].radiance / *atten (*atten = the
   clamped r^2 of a point light, 1 for a sun). Returns 0 when p sits on a point light. */
inline int vr_light_at(__constant VolumeParams* vp, __constant Light* lights, int i, float3 p,
                       float3* dl, float* tmax, float3* prop, float* atten)
{
    if (i < VR_N_SUNS) {
        float3 d = lights[i].vec.xyz;                       /* propagation, world, unit */
        *dl = vr_mat3(vp->world_to_local0, vp->world_to_local1, vp->world_to_local2, -d);
        *tmax = INFINITY;
        *prop = d;
        *atten = 1.0f;
        return 1;
    }
    float3 to_l = lights[i].vec.xyz - p;                    /* local */
    float3 w = vr_mat3(vp->local_to_world0, vp->local_to_world1, vp->local_to_world2, to_l);
    float r2 = dot(w, w);
    float r = sqrt(r2);
    if (r <= 0.0f)
        return 0;
    *dl = to_l / r;
    *tmax = r;
    *prop = -w / r;                                         /* from the light through p */
    *atten = fmax(r2, vp->point_r2_min);
    return 1;
}

#endif
