/* Sparse brick volume: trilinear density lookup, empty-brick skipping, shadow march.
   Everything here works in the layout's local index space (voxel centres at integer
   coordinates, box [0, dims*8]); ray parameters t are world distances.
   Reads VR_SKIP_EMPTY, VR_EMISSION; VR_BRICK and VR_BRICK_VALUES come from structs.h. */
#ifndef VR_VOLUME_H
#define VR_VOLUME_H

typedef struct {
    int4 dims;                        /* bricks per axis */
    __global const int* table;        /* brick -> slot, or -1 when empty */
    __global const float* data;       /* slot * 729 + (i*9 + j)*9 + k */
} VrGrid;

/* Slot of the brick holding cell c, -1 when outside or empty. */
inline int vr_brick_slot(const VrGrid* g, int3 c)
{
    int3 b = c >> 3;
    if (any(c < 0) || b.x >= g->dims.x || b.y >= g->dims.y || b.z >= g->dims.z)
        return -1;
    return g->table[(b.x * g->dims.y + b.y) * g->dims.z + b.z];
}

/* Trilinear value of brick `slot` at cell c with fractional offset f. */
inline float vr_trilinear(__global const float* data, int slot, int3 c, float3 f)
{
    int3 l = c & (VR_BRICK - 1);
    __global const float* v = data + slot * VR_BRICK_VALUES + (l.x * 9 + l.y) * 9 + l.z;
    float c00 = mix(v[0],   v[1],   f.z), c01 = mix(v[9],  v[10], f.z);
    float c10 = mix(v[81],  v[82],  f.z), c11 = mix(v[90], v[91], f.z);
    return mix(mix(c00, c01, f.y), mix(c10, c11, f.y), f.x);
}

/* Trilinear value of the brick data at local point p (0 outside the layout). */
inline float vr_lookup(const VrGrid* g, __global const float* data, float3 p)
{
    float3 cf = floor(p);
    int3 c = convert_int3(cf);
    int slot = vr_brick_slot(g, c);
    return slot < 0 ? 0.0f : vr_trilinear(data, slot, c, p - cf);
}

/* World parameter where the ray leaves the brick containing point p. */
inline float vr_brick_exit(float3 o, float3 inv_d, float3 p)
{
    float3 lo = floor(p * (1.0f / VR_BRICK)) * VR_BRICK;
    float2 tt = vr_ray_box(o, inv_d, lo, lo + (float3)(VR_BRICK));
    return tt.y;
}

/* Optical depth along o + t d, t in [t0, t1), samples at t0 + (k + u) dt. With
   VR_SKIP_EMPTY, samples in empty bricks are skipped (they read exactly zero). Stops
   early once tau exceeds tau_stop. */
inline float vr_optical_depth(const VrGrid* g, float3 o, float3 d, float t0, float t1,
                              float dt, float u, float scale, float tau_stop)
{
    float3 inv_d = 1.0f / d;
    float tau = 0.0f;
    for (int k = 0; k < VR_MAX_RAY_SAMPLES; ++k) {
        float t = t0 + ((float)k + u) * dt;
        if (t >= t1 || tau > tau_stop)
            break;
        float3 p = o + t * d;
        float3 cf = floor(p);
        int3 c = convert_int3(cf);
        int slot = vr_brick_slot(g, c);
        if (slot < 0) {                /* empty brick: density is exactly zero */
#if VR_SKIP_EMPTY
            float te = vr_brick_exit(o, inv_d, p);
            k = max(k, (int)ceil((te - t0) / dt - u) - 1);
#endif
            continue;
        }
        tau += scale * vr_trilinear(g->data, slot, c, p - cf) * dt;
    }
    return tau;
}

#endif
