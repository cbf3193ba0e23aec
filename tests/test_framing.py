"""The default framing's shortcuts (issue 35): blend_growth's float32 pass finds the same
spheres as float64 over all of them, and fit's strided first pass ends on the exact fit."""
import math

import numpy as np
import pytest

from volrender import framing, generators, points

DIRS = np.array(framing.GROWTH_DIRECTIONS)


def _slabs_by_brute_force(c, r, reach):
    out = c @ DIRS.T + r[:, None]
    best = out.max(axis=0)
    return out.argmax(axis=0), [np.nonzero(out[:, n] >= best[n] - reach)[0] for n in range(len(DIRS))]


def _clouds(shared_data=None):
    far = np.array([1.0e4, -3.0e3, 7.0e2])        # float32 rounds these to ~1e-3
    blob = generators.generate("blob", 20000)
    box = generators.generate("uniform_box", 20000)
    yield "blob far away", blob.centers.astype(np.float64) * 50 + far, np.full(20000, 0.4)
    yield "box, radii varying", box.centers.astype(np.float64), \
        np.random.default_rng(2).uniform(0.001, 0.02, 20000)
    # spheres whose c.d + r lies within float32's error of the slab's edge along a
    # diagonal, far from the origin, with radii: rounded several times in float32
    rng = np.random.default_rng(4)
    e = DIRS[6]
    p1 = np.cross(e, [1.0, 0.0, 0.0])
    p1 /= np.linalg.norm(p1)
    p2 = np.cross(e, p1)
    r = rng.uniform(0.0, 1.0, 4001)
    reach = np.linspace(-3e-3, 3e-3, 4001) + 0.3      # below the top sphere's c.d + r
    c = (2.0e4 - reach - r)[:, None] * e + rng.uniform(-1e4, 1e4, (4001, 2)) @ np.stack([p1, p2])
    yield "on the edge", np.vstack([c, 2.0e4 * e]), np.append(r, 0.0)
    if shared_data is not None:
        bunny = points.load_points(shared_data / "points" / "bun_zipper.ply")
        yield "bunny", bunny.centers.astype(np.float64), np.full(len(bunny.centers), 0.002)


def test_slabs_are_the_float64_ones(shared_data):
    for name, c, r in _clouds(shared_data):
        reach = 0.3 if name == "on the edge" else 5.0 * float(r.max()) + 0.01 * np.ptp(c)
        arg, slabs = framing._slabs(c, r, DIRS, reach)
        want_arg, want = _slabs_by_brute_force(c, r, reach)
        assert np.array_equal(arg, want_arg), name
        for n in range(len(DIRS)):
            assert np.array_equal(slabs[n], want[n]), (name, n, len(slabs[n]), len(want[n]))
        if name == "on the edge":                 # half the spheres and the top one
            assert abs(len(want[6]) - 2001) <= 2


def test_fewer_bisection_steps_stay_within_their_bound(monkeypatch):
    cloud = generators.generate("blob", 5000)
    c, r, k = cloud.centers.astype(np.float64), np.full(5000, 0.08), 0.1
    fine, steps = framing.blend_growth(c, r, k), framing.GROWTH_STEPS
    assert steps <= 30
    monkeypatch.setattr(framing, "GROWTH_STEPS", 40)
    exact = framing.blend_growth(c, r, k)
    top = 0.5 * k * math.log(5000)
    assert exact > 0.1 * k
    assert exact <= fine <= exact + top * 2.0 ** -steps + 1e-15


def _footprint(target, dist, basis, pts, rad, fov, width, height):
    """(larger projected side / smaller frame side, centre offset / frame) by brute force."""
    f, r_, u = basis
    d = pts - (target - dist * f)
    depth = d @ f
    k = height / (2.0 * math.tan(math.radians(fov) / 2.0))
    x0, x1 = k * ((d @ r_ - rad) / depth).min(), k * ((d @ r_ + rad) / depth).max()
    y0, y1 = k * ((d @ u - rad) / depth).min(), k * ((d @ u + rad) / depth).max()
    return max(x1 - x0, y1 - y0) / min(width, height), max(abs(x0 + x1), abs(y0 + y1)) / height


def _content(source, shared_data):
    """(points, radii) the default framing fits: a generated cloud with random radii, or a
    real file's extent (smoke.vdb's occupied boxes, the bunny's grown spheres)."""
    if ":" in source:
        name, n = source.split(":")
        pts = generators.generate(name, int(n)).centers.astype(np.float64)
        return pts, np.random.default_rng(5).uniform(0.002, 0.01, len(pts))
    import volrender
    if source.endswith(".vdb"):
        from conftest import openvdb_missing
        if openvdb_missing():
            pytest.skip(openvdb_missing())
    pts, rad = volrender.load_scene(str(shared_data / source), size=(64, 48)).content.extent()
    pts = np.asarray(pts, np.float64).reshape(-1, 3)
    return pts, np.array(np.broadcast_to(rad, (len(pts),)), np.float64)


@pytest.mark.parametrize("source", ["blob:300000", "glass_gather:100000", "uniform_box:200000",
                                    "vdb/smoke.vdb", "points/bun_zipper.ply"])
def test_fit_after_a_strided_pass_is_the_exact_fit(source, monkeypatch, shared_data):
    pts, rad = _content(source, shared_data)
    f = np.array([0.25, 0.35, 1.0]) / np.linalg.norm([0.25, 0.35, 1.0])
    r_ = np.cross(f, [0.0, 1.0, 0.0])
    r_ /= np.linalg.norm(r_)
    basis = (-f, -r_, np.cross(-r_, -f))
    centre = 0.5 * (pts.min(0) + pts.max(0))
    target, dist = framing.fit(pts, rad, basis, centre, 40.0, 1920, 1080, 0.9)
    size, off = _footprint(target, dist, basis, pts, rad, 40.0, 1920, 1080)
    assert abs(size - 0.9) < 1e-9 and off < 1e-9
    assert len(pts) // framing.SAMPLE > 1                  # the strided pass ran
    monkeypatch.setattr(framing, "SAMPLE", len(pts) + 1)    # every point from the start
    t2, d2 = framing.fit(pts, rad, basis, centre, 40.0, 1920, 1080, 0.9)
    assert abs(d2 - dist) <= 1e-10 * dist and np.abs(t2 - target).max() <= 1e-10 * dist
