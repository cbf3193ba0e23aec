"""Helpers shared by the tests: render Bricks or a PointCloud with a camera, lights and
settings through the public path (Scene.of, render.render); the result is
Image.as_dict() ('rgba', each AOV by name, the timings and the render's info)."""
from volrender.render import render
from volrender.scene import GlassContent, Scene, VolumeContent


def render_points(cloud, camera, lights, settings, device, progress=None, variant=None,
                  launch=None):
    scene = Scene.of(camera, lights, GlassContent(cloud, settings))
    return render(scene, device, progress=progress, variant=variant, launch=launch).as_dict()


def render_volume(bricks, camera, lights, settings, device, progress=None, launch=None):
    """Settings left at --estimator auto render as `march` here: these tests check the
    marcher's estimand (single scattering, or the octaves asked for); auto's choice has
    its own tests (test_defaults.py), through load_scene as the CLI renders."""
    if settings.estimator == "auto":
        import dataclasses
        settings = dataclasses.replace(settings, estimator="march")
    scene = Scene.of(camera, lights, VolumeContent(bricks, settings))
    return render(scene, device, progress=progress, launch=launch).as_dict()
