"""volrender: OpenCL volume and molten-glass renderer.

    import volrender
    scene = volrender.load_scene("smoke.vdb", size=(320, 240), density_scale=2.0)
    image = volrender.render(scene)              # PoCL, or device="nvidia"
    image.save("smoke.exr")

load_scene takes the command line's option names with underscores as keywords
(`volrender render --help` lists them); render also takes what load_scene takes (a path,
GENERATOR:COUNT, a numpy volume or points) with the keywords. Image holds rgba (H x W x 4
float32, linear), the AOVs, timings and the device name. docs/python.md has the whole API.
"""
__version__ = "0.1.0"

import sys as _sys  # noqa: E402

# The command line (`volrender ...`, `python -m volrender ...`): a Ctrl-C while the
# modules below import ends it with one line, not a traceback (cli.main takes over).
if _sys.argv and (_sys.argv[0].rsplit("/", 1)[-1] == "volrender"
                  or list(getattr(_sys, "orig_argv", ()))[1:3] == ["-m", "volrender"]):
    from .process import exit_on_signals_during_startup as _startup
    _startup()

from .errors import UserError  # noqa: E402
from .lights import PointLight, Sun  # noqa: E402
from .render import Image, render  # noqa: E402
from .scene import Scene, load_scene  # noqa: E402
from .sequence import render_sequence  # noqa: E402

__all__ = ["load_scene", "render", "render_sequence", "Scene", "Image", "Sun", "PointLight",
           "UserError", "__version__"]
