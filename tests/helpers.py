"""Shared helpers of the tests: renders through the public path (`render.render` of a
`Scene.of(...)`) as an Image (volume_image, render_glass, and render_points, render_volume:
bench/common.py's wrappers, shared with the benchmarks), and,
for the closed-form tests (test_optics, test_depth, test_env_sampling), grids with a known
world transform, cameras and reference formulas.

Statistics: every pixel is an independent estimate (the RNG is keyed by pixel), so the
spread of residuals across pixels estimates the per-pixel standard deviation. Bounds
are Z = 5 standard errors: a false alarm has probability ~6e-7 per check for a normal
mean, and seeds are fixed, so a pass or a failure is reproducible."""
from __future__ import annotations

import dataclasses

import numpy as np
from bench import common
from bench.common import render_points  # noqa: F401  (the one render wrapper, shared)

from volrender import dispatch
from volrender.camera import Camera
from volrender.render import render
from volrender.scene import Environment, GlassContent, Scene, VolumeContent
from volrender.bricks import Bricks
from volrender.volume import VolumeSettings

Z = 5.0
VOX = 0.1            # the voxel size of the synthetic volumes
ENV = (0.6, 0.8, 1.0)    # a uniform bluish environment (test_path, test_defaults)


def scaled(vox, offset=(0.0, 0.0, 0.0), rot=None):
    """index -> world: voxel size vox, voxel (0, 0, 0) at `offset`, axes turned by `rot`."""
    m = np.eye(4)
    m[:3, :3] = (np.eye(3) if rot is None else rot) * vox
    m[:3, 3] = offset
    return m


def top_camera(n=16, fov=6.0):
    """n x n pixels looking down -z from (0, 0, 5) at the origin."""
    return Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), fov, n, n)


def centred_bricks(values, vox, **kw):
    """Bricks of a dense array whose centre sits at the world origin; also returns the
    index -> world matrix (voxel (i, j, k) at m @ (i, j, k, 1))."""
    c = (np.array(values.shape) - 1) / 2 * vox
    m = scaled(vox, -c)
    return Bricks.from_dense(values, m, **kw), m


def look_at(origin, target=(0.0, 0.0, 0.0), fov=10.0, n=16, up=(0.0, 1.0, 0.0)):
    return Camera(tuple(map(float, origin)), tuple(map(float, target)), up, fov, n, n)


def volume_image(bricks, camera, lights, settings, device, environment=None):
    """render.Image of a volume (the public path); environment: texels (H, W, 3) of a
    map, else settings.env."""
    env = None if environment is None else Environment(np.asarray(environment, np.float32))
    settings = exact_march(settings)
    return render(Scene.of(camera, list(lights), VolumeContent(bricks, settings), env), device)


def render_glass(cloud, camera, lights, settings, device, environment=None):
    """render.Image of a point cloud as glass (the public path); environment as above."""
    env = None if environment is None else Environment(np.asarray(environment, np.float32))
    return render(Scene.of(camera, list(lights), GlassContent(cloud, settings), env), device)


def trilinear(values, m, x):
    """The renderer's density model in numpy: values (nx, ny, nz) at voxel centres
    m @ (i, j, k), trilinear in between, 0 outside (the layout pads with zeros), at
    world points x (..., 3)."""
    inv = np.linalg.inv(m)
    p = x @ inv[:3, :3].T + inv[:3, 3]
    v = np.pad(np.asarray(values, np.float64), 1)
    q = p + 1.0                                  # index into the padded array
    i0 = np.floor(q).astype(np.int64)
    f = q - i0
    out = np.zeros(x.shape[:-1])
    shape = np.array(v.shape)
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                idx = i0 + (dx, dy, dz)
                ok = np.all((idx >= 0) & (idx < shape), axis=-1)
                idc = np.clip(idx, 0, shape - 1)
                w = (np.where(dx, f[..., 0], 1 - f[..., 0]) * np.where(dy, f[..., 1], 1 - f[..., 1])
                     * np.where(dz, f[..., 2], 1 - f[..., 2]))
                out += np.where(ok, w * v[idc[..., 0], idc[..., 1], idc[..., 2]], 0.0)
    return out


def assert_unbiased(est, want, what, z=Z):
    """est, want: per-pixel estimates and their expected values (independent pixels):
    the mean residual within z standard errors, and no pixel beyond 6 standard
    deviations of the spread (a NaN, a lost sample, a stuck pixel). Returns the spread."""
    r = (np.asarray(est, np.float64) - np.asarray(want, np.float64)).ravel()
    assert np.all(np.isfinite(r)), f"{what}: non-finite pixels"
    sd = r.std(ddof=1)
    se = sd / np.sqrt(r.size)
    assert abs(r.mean()) <= z * se + 1e-7, f"{what}: mean residual {r.mean():.3e}, se {se:.3e}"
    assert np.all(np.abs(r - r.mean()) <= 6 * sd + 1e-7), f"{what}: outlier pixel"
    return sd


def fresnel(cos_i, eta):
    """Exact dielectric Fresnel in float64: (rs, rp, F = (rs^2 + rp^2) / 2), eta =
    n_incident / n_transmitted; TIR gives rs = rp = 1 (|r| = 1)."""
    cos_i = np.asarray(cos_i, np.float64)
    s2 = eta * eta * (1.0 - cos_i * cos_i)
    tir = s2 >= 1.0
    cos_t = np.sqrt(np.maximum(1.0 - s2, 0.0))
    rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rs, rp = np.where(tir, 1.0, rs), np.where(tir, 1.0, rp)
    return rs, rp, 0.5 * (rs * rs + rp * rp)


def env_lookup(texels, d):
    """The equirectangular map at world directions d (..., 3), bilinear between texel
    centres, in numpy (DESIGN.md: u = 0.5 + atan2(x, -z) / 2 pi, v = acos(y) / pi,
    wrapping in u, clamped in v)."""
    t = np.asarray(texels, np.float64)
    h, w = t.shape[:2]
    d = np.asarray(d, np.float64)
    u = 0.5 + np.arctan2(d[..., 0], -d[..., 2]) / (2 * np.pi)
    v = np.arccos(np.clip(d[..., 1], -1, 1)) / np.pi
    fx, fy = u * w - 0.5, np.clip(v * h - 0.5, 0, h - 1)
    x0, y0 = np.floor(fx), np.floor(fy)
    ax, ay = (fx - x0)[..., None], (fy - y0)[..., None]
    x0 = x0.astype(int) % w
    x1 = (x0 + 1) % w
    y0 = y0.astype(int)
    y1 = np.minimum(y0 + 1, h - 1)
    a = (1 - ax) * t[y0, x0] + ax * t[y0, x1]
    b = (1 - ax) * t[y1, x0] + ax * t[y1, x1]
    return (1 - ay) * a + ay * b


def texel_dirs(h, w):
    """Unit directions of the texel centres of an h x w map (h, w, 3)."""
    th = np.pi * (np.arange(h) + 0.5) / h
    ph = ((np.arange(w) + 0.5) / w - 0.5) * 2 * np.pi
    T, P = np.meshgrid(th, ph, indexing="ij")
    return np.stack([np.sin(T) * np.sin(P), np.cos(T), -np.sin(T) * np.cos(P)], -1)


def ray_sphere(o, d, c, r):
    """Nearest t >= 0 of o + t d (unit d, broadcast) on the sphere (c, r); inf on a miss."""
    oc = np.asarray(o, np.float64) - c
    b = (d * oc).sum(-1)
    disc = b * b - ((oc * oc).sum(-1) - r * r)
    root = np.sqrt(np.maximum(disc, 0.0))
    t0, t1 = -b - root, -b + root
    t = np.where(t0 >= 0, t0, t1)
    return np.where((disc > 0) & (t >= 0), t, np.inf)


def run_unprivileged(code, *args, timeout=60):
    """stdout of `python -c code args` run by a user whom permission bits bind: this user
    when it is not root, else `nobody` (the child drops root with setgroups, setgid and
    setuid before it starts). Skips the calling test, saying why, when neither works (no
    `nobody`, or no right to change users, as in some containers)."""
    import os
    import subprocess
    import sys

    import pytest
    env = {k: v for k, v in os.environ.items() if k not in ("HOME", "XDG_CACHE_HOME")}
    env["HOME"] = "/nonexistent"
    preexec = None
    if os.geteuid() == 0:
        import pwd
        try:
            pw = pwd.getpwnam("nobody")
        except KeyError:
            pytest.skip("running as root, and there is no user `nobody` to drop to")

        def preexec():
            os.setgroups([])
            os.setgid(pw.pw_gid)
            os.setuid(pw.pw_uid)
    import volrender
    here = os.path.realpath(volrender.__file__)
    # the child names the volrender it imports first: it must be this one (a user who
    # cannot read this checkout would import another, or none)
    prelude = "import os, volrender; print(os.path.realpath(volrender.__file__))\n"
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [os.path.dirname(os.path.dirname(here)),
                                                      env.get("PYTHONPATH")]))
    try:
        p = subprocess.run([sys.executable, "-c", prelude + code, *map(str, args)],
                           preexec_fn=preexec, capture_output=True, text=True, env=env, cwd="/",
                           timeout=timeout)
    except subprocess.SubprocessError as exc:        # setuid refused in the child
        pytest.skip(f"running as root and cannot become `nobody`: {exc}")
    first, _, rest = p.stdout.partition("\n")
    if first != here:
        pytest.skip(f"the unprivileged user cannot import this checkout's volrender ({here}): "
                    f"got {first or p.stderr.strip().splitlines()[-1:]}")
    assert p.returncode == 0, p.stderr[-2000:]
    return rest


def unprivileged_uid():
    """The uid run_unprivileged runs as."""
    import os
    if os.geteuid() != 0:
        return os.geteuid()
    import pwd
    return pwd.getpwnam("nobody").pw_uid


def exact_march(settings):
    """Settings left at --estimator auto render as `march`, and --light-cache auto as
    off, here: these tests check the marcher's estimand (single scattering, or the octaves
    asked for) with its exact shadow marches; auto's choice has its own tests
    (test_defaults.py), through load_scene as the CLI renders, and the cache its own
    (test_light_cache.py)."""
    if settings.estimator == "auto":
        settings = dataclasses.replace(settings, estimator="march")
    if settings.light_cache == "auto":
        settings = dataclasses.replace(settings, light_cache="off")
    return settings


def render_volume(bricks, camera, lights, settings, device, progress=None, launch=None):
    """See exact_march."""
    settings = exact_march(settings)
    return common.render_volume(bricks, camera, lights, settings, device, progress, launch)


def lumpy_ball(n=20, seed=4):
    """A lumpy ball: smooth noise inside a sphere of radius n/2 - 1 voxels."""
    rng = np.random.default_rng(seed)
    v = rng.random((n, n, n))
    for ax in range(3):
        for _ in range(2):
            v = (np.roll(v, 1, ax) + v + np.roll(v, -1, ax)) / 3
    i = np.indices((n, n, n)) - (n - 1) / 2
    r = np.sqrt((i ** 2).sum(0))
    v = np.where(r < n / 2 - 1.5, 0.4 + (v - v.mean()) / v.std() * 0.15, 0.0)
    return Bricks.from_dense(np.clip(v, 0, None).astype(np.float32),
                             scaled(VOX, (-(n - 1) / 2 * VOX,) * 3))


def glowing_ball(n=20):
    """A ball of density falling linearly from 1 at the centre, emitting half of it."""
    i = np.indices((n, n, n)).astype(np.float64) - (n - 1) / 2
    v = np.clip(1.0 - np.sqrt((i ** 2).sum(0)) / 8.0, 0.0, None).astype(np.float32)
    m = np.eye(4)
    m[:3, :3] *= 0.1
    m[:3, 3] = -(n - 1) / 2 * 0.1
    return Bricks.from_dense(v, m, emission=v * 0.5)


def sky(h=16, w=32, seed=3):
    """A map with a bright sun-like spot, a blue sky and a dark ground."""
    rng = np.random.default_rng(seed)
    t = np.zeros((h, w, 3), np.float32)
    t[: h // 2] = (0.3, 0.45, 0.8)
    t[h // 2:] = (0.05, 0.04, 0.03)
    t[3, 20] = (60.0, 55.0, 50.0)
    t *= rng.uniform(0.8, 1.2, size=(h, w, 1)).astype(np.float32)
    return t


def chi2_sf(x, k):
    """P(chi-square with k degrees of freedom > x), Wilson-Hilferty (error < 1e-3 in p
    at these k)."""
    from math import erfc, sqrt
    z = ((x / k) ** (1 / 3) - (1 - 2 / (9 * k))) / sqrt(2 / (9 * k))
    return 0.5 * erfc(z / sqrt(2))


# ---- a faked kernel clock (test_cadence, test_eta): each launch 'takes' a cost by row

CADENCE_W, CADENCE_H, CADENCE_SPP = 32, 240, 8   # the fake-clock scene (test_cadence, test_eta)


def cadence_scene():
    v = np.zeros((8, 8, 8), np.float32)
    v[2:6, 2:6, 2:6] = 1.0
    m = np.eye(4)
    m[:3, :3] *= 0.1
    camera = Camera((0.4, 0.4, 3.0), (0.4, 0.4, 0.4), (0.0, 1.0, 0.0), 40.0, CADENCE_W, CADENCE_H)
    return Scene(camera, (),
                 VolumeContent(Bricks.from_dense(v, m), VolumeSettings(spp=CADENCE_SPP)))


def fake_cost(monkeypatch, per_sample, log):
    """Each launch 'takes' the sum of per_sample(row) over its rows x its samples x width."""
    real = dispatch._enqueue

    def enqueue(device, kernel, global_size, local_size):
        ns, _ = real(device, kernel, global_size, local_size)
        y0, s0, s1 = log["args"][-3:]
        rows = min(global_size[1], CADENCE_H - int(y0))
        took = CADENCE_W * int(s1 - s0) * sum(
            per_sample(y) for y in range(int(y0), int(y0) + rows))
        log["launches"].append((int(y0), rows, int(s1 - s0), took))
        log["clock"] += took
        return ns, took
    monkeypatch.setattr(dispatch, "_enqueue", enqueue)


def spy_args(monkeypatch, log):
    """Record the last set_args of each kernel run (y0, s0, s1 are its last three)."""
    import pyopencl as cl
    real = cl.Kernel.set_args

    def set_args(self, *a):
        log["args"] = a
        return real(self, *a)
    monkeypatch.setattr(cl.Kernel, "set_args", set_args)
