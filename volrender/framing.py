"""The default camera's fit: where the content's projected bounds cover a fraction of the
frame (docs/camera.md, "The default framing").

The content is a set of points with a radius each (sphere centres and radii; a volume's
occupied voxels as box corners, radius 0). For a fixed view direction the camera moves
sideways until the points' projected bounding rectangle is centred, and along the view
direction until its larger side (in pixels) covers `fill` of the frame's smaller side:

    X_i = (x_i - a ± r_i) / (z_i + D),   Y_i likewise,

x, y, z the points in the camera's basis about a reference centre, (a, b) the sideways
shift and D the distance. Exact perspective; a sphere's silhouette is taken as r / depth
wide (its tangent cone is wider by a factor 1 / cos, under 1% within 8 degrees of the axis).
"""
from __future__ import annotations

import math

import numpy as np

def box(points, radii=0.0):
    """(lo, hi) float64 of points (N, 3) +- radii (one, or (N,)), a column at a time: numpy
    reduces an (N, 3) array along its first axis ~20x slower than its columns."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    r = np.asarray(radii, np.float64)
    lo, hi = np.empty(3), np.empty(3)
    for i in range(3):
        col = p[:, i]
        lo[i], hi[i] = (col - r).min(), (col + r).max()
    return lo, hi


def column_extremes(occ):
    """The cells of a boolean grid (..., nx, ny, nz) that are the first or last occupied
    one along a line of cells parallel to x, y or z (leading axes: a batch of grids): every
    other occupied cell lies between two of them, so their boxes' convex hull is the
    grid's."""
    keep = np.zeros_like(occ)
    for axis in (-3, -2, -1):
        o = np.moveaxis(occ, axis, -1)
        k = np.moveaxis(keep, axis, -1)           # a view: writes land in keep
        n = o.shape[-1]
        has = o.any(axis=-1)
        first = o.argmax(axis=-1)
        last = n - 1 - o[..., ::-1].argmax(axis=-1)
        where = np.nonzero(has)
        k[where + (first[where],)] = True
        k[where + (last[where],)] = True
    return keep


def box_corners(lo, hi):
    """The 8 corners of the box lo..hi (the content of a box known only by its bounds)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                     for z in (lo[2], hi[2])])


SAMPLE = 1 << 14             # fit: points in the strided sample solved on first


def fit(points, radii, basis, centre, fov, width, height, fill, centred=True, distance=None):
    """(target, distance) of the camera looking along basis[0] (forward, right, up: unit
    vectors) at the content `points` (N, 3) with `radii`. The target lies on the plane
    through `centre` facing the camera; with `centred` it moves sideways so that the
    projected bounds are centred in the frame, else it stays at `centre` and the bounds'
    farther side from it counts twice. The distance is `distance`, else where the bounds'
    larger side covers `fill` of the frame's smaller side at vertical field of view `fov`.

    Solved on a few points (the extremes found so far), then checked against all of them:
    a point outside the few's bounds joins them and the fit is solved again; for many
    points, first so against a strided sample of SAMPLE of them."""
    f, r_, u = (np.asarray(v, np.float64) for v in basis)
    p = np.asarray(points, np.float64) - np.asarray(centre, np.float64)
    rad = np.array(np.broadcast_to(np.asarray(radii, np.float64), (len(p),)))
    floor = 1e-12 * max(1.0, float(np.abs(centre).max()))
    if float(np.abs(p).max() + rad.max()) < floor:     # one point: a tiny sphere
        rad = rad + floor
    x, y, z = p @ r_, p @ u, p @ f
    tan_h = math.tan(math.radians(fov) / 2.0)
    want = fill * min(width, height) * 2.0 * tan_h / height   # tan units at unit depth
    near = float(np.max(rad - z))            # D must exceed it: every point in front
    # a strided sample first (cheap passes), then all the points: the fit ends when a
    # pass over every point finds no extreme outside the few it was solved on
    stride = max(1, len(p) // SAMPLE)
    sets = [np.arange(0, len(p), stride), None] if stride > 1 else [None]
    pick = set()
    for sub in sets:
        xs, ys, zs, rs = (x, y, z, rad) if sub is None else (x[sub], y[sub], z[sub], rad[sub])
        if not pick:
            pick = {int(i) for a in (xs - rs, ys - rs, -zs, -xs - rs, -ys - rs, zs)
                    for i in (a.argmin(),)}
            pick = pick if sub is None else {int(sub[i]) for i in pick}
        for _ in range(100):
            idx = np.fromiter(sorted(pick), np.int64)
            d, a, b = _solve(x[idx], y[idx], z[idx], rad[idx], want, near, centred, distance)
            inv = 1.0 / (zs + d)
            ends = (((xs - a - rs) * inv).argmin(), ((xs - a + rs) * inv).argmax(),
                    ((ys - b - rs) * inv).argmin(), ((ys - b + rs) * inv).argmax())
            ends = [int(i) if sub is None else int(sub[i]) for i in ends]
            if all(i in pick for i in ends):
                break
            pick.update(ends)
    target = np.asarray(centre, np.float64) + a * r_ + b * u
    return target, float(d)


def _solve(x, y, z, rad, want, near, centred, distance):
    """fit() on a few points: (distance, a, b)."""
    scale = max(float(np.abs(np.stack([x, y, z])).max() + rad.max()), 1e-300)

    def centre_at(D):
        a = b = 0.0
        if not centred:
            return a, b
        depth = z + D
        for _ in range(100):         # Newton on the piecewise-linear offset: a few steps
            lo_x, hi_x = (x - a - rad) / depth, (x - a + rad) / depth
            lo_y, hi_y = (y - b - rad) / depth, (y - b + rad) / depth
            i, j, k, m = lo_x.argmin(), hi_x.argmax(), lo_y.argmin(), hi_y.argmax()
            da = (lo_x[i] + hi_x[j]) / (1.0 / depth[i] + 1.0 / depth[j])
            db = (lo_y[k] + hi_y[m]) / (1.0 / depth[k] + 1.0 / depth[m])
            a, b = a + da, b + db
            if abs(da) <= 1e-13 * scale and abs(db) <= 1e-13 * scale:
                break
        return a, b

    def size(D):
        a, b = centre_at(D)
        depth = z + D
        x0, x1 = ((x - a - rad) / depth).min(), ((x - a + rad) / depth).max()
        y0, y1 = ((y - b - rad) / depth).min(), ((y - b + rad) / depth).max()
        if centred:
            return max(x1 - x0, y1 - y0)
        return 2.0 * max(-x0, x1, -y0, y1)

    if distance is None:
        lo = near + 1e-9 * scale if near > 0 else 0.0
        hi = max(near, 0.0) + 2.0 * scale / max(want, 1e-12) + scale
        while size(hi) > want:
            hi = 2.0 * hi + scale
        for _ in range(200):            # bisection: the size shrinks as D grows
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if size(mid) > want else (lo, mid)
            if hi - lo <= 1e-12 * hi:
                break
        distance = hi
    return (distance, *centre_at(distance))


GROWTH_STEPS = 24          # bisection steps: the growth to 2^-24 of its bound, from above
# where blend_growth looks: the axes and the cube's diagonals
GROWTH_DIRECTIONS = tuple([np.eye(3)[i] * s for i in range(3) for s in (1.0, -1.0)]
                          + [np.array([x, y, z]) / math.sqrt(3.0) for x in (1, -1)
                             for y in (1, -1) for z in (1, -1)])


def blend_growth(centres, radii, k, directions=None) -> float:
    """How far the smooth union of the spheres (blend width k: F = m - (k/2) ln S, see
    reference.smooth_union) reaches beyond them where the content is outermost: along each
    of 14 directions (the axes and the cube's diagonals), from the sphere that reaches
    farthest that way, the distance out to F = 0 (bisection on the exact field of the
    spheres within reach); the largest. At most (k/2) ln n for n spheres meeting there."""
    c = np.asarray(centres, np.float64)
    r = np.broadcast_to(np.asarray(radii, np.float64), (len(c),))
    if k <= 0 or len(c) < 2:
        return 0.0
    dirs = np.array(directions if directions is not None else GROWTH_DIRECTIONS)
    reach = float(r.max()) + k + 0.5 * k * math.log(len(c))
    arg, slabs = _slabs(c, r, dirs, reach)
    grow = 0.0
    for n, d in enumerate(dirs):
        i = int(arg[n])
        start = c[i] + r[i] * d
        slab = slabs[n]
        near = slab[np.linalg.norm(c[slab] - start, axis=1) - r[slab] < reach]
        cn, rn = c[near], r[near]
        top = 0.5 * k * math.log(max(len(cn), 2))

        def field(t):
            dist = np.linalg.norm(cn - (start + t * d), axis=1) - rn
            m = dist.min()
            h = np.maximum(0.0, 1.0 - (dist - m) / k)
            return m - 0.5 * k * math.log(float((h * h).sum()))
        lo, hi = 0.0, top
        if field(hi) < 0:
            grow = max(grow, hi)
            continue
        for _ in range(GROWTH_STEPS):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if field(mid) < 0 else (lo, mid)
        grow = max(grow, hi)
    return grow


def _slabs(c, r, dirs, reach):
    """For each direction d: the sphere reaching farthest along it (the first of equals),
    and every sphere whose c.d + r is within `reach` of that one's, in index order; the
    same as float64 passes over all, found by one float32 pass over the cloud in chunks
    (a candidate where its float32 value is within reach plus twice a bound of float32's
    rounding of the running largest one) and float64 on the candidates."""
    err = 1e-6 * (3.0 * float(np.abs(c).max()) + float(r.max()))   # > 4x float32's error
    d32 = dirs.astype(np.float32)
    best = np.full((len(dirs), 1), -np.inf, np.float32)
    found = [[] for _ in dirs]
    step = 1 << 18
    for s0 in range(0, len(c), step):
        out = d32 @ c[s0:s0 + step].astype(np.float32).T      # (directions, points)
        out += r[s0:s0 + step].astype(np.float32)
        best = np.maximum(best, out.max(axis=1, keepdims=True))
        for n, row in enumerate(out >= best - np.float32(reach + 2.0 * err)):
            found[n].append(np.nonzero(row)[0] + s0)
    arg, slabs = np.zeros(len(dirs), np.int64), []
    for n, d in enumerate(dirs):
        idx = np.concatenate(found[n])
        exact = c[idx] @ d + r[idx]
        j = int(exact.argmax())
        arg[n] = idx[j]
        slabs.append(idx[exact >= exact[j] - reach])
    return arg, slabs
