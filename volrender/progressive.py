"""The interactive viewer's renderer, without the browser (volrender/view.py drives it).

A `Session` holds one loaded scene and what the viewer changes: the camera (a Scene field)
and the options a user tunes (Scene.replace keywords, resolved on the device as
`volrender render` resolves them). `step()` is its state machine, one unit of work a call:

- moving (a change in the last `still_after` seconds): one frame at a reduced size and one
  sample per pixel (`preview`), sized from the measured speed to come back in about
  `preview_s`;
- still: the CLI's render of this camera and these options, samples 0..spp-1, launched in
  ranges over the whole image and read back in between (`Accumulation`); the kernels keep
  a pixel's sums across launches (dispatch.py: any split gives the bit-identical image),
  so the image shown after s samples is their mean and the last one is exactly what
  `volrender render --camera CAM.toml --spp N ...` writes (`command_line` says which).
  Denoised (denoise.py, render.denoised) at doubling sample counts and at the end when
  the denoiser exists and the session's denoise is on;
- converged: nothing to do until the next change.

The scene's content is loaded once: a camera change is a Scene field, an option change
goes through Scene.replace, which keeps the bricks, the cloud and their device builds
(uploads, tree, cells, light cache) unless the option changes them (blend, grid names).
"""
from __future__ import annotations

import dataclasses
import math
import shlex
import threading
import time
import warnings
from dataclasses import dataclass

import numpy as np

from .errors import UserError

STILL_AFTER_S = 0.25     # a camera or option unchanged this long is still: accumulate
PREVIEW_S = 0.1          # seconds a moving frame aims at
PREVIEW_MAX = 0.5        # a preview is at most this fraction of the still size per side
PREVIEW_MIN = 1 / 8      # ... and at least this (or 16 pixels)
STEP_S = 0.25            # seconds an accumulation step aims at (then it is shown)
LAUNCH_S = 0.25          # seconds a launch aims at on CPUs (dispatch.TARGET_S)


@dataclass
class Frame:
    """What the viewer shows: a linear render.Image and where the state machine is."""
    image: object               # render.Image (rgba: the mean of the samples taken)
    state: str                  # "preview", "progressive" or "converged"
    spp: int                    # samples per pixel taken
    target: int                 # samples per pixel the still frame ends at
    version: int                # Session.version it shows
    denoised: bool = False
    seconds: float = 0.0        # render time of this step


class Accumulation:
    """One still frame of `scene` on `device`, its samples launched in ranges: `advance`
    renders the next samples over the whole image and returns the mean so far."""

    def __init__(self, scene, device):
        import pyopencl as cl
        from .dispatch import upload
        from .render import PLANNERS, check_image_memory
        cam = scene.camera
        self.scene, self.dev = scene, device
        self.plan = plan = PLANNERS[scene.kind](scene, device, None, None)
        check_image_memory(cam.width, cam.height, device, len(plan.aovs))
        self.kernel = device.kernel(plan.entry, plan.features.flags(), options=plan.build_options)
        ctx = device.context
        args = [upload(ctx, a) if isinstance(a, np.ndarray) else a for _, a in plan.inputs]
        self.outs = {name: cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 4 * int(np.prod(shape)))
                     for name, shape in plan.outputs}
        args += list(self.outs.values())
        args += [upload(ctx, a) if isinstance(a, np.ndarray) else a for _, a in plan.extra]
        self.args = args
        self.spp = plan.spp
        self.taken = 0                    # samples per pixel in the buffers
        self.rate = None                  # seconds per pixel-sample, measured
        self.kernel_ms = 0.0
        self.dispatch = plan.dispatch.resolve(device)
        self.dispatch.check(device, self.kernel)

    @property
    def done(self) -> bool:
        return self.taken >= self.spp

    def advance(self, seconds=STEP_S, cancelled=lambda: False):
        """Render the next samples (about `seconds` of them at the measured speed, at most
        as many as taken so far, at least one) and return render.Image of the mean so far;
        None when `cancelled()` turned true between launches (the buffers are then mixed:
        drop this Accumulation)."""
        from .dispatch import enqueue, is_gpu
        from .render import Image
        cam = self.scene.camera
        W, H = cam.width, cam.height
        left = self.spp - self.taken
        n = 1 if self.rate is None else seconds / max(self.rate * W * H, 1e-12)
        n = int(max(1, min(n, left, max(1, self.taken))))
        tw, th = self.dispatch.tile
        if is_gpu(self.dev):
            rows = H
        elif self.rate is None:
            rows = max(1, self.plan.band_pixels // (W * n))
        else:
            rows = int(LAUNCH_S / max(self.rate * W * n, 1e-12))
        rows = min(H, max(th, rows // th * th))
        s0, s1 = self.taken, self.taken + n
        t0, c0 = time.perf_counter(), time.process_time()
        gx = -(-W // tw) * tw
        for y0 in range(0, H, rows):
            if cancelled():
                return None
            r = min(rows, H - y0)
            self.kernel.set_args(*self.args, np.int32(y0), np.int32(s0), np.int32(s1))
            ns, _ = enqueue(self.dev, self.kernel, (gx, -(-r // th) * th), (tw, th))
            self.kernel_ms += ns * 1e-6
        import pyopencl as cl
        rgba = np.empty((H, W, 4), np.float32)
        cl.enqueue_copy(self.dev.queue, rgba, self.outs["rgba"])
        self.dev.queue.finish()
        took = time.perf_counter() - t0
        self.rate = took / (W * H * n)
        self.taken = s1
        if not self.done:                 # sums until the last launch divides
            rgba /= np.float32(s1)
        settings = self.scene.settings
        return Image(rgba=rgba, aovs={}, kernel_ms=self.kernel_ms, wall_ms=1e3 * took,
                     cpu_ms=1e3 * (time.process_time() - c0), device=self.dev.name,
                     flags=self.plan.features.flags(), camera=cam,
                     info=self.plan.info.replace(
                         transparent=bool(getattr(settings, "transparent", False)),
                         spp=s1, spp_target=self.spp))


def preview_size(still, rate, seconds=PREVIEW_S):
    """(w, h) of a moving frame: the pixels `rate` (seconds per pixel-sample; None: not
    measured yet) renders in `seconds`, between PREVIEW_MIN and PREVIEW_MAX of the still
    size per side (at least 16 pixels), the still's aspect kept."""
    w, h = still
    hi = PREVIEW_MAX
    lo = min(hi, max(PREVIEW_MIN, 16 / min(w, h)))
    f = hi if rate is None else math.sqrt(seconds / max(rate, 1e-12) / (w * h))
    f = min(hi, max(lo, f))
    return max(1, round(w * f)), max(1, round(h * f))


class Session:
    """The renderer of `volrender view` (see the module docstring). Thread-safe: the
    browser's callbacks call set_camera / set_options / set_size, one loop calls step()."""

    def __init__(self, scene, device=None, *, size=None, still_after=STILL_AFTER_S,
                 preview_s=PREVIEW_S, step_s=STEP_S, clock=time.monotonic):
        from . import device as device_mod, volume
        if scene.kind == "volume" and volume.adaptive(scene.settings):
            raise UserError("--noise-target and --time-limit do not apply to the viewer (it "
                            "accumulates samples until you move)", fix="give --spp N instead")
        self.dev = device_mod.resolve(device)
        self.base = scene
        self.size = tuple(size) if size else (scene.camera.width, scene.camera.height)
        self.camera = dataclasses.replace(scene.camera, width=self.size[0], height=self.size[1])
        self.options = {}                 # option keywords the viewer changed
        self.still_after, self.preview_s, self.step_s = still_after, preview_s, step_s
        self.clock = clock
        self.version = 0
        self.changed_at = -math.inf
        self.error = None                 # the last option change that failed, as a line
        self.rate = None                  # seconds per pixel-sample of 1-spp frames
        self.frame = None                 # the last Frame
        self._lock = threading.RLock()
        self._wake = threading.Event()
        self._scenes = {}                 # (options, size) -> the resolved scene (one kept)
        self._good = {}                   # the last options that resolved
        self._accum = None
        self._preview_version = -1
        self._denoised_at = 0

    # ---------------------------------------------------------------- changes

    def _changed(self):
        self.version += 1
        self.changed_at = self.clock()
        self._wake.set()

    def set_camera(self, camera):
        """A new camera (camera.Camera; its size is replaced by the session's)."""
        with self._lock:
            camera = dataclasses.replace(camera, width=self.size[0], height=self.size[1])
            if camera != self.camera:
                self.camera = camera
                self._changed()

    def set_size(self, size):
        with self._lock:
            size = (int(size[0]), int(size[1]))
            if size != self.size:
                self.size = size
                self.camera = dataclasses.replace(self.camera, width=size[0], height=size[1])
                self._changed()

    def set_options(self, **options):
        """Change load_scene keywords (density_scale=2, ior=1.3, sun=[...], spp=64,
        denoise="on", ...); checked when the next frame resolves them (`error`)."""
        with self._lock:
            new = {**self.options, **options}
            if new != self.options:
                self.options, self.error = new, None
                self._changed()

    def wake(self):
        """End a wait() now (the viewer stopping)."""
        self._wake.set()

    def wait(self, timeout=None):
        """Block until a change, or until a moving camera turns still (at most `timeout`)."""
        with self._lock:
            left = self.changed_at + self.still_after - self.clock()
        t = left if left > 0 else None
        if timeout is not None:
            t = timeout if t is None else min(t, timeout)
        self._wake.wait(t)
        self._wake.clear()

    # ---------------------------------------------------------------- scenes

    def scene(self, options=None, size=None):
        """The still scene: the base scene with `options` (default: the session's) at
        `size`, resolved on the device as the CLI resolves it, with the session's camera."""
        with self._lock:
            options = dict(self.options if options is None else options)
            size = self.size if size is None else size
            camera = self.camera
        key = (repr(sorted(options.items())), size)
        if key not in self._scenes:
            scene = self.base.replace(**options, size=size, device=self.dev) \
                if self.base.request is not None else self.base.replace(**options)
            self._scenes = {key: scene}
        return self._scenes[key].replace(camera=dataclasses.replace(
            camera, width=size[0], height=size[1]))

    def _resolve(self):
        """The still scene, or None after an option that failed (`error` says why; the
        options go back to the last ones that worked)."""
        try:
            scene = self.scene()
        except UserError as exc:
            with self._lock:
                self.error = str(exc)
                self.options = dict(self._good)
            return None
        self._good = dict(self.options)
        return scene

    def denoise_on(self, scene) -> bool:
        from .denoise import unavailable
        return getattr(scene.settings, "denoise", "off") in ("on", "auto") and not unavailable()

    # ---------------------------------------------------------------- the state machine

    @property
    def moving(self) -> bool:
        return self.clock() - self.changed_at < self.still_after

    def step(self):
        """One unit of work (see the module docstring): a Frame to show, or None when
        there is nothing to do now (wait())."""
        with self._lock:
            version, moving = self.version, self.moving
        scene = self._resolve()
        if scene is None:
            return None
        if moving:
            if self._preview_version == version:
                return None
            self._preview_version = version
            if scene.kind == "glass":     # built for the still frame's samples, as the CLI
                cam = scene.camera
                scene.content.prepare(self.dev, samples=cam.width * cam.height * scene.settings.spp)
            return self._preview(scene, version)
        acc = self._accum
        if acc is None or acc.version != version:
            acc = self._accum = Accumulation(scene, self.dev)
            acc.version, self._denoised_at = version, 0
        if acc.done:
            return None
        t0 = time.perf_counter()
        img = acc.advance(self.step_s, cancelled=lambda: self.version != version)
        if img is None:
            self._accum = None
            return None
        if acc.taken == 1 or self.rate is None:
            self.rate = acc.rate
        denoised = False
        if self.denoise_on(scene) and (acc.done or acc.taken >= 2 * max(self._denoised_at, 1)):
            from .render import denoised as denoise_image
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                img = denoise_image(scene, self.dev, img)
            denoised, self._denoised_at = bool(img.info.denoised), acc.taken
        frame = Frame(img, "converged" if acc.done else "progressive", acc.taken, acc.spp,
                      version, denoised, time.perf_counter() - t0)
        self.frame = frame
        return frame

    def _preview(self, scene, version):
        """A moving frame: preview_size, one sample, the still's resolved settings."""
        t0 = time.perf_counter()
        w, h = preview_size(self.size, self.rate, self.preview_s)
        cam = dataclasses.replace(scene.camera, width=w, height=h)
        content = dataclasses.replace(scene.content, settings=dataclasses.replace(
            scene.content.settings, spp=1))
        acc = Accumulation(scene.replace(camera=cam, content=content), self.dev)
        img = acc.advance(math.inf)
        self.rate = acc.rate
        frame = Frame(img, "preview", acc.taken, acc.spp, version, False, time.perf_counter() - t0)
        self.frame = frame
        return frame

    def run(self, show, stop=lambda: False):
        """Step and `show(frame)` until `stop()`; waits while there is nothing to do."""
        while not stop():
            frame = self.step()
            if frame is not None:
                show(frame)
            elif not stop():
                self.wait(0.5)


# -------------------------------------------------------------------- the command line

def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (tuple, list)):
        if len(v) == 2 and all(isinstance(c, int) and not isinstance(c, bool) for c in v):
            return f"{v[0]}x{v[1]}"
        return ",".join(_value(float(c)) if isinstance(c, (int, float)) and not isinstance(c, bool)
                        else str(c) for c in v)
    return str(v)


def command_line(scene, camera_file, output, exposure=0.0, view="filmic", spp=None,
                 packed=None):
    """`volrender render ...` that renders `scene` (a Session's still scene) identically:
    its input and options (the camera ones replaced by `camera_file`; --estimator auto
    written as what it resolved to; --spp and --denoise explicit; for glass, `packed`, the
    spheres.PackedSpheres the viewer built: its --accel and support-cell edge, which the
    CLI would choose from its own job's size), as one shell line. None for a scene made
    without an input (an array, Scene.of)."""
    from .scene_file import options
    req = scene.request
    if req is None or req.origin == "array":
        return None
    opts = options()
    s = scene.settings
    given = {k: v for k, v in req.overrides.items() if v is not None}
    drop = {k for k, o in opts.items() if o.owner == "view" and k != "up_axis"} | {"camera"}
    given = {k: v for k, v in given.items() if k not in drop}
    if scene.kind == "volume":
        given["estimator"] = s.estimator
        if s.estimator == "march":
            given["ms_octaves"] = s.ms_octaves if s.ms_octaves is not None else s.octaves
    if packed is not None:
        given["accel"] = packed.accel
        if packed.cells is not None:
            given["cell_size"] = float(packed.cells.cell)
    given["spp"] = int(spp if spp is not None else s.spp)
    given["denoise"] = "on" if s.denoise in ("on", "auto") and _can_denoise() else "off"
    words = ["volrender", "render", str(req.source), "--camera", str(camera_file)]
    for key, value in given.items():
        if key == "lights":
            for light in value:
                if hasattr(light, "direction"):
                    words.append(f"--sun={_value((*light.direction, float(light.irradiance)))}")
                else:
                    point = (*light.position, float(light.intensity))
                    words.append(f"--point-light={_value(point)}")
            continue
        flag = opts[key].flag if key in opts else "--" + key.replace("_", "-")
        if isinstance(value, bool) or opts.get(key) and opts[key].meta["kind"] is bool \
                or key == "no_lights":
            if value:
                words.append(flag)
            continue
        if key in ("sun", "point_light", "aov"):
            words += [f"{flag}={_value(v)}" for v in value]
            continue
        words.append(f"{flag}={_value(value)}")
    if exposure:
        words.append(f"--exposure={_value(float(exposure))}")
    if view != "filmic":
        words.append(f"--view={view}")
    words += ["-o", str(output)]
    return " ".join(shlex.quote(w) for w in words)


def _can_denoise() -> bool:
    from .denoise import unavailable
    return unavailable() is None
