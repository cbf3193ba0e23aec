import dataclasses
import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from volrender.errors import UserError
from volrender.generators import blob, glass_gather
from volrender.tree import build, check_invariants, query_point, tree_depth


def leaf_sets(tree):
    leaves = range(tree.first_leaf, tree.n_nodes)
    return [tree.order[tree.start[k]:tree.start[k] + tree.count[k]] for k in leaves]


def brute_leaf_scan(tree, x, radius):
    """All spheres of every leaf whose box is within radius of x, no pruning."""
    out = []
    for k in range(tree.first_leaf, tree.n_nodes):
        gap = np.maximum(np.maximum(tree.lo[k] - x, x - tree.hi[k]), 0)
        if gap @ gap <= radius * radius:
            out.append(tree.order[tree.start[k]:tree.start[k] + tree.count[k]])
    return np.sort(np.concatenate(out)) if out else np.zeros(0, np.int64)


def brute_sphere_scan(centers, radii, margin, x, radius):
    """Spheres whose own AABB, inflated by margin, is within radius of x."""
    r = (radii + margin)[:, None]
    gap = np.maximum(np.maximum(centers - r - x, x - centers - r), 0)
    return np.flatnonzero((gap * gap).sum(1) <= radius * radius)


def degenerate(kind, n, rng):
    if kind == "uniform":
        return rng.random((n, 3))
    if kind == "coincident":
        return np.tile(rng.random(3), (n, 1))
    if kind == "duplicates":
        return rng.integers(0, 3, size=(n, 3)).astype(float)
    if kind == "collinear":
        return np.outer(rng.random(n), [1.0, -2.0, 0.5]) + [3, 4, 5]
    if kind == "coplanar":
        uv = rng.random((n, 2))
        return uv[:, :1] * [1, 0, 1] + uv[:, 1:] * [0, 1, -1]
    if kind == "offset":
        return rng.random((n, 3)) * 1e-3 + 1e5
    if kind == "clustered":
        return np.concatenate([rng.normal(size=(n - n // 2, 3)) * 1e-6,
                               rng.normal(size=(n // 2, 3)) * 100])
    raise ValueError(kind)


KINDS = ["uniform", "coincident", "duplicates", "collinear", "coplanar", "offset", "clustered"]


# ---------------------------------------------------------------- structure

def test_depth_rule():
    assert tree_depth(1, 8) == 0 and tree_depth(8, 8) == 0 and tree_depth(9, 8) == 1
    assert tree_depth(17, 8) == 2 and tree_depth(1000, 1) == 10 and tree_depth(1024, 1) == 10
    for n in range(1, 200):
        for leaf in (1, 3, 8):
            d = tree_depth(n, leaf)
            assert -(-n // 2 ** d) <= leaf and (d == 0 or -(-n // 2 ** (d - 1)) > leaf)


@pytest.mark.parametrize("axis", ["longest", "cycle"])
@pytest.mark.parametrize("n,leaf_size,margin", [(1, 8, 0.0), (7, 8, 0.1), (9, 8, 0.0),
                                                (1000, 8, 0.05), (1001, 1, 0.0), (5000, 16, 1.0)])
def test_random_clouds(rng, axis, n, leaf_size, margin):
    c = rng.normal(size=(n, 3))
    r = rng.random(n) * 0.1
    t = build(c, r, leaf_size, margin, axis)
    check_invariants(t, c, r)
    assert t.n_nodes == 2 ** (t.depth + 1) and t.first_leaf == 2 ** t.depth
    assert t.lo.dtype == np.float64 and t.order.dtype == np.int64 and t.start.dtype == np.int64
    assert t.margin == margin and t.leaf_size == leaf_size and t.n_points == n


def test_leaves_partition_points(rng):
    c = rng.random((777, 3))
    t = build(c, 0.01, leaf_size=5)
    parts = leaf_sets(t)
    assert len(parts) == 2 ** t.depth
    allpts = np.concatenate(parts)
    np.testing.assert_array_equal(np.sort(allpts), np.arange(777))
    assert max(map(len, parts)) <= 5


def test_median_split_and_axes(rng):
    c = rng.random((1001, 3)) * [10, 1, 0.1]       # longest along x
    t = build(c, 0.0, leaf_size=4)
    assert t.count[2] == 501 and t.count[3] == 500    # ceil(n/2) goes left
    left, right = t.order[:501], t.order[501:]
    assert c[left, 0].max() <= c[right, 0].min()
    # 'cycle' splits the root along x, depth-1 nodes along y
    t = build(c, 0.0, leaf_size=4, axis="cycle")
    a = t.order[t.start[2]:t.start[2] + t.count[2]]
    aa, ab = a[:t.count[4]], a[t.count[4]:]
    assert c[aa, 1].max() <= c[ab, 1].min()


def test_longest_axis_per_node(rng):
    # two slabs side by side along x, each elongated along z: root splits x, children z
    c = np.concatenate([rng.random((500, 3)) * [1, 0.1, 5], rng.random((500, 3)) * [1, 0.1, 5] + [10, 0, 0]])
    t = build(c, 0.0, leaf_size=8)
    for child in (2, 3):
        idx = t.order[t.start[child]:t.start[child] + t.count[child]]
        lo_half = idx[:t.count[2 * child]]
        hi_half = idx[t.count[2 * child]:]
        assert c[lo_half, 2].max() <= c[hi_half, 2].min()


def test_bounds_are_tight_aabb_plus_margin(rng):
    c = rng.normal(size=(300, 3))
    r = rng.random(300)
    t = build(c, r, leaf_size=8, margin=0.25)
    np.testing.assert_array_equal(t.lo[1], (c - r[:, None]).min(0) - 0.25)
    np.testing.assert_array_equal(t.hi[1], (c + r[:, None]).max(0) + 0.25)
    for k in range(t.first_leaf, t.n_nodes):
        idx = t.spheres(k)
        np.testing.assert_array_equal(t.lo[k], (c[idx] - r[idx, None]).min(0) - 0.25)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("axis", ["longest", "cycle"])
def test_degenerate_inputs(rng, kind, axis):
    c = degenerate(kind, 2000, rng)
    for r in (np.zeros(len(c)), rng.random(len(c)) * 0.01):
        t = build(c, r, leaf_size=8, margin=0.01, axis=axis)
        check_invariants(t, c, r)
        lc = t.count[t.first_leaf:]
        assert lc.max() - lc.min() <= 1 and lc.max() <= 8     # balanced despite ties


def test_many_coincident_points():
    c = np.full((100_000, 3), 1e5)
    t = build(c, 0.5, leaf_size=8, margin=0.1)
    check_invariants(t, c, 0.5)
    lc = t.count[t.first_leaf:]
    assert lc.max() - lc.min() <= 1               # still split evenly
    np.testing.assert_array_equal(t.lo[1], [1e5 - 0.6] * 3)


def test_single_point_and_empty_leaves():
    t = build([[1.0, 2.0, 3.0]], [0.5])
    check_invariants(t, [[1.0, 2.0, 3.0]], [0.5])
    assert t.depth == 0 and t.first_leaf == 1 and t.n_nodes == 2 and t.count[1] == 1
    np.testing.assert_array_equal(t.lo[1], [0.5, 1.5, 2.5])
    np.testing.assert_array_equal(query_point(t, [1, 2, 3], 0.0), [0])
    # 3 points, leaf_size 1: 4 leaves, one of them empty with inverted bounds
    c = np.eye(3)
    t = build(c, 0.1, leaf_size=1)
    check_invariants(t, c, 0.1)
    assert t.depth == 2 and sorted(t.count[4:]) == [0, 1, 1, 1]
    e = 4 + int(np.argmin(t.count[4:]))
    assert np.isposinf(t.lo[e]).all() and np.isneginf(t.hi[e]).all()
    assert len(query_point(t, [0, 0, 0], 100.0)) == 3


def test_check_invariants_catches_corruption(rng):
    c = rng.random((100, 3))
    t = build(c, 0.05, leaf_size=4, margin=0.1)
    check_invariants(t, c, 0.05)

    def broken(**fields):
        with pytest.raises(AssertionError):
            check_invariants(dataclasses.replace(t, **fields), c, 0.05)

    lo = t.lo.copy(); lo[t.first_leaf + 3] += 0.01
    broken(lo=lo)
    hi = t.hi.copy(); hi[1] -= 1e-6
    broken(hi=hi)
    order = t.order.copy(); order[0] = order[1]
    broken(order=order)
    count = t.count.copy(); count[t.first_leaf] += 1
    broken(count=count)
    start = t.start.copy(); start[3] += 1
    broken(start=start)
    broken(leaf_size=2)
    broken(margin=0.2)
    with pytest.raises(AssertionError):
        check_invariants(t, c, 0.06)          # bigger spheres than built for


def test_build_errors(rng):
    c = rng.random((10, 3))
    for kwargs, frag in [({"leaf_size": 0}, "leaf_size"), ({"margin": -1.0}, "margin"),
                         ({"margin": np.nan}, "margin"), ({"axis": "median"}, "longest, cycle")]:
        with pytest.raises(UserError, match=frag):
            build(c, 0.1, **kwargs)
    with pytest.raises(UserError, match="zero points"):
        build(np.zeros((0, 3)), 0.1)
    bad = c.copy(); bad[3, 1] = np.nan
    with pytest.raises(UserError, match="finite"):
        build(bad, 0.1)
    with pytest.raises(UserError, match="finite"):
        build(c, -np.ones(10))
    with pytest.raises(ValueError):
        build(c[:, :2], 0.1)


# ---------------------------------------------------------------- queries

@pytest.mark.parametrize("axis", ["longest", "cycle"])
def test_query_point_matches_brute_force(rng, axis):
    pc = glass_gather(3000, seed=2)
    margin = 0.02
    t = build(pc.centers, pc.radii, leaf_size=8, margin=margin, axis=axis)
    lo, hi = pc.centers.min(0) - 0.3, pc.centers.max(0) + 0.3
    for x in rng.uniform(lo, hi, size=(100, 3)):
        radius = rng.choice([0.0, 0.01, 0.1])
        got = query_point(t, x, radius)
        np.testing.assert_array_equal(got, brute_leaf_scan(t, x, radius))
        need = brute_sphere_scan(pc.centers, pc.radii, margin, x, radius)
        assert np.isin(need, got).all()        # every sphere that can matter is found
        # and every sphere whose inflated ball touches the query ball in particular
        d = np.linalg.norm(pc.centers - x, axis=1)
        assert np.isin(np.flatnonzero(d <= pc.radii + margin + radius), got).all()


@settings(max_examples=150, deadline=None)
@given(n=st.integers(1, 400), leaf_size=st.integers(1, 20),
       margin=st.sampled_from([0.0, 1e-9, 0.01, 0.5, 10.0]),
       kind=st.sampled_from(KINDS), axis=st.sampled_from(["longest", "cycle"]),
       zero_radius=st.booleans(), seed=st.integers(0, 2 ** 32 - 1))
def test_property_invariants_and_queries(n, leaf_size, margin, kind, axis, zero_radius, seed):
    rng = np.random.default_rng(seed)
    c = degenerate(kind, n, rng)
    r = np.zeros(n) if zero_radius else rng.random(n) * 0.05
    t = build(c, r, leaf_size=leaf_size, margin=margin, axis=axis)
    check_invariants(t, c, r)
    assert t.depth == tree_depth(n, leaf_size)
    lc = t.count[t.first_leaf:]
    assert lc.max() == -(-n // 2 ** t.depth) and lc.max() - lc.min() <= 1
    parts = leaf_sets(t)
    np.testing.assert_array_equal(np.sort(np.concatenate(parts)), np.arange(n))
    for _ in range(3):
        x = c[rng.integers(n)] + rng.normal(size=3) * 0.1
        radius = float(rng.choice([0.0, 0.05, 1.0]))
        got = query_point(t, x, radius)
        np.testing.assert_array_equal(got, brute_leaf_scan(t, x, radius))
        assert np.isin(brute_sphere_scan(c, r, margin, x, radius), got).all()


# ---------------------------------------------------------------- large builds (opt-in)
# Build times are measured by bench/build.py (tree_ms against the sphere count), not here.

@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("VOLRENDER_SLOW"), reason="set VOLRENDER_SLOW=1")
@pytest.mark.parametrize("n", [10 ** 5, 10 ** 6])
def test_large_builds_keep_the_invariants(n):
    pc = blob(n, seed=0)
    for axis in ("longest", "cycle"):
        t = build(pc.centers, pc.radii, leaf_size=8, margin=0.01, axis=axis)
        check_invariants(t, pc.centers, pc.radii)


def _sorting_reference(centers, depth, axis):
    """The first build: one argsort per level of (node, rank along the node's axis)."""
    n = len(centers)
    start = np.zeros(2 << depth, np.int64)
    count = np.zeros(2 << depth, np.int64)
    start[1], count[1] = 0, n
    rank = np.empty((3, n), np.int64)
    for a in range(3):
        rank[a, np.argsort(centers[:, a], kind="stable")] = np.arange(n)
    order, pts = np.arange(n), centers.copy()
    for d in range(depth):
        first = 1 << d
        s, c = start[first:2 * first], count[first:2 * first]
        node = np.repeat(np.arange(first), c)
        if axis == "cycle":
            ax = np.full(first, d % 3)
        else:
            ax = np.zeros(first, np.int64)
            full = c > 0
            idx = s[full]
            ext = np.maximum.reduceat(pts, idx, axis=0) - np.minimum.reduceat(pts, idx, axis=0)
            ax[full] = np.argmax(ext, axis=1)
        key = rank[ax[node], np.arange(n)]
        perm = np.argsort(node * n + key)
        order, pts, rank = order[perm], pts[perm], rank[:, perm]
        left = (c + 1) // 2
        kids = np.arange(2 * first, 4 * first)
        start[kids[0::2]], count[kids[0::2]] = s, left
        start[kids[1::2]], count[kids[1::2]] = s + left, c - left
    return order, start, count


@pytest.mark.parametrize("axis", ["longest", "cycle"])
@pytest.mark.parametrize("n, leaf, dup", [(1, 1, 0), (7, 1, 0), (1000, 8, 0), (3001, 16, 0),
                                          (2000, 4, 3), (513, 2, 40)])
def test_partition_equals_the_sorting_build(n, leaf, dup, axis):
    rng = np.random.default_rng(n + leaf + dup)
    c = rng.standard_normal((n, 3)) * [3.0, 1.0, 0.2]
    if dup:                                   # coincident points and shared coordinates
        c[rng.integers(0, n, n // 2)] = c[rng.integers(0, dup, n // 2)]
        c[:, 1] = np.round(c[:, 1], 1)
    depth = tree_depth(n, leaf)
    t = build(c, 0.1, leaf, axis=axis)
    order, start, count = _sorting_reference(c, depth, axis)
    assert np.array_equal(t.order, order)
    assert np.array_equal(t.start, start) and np.array_equal(t.count, count)


def test_in_frame_gives_the_render_frames_float32_boxes():
    """Tree.in_frame: the same partition with float32 boxes of the render-frame spheres,
    no margin, the frame's world origin kept; the boxes hold their float32 spheres."""
    rng = np.random.default_rng(7)
    c = 1e3 + rng.standard_normal((500, 3))
    r = rng.uniform(0.01, 0.1, 500)
    origin = 0.5 * (c.min(0) + c.max(0))
    t = build(c, r, 8, margin=0.3, keys=(c - origin).astype(np.float32))
    assert t.lo.dtype == np.float64 and (t.origin == 0).all() and t.margin == 0.3
    sp = np.zeros((500, 4), np.float32)
    sp[:, :3], sp[:, 3] = c - origin, r
    sp = sp[t.order]
    f = t.in_frame(sp, origin)
    assert f.lo.dtype == np.float32 and f.margin == 0.0 and (f.origin == origin).all()
    for name in ("order", "start", "count"):
        np.testing.assert_array_equal(getattr(f, name), getattr(t, name))
    leaf_of = np.repeat(np.arange(f.first_leaf, 2 * f.first_leaf), f.count[f.first_leaf:])
    for d in range(f.depth + 1):
        node = leaf_of >> (f.depth - d)
        assert (f.lo[node] <= sp[:, :3] - sp[:, 3:]).all()
        assert (f.hi[node] >= sp[:, :3] + sp[:, 3:]).all()
    # the world boxes, moved into the frame, are the float32 ones up to float32 rounding
    # plus the margin
    np.testing.assert_allclose(f.lo[1], t.lo[1] - origin + 0.3, atol=1e-4)
