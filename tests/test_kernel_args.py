"""Every plan passes its kernel's arguments by name: the (name, value) pairs of Plan.inputs
and Plan.extra are the kernel's parameters in order (OpenCL's kernel-argument info of a
build with -cl-kernel-arg-info), the outputs fill the slots between, y0, s0, s1 close."""
import pyopencl as cl
import pytest

from volrender import generators, glass, volume
from volrender.lights import PointLight, Sun
from volrender.scene import GlassContent, Scene, VolumeContent
from helpers import glowing_ball


def kernel_names(dev, plan):
    kernel = dev.kernel(plan.entry, plan.features.flags(),
                        options=(*plan.build_options, "-cl-kernel-arg-info"))
    n = kernel.get_info(cl.kernel_info.NUM_ARGS)
    try:
        return [kernel.get_arg_info(i, cl.kernel_arg_info.NAME) for i in range(n)]
    except cl.Error as exc:                     # a runtime without the arg info
        pytest.skip(f"{dev.name} gives no kernel argument names ({exc})")


def plans(dev):
    lights = (Sun((0.2, -1.0, -0.4), 2.0), PointLight((0.5, 0.5, 0.5), 1.0))
    ball = glowing_ball()
    from volrender.camera import Camera
    cam = Camera((0.3, 0.4, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 8, 8)
    for est in ("march", "track"):
        s = volume.VolumeSettings(estimator=est, emission_grid="emission", aovs=("depth",))
        yield volume.plan(Scene(cam, lights, VolumeContent(ball, s)), dev)
    s = volume.VolumeSettings(dispatch="tiled", tile=(4, 4))
    yield volume.plan(Scene(cam, lights, VolumeContent(ball, s)), dev)
    cloud = generators.blob(60, seed=1)
    for accel in ("grid", "tree"):
        content = GlassContent(cloud, glass.GlassSettings(accel=accel))
        yield glass.plan(Scene(glass.default_camera(cloud, 8, 8), lights, content), dev)


def guide_plans(dev):
    """The denoising guides' launches (volrender.guides) beside a render plan of each kind."""
    from volrender import guides
    lights = (Sun((0.2, -1.0, -0.4), 2.0),)
    from volrender.camera import Camera
    cam = Camera((0.3, 0.4, 3.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 8, 8)
    vs = Scene(cam, lights, VolumeContent(glowing_ball(), volume.VolumeSettings(estimator="march")))
    yield guides.plan(vs, volume.plan(vs, dev))
    cloud = generators.blob(60, seed=1)
    gs = Scene(glass.default_camera(cloud, 8, 8), lights, GlassContent(cloud, glass.GlassSettings()))
    yield guides.plan(gs, glass.plan(gs, dev))


def test_plans_pass_arguments_by_the_kernels_names(cl_device):
    for plan in [*plans(cl_device), *guide_plans(cl_device)]:
        names = kernel_names(cl_device, plan)
        want = plan.arg_names()
        assert len(names) == len(want), (plan.entry, names, want)
        for got, expected in zip(names, want):
            if expected is not None:
                assert got == expected, (plan.entry, names, want)
