"""pyvista views of the sphere tree, the glass support cells and the volume bricks.

Build blocks for a notebook::

    from volrender import generators, inspect, tree
    cloud = generators.generate("blob", 2000, seed=0)
    t = tree.build(cloud.centers, cloud.radii)
    boxes = inspect.tree_boxes(t)              # MultiBlock, one block per depth
    inspect.show_tree(t, cloud.centers, screenshot="tree.png")

Every box is a wireframe of 8 points and 12 line cells, stored box after box,
so box ``k`` of a mesh owns points ``8k .. 8k+7`` and cells ``12k .. 12k+11``
(see :func:`n_boxes`).  Cell arrays name what each box belongs to.

Off-screen rendering needs no display: the VTK wheels fall back to EGL (Mesa's
``libEGL_mesa`` renders on the CPU with llvmpipe when there is no GPU).  VTK first
tries X11 and logs one "bad X server connection" warning, which is harmless.

Long file: one idea, the pyvista views (tree, cells, bricks, clouds), each a short
function over the same box-wireframe builder, plus their atomic .vtm writing and the
dispatch by input kind that `volrender tree` calls.
"""
from __future__ import annotations

import dataclasses
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from . import atomic
from .cells import B, B3
from .errors import UserError
from .layout import BRICK
from .scene import load_scene
from .spheres import default_radius, pack_scene, sphere_radii
from .tree import build

__all__ = ["tree_boxes", "points_mesh", "brick_boxes", "tree_stats", "n_boxes",
           "leaf_of_points", "show_tree", "show_bricks", "inspect_input", "cell_boxes",
           "show_cells", "MAX_CELL_BOXES",
           "default_radius", "show_cloud", "SCREENSHOT_SUFFIXES", "EXPORT_SUFFIXES"]

SCREENSHOT_SUFFIXES = (".png",)
MAX_CELL_BOXES = 100_000      # more listed cells are drawn as points at their centres
EXPORT_SUFFIXES = (".vtm", ".vtk", ".vtp")

# The 12 edges of a box whose corners are numbered by bits (x, y, z) = (c&1, c&2, c&4).
_EDGES = np.array([(0, 1), (2, 3), (4, 5), (6, 7),      # along x
                   (0, 2), (1, 3), (4, 6), (5, 7),      # along y
                   (0, 4), (1, 5), (2, 6), (3, 7)])     # along z
_CORNER_BITS = np.array([[(c >> a) & 1 for a in range(3)] for c in range(8)], dtype=float)


def _pv():
    """pyvista, with VTK's logger quiet: errors only on stderr (its off-screen warnings,
    such as "bad X server connection", said nothing a user can act on), and without
    colour codes when stderr is no terminal (VTK's loguru decides its colours from $TERM
    when it loads)."""
    if "vtkmodules.vtkCommonCore" not in sys.modules and not _isatty(sys.stderr):
        term = os.environ.get("TERM")
        os.environ["TERM"] = "dumb"
    else:
        term = False
    try:
        import pyvista
        from vtkmodules.vtkCommonCore import vtkLogger
    except ImportError as exc:
        raise UserError(f"pyvista is not installed ({exc})",
                        fix="bash run.sh setup --inspect (or pip install 'volrender[inspect]')") from None
    finally:
        if term is None:
            os.environ.pop("TERM", None)
        elif term:
            os.environ["TERM"] = term
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)
    return pyvista


def _isatty(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError, OSError):
        return False


# --------------------------------------------------------------------------- meshes

def _wireframes(corners, cell_arrays):
    """PolyData of box wireframes: ``corners`` (M, 8, 3) in corner-bit order,
    ``cell_arrays`` name -> (M,) values, repeated over each box's 12 edges."""
    pv = _pv()
    m = len(corners)
    ends = (np.arange(m)[:, None, None] * 8 + _EDGES[None]).reshape(-1, 2)
    lines = np.hstack([np.full((len(ends), 1), 2), ends]).astype(np.int64).ravel()
    mesh = pv.PolyData(np.asarray(corners, np.float64).reshape(-1, 3), lines=lines)
    for name, values in cell_arrays.items():
        mesh.cell_data[name] = np.repeat(np.asarray(values), 12)
    return mesh


def _aabb_corners(lo, hi):
    """(M, 8, 3) corners of axis-aligned boxes lo..hi."""
    return lo[:, None, :] + _CORNER_BITS[None] * (hi - lo)[:, None, :]


def n_boxes(mesh) -> int:
    """Number of boxes in a wireframe mesh made by this module (8 points each)."""
    return mesh.n_points // 8


def _levels(tree, depth, leaves, max_depth):
    """The depth levels selected by the tree_boxes / show_tree options."""
    D = tree.depth
    if leaves and depth is not None and depth != D:
        raise UserError(f"leaves=True selects depth {D}, but depth={depth} was given",
                        fix="give either depth or leaves")
    if leaves:
        depth = D
    if depth is not None:
        if max_depth is not None:
            raise UserError("give either depth (one level) or max_depth (levels 0..max_depth)",
                            fix="drop one of them")
        if isinstance(depth, bool) or not isinstance(depth, (int, np.integer)) \
                or not 0 <= depth <= D:
            raise UserError(f"depth {depth!r} is out of range for this tree",
                            fix=f"use a depth from 0 to {D} (the leaves are at depth {D})")
        return [int(depth)]
    if max_depth is not None:
        if isinstance(max_depth, bool) or not isinstance(max_depth, (int, np.integer)) \
                or max_depth < 0:
            raise UserError(f"max_depth must be an integer >= 0, got {max_depth!r}",
                            fix=f"use 0 to {D} (larger values show all {D + 1} levels)")
        D = min(D, int(max_depth))
    return list(range(D + 1))


def _level_nodes(tree, d):
    nodes = np.arange(1 << d, 2 << d)
    return nodes[tree.count[nodes] > 0]


def _level_mesh(tree, nodes, d):
    return _wireframes(_aabb_corners(tree.lo[nodes], tree.hi[nodes]),
                       {"depth": np.full(len(nodes), d, np.int32),
                        "node": nodes.astype(np.int64)})


def tree_boxes(tree, depth=None, leaves=False, max_depth=None):
    """Wireframe boxes of the tree's non-empty nodes, one block per depth level.

    Parameters
    ----------
    tree : volrender.tree.Tree
    depth : int, optional
        Only this level (0 = root, ``tree.depth`` = leaves).
    leaves : bool
        Only the leaf level (same as ``depth=tree.depth``).
    max_depth : int, optional
        Levels 0 .. min(max_depth, tree.depth); ignored levels are left out.

    Returns
    -------
    pyvista.MultiBlock
        Blocks named ``"depth d"`` in increasing d.  Each is a PolyData of
        wireframes (8 points, 12 line cells per box) in heap order, with cell
        arrays ``depth`` (int32, the level, for colouring) and ``node`` (heap
        index, so ``tree.lo[node]`` / ``tree.hi[node]`` are the box's corners).

    Raises
    ------
    UserError
        A depth outside 0..tree.depth, or conflicting options.
    """
    pv = _pv()
    blocks = pv.MultiBlock()
    for d in _levels(tree, depth, leaves, max_depth):
        blocks[f"depth {d}"] = _level_mesh(tree, _level_nodes(tree, d), d)
    return blocks


def _merged_tree_boxes(tree, levels):
    nodes = np.concatenate([_level_nodes(tree, d) for d in levels])
    depth = np.floor(np.log2(nodes)).astype(np.int32)
    return _wireframes(_aabb_corners(tree.lo[nodes], tree.hi[nodes]),
                       {"depth": depth, "node": nodes.astype(np.int64)})


def leaf_of_points(tree) -> np.ndarray:
    """int64 (N,): heap index of the leaf holding each sphere (first_leaf .. n_nodes-1)."""
    leaves = np.arange(tree.first_leaf, tree.n_nodes)
    leaf = np.empty(tree.n_points, np.int64)
    leaf[tree.order] = np.repeat(leaves, tree.count[leaves])
    return leaf


def points_mesh(centers, tree=None):
    """Point cloud as PolyData (one vertex per point).

    Parameters
    ----------
    centers : (N, 3) array
    tree : volrender.tree.Tree, optional
        When given, adds the point array ``leaf``: the heap index of the leaf
        holding each point (the same number as the ``node`` array of its leaf box).

    Returns
    -------
    pyvista.PolyData
    """
    pv = _pv()
    centers = np.asarray(centers, np.float64)
    if centers.ndim != 2 or centers.shape[1] != 3:
        raise ValueError(f"centers must be (N, 3), got {centers.shape}")
    mesh = pv.PolyData(centers.copy())
    if tree is not None:
        if tree.n_points != len(centers):
            raise UserError(f"the tree holds {tree.n_points} points, but {len(centers)} "
                            "centres were given", fix="pass the centres the tree was built on")
        mesh.point_data["leaf"] = leaf_of_points(tree)
    return mesh


def brick_boxes(bricks):
    """Wireframe boxes of the occupied bricks, in world space.

    Brick (bx, by, bz) covers local index coordinates [8b, 8b+8]^3; its 8 corners
    are mapped by ``bricks.local_to_world``, so a rotated or sheared grid gives
    rotated or sheared boxes.

    Returns
    -------
    pyvista.PolyData
        One box per slot in slot order (8 points, 12 line cells each), with cell
        arrays ``majorant`` (float32, the slot's maximum density) and ``slot``.
    """
    dims = np.asarray(bricks.dims, np.int64)
    table = np.asarray(bricks.table)
    flat = np.flatnonzero(table >= 0)
    slots = table[flat]
    sort = np.argsort(slots, kind="stable")
    flat, slots = flat[sort], slots[sort]
    b = np.stack([flat // (dims[1] * dims[2]), (flat // dims[2]) % dims[1], flat % dims[2]],
                 axis=1).astype(np.float64)
    local = (b[:, None, :] + _CORNER_BITS[None]) * BRICK              # (M, 8, 3)
    m = np.asarray(bricks.local_to_world, np.float64)
    world = local @ m[:3, :3].T + m[:3, 3]
    return _wireframes(world, {"majorant": np.asarray(bricks.majorant, np.float32)[slots],
                               "slot": slots.astype(np.int64)})


def tree_stats(tree) -> dict:
    """Counts of a tree, for a legend or a report.

    Returns
    -------
    dict
        ``points``, ``leaf_size``, ``depth``, ``nodes`` (all heap nodes,
        2^(depth+1) - 1), ``non_empty_nodes``, ``leaves`` (2^depth),
        ``non_empty_leaves``, and ``points_per_leaf_min`` / ``_mean`` / ``_max``
        over the non-empty leaves.
    """
    leaves = tree.count[tree.first_leaf:tree.n_nodes]
    full = leaves[leaves > 0]
    return {
        "points": int(tree.n_points),
        "leaf_size": int(tree.leaf_size),
        "depth": int(tree.depth),
        "nodes": int(tree.n_nodes - 1),
        "non_empty_nodes": int(np.count_nonzero(tree.count[1:])),
        "leaves": int(len(leaves)),
        "non_empty_leaves": int(len(full)),
        "points_per_leaf_min": int(full.min()),
        "points_per_leaf_mean": float(full.mean()),
        "points_per_leaf_max": int(full.max()),
    }


def _legend(s) -> str:
    return (f"{s['points']} points, leaf size {s['leaf_size']}, depth {s['depth']}\n"
            f"{s['nodes']} nodes ({s['non_empty_nodes']} non-empty), "
            f"{s['leaves']} leaves ({s['non_empty_leaves']} non-empty)\n"
            f"points per leaf: min {s['points_per_leaf_min']}, "
            f"mean {s['points_per_leaf_mean']:.2f}, max {s['points_per_leaf_max']}")


# --------------------------------------------------------------------------- output

def _check_outputs(screenshot, export, show):
    if not (show or screenshot or export):
        raise UserError("nothing to do: no window, screenshot or export requested",
                        fix="pass show=True, screenshot='view.png' or export='boxes.vtm'")
    out = []
    for path, allowed, what in ((screenshot, SCREENSHOT_SUFFIXES, "screenshot"),
                                (export, EXPORT_SUFFIXES, "export")):
        if path is None:
            out.append(None)
            continue
        path = Path(path)
        if path.suffix.lower() not in allowed:
            raise UserError(f"unsupported {what} file type '{path.suffix or '(none)'}'",
                            path=path, fix=f"use one of: {', '.join(allowed)}")
        parent = path.parent
        if not parent.is_dir():
            raise UserError("the folder does not exist", path=path,
                            fix="create it first or choose another path")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise UserError("the folder is not writable", path=path,
                            fix="choose a writable folder")
        out.append(path)
    # (a notebook shows through its own pyvista backend, with or without a display)
    if show and sys.platform.startswith("linux") and "ipykernel" not in sys.modules \
            and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise UserError("show=True needs a display, and none is set (no $DISPLAY)",
                        fix="use screenshot='view.png' or export='boxes.vtm' instead")
    return out


def _atomic(path: Path, write):
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, then rename it
    (volrender.atomic: signals, temporary files and errors handled as for images)."""
    with atomic.replace_by_name(path, "view") as tmp:
        write(tmp)


def _save_vtm(blocks, path: Path):
    """A .vtm is an index file plus a folder of block files named after it: write
    both into a temporary folder, then move the block files, then the index."""
    try:
        tmpdir = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.stem}."))
    except OSError as e:
        raise UserError(f"cannot write ({e.strerror})", path=path,
                        fix="check that the folder exists and is writable") from None
    try:
        blocks.save(tmpdir / path.name)
        parts = tmpdir / path.stem
        if parts.is_dir():
            dest = path.parent / path.stem
            dest.mkdir(exist_ok=True)
            for f in parts.iterdir():
                os.replace(f, dest / f.name)
            parts.rmdir()
        index = (tmpdir / path.name).read_bytes()
        atomic.write_bytes(path, index, "export")
    finally:
        for f in tmpdir.rglob("*"):
            if f.is_file():
                f.unlink()
        for d in sorted(tmpdir.rglob("*"), reverse=True):
            d.rmdir()
        tmpdir.rmdir()


def _export(path: Path, blocks, merged):
    if path.suffix.lower() == ".vtm":
        _save_vtm(blocks, path)
    else:
        _atomic(path, lambda tmp: merged.save(tmp))


def _finish(plotter, screenshot, show):
    try:
        if show:
            plotter.show(auto_close=False)
        if screenshot is not None:
            _atomic(screenshot, lambda tmp: plotter.screenshot(tmp))
    finally:
        plotter.close()


def _plotter(show, window_size):
    pv = _pv()
    return pv.Plotter(off_screen=not show, window_size=list(window_size))


def set_view(plotter, camera=None):
    """The render's camera (a volrender Camera: position, focal point, up, vertical view
    angle), else pyvista's isometric view."""
    if camera is None:
        plotter.view_isometric()
        return
    c = plotter.camera
    c.position, c.focal_point, c.up = (tuple(map(float, v)) for v in
                                       (camera.origin, camera.target, camera.up))
    c.view_angle = float(camera.fov)
    plotter.reset_camera_clipping_range()


def show_tree(tree, centers, *, depth=None, leaves=False, max_depth=None, screenshot=None,
              export=None, show=False, window_size=(1024, 768), point_size=4.0, camera=None):
    """Draw the tree's boxes coloured by depth, and the points coloured by leaf.

    Parameters
    ----------
    tree : volrender.tree.Tree
    centers : (N, 3) array
        The sphere centres the tree was built on.
    depth, leaves, max_depth
        Which levels to draw, as in :func:`tree_boxes` (default: all).
    screenshot : path, optional
        Render off-screen and save a ``.png`` (written atomically).
    export : path, optional
        Save the boxes for ParaView: ``.vtm`` (one block per level, plus a folder
        of block files named after it) or ``.vtk`` / ``.vtp`` (one merged PolyData
        with the ``depth`` and ``node`` cell arrays).
    show : bool
        Open an interactive window (needs a display).
    window_size : (int, int)
    point_size : float
    camera : volrender.camera.Camera, optional
        View through this camera (the render's); default: pyvista's isometric view.

    Returns
    -------
    pyvista.MultiBlock
        The boxes drawn (as :func:`tree_boxes`).

    Raises
    ------
    UserError
        Nothing requested, a bad depth, an unsupported suffix or an unwritable folder.
    """
    screenshot, export = _check_outputs(screenshot, export, show)
    levels = _levels(tree, depth, leaves, max_depth)
    blocks = tree_boxes(tree, depth=depth, leaves=leaves, max_depth=max_depth)
    merged = _merged_tree_boxes(tree, levels)
    if export is not None:
        _export(export, blocks, merged)
    if not (show or screenshot):
        return blocks
    cloud = points_mesh(centers, tree)
    # neighbouring leaves have neighbouring indices: scatter them over 20 colours
    cloud.point_data["leaf colour"] = (cloud.point_data["leaf"] * 7) % 20
    p = _plotter(show, window_size)
    p.add_mesh(merged, scalars="depth", cmap="viridis", clim=[0, max(tree.depth, 1)],
               line_width=1.0, opacity=0.6,
               scalar_bar_args={"title": "depth", "n_labels": 2, "fmt": "%.0f",
                                "vertical": True, "position_x": 0.88, "position_y": 0.1})
    p.add_mesh(cloud, scalars="leaf colour", cmap="tab20", clim=[0, 19],
               point_size=point_size, show_scalar_bar=False)
    p.add_text(_legend(tree_stats(tree)), position="upper_left", font_size=9)
    set_view(p, camera)
    _finish(p, screenshot, show)
    return blocks


def show_bricks(bricks, *, screenshot=None, export=None, show=False,
                window_size=(1024, 768), camera=None):
    """Draw the occupied bricks in world space, coloured by their majorant.

    Parameters
    ----------
    bricks : volrender.bricks.Bricks
    screenshot, export, show, window_size
        As in :func:`show_tree`; a ``.vtm`` export holds one block, ``bricks``.

    Returns
    -------
    pyvista.PolyData
        The boxes drawn (as :func:`brick_boxes`).
    """
    pv = _pv()
    screenshot, export = _check_outputs(screenshot, export, show)
    boxes = brick_boxes(bricks)
    if export is not None:
        _export(export, pv.MultiBlock({"bricks": boxes}), boxes)
    if not (show or screenshot):
        return boxes
    p = _plotter(show, window_size)
    if boxes.n_points:
        p.add_mesh(boxes, scalars="majorant", cmap="inferno", line_width=1.5,
                   scalar_bar_args={"title": "majorant", "vertical": True,
                                    "position_x": 0.88, "position_y": 0.1})
    p.add_text(f"{bricks.grid_name}: {bricks.n_slots} occupied bricks of "
               f"{int(np.prod(bricks.dims))} ({' x '.join(str(int(d)) for d in bricks.dims)})",
               position="upper_left", font_size=9)
    set_view(p, camera)
    _finish(p, screenshot, show)
    return boxes


def _listed_cells(grid):
    """(integer cell coordinates (M, 3), list lengths (M,)) of the cells with a list."""
    blocks = np.nonzero(grid.bricks[:, 0] >= 0)[0]
    brick_of = np.empty(len(blocks), np.int64)
    brick_of[grid.bricks[blocks, 0]] = blocks
    idx = np.nonzero(grid.cells[:, 0] >= 0)[0]
    b = brick_of[idx // B3]
    l = idx % B3
    bd = grid.bdims
    q = np.stack([(b % bd[0]) * B + l % B, ((b // bd[0]) % bd[1]) * B + (l // B) % B,
                  (b // (bd[0] * bd[1])) * B + l // (B * B)], axis=1)
    return q, grid.lengths()[grid.cells[idx, 0]]


def cell_boxes(grid, centre=(0.0, 0.0, 0.0)):
    """Wireframe boxes of the support cells that hold a list (volrender.cells.Cells), in
    world space (render frame + centre), with cell arrays ``spheres`` (list length) and
    ``core`` (spheres that can be the nearest)."""
    q, n = _listed_cells(grid)
    lo, hi = grid.box(q)
    c = np.asarray(centre, np.float64)
    core = grid.lengths(core=True)[grid.cells[grid.cells[:, 0] >= 0, 0]]
    return _wireframes(_aabb_corners(lo + c, hi + c), {"spheres": n, "core": core})


def show_cells(grid, centers, centre=(0.0, 0.0, 0.0), *, screenshot=None, export=None,
               show=False, window_size=(1024, 768), point_size=3.0, camera=None):
    """Draw the support cells that hold a list, coloured by list length, over the points.

    Parameters
    ----------
    grid : volrender.cells.Cells
    centers : (N, 3) array
        The sphere centres (world).
    centre : (3,) array
        The render frame's origin in world space (spheres.PackedSpheres.centre).
    screenshot, export, show, window_size, point_size
        As in :func:`show_tree`; a ``.vtm`` export holds one block, ``cells``. Beyond
        MAX_CELL_BOXES cells the view draws each cell as a point at its centre (the
        export keeps every box).

    Returns
    -------
    pyvista.PolyData
        The boxes (as :func:`cell_boxes`).
    """
    pv = _pv()
    screenshot, export = _check_outputs(screenshot, export, show)
    boxes = cell_boxes(grid, centre)
    if export is not None:
        _export(export, pv.MultiBlock({"cells": boxes}), boxes)
    if not (show or screenshot):
        return boxes
    q, n = _listed_cells(grid)
    st = grid.stats()
    p = _plotter(show, window_size)
    bar = {"title": "spheres on the list", "vertical": True, "position_x": 0.88,
           "position_y": 0.1}
    clim = [0, max(int(n.max()) if len(n) else 1, 1)]
    if len(q) > MAX_CELL_BOXES:
        lo, hi = grid.box(q)
        mids = pv.PolyData(0.5 * (lo + hi) + np.asarray(centre, np.float64))
        mids.point_data["spheres"] = n
        p.add_mesh(mids, scalars="spheres", cmap="plasma", clim=clim, point_size=point_size,
                   scalar_bar_args=bar)
        drawn = "centres"
    else:
        if boxes.n_points:
            p.add_mesh(boxes, scalars="spheres", cmap="plasma", clim=clim, line_width=1.0,
                       opacity=0.7, scalar_bar_args=bar)
        p.add_mesh(pv.PolyData(np.asarray(centers, np.float64)), color="white",
                   point_size=point_size)
        drawn = "boxes"
    p.add_text(f"{st['cells_listed']} cells with lists ({drawn}), edge {st['cell']:.4g}\n"
               f"list {st['list_mean']:.1f} spheres on average (max {st['list_max']}), core "
               f"{st['core_mean']:.1f}\n{st['cells_outside'] + st['cells_inside']} cells and "
               f"{st['bricks_outside'] + st['bricks_inside']} bricks skipped\n"
               f"{st['bytes'] / max(len(centers), 1):.0f} bytes per sphere",
               position="upper_left", font_size=9)
    set_view(p, camera)
    _finish(p, screenshot, show)
    return boxes


# --------------------------------------------------------------------------- files

def _show_cloud(cloud, radii, opts):
    t = build(cloud.centers, radii, leaf_size=opts["leaf_size"], margin=opts["blend"])
    show_tree(t, cloud.centers, **opts["view"], **opts["output"])
    return t


def show_cloud(cloud, *, leaf_size=16, radius=None, blend=0.0, depth=None, leaves=False,
               max_depth=None, screenshot=None, export=None, show=False, window_size=(1024, 768)):
    """Build the tree of a PointCloud (as the renderer does) and show it; see inspect_input."""
    _check_outputs(screenshot, export, show)
    if radius is not None:
        radii = float(radius)
        if not np.isfinite(radii) or radii < 0:
            raise UserError(f"radius must be finite and >= 0, got {radius}",
                            fix="pass e.g. radius=0.05")
    elif cloud.radii is not None:
        radii = cloud.radii
    else:
        radii = default_radius(cloud.centers)
    opts = dict(leaf_size=leaf_size, blend=blend,
                output=dict(screenshot=screenshot, export=export, show=show, window_size=window_size),
                view=dict(depth=depth, leaves=leaves, max_depth=max_depth))
    return _show_cloud(cloud, radii, opts)


def inspect_input(path, *, leaf_size=None, radius=None, blend=0.0, grid=None, depth=None,
                  leaves=False, max_depth=None, screenshot=None, export=None, show=False,
                  window_size=(1024, 768), cells=False, camera=None):
    """View any render input: a volume's bricks, or a point cloud's tree.

    Parameters
    ----------
    path : path or str
        Whatever ``volrender render`` reads: ``.vdb`` / ``.npz`` (a volume:
        :func:`show_bricks`), ``.ply`` / ``.xyz`` / ``.csv`` / ``.txt`` / ``.npy``,
        ``GENERATOR:COUNT`` or a ``.toml`` scene (points: build the tree,
        :func:`show_tree`). It is resolved by :func:`volrender.load_scene`, so the
        radius and leaf size are the renderer's.
    leaf_size : int, optional
        Tree leaf size (default: the renderer's).
    radius : float, optional
        Sphere radius for every point, overriding the file's radii (default: the
        renderer's choice).
    blend : float
        The node boxes are inflated by this margin.
    grid : str, optional
        Grid name in a ``.vdb`` file (default: the density grid).
    depth, leaves, max_depth, screenshot, export, show, window_size
        As in :func:`show_tree` / :func:`show_bricks`.
    cells : bool
        Points: draw the renderer's support cells (:func:`show_cells`, built with the
        renderer's blend and cell size on the default device) instead of the tree.
    camera : dict, optional
        The render's camera options (``fov=``, ``azimuth=``, ``camera="cam.toml"``, ...):
        the view is the camera ``volrender render`` would use at ``window_size``.

    Returns
    -------
    volrender.tree.Tree, volrender.cells.Cells or volrender.bricks.Bricks
        What was shown.
    """
    _check_outputs(screenshot, export, show)      # fail before loading a large file
    scene = load_scene(path, leaf_size=leaf_size, radius=radius, grid=grid,
                       size=tuple(window_size), **(camera or {}))
    output = dict(screenshot=screenshot, export=export, show=show, window_size=window_size,
                  camera=scene.camera)
    if scene.kind == "volume":
        show_bricks(scene.content.bricks, **output)
        return scene.content.bricks
    cloud, settings = scene.content.cloud, scene.content.settings
    if cells:
        packed = pack_scene(cloud, dataclasses.replace(settings, accel="grid"))
        if packed.cells is None:
            raise UserError(packed.note or "no support cells for this cloud",
                            fix="view the tree instead (drop --cells)")
        show_cells(packed.cells, cloud.centers, packed.centre, **output)
        return packed.cells
    opts = dict(leaf_size=settings.leaf_size, blend=blend, output=output,
                view=dict(depth=depth, leaves=leaves, max_depth=max_depth))
    return _show_cloud(cloud, sphere_radii(cloud, settings), opts)
