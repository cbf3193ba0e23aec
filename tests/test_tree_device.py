"""The partition tree built on the device (volrender/tree_device.py) is the numpy build's
tree (volrender/tree.py with the same float32 keys): the same sphere order, node ranges
and float32 boxes, so the support cells built from it hold the same lists and a render
is the same image bit for bit; on random, degenerate (coincident points, shared
coordinates, signed zeros) and real clouds."""
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from volrender import generators, glass, spheres, tree, tree_device
from volrender.points import load_points
from volrender.lights import Sun
from volrender.render import render
from volrender.scene import GlassContent, Scene

FAST = settings(max_examples=25, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def both(dev, c, r, leaf):
    origin = 0.5 * (c.min(0) + c.max(0))
    keys = (c - origin).astype(np.float32)
    sp = np.zeros((len(c), 4), np.float32)
    sp[:, :3], sp[:, 3] = keys, r
    host = tree.build(c, r, leaf, keys=keys)
    dev_tree, dev_spheres = tree_device.build(dev, keys, sp, leaf, origin)
    return host.in_frame(sp[host.order], origin), sp, dev_tree, dev_spheres


@FAST
@given(n=st.integers(1, 3000), leaf=st.sampled_from([1, 2, 8, 16]), dup=st.integers(0, 3),
       seed=st.integers(0, 2 ** 31))
def test_device_tree_is_the_numpy_tree(cl_device, n, leaf, dup, seed):
    rng = np.random.default_rng(seed)
    c = rng.standard_normal((n, 3)) * rng.uniform(0.1, 3, 3)
    if dup == 1:                                   # coincident points
        c[rng.integers(0, n, n // 2)] = c[rng.integers(0, max(1, n // 20), n // 2)]
    elif dup == 2:                                 # shared coordinates, signed zeros
        c = np.round(c, 1)
        c[rng.random(n) < 0.2, 1] = -0.0
    elif dup == 3:                                 # one point n times
        c[:] = c[0]
    host, sp, dev, spheres = both(cl_device, c, 0.05, leaf)
    np.testing.assert_array_equal(spheres, sp[host.order])
    for name in ("order", "start", "count", "lo", "hi", "origin"):
        np.testing.assert_array_equal(getattr(dev, name), getattr(host, name), name)
    assert (dev.depth, dev.leaf_size, dev.n_points, dev.margin) == \
        (host.depth, host.leaf_size, host.n_points, 0.0)
    assert dev.lo.dtype == np.float32
    np.testing.assert_array_equal(dev.origin, 0.5 * (c.min(0) + c.max(0)))


def clouds(shared):
    yield "blob", generators.blob(4000, seed=3), {}
    yield "gather", generators.generate("glass_gather", 3000, 1), {}
    if shared is not None:
        yield "bunny", load_points(shared / "points" / "bun_zipper.ply"), \
            {"radius": 0.002, "blend": 0.004}


@pytest.mark.parametrize("name", ["blob", "gather", "bunny"])
def test_cells_and_images_from_the_device_tree_are_the_same(cl_device, request, name):
    shared = None
    if name == "bunny":
        shared = request.getfixturevalue("shared_data")
    cloud, kw = next((c, k) for n, c, k in clouds(shared) if n == name)
    s = glass.GlassSettings(bounces=2, **kw)
    host = spheres.pack_scene(cloud, s, cl_device, tree_on="host")
    dev = spheres.pack_scene(cloud, s, cl_device, tree_on="device")
    np.testing.assert_array_equal(dev.spheres, host.spheres)
    np.testing.assert_array_equal(dev.nodes, host.nodes)
    for field in ("bricks", "cells", "lists", "runs", "walk", "entries"):
        np.testing.assert_array_equal(getattr(dev.cells, field), getattr(host.cells, field))
    cam = glass.default_camera(cloud, 24, 18, radius=kw.get("radius"))
    img = {}
    for on in ("host", "device"):
        content = GlassContent(cloud, s)
        content.prepare(cl_device, tree_on=on)
        img[on] = render(Scene.of(cam, [Sun((0.3, -1.0, -0.2), 2.0)], content), cl_device).rgba
    np.testing.assert_array_equal(img["device"], img["host"])
