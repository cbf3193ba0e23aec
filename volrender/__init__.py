"""volrender: OpenCL volume and molten-glass renderer.

    import volrender
    scene = volrender.load_scene("smoke.vdb", size=(320, 240), density_scale=2.0)
    image = volrender.render(scene)              # PoCL, or device="nvidia"
    image.save("smoke.exr")
    viewer = volrender.view(scene)               # a progressive viewer in the browser

load_scene takes the command line's option names with underscores as keywords
(`volrender render --help` lists them); render also takes what load_scene takes (a path,
GENERATOR:COUNT, a numpy volume or points) with the keywords. Image holds rgba (H x W x 4
float32, linear), the AOVs, timings and the device name. docs/python.md has the whole API.
"""
import sys as _sys

# The command line (`volrender ...`, `python -m volrender ...`): from this line on, a
# SIGINT, SIGTERM or SIGHUP ends it with one line and 128 + the signal, never a traceback
# (cli.main takes over). First, before any import: nothing else runs before it. The
# process's own argv (orig_argv), not sys.argv: a Dask worker spawned from the command
# is given the command's sys.argv, and must keep Dask's handlers.
_argv = list(getattr(_sys, "orig_argv", ()))[1:3]
if _argv[:1] and _argv[0].rsplit("/", 1)[-1] == "volrender" or _argv == ["-m", "volrender"]:
    def _starting(signum, frame):
        import os
        name = {1: "SIGHUP", 2: "SIGINT", 15: "SIGTERM"}.get(signum, str(signum))
        os.write(2, f"volrender: interrupted ({name}) while starting; no output written\n".encode())
        os._exit(128 + signum)

    def _start():
        import _signal
        for sig in (1, 2, 15):                       # SIGHUP, SIGINT, SIGTERM (POSIX numbers)
            if _signal.getsignal(sig) is not _signal.SIG_IGN:   # nohup, a background job
                _signal.signal(sig, _starting)
    _start()
    from . import process as _process
    _process.route_signals(_starting)   # before numpy: its threads inherit the block
del _argv

__version__ = "0.1.0"

from .errors import UserError  # noqa: E402
from .lights import PointLight, Sun  # noqa: E402
from .render import Image, render  # noqa: E402
from .scene import Scene, load_scene  # noqa: E402
from .sequence import render_sequence  # noqa: E402
from .viewer import view  # noqa: E402

__all__ = ["load_scene", "render", "render_sequence", "view", "Scene", "Image", "Sun", "PointLight",
           "UserError", "__version__"]
