"""Point files read as users write them: text columns by header name (CloudCompare's
//X,Y,Z,R,G,B,Nx,Ny,Nz, 9-column CSVs with a header), normals recognised and ignored on
purpose (and said), LAS/LAZ through laspy, and `volrender info` on point files."""
import numpy as np
import pytest

from volrender import cli
from volrender.errors import UserError
from volrender.points import load_points

XYZ = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]])
NRM = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.6, -0.8, 0.0]])
RGB = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [10, 20, 30]])


def write(path, header, rows, sep=" "):
    lines = ([header] if header else []) + [sep.join(f"{v:g}" for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_cloudcompare_export_with_normals(tmp_path):
    p = write(tmp_path / "cc.xyz", "//X Y Z R G B Nx Ny Nz", np.hstack([XYZ, RGB, NRM]))
    c = load_points(p)
    np.testing.assert_array_equal(c.centers, XYZ)
    np.testing.assert_allclose(c.colors, RGB / 255, rtol=1e-6)
    assert c.radii is None and "Nx, Ny, Nz" in c.notes[0] and "ignored" in c.notes[0]


def test_six_columns_of_unit_vectors_are_normals_not_colours(tmp_path):
    c = load_points(write(tmp_path / "n.xyz", None, np.hstack([XYZ, NRM])))
    np.testing.assert_array_equal(c.centers, XYZ)
    assert c.colors is None and "nx, ny, nz" in c.notes[0]
    # and six columns of colours are still colours
    c = load_points(write(tmp_path / "c.xyz", None, np.hstack([XYZ, RGB])))
    np.testing.assert_allclose(c.colors, RGB / 255, rtol=1e-6)


@pytest.mark.parametrize("order", ["rgb first", "normals first"])
def test_nine_columns_without_header_in_either_order(tmp_path, order):
    extra = np.hstack([RGB, NRM]) if order == "rgb first" else np.hstack([NRM, RGB])
    c = load_points(write(tmp_path / "nine.xyz", None, np.hstack([XYZ, extra])))
    np.testing.assert_allclose(c.colors, RGB / 255, rtol=1e-6)
    assert "normals" in c.notes[0]


def test_csv_header_in_any_order_with_unknown_columns(tmp_path):
    rows = np.column_stack([RGB[:, 0], XYZ[:, 2], XYZ[:, 0], np.full(4, 7.0), RGB[:, 1],
                            XYZ[:, 1], RGB[:, 2], np.full(4, 0.1), NRM[:, 0]])
    p = write(tmp_path / "h.csv", "red,z,x,intensity,green,y,blue,radius,nx", rows, sep=",")
    c = load_points(p)
    np.testing.assert_array_equal(c.centers, XYZ)
    np.testing.assert_allclose(c.radii, 0.1)
    np.testing.assert_allclose(c.colors, RGB / 255, rtol=1e-6)
    assert "intensity" in c.notes[0] and "nx" in c.notes[0]


def test_a_header_without_coordinates_is_one_line(tmp_path):
    p = write(tmp_path / "bad.csv", "a,b,c", XYZ, sep=",")
    with pytest.raises(UserError, match="names no x, y and z"):
        load_points(p)


def test_las_and_laz(tmp_path):
    laspy = pytest.importorskip("laspy", reason="laspy is not installed (pip install 'volrender[las]')")
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.001] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.x, las.y, las.z = XYZ[:, 0], XYZ[:, 1], XYZ[:, 2]
    las.red, las.green, las.blue = (RGB * 257).T
    for suffix in (".las", ".laz"):
        try:
            las.write(tmp_path / f"t{suffix}")
        except Exception as exc:                  # no LAZ backend
            pytest.skip(f"laspy cannot write {suffix} here ({exc})")
        c = load_points(tmp_path / f"t{suffix}")
        np.testing.assert_allclose(c.centers, XYZ, atol=1e-3)
        np.testing.assert_allclose(c.colors, RGB / 255, atol=1e-4)
    (tmp_path / "bad.las").write_bytes(b"LASF" + b"\0" * 40)
    with pytest.raises(UserError, match="not a readable LAS/LAZ"):
        load_points(tmp_path / "bad.las")


def test_info_describes_point_files(tmp_path, capsys):
    p = write(tmp_path / "cloud.xyz", None, XYZ)
    assert cli.main(["info", str(p)]) == 0
    out = capsys.readouterr().out
    assert "4 points" in out and "radius" in out and "blend" in out
