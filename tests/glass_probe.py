"""Probe kernels for the glass field (cl/sdf.h) with any acceleration: the field and its
gradient bound at points, sphere tracing along rays, Fresnel/Snell. Shared by the glass,
cells and extreme-case tests."""
import numpy as np
import pyopencl as cl

from volrender import glass, layout, spheres

SOURCE = """
#include "common.h"
#include "structs.h"
#include "sdf.h"
#include "glass.h"
#include "shade_glass.h"

#define PROBE_ARGS __global const float4* spheres, __global const TreeNode* nodes, \\
    __constant GlassParams* gp, __global const int2* bricks, __global const int2* cells, \\
    __global const int4* lists, __global const int2* entries
#define PROBE_SCENE sdf_scene(gp, spheres, nodes, 0, bricks, cells, lists, entries)

/* out: grad xyz, F */
__kernel void field(PROBE_ARGS, __global const float4* pts, __global float4* out)
{
    int i = get_global_id(0);
    SdfScene sc = PROBE_SCENE;
    SdfSample s = sdf_eval(&sc, pts[i].xyz);
    out[i] = (float4)(s.grad, s.f);
}

/* out: |grad|, lip, F */
__kernel void lip(PROBE_ARGS, __global const float4* pts, __global float4* out)
{
    int i = get_global_id(0);
    SdfScene sc = PROBE_SCENE;
    SdfSample s = sdf_eval(&sc, pts[i].xyz);
    out[i] = (float4)(length(s.grad), s.lip, s.f, 0.0f);
}

/* o.w: side (+1 outside, -1 inside glass); d.w: relax; march over [0, t1] with penumbra
   cone `cone`. out: unit normal, t (-1: no hit); vis: the penumbra ratio (1: none) */
__kernel void trace(PROBE_ARGS, __global const float4* o, __global const float4* d, float t1,
                    float cone, __global float* vis, __global float4* out)
{
    int i = get_global_id(0);
    SdfScene sc = PROBE_SCENE;
    float t, v = 1.0f;
    SdfSample s;
    float side = o[i].w != 0.0f ? o[i].w : 1.0f, relax = d[i].w != 0.0f ? d[i].w : 1.0f;
    int hit = sdf_march(&sc, o[i].xyz, d[i].xyz, 0.0f, t1, side, gp->epsilon, 1.0f, 1024,
                        relax, cone, &v, &t, &s);
    float gl = length(s.grad);
    float3 g = gl > 0.0f ? s.grad / gl : (float3)(0.0f);
    out[i] = hit ? (float4)(g, t) : (float4)(0.0f, 0.0f, 0.0f, -1.0f);
    vis[i] = v;
}

/* out: rgb transmittance of the shadow ray o + t d through refracting glass (--glass-model
   full), base 1 */
__kernel void shadow(PROBE_ARGS, __global const float4* o, __global const float4* d,
                     __global float4* out)
{
    int i = get_global_id(0);
    SdfScene sc = PROBE_SCENE;
    out[i] = (float4)(glass_shadow_full(&sc, gp, o[i].xyz, d[i].xyz, 1.0f, INFINITY), 0.0f);
}

/* in: incident direction xyz, eta w; normal +z. out: refracted xyz (0 on TIR), Fresnel w */
__kernel void optics(__global const float4* in, __global float4* out)
{
    int i = get_global_id(0);
    float3 d = in[i].xyz, n = (float3)(0.0f, 0.0f, 1.0f), t = (float3)(0.0f);
    float eta = in[i].w;
    if (!glass_refract(d, n, eta, &t))
        t = (float3)(0.0f);
    out[i] = (float4)(t, glass_fresnel(-dot(d, n), eta));
}
"""

_PROGRAMS = {}


def f4(a, w=0.0):
    """float32 (N, 4) of (N, 3) with w as the 4th column."""
    out = np.zeros((len(a), 4), np.float32)
    out[:, :3] = a
    out[:, 3] = w
    return out


class Probe:
    """The probe kernels over one packed scene (spheres.pack_scene, glass.glass_params)."""

    def __init__(self, dev, cloud, settings):
        self.dev = dev
        self.settings = settings
        self.scene = spheres.pack_scene(cloud, settings, device=dev)
        p = self.scene
        flags = {"VR_TREE": int(p.accel == "tree"), "VR_GRID": int(p.accel == "grid"),
                 "VR_TILED": 0, "VR_COLORS": 0,
                 "VR_TREE_STACK": layout.tree_stack(p.first_leaf),
                 # shade_glass.h (the shadow probe): one sun, refracting absorbing glass
                 "VR_UBER": 0, "VR_N_SUNS": 1, "VR_N_POINTS": 0, "VR_SHADOWS": 1,
                 "VR_REFRACTION": 1, "VR_ABSORPTION": 1, "VR_GLOW": 0, "VR_ENV_MAP": 0,
                 "VR_FULL": 1, "VR_STATS": 0}
        key = (id(dev), tuple(sorted(flags.items())))
        if key not in _PROGRAMS:
            prg = dev.build(SOURCE, flags, "glass probe")
            _PROGRAMS[key] = {n: cl.Kernel(prg, n)
                              for n in ("field", "lip", "trace", "shadow", "optics")}
        self.kernels = _PROGRAMS[key]
        params = glass.glass_params(p, settings)
        balls, grid = glass.kernel_arrays(p, params)
        mf = cl.mem_flags
        self.bufs = [cl.Buffer(dev.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                               hostbuf=np.ascontiguousarray(a))
                     for a in (balls, p.nodes, params, *grid)]

    def _run(self, name, *arrays, n_out, scalars=(), n_vis=0):
        mf = cl.mem_flags
        ctx = self.dev.context
        extra = [cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a))
                 for a in arrays]
        out = np.zeros((n_out, 4), np.float32)
        d_out = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
        vis = np.zeros(max(n_vis, 1), np.float32)
        d_vis = [cl.Buffer(ctx, mf.WRITE_ONLY, vis.nbytes)] if n_vis else []
        self.kernels[name](self.dev.queue, (n_out,), None, *self.bufs, *extra,
                           *(np.float32(v) for v in scalars), *d_vis, d_out)
        cl.enqueue_copy(self.dev.queue, out, d_out)
        if n_vis:
            cl.enqueue_copy(self.dev.queue, vis, d_vis[0])
            self.vis = vis
        return out

    def field(self, x):
        """(F, gradient) at world points x (M, 3)."""
        out = self._run("field", f4(np.asarray(x) - self.scene.centre), n_out=len(x))
        return out[:, 3], out[:, :3]

    def lip(self, x):
        """(|grad F|, gradient bound, F) at world points x."""
        out = self._run("lip", f4(np.asarray(x) - self.scene.centre), n_out=len(x))
        return out[:, 0], out[:, 1], out[:, 2]

    def trace(self, o, d, side=1.0, relax=1.0, t1=100.0, cone=0.0):
        """(t or -1, unit normal) of sphere tracing world rays o + t d over [0, t1]
        (threshold: the settings' epsilon times (1 + t)); with cone > 0 self.vis holds each
        ray's penumbra ratio (the shadow rays' march)."""
        out = self._run("trace", f4(np.asarray(o) - self.scene.centre, side), f4(d, relax),
                        n_out=len(o), scalars=(t1, cone), n_vis=len(o))
        return out[:, 3], out[:, :3]

    def shadow(self, o, d):
        """rgb transmittance of shadow rays o + t d (world) through the glass."""
        out = self._run("shadow", f4(np.asarray(o) - self.scene.centre), f4(d), n_out=len(o))
        return out[:, :3]


def optics(dev, d, eta):
    """Refracted directions (0 on TIR) and Fresnel reflectance for normal +z."""
    from volrender.cloud import PointCloud
    key = next((k for k in _PROGRAMS if k[0] == id(dev)), None)
    if key is None:
        Probe(dev, PointCloud(np.zeros((1, 3)), np.ones(1)), glass.GlassSettings(accel="none"))
        key = next(k for k in _PROGRAMS if k[0] == id(dev))
    inp = np.zeros((len(d), 4), np.float32)
    inp[:, :3], inp[:, 3] = d, eta
    mf = cl.mem_flags
    d_in = cl.Buffer(dev.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=inp)
    out = np.zeros_like(inp)
    d_out = cl.Buffer(dev.context, mf.WRITE_ONLY, out.nbytes)
    _PROGRAMS[key]["optics"](dev.queue, (len(d),), None, d_in, d_out)
    cl.enqueue_copy(dev.queue, out, d_out)
    return out
