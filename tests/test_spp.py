"""One carrier for the samples per pixel: the count a user gives reaches the kernel unchanged
whichever way it is given (Python render(), the command line, a scene file, a sequence).
What the kernel reads is checked, not what the host meant: the `spp` of the camera record
read back from its device buffer, and the sample ranges (s0, s1) of the launches, which must
cover [0, spp) for every row exactly once (dispatch.Plan.spp carries the count to both)."""
import numpy as np
import pyopencl as cl
import pytest

import volrender
from volrender import cli, generators, layout

SPP = 3                       # not a default, not a power of two
SIZE = (12, 10)


@pytest.fixture
def launches(monkeypatch):
    """(camera spp, y0, s0, s1) of every render_* kernel launch (the camera buffer is the
    first argument of both integrators' kernels)."""
    seen, queues = [], {}
    real = cl.Kernel.set_args

    def set_args(self, *a):
        if self.function_name.startswith("render_"):
            ctx = a[0].context
            q = queues.setdefault(ctx.int_ptr, cl.CommandQueue(ctx))
            cam = np.empty(1, layout.dtype("Camera"))
            cl.enqueue_copy(q, cam, a[0])
            q.finish()
            seen.append((int(cam["spp"][0]), int(a[-3]), int(a[-2]), int(a[-1])))
        return real(self, *a)
    monkeypatch.setattr(cl.Kernel, "set_args", set_args)
    return seen


def renders(seen, n_images=1):
    """Check every launch read SPP and the ranges cover [0, SPP) per row band, once per
    image; return the number of launches."""
    assert seen, "no render kernel ran"
    assert {c for c, *_ in seen} == {SPP}, seen
    per_band = {}
    for _, y0, s0, s1 in seen:
        per_band.setdefault(y0, []).append((s0, s1))
    for y0, ranges in per_band.items():
        covered = np.zeros(SPP, int)
        for s0, s1 in ranges:
            covered[s0:s1] += 1
        assert (covered == n_images).all(), (y0, ranges)
    return len(seen)


@pytest.fixture(scope="module")
def cloud(tmp_path_factory):
    d = tmp_path_factory.mktemp("spp")
    pts = generators.blob(200, seed=3).centers.astype(np.float32)
    for f in (1, 2):
        np.save(d / f"p_{f:04d}.npy", pts + [0.1 * f, 0.0, 0.0])
    return d


def test_python_render(launches, cloud):
    img = volrender.render(str(cloud / "p_0001.npy"), size=SIZE, spp=SPP, bounces=1)
    renders(launches)
    assert img.info.spp == SPP


def test_python_render_of_a_volume(launches, box):
    img = volrender.render(box, size=SIZE, spp=SPP, estimator="march", density_scale=0.5)
    renders(launches)
    assert img.info.spp == SPP


def test_command_line(launches, cloud, tmp_path, capsys):
    code = cli.main(["render", str(cloud / "p_0001.npy"), "-o", str(tmp_path / "o.exr"),
                     "--size", "12x10", "--spp", str(SPP), "--bounces", "1", "--no-progress"])
    assert code == 0
    renders(launches)
    assert f"{SPP} spp" in capsys.readouterr().err


def test_scene_file(launches, cloud, tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text(f'[points]\nfile = "{cloud / "p_0001.npy"}"\n'
                     f'[render]\nsize = [12, 10]\nspp = {SPP}\nbounces = 1\n')
    assert cli.main(["render", str(scene), "-o", str(tmp_path / "o.exr"), "--no-progress"]) == 0
    renders(launches)
    launches.clear()
    img = volrender.render(volrender.load_scene(str(scene)))
    renders(launches)
    assert img.info.spp == SPP


def test_sequence(launches, cloud, tmp_path):
    r = volrender.render_sequence(str(cloud / "p_####.npy"), str(tmp_path / "g_####.exr"),
                                  frames="1-2", size=SIZE, spp=SPP, bounces=1, workers=0)
    assert [rec.status for rec in r.records] == ["ok"] * 2
    renders(launches, n_images=2)
