import os

import numpy as np
import pytest

pv = pytest.importorskip("pyvista")
pv.OFF_SCREEN = True

from volrender import inspect  # noqa: E402
from volrender.errors import UserError  # noqa: E402
from volrender.generators import generate  # noqa: E402
from volrender.tree import build  # noqa: E402
from volrender.bricks import Bricks  # noqa: E402


@pytest.fixture(scope="module")
def cloud():
    return generate("blob", 500, seed=3)


@pytest.fixture(scope="module")
def tree(cloud):
    return build(cloud.centers, cloud.radii, leaf_size=4)


def box_bounds(mesh, k):
    p = mesh.points[8 * k:8 * k + 8]
    return p.min(axis=0), p.max(axis=0)


def test_boxes_at_a_depth_match_the_nodes(tree):
    for d in (0, 3, tree.depth):
        mb = inspect.tree_boxes(tree, depth=d)
        assert mb.keys() == [f"depth {d}"]
        mesh = mb[0]
        nodes = np.arange(1 << d, 2 << d)
        nodes = nodes[tree.count[nodes] > 0]
        assert inspect.n_boxes(mesh) == len(nodes) == 2 ** d    # 500 points: full tree
        assert mesh.n_cells == 12 * len(nodes)
        assert (mesh.cell_data["depth"] == d).all()
        node = mesh.cell_data["node"][::12]
        assert (node == nodes).all()
        for k, n in enumerate(node):
            lo, hi = box_bounds(mesh, k)
            assert np.allclose(lo, tree.lo[n]) and np.allclose(hi, tree.hi[n])


def test_all_levels_and_caps(tree):
    mb = inspect.tree_boxes(tree)
    assert mb.n_blocks == tree.depth + 1
    for d, mesh in enumerate(mb):
        assert mb.get_block_name(d) == f"depth {d}"
        assert (mesh.cell_data["depth"] == d).all()
    assert inspect.tree_boxes(tree, max_depth=2).n_blocks == 3
    assert inspect.tree_boxes(tree, max_depth=99).n_blocks == tree.depth + 1
    leaves = inspect.tree_boxes(tree, leaves=True)
    assert leaves.n_blocks == 1
    node = leaves[0].cell_data["node"][::12]
    assert (node == np.arange(tree.first_leaf, tree.n_nodes)).all()


def test_empty_nodes_are_left_out():
    t = build(np.random.default_rng(0).random((5, 3)), 0.1, leaf_size=1)  # 8 leaves, 5 full
    mesh = inspect.tree_boxes(t, leaves=True)[0]
    assert inspect.n_boxes(mesh) == 5
    assert np.isfinite(mesh.points).all()


def test_points_leaf_ids_follow_the_tree(cloud, tree):
    mesh = inspect.points_mesh(cloud.centers, tree)
    assert mesh.n_points == len(cloud.centers)
    assert np.allclose(mesh.points, cloud.centers)
    leaf = mesh.point_data["leaf"]
    for L in range(tree.first_leaf, tree.n_nodes):
        s, c = tree.start[L], tree.count[L]
        assert (leaf[tree.order[s:s + c]] == L).all()
    assert "leaf" not in inspect.points_mesh(cloud.centers).point_data
    with pytest.raises(UserError, match="centres"):
        inspect.points_mesh(cloud.centers[:10], tree)


def test_tree_stats(tree):
    s = inspect.tree_stats(tree)
    assert s["points"] == 500 and s["depth"] == tree.depth
    assert s["leaves"] == tree.first_leaf and s["nodes"] == tree.n_nodes - 1
    assert s["points_per_leaf_max"] <= 4 and s["points_per_leaf_min"] >= 1
    assert s["points_per_leaf_mean"] == pytest.approx(500 / s["non_empty_leaves"])


def _bricks(index_to_world=None):
    v = np.zeros((20, 17, 9), np.float32)
    v[1:5, 2:4, 1:3] = 2.0          # brick (0,0,0)
    v[12:14, 10:12, 2] = 0.5        # brick (1,1,0)
    v[3, 15, 7] = 1.5               # brick (0,1,0)
    return Bricks.from_dense(v, index_to_world)


@pytest.mark.parametrize("rotated", [False, True])
def test_brick_boxes(rotated):
    m = None
    if rotated:
        a = np.deg2rad(40)
        m = np.eye(4)
        m[:3, :3] = 0.25 * np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0],
                                      [-np.sin(a), 0, np.cos(a)]])
        m[:3, 3] = (5, -2, 1)
    b = _bricks(m)
    mesh = inspect.brick_boxes(b)
    assert inspect.n_boxes(mesh) == b.n_slots and b.n_slots >= 3
    assert np.array_equal(mesh.cell_data["majorant"][::12], b.majorant)
    l2w = b.local_to_world
    flat = np.flatnonzero(b.table >= 0)
    for f in flat:
        slot = b.table[f]
        bx, by, bz = np.unravel_index(f, tuple(b.dims))
        corner0 = l2w @ [8 * bx, 8 * by, 8 * bz, 1.0]
        corner7 = l2w @ [8 * bx + 8, 8 * by + 8, 8 * bz + 8, 1.0]
        pts = mesh.points[8 * slot:8 * slot + 8]
        assert np.allclose(pts[0], corner0[:3]) and np.allclose(pts[7], corner7[:3])
    if rotated:   # a rotated box's edges are not axis-aligned
        edge = mesh.points[8 * 0 + 1] - mesh.points[0]
        assert np.count_nonzero(np.abs(edge) > 1e-9) == 2


def _not_one_colour(path):
    img = np.asarray(pv.read(str(path)).point_data.active_scalars)
    assert img.size > 0
    return len(np.unique(img.reshape(len(img), -1), axis=0)) > 10


def test_screenshot_and_export_tree(tmp_path, cloud, tree):
    png, vtm = tmp_path / "tree.png", tmp_path / "tree.vtm"
    blocks = inspect.show_tree(tree, cloud.centers, screenshot=png, export=vtm,
                               window_size=(320, 240))
    assert png.stat().st_size > 0 and _not_one_colour(png)
    back = pv.read(str(vtm))
    assert back.n_blocks == blocks.n_blocks == tree.depth + 1
    for a, b in zip(blocks, back):
        assert a.n_cells == b.n_cells
        assert np.array_equal(np.asarray(b.cell_data["node"]), a.cell_data["node"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tree", "tree.png", "tree.vtm"]

    vtp = tmp_path / "tree.vtp"
    inspect.show_tree(tree, cloud.centers, export=vtp, max_depth=2)
    merged = pv.read(str(vtp))
    assert merged.n_cells == 12 * 7
    assert sorted(set(merged.cell_data["depth"])) == [0, 1, 2]


def test_screenshot_and_export_bricks(tmp_path):
    b = _bricks()
    png, vtk = tmp_path / "b.png", tmp_path / "b.vtk"
    inspect.show_bricks(b, screenshot=png, export=vtk, window_size=(320, 240))
    assert _not_one_colour(png)
    back = pv.read(str(vtk))
    assert back.n_cells == 12 * b.n_slots
    assert np.allclose(back.cell_data["majorant"][::12], b.majorant)


def test_user_errors(tmp_path, cloud, tree):
    with pytest.raises(UserError, match=f"0 to {tree.depth}"):
        inspect.tree_boxes(tree, depth=tree.depth + 1)
    with pytest.raises(UserError, match=f"0 to {tree.depth}"):
        inspect.tree_boxes(tree, depth=-1)
    with pytest.raises(UserError, match="nothing to do"):
        inspect.show_tree(tree, cloud.centers)
    with pytest.raises(UserError, match=r"\.vtm, \.vtk, \.vtp"):
        inspect.show_tree(tree, cloud.centers, export=tmp_path / "boxes.obj")
    with pytest.raises(UserError, match=r"\.png"):
        inspect.show_bricks(_bricks(), screenshot=tmp_path / "b.jpg")
    with pytest.raises(UserError, match="does not exist"):
        inspect.show_tree(tree, cloud.centers, screenshot=tmp_path / "no" / "t.png")
    with pytest.raises(UserError, match="unsupported input type"):
        inspect.inspect_input(tmp_path / "scene.abc", screenshot=tmp_path / "x.png")
    assert list(tmp_path.iterdir()) == []


def test_unwritable_folder(tmp_path, cloud, tree):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        if os.access(ro, os.W_OK):      # root ignores permissions; /proc refuses files
            target, message = "/proc/volrender-t.vtp", "cannot write"
        else:
            target, message = ro / "t.vtp", "not writable"
        with pytest.raises(UserError, match=message):
            inspect.show_tree(tree, cloud.centers, export=target)
    finally:
        ro.chmod(0o700)


def test_inspect_input_points(tmp_path, cloud):
    path = tmp_path / "pts.npy"
    np.save(path, cloud.centers)                      # no radii in the file
    t = inspect.inspect_input(path, leaf_size=16, export=tmp_path / "t.vtp")
    assert t.leaf_size == 16 and t.n_points == 500
    r = inspect.default_radius(cloud.centers)
    assert 0 < r < 0.2
    # the default radius is what the leaf boxes were inflated by
    leaf = t.first_leaf
    c = cloud.centers[t.spheres(leaf)]
    assert np.allclose(t.lo[leaf], c.min(axis=0) - r)

    t = inspect.inspect_input(path, radius=0.25, blend=0.1, export=tmp_path / "t.vtp")
    c = cloud.centers[t.spheres(leaf)]
    assert np.allclose(t.hi[leaf], c.max(axis=0) + 0.35)


def test_default_radius_edge_cases():
    assert inspect.default_radius(np.zeros((1, 3))) == 0.5
    assert inspect.default_radius(np.zeros((10, 3))) == 0.5
    grid = np.stack(np.meshgrid(*[np.arange(6.0)] * 3), -1).reshape(-1, 3) * 0.2
    assert inspect.default_radius(grid) == pytest.approx(0.1)


def test_inspect_input_volume(tmp_path):
    b = _bricks()
    path = tmp_path / "v.npz"
    b.save_npz(path)
    got = inspect.inspect_input(path, export=tmp_path / "v.vtm")
    assert got.n_slots == b.n_slots
    back = pv.read(str(tmp_path / "v.vtm"))
    assert back.keys() == ["bricks"] and back[0].n_cells == 12 * b.n_slots
