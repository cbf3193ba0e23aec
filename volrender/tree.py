"""Balanced median partition tree over spheres, in heap layout.

Node 1 is the root, the children of node i are 2i and 2i+1, index 0 is unused.
All leaves sit at depth D (the smallest D with ceil(N / 2^D) <= leaf_size), at
indices 2^D .. 2^(D+1)-1.  Each node covers the contiguous range
``order[start:start+count]`` of sphere indices; a split sends ceil(count/2)
spheres (the lower half along the split axis) left, so a leaf holds at most
ceil(N / 2^D) spheres and only the rightmost leaves of tiny inputs can be empty.

Node bounds are the AABB of (center +- radius) of the node's spheres, inflated
by ``margin`` on every side (the blend's support width, so that every sphere that
can influence a point is found; the renderer passes 0).  Empty nodes have lo = +inf,
hi = -inf.  Both builders (``build`` here, tree_device.build on the device) return a
``Tree``; its boxes are float64 world boxes (``build``) or the float32 boxes of the
render frame, whose world origin the record keeps (tree_device.build, Tree.in_frame).

The build is vectorised level by level, with no Python work per node: the points are
sorted once along each axis, and each level splits every node's three sorted lists
stably into its children's (a cumulative sum and a scatter per list), so no level sorts.
Within a leaf, points stay in the order of its parent's split axis.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .errors import UserError

__all__ = ["Tree", "build", "tree_depth", "check_invariants", "query_point"]

AXES = ("longest", "cycle")


@dataclass(frozen=True)
class Tree:
    lo: np.ndarray        # float64 (2^(D+1), 3) node bounds, min corner
    hi: np.ndarray        # float64 (2^(D+1), 3) node bounds, max corner
    start: np.ndarray     # int64 (2^(D+1),) first position in ``order``
    count: np.ndarray     # int64 (2^(D+1),) spheres below the node
    depth: int            # D: the leaves are at depth D
    leaf_size: int
    margin: float
    n_points: int
    order: np.ndarray     # int64 (N,) sphere indices, grouped leaf by leaf
    # the frame of lo/hi: the world position of its origin (zeros: world coordinates)
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def n_nodes(self) -> int:
        """Length of the node arrays, 2^(D+1) (slot 0 unused)."""
        return 2 << self.depth

    @property
    def first_leaf(self) -> int:
        """Index of the leftmost leaf, 2^D."""
        return 1 << self.depth

    def in_frame(self, spheres, origin) -> "Tree":
        """This tree with the float32 boxes of `spheres` (float32 (N, 4): centre, radius;
        tree order; in the frame whose world origin is `origin`) and no margin: the boxes
        the device build gives, bit for bit (float32_boxes)."""
        lo, hi = float32_boxes(spheres, self.start, self.count, self.depth)
        return dataclasses.replace(self, lo=lo, hi=hi, margin=0.0,
                                   origin=np.asarray(origin, np.float64))

    def spheres(self, node: int) -> np.ndarray:
        """Sphere indices under ``node``."""
        s = int(self.start[node])
        return self.order[s:s + int(self.count[node])]


def tree_depth(n: int, leaf_size: int) -> int:
    """Smallest D with ceil(n / 2^D) <= leaf_size."""
    d = 0
    while -(-n // (1 << d)) > leaf_size:
        d += 1
    return d


def build(centers, radii, leaf_size: int = 8, margin: float = 0.0,
          axis: str = "longest", keys=None) -> Tree:
    """Build the tree over spheres ``centers`` (N,3) with ``radii`` (N,) or a scalar.

    axis: 'longest' splits each node across the longest extent of its centres;
    'cycle' splits at depth d across axis d % 3 (x, y, z, x, ...).
    keys: (N, 3) coordinates the splits compare instead of the centres (the renderer
    passes its float32 render-frame centres, so the device build, tree_device.py, which
    sorts those, makes the same tree); ties keep the points' order (stable sorts).
    """
    centers = np.asarray(centers, dtype=np.float64)
    if centers.ndim != 2 or centers.shape[1] != 3:
        raise ValueError(f"centers must be (N, 3), got {centers.shape}")
    n = len(centers)
    if radii is None:
        raise ValueError("radii must be an array (N,) or a scalar, not None")
    radii = np.broadcast_to(np.asarray(radii, dtype=np.float64), (n,))
    if n == 0:
        raise UserError("cannot build a tree over zero points", fix="give at least one point")
    if isinstance(leaf_size, bool) or not isinstance(leaf_size, (int, np.integer)) \
            or leaf_size < 1:
        raise UserError(f"leaf_size must be an integer >= 1, got {leaf_size!r}",
                        fix="use e.g. leaf_size=8")
    margin = float(margin)
    if not np.isfinite(margin) or margin < 0:
        raise UserError(f"margin must be finite and >= 0, got {margin}",
                        fix="pass the blend's support width (>= 0)")
    if axis not in AXES:
        raise UserError(f"unknown split axis rule '{axis}'", fix=f"use one of: {', '.join(AXES)}")
    if not (np.isfinite(centers).all() and np.isfinite(radii).all()) or (radii < 0).any():
        raise UserError("sphere centres/radii must be finite and radii >= 0",
                        fix="remove or repair NaN/Inf points and negative radii")

    depth = tree_depth(n, int(leaf_size))
    order, start, count = _partition(centers if keys is None else np.asarray(keys), depth, axis)
    pts = centers[order]
    lo, hi = _bounds(pts, radii[order], start, count, depth, margin)
    return Tree(lo=lo, hi=hi, start=start, count=count, depth=depth,
                leaf_size=int(leaf_size), margin=margin, n_points=n, order=order)


def _partition(centers, depth, axis):
    """(order, start, count) of the median splits down to depth. Each level takes per
    node the axis of the longest extent of its centres ('cycle': d % 3), sends the first
    ceil(c/2) points along it left, and splits the three sorted lists stably into the
    children's (ties along an axis keep the order of the first argsort, so coincident
    points still split exactly in half)."""
    n = len(centers)
    start, count = node_ranges(n, depth)
    it = np.int32 if n < 2 ** 31 else np.int64
    by_axis = [np.argsort(centers[:, a], kind="stable").astype(it) for a in range(3)]
    coords = np.ascontiguousarray(centers.T)
    pos = np.arange(n, dtype=it)
    order = pos.astype(np.int64)
    is_left = np.empty(n, dtype=bool)
    for d in range(depth):
        first = 1 << d
        s, c = start[first:2 * first], count[first:2 * first]
        if axis == "cycle":
            ax = np.full(first, d % 3)
        else:
            ext = np.zeros((first, 3))
            full = np.nonzero(c > 0)[0]
            lo_i, hi_i = s[full], s[full] + c[full] - 1
            for a in range(3):
                ext[full, a] = coords[a][by_axis[a][hi_i]] - coords[a][by_axis[a][lo_i]]
            ax = np.argmax(ext, axis=1)
        node = np.repeat(np.arange(first, dtype=it), c)     # level-local node per position
        s_node = s.astype(it)[node]
        rel = pos - s_node
        left = (c + 1) // 2
        left_node = left.astype(it)[node]
        ax_node = ax[node]
        split = np.where(ax_node == 0, by_axis[0], np.where(ax_node == 1, by_axis[1], by_axis[2]))
        if d == depth - 1:
            order = split.astype(np.int64)
            break
        is_left[split] = rel < left_node
        for a in range(3):
            f = is_left[by_axis[a]]
            before = np.cumsum(f, dtype=it)
            lefts_before_node = np.concatenate([np.zeros(1, it), before])[s].astype(it)[node]
            lb = before - f - lefts_before_node              # lefts before, within the node
            moved = np.empty(n, dtype=it)
            moved[s_node + np.where(f, lb, left_node + rel - lb)] = by_axis[a]
            by_axis[a] = moved
    return order, start, count


def node_ranges(n: int, depth: int):
    """(start, count) int64 of every heap node: the ranges of positions the median splits
    give, which depend on n and the depth only (a node of c points sends ceil(c/2) left)."""
    size = 2 << depth
    start = np.zeros(size, dtype=np.int64)
    count = np.zeros(size, dtype=np.int64)
    start[1], count[1] = 0, n
    for d in range(depth):
        first = 1 << d
        s, c = start[first:2 * first], count[first:2 * first]
        left = (c + 1) // 2
        start[2 * first:4 * first:2], count[2 * first:4 * first:2] = s, left
        start[2 * first + 1:4 * first:2], count[2 * first + 1:4 * first:2] = s + left, c - left
    return start, count


def float32_boxes(spheres, start, count, depth):
    """(lo, hi) float32 (2^(D+1), 3) node boxes of float32 spheres (N, 4: centre, radius;
    tree order) computed in float32 (centre -+ radius, then min and max): the boxes the
    device build (tree_device.py) computes, bit for bit. Empty nodes: +inf, -inf."""
    size = 2 << depth
    lo = np.full((size, 3), np.inf, np.float32)
    hi = np.full((size, 3), -np.inf, np.float32)
    first = 1 << depth
    leaves = np.arange(first, 2 * first)
    full = leaves[count[leaves] > 0]
    sp = np.asarray(spheres, np.float32)
    if len(full):
        idx = start[full]
        lo[full] = np.minimum.reduceat(sp[:, :3] - sp[:, 3:], idx, axis=0)
        hi[full] = np.maximum.reduceat(sp[:, :3] + sp[:, 3:], idx, axis=0)
    for d in range(depth - 1, -1, -1):
        p = np.arange(1 << d, 2 << d)
        lo[p] = np.minimum(lo[2 * p], lo[2 * p + 1])
        hi[p] = np.maximum(hi[2 * p], hi[2 * p + 1])
    return lo, hi


def _bounds(pts, rad, start, count, depth, margin):
    """Leaf AABBs of (center +- radius) +- margin, then parents as unions."""
    size = 2 << depth
    lo = np.full((size, 3), np.inf)
    hi = np.full((size, 3), -np.inf)
    first = 1 << depth
    leaves = np.arange(first, 2 * first)
    full = leaves[count[leaves] > 0]
    r = rad[:, None]
    idx = start[full]
    lo[full] = np.minimum.reduceat(pts - r, idx, axis=0) - margin
    hi[full] = np.maximum.reduceat(pts + r, idx, axis=0) + margin
    for d in range(depth - 1, -1, -1):           # parents are the union of children
        p = np.arange(1 << d, 2 << d)
        lo[p] = np.minimum(lo[2 * p], lo[2 * p + 1])
        hi[p] = np.maximum(hi[2 * p], hi[2 * p + 1])
    return lo, hi


def check_invariants(tree: Tree, centers, radii) -> None:
    """Raise AssertionError (with a message) if ``tree`` is not valid for the spheres."""
    centers = np.asarray(centers, dtype=np.float64)
    n = len(centers)
    radii = np.broadcast_to(np.asarray(radii, dtype=np.float64), (n,))
    D, size, first = tree.depth, tree.n_nodes, tree.first_leaf
    assert tree.n_points == n, f"n_points {tree.n_points} != {n} spheres"
    assert size == 2 ** (D + 1) and first == 2 ** D, "heap sizes inconsistent with depth"
    for name in ("lo", "hi"):
        assert getattr(tree, name).shape == (size, 3), f"{name} shape != ({size}, 3)"
    for name in ("start", "count"):
        assert getattr(tree, name).shape == (size,), f"{name} shape != ({size},)"
    assert D == tree_depth(n, tree.leaf_size), \
        f"depth {D} is not the smallest with ceil(N/2^D) <= leaf_size"
    assert tree.start[1] == 0 and tree.count[1] == n, "root does not cover all spheres"
    assert tree.count[0] == 0, "node 0 must be unused"

    order = np.asarray(tree.order)
    assert order.shape == (n,), "order must hold one entry per sphere"
    seen = np.bincount(order, minlength=n) if n else np.zeros(0, int)
    assert len(seen) == n and (seen == 1).all(), "order is not a permutation: a sphere " \
        "is in no leaf or in several"

    parents = np.arange(1, first)
    l, r = 2 * parents, 2 * parents + 1
    assert (tree.start[l] == tree.start[parents]).all() and \
        (tree.start[r] == tree.start[l] + tree.count[l]).all() and \
        (tree.count[l] + tree.count[r] == tree.count[parents]).all(), \
        "children's [start, count) do not partition the parent's"
    leaves = np.arange(first, 2 * first)
    lc = tree.count[leaves]
    assert (lc >= 0).all() and (lc <= tree.leaf_size).all(), \
        f"a leaf holds more than leaf_size={tree.leaf_size} spheres (max {lc.max()})"
    assert (tree.start[leaves] == np.concatenate([[0], np.cumsum(lc)[:-1]])).all(), \
        "leaf ranges are not contiguous"

    empty = tree.count == 0
    assert np.isposinf(tree.lo[empty]).all() and np.isneginf(tree.hi[empty]).all(), \
        "empty nodes must have lo=+inf, hi=-inf"
    full = parents[~empty[parents]]
    for kid in (2 * full, 2 * full + 1):
        ok = ~empty[kid]
        k, p = kid[ok], kid[ok] // 2
        assert (tree.lo[k] >= tree.lo[p]).all() and (tree.hi[k] <= tree.hi[p]).all(), \
            "child bounds are not within the parent bounds"

    # every node's bounds hold each of its spheres inflated by margin
    leaf_of = np.repeat(leaves, lc)                 # leaf of each position in order
    c, rr = centers[order], radii[order][:, None]
    smin, smax = c - rr - tree.margin, c + rr + tree.margin
    tol = 1e-12 * (np.abs(c) + rr + tree.margin + 1.0)
    for d in range(D + 1):
        node = leaf_of >> (D - d)
        assert (tree.lo[node] <= smin + tol).all() and (tree.hi[node] >= smax - tol).all(), \
            f"a node at depth {d} does not contain all its spheres (+margin)"


def query_point(tree: Tree, x, radius: float) -> np.ndarray:
    """Sorted indices of the spheres in leaves whose bounds lie within ``radius`` of x.

    A numpy reference traversal (level by level, pruning nodes whose box is farther
    than ``radius``); the kernels do the same walk per ray.
    """
    x = np.asarray(x, dtype=np.float64).reshape(3)
    nodes = np.array([1])
    for d in range(tree.depth + 1):
        gap = np.maximum(np.maximum(tree.lo[nodes] - x, x - tree.hi[nodes]), 0.0)
        nodes = nodes[np.einsum("ij,ij->i", gap, gap) <= radius * radius]
        if d < tree.depth:
            nodes = np.stack([2 * nodes, 2 * nodes + 1], axis=1).ravel()
    if nodes.size == 0:
        return np.zeros(0, dtype=np.int64)
    parts = [tree.order[tree.start[k]:tree.start[k] + tree.count[k]] for k in nodes]
    return np.sort(np.concatenate(parts))
