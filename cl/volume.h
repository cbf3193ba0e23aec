/* Sparse brick volume: trilinear density lookup, empty-brick skipping, shadow march,
   spectral types and the emission colour (blackbody table, temperature grid).
   Everything here works in the layout's local index space (voxel centres at integer
   coordinates, box [0, dims*8]); ray parameters t are world distances.
   Reads VR_SKIP_EMPTY, VR_CHROMATIC, VR_TEMPERATURE; VR_BRICK and VR_BRICK_VALUES come
   from structs.h. */
#ifndef VR_VOLUME_H
#define VR_VOLUME_H

/* Per-channel quantities: one float for grey media, float3 with VR_CHROMATIC (an albedo
   or a sigma_t scale that differs between channels). */
#if defined(VR_CHROMATIC) && VR_CHROMATIC
typedef float3 VrSpec;
inline float vr_spec_max(float3 v) { return fmax(fmax(v.x, v.y), v.z); }
inline float vr_spec_mean(float3 v) { return (v.x + v.y + v.z) * (1.0f / 3.0f); }
inline float3 vr_spec_transmit(float3 tau)
{
    return (float3)(vr_transmit(tau.x), vr_transmit(tau.y), vr_transmit(tau.z));
}
#define VR_EXTINCTION(vp) ((vp)->extinction.xyz)
#define VR_ALBEDO(vp) ((vp)->albedo_rgb.xyz)
#else
typedef float VrSpec;
inline float vr_spec_max(float v) { return v; }
inline float vr_spec_mean(float v) { return v; }
inline float vr_spec_transmit(float tau) { return vr_transmit(tau); }
#define VR_EXTINCTION(vp) 1.0f
#define VR_ALBEDO(vp) ((vp)->albedo)
#endif

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

/* Blackbody colour at `kelvin` from the table (volrender/blackbody.py: entry
   bb_a / T + bb_b, linear between entries, clamped to the table's range). */
inline float3 vr_blackbody(__global const float4* bb, __constant VolumeParams* vp, float kelvin)
{
    float f = clamp(vp->bb_a / fmax(kelvin, 1.0f) + vp->bb_b, 0.0f, (float)(vp->bb_n - 1));
    int i = min((int)f, vp->bb_n - 2);
    float4 c = mix(bb[i], bb[i + 1], f - (float)i);
    /* the intensity law (emission_color.w = its constant; 0: the colour alone):
       k T^4 x the colour of luminance 1 (c.w = 1 / luminance), volrender/blackbody.py */
    float k = vp->emission_color.w;
    if (k > 0.0f) {
        float t2 = fmax(kelvin, 0.0f) * fmax(kelvin, 0.0f);
        return c.xyz * (c.w * k * t2 * t2);
    }
    return c.xyz;
}

/* Emitted radiance per unit length per emission-grid value at cell c + f of brick
   `slot`: the blackbody colour of the voxel's own temperature (VR_TEMPERATURE), else the
   one colour of --emission-temperature. */
inline float3 vr_emission_color(__constant VolumeParams* vp, __global const float* temperature,
                                __global const float4* bb, int slot, int3 c, float3 f)
{
#if defined(VR_TEMPERATURE) && VR_TEMPERATURE
    float kelvin = vp->temp_offset + vp->temp_scale * vr_trilinear(temperature, slot, c, f);
    return vp->emission_scale * vr_blackbody(bb, vp, kelvin);
#else
    (void)temperature; (void)bb; (void)slot; (void)c; (void)f;
    return vp->emission_color.xyz;
#endif
}

/* World parameter where the ray leaves the (empty) brick containing point p: one ray-box
   test (VR_SKIP_RUNS 0, GPUs). */
inline float vr_brick_exit(float3 o, float3 inv_d, float3 p)
{
    float3 lo = floor(p * (1.0f / VR_BRICK)) * VR_BRICK;
    float2 tt = vr_ray_box(o, inv_d, lo, lo + (float3)(VR_BRICK));
    return tt.y;
}

/* World parameter where the ray o + t d leaves the run of empty bricks that starts with
   the (empty) brick holding p: a DDA over the brick table from there to the first
   stored brick or out of the layout, so a run of empty bricks costs one table read
   each instead of a ray-box test per brick and a sample in each. Each face parameter
   is computed afresh from the brick's integer corner (no accumulated rounding). */
inline float vr_empty_exit(const VrGrid* g, float3 o, float3 inv_d, float3 p)
{
    int3 b = convert_int3(floor(p * (1.0f / VR_BRICK)));
    int3 step = select((int3)(-1), (int3)(1), inv_d > 0.0f);
    int3 next = b + select((int3)(0), (int3)(1), inv_d > 0.0f);
    for (;;) {
        float3 tf = (convert_float3(next * VR_BRICK) - o) * inv_d;
        tf = select(tf, (float3)(INFINITY), isnan(tf));
        float te = fmin(fmin(tf.x, tf.y), tf.z);
        if (tf.x <= tf.y && tf.x <= tf.z) {
            b.x += step.x; next.x += step.x;
        } else if (tf.y <= tf.z) {
            b.y += step.y; next.y += step.y;
        } else {
            b.z += step.z; next.z += step.z;
        }
        if (any(b < 0) || any(b >= g->dims.xyz)
            || g->table[(b.x * g->dims.y + b.y) * g->dims.z + b.z] >= 0)
            return te;
    }
}

/* Where a sample in an empty brick resumes: past the run of empty bricks (VR_SKIP_RUNS 1,
   CPUs) or past its brick (GPUs); either way the skipped samples read exactly zero, so the
   image is the same (volume.VolumeSettings.skip_runs, README "Volumes" for the timings). */
#if VR_SKIP_RUNS
#define VR_EMPTY_EXIT(g, o, inv_d, p) vr_empty_exit(g, o, inv_d, p)
#else
#define VR_EMPTY_EXIT(g, o, inv_d, p) vr_brick_exit(o, inv_d, p)
#endif

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
            float te = VR_EMPTY_EXIT(g, o, inv_d, p);
            k = max(k, (int)ceil((te - t0) / dt - u) - 1);
#endif
            continue;
        }
        tau += scale * vr_trilinear(g->data, slot, c, p - cf) * dt;
    }
    return tau;
}

#endif
