"""`volrender view INPUT [render options] [--port N]` and `volrender.view(scene)`: a
progressive viewer in the browser, on viser (the viewer nerfstudio uses for remote GPUs:
orbit controls in the browser, images sent from Python over one websocket, GUI widgets).

The renderer stays where it runs (PoCL, or a GPU on a remote machine reached through
`ssh -N -L PORT:localhost:PORT HOST`); the browser's camera comes back over the
websocket and each frame is sent as the scene's background image. progressive.Session
does the rendering (moving: small and one sample; still: the CLI's render, its samples
accumulated); this module is the server, the controls and the save button.
docs/viewer.md is the user's page.
"""
from __future__ import annotations

import contextlib
import errno
import io
import math
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np

from . import process
from .errors import UserError

DEFAULT_PORT = 8080
DEFAULT_HOST = "127.0.0.1"          # this machine only (an SSH tunnel reaches it)
MAX_CANVAS = 1920                   # the still size follows the canvas up to this width
VIEWS = ("filmic", "standard", "agx", "aces")
INSTALL = "pip install 'volrender[view]' (bash run.sh setup installs it)"


def import_viser():
    """viser, or a UserError naming the install."""
    try:
        import viser
    except ImportError as exc:
        raise UserError(f"the viewer needs viser, which does not import ({exc})",
                        fix=INSTALL) from None
    return viser


def check_port(host: str, port: int):
    """Refuse a port that is out of range or taken, before the server starts (viser would
    quietly move to the next free one)."""
    import socket
    if not isinstance(port, int) or isinstance(port, bool) or not 0 <= port <= 65535:
        raise UserError(f"--port must be an integer in 0..65535, got {port!r}",
                        fix=f"e.g. --port {DEFAULT_PORT}")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        raise UserError(f"--host {host}: {exc.strerror}", fix="give an address such as "
                        "127.0.0.1 (this machine) or 0.0.0.0 (every interface)") from None
    family, kind, proto, _, addr = infos[0]
    with socket.socket(family, kind, proto) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)   # as the server binds
        try:
            s.bind(addr)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise UserError(f"port {port} on {host} is in use (another viewer or server)",
                                fix=f"give a free one with --port N, e.g. --port {port + 1}") \
                    from None
            raise UserError(f"cannot listen on {host}:{port} ({exc.strerror})",
                            fix="give another --port (1024..65535) or --host") from None


def url_of(host: str, port: int) -> str:
    shown = "localhost" if host in ("127.0.0.1", "localhost", "0.0.0.0", "::", "") else host
    return f"http://{shown}:{port}/"


def sun_angles(sun, frame):
    """(azimuth, elevation) in degrees of the direction towards `sun` (lights.Sun) in the
    y-up frame (`frame`: camera.up_frame's rotation, None for y up)."""
    to = -np.asarray(sun.direction, np.float64)
    if frame is not None:
        to = frame.T @ to
    return math.degrees(math.atan2(to[0], to[2])), math.degrees(math.asin(np.clip(to[1], -1, 1)))


def sun_direction(azimuth, elevation, frame):
    """The propagation direction of a sun seen at (azimuth, elevation) degrees."""
    a, e = math.radians(azimuth), math.radians(elevation)
    to = np.array([math.sin(a) * math.cos(e), math.sin(e), math.cos(a) * math.cos(e)])
    if frame is not None:
        to = frame @ to
    return tuple(float(v) for v in -to)


def ordered(fn):
    """An async viser callback calling fn(): run in viser's event loop, so the changes apply
    in the order the browser sent them (sync callbacks run on a thread pool, in any order)."""
    async def callback(_):
        fn()
    return callback


class Viewer:
    """The running viewer: a viser server, its controls, and a progressive.Session. `run()`
    renders until stopped (the CLI's main thread); `start()` runs it in a thread (Python,
    Jupyter); `stop()` ends both. `url` is what it serves; `controls` the GUI handles by
    label."""

    def __init__(self, scene, device=None, *, port=DEFAULT_PORT, host=DEFAULT_HOST, size=None,
                 exposure=0.0, view="filmic", save_dir="."):
        from .progressive import Session
        viser = import_viser()
        check_port(host, port)
        self.follow_canvas = size == "canvas"
        self.session = Session(scene, device, size=None if self.follow_canvas else size)
        self.exposure, self.view = float(exposure), view
        self.save_dir = Path(save_dir)
        self.saved = []                    # (png, camera file, command) per save
        self._stopping = threading.Event()
        self._thread = None
        self._shown_at = None
        self._fps = 0.0
        with contextlib.redirect_stdout(io.StringIO()):
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        bound = self.server.get_port()
        if port and bound != port:         # taken between the check and the bind
            self._stop_server()
            raise UserError(f"port {port} on {host} is in use (another viewer or server)",
                            fix=f"give a free one with --port N, e.g. --port {port + 1}")
        self.port, self.host = bound, host
        self.url = url_of(host, bound)
        try:
            self._place_camera(self.session.camera)
            self.server.on_client_connect(self._connect)
            self._controls(scene)
        except BaseException:
            self._stop_server()
            raise

    # ---------------------------------------------------------------- camera

    def _place_camera(self, cam):
        ic = self.server.initial_camera
        ic.position, ic.look_at, ic.up = cam.origin, cam.target, cam.up
        ic.fov = math.radians(cam.fov)
        up = np.asarray(cam.up, np.float64)
        self.server.scene.set_up_direction(tuple(up / np.linalg.norm(up)))

    # Both run in viser's event loop (async): the camera callback is registered before the
    # client's first camera message is handled, and the cameras apply in the order sent
    # (sync callbacks run on a thread pool, in any order).
    async def _connect(self, client):
        # the browser starts at server.initial_camera (or its URL's initialCamera* parameters)
        client.camera.on_update(self._camera_moved)

    async def _camera_moved(self, handle):
        from .camera import Camera
        if self.follow_canvas and handle.image_width > 0 and handle.image_height > 0:
            w, h = handle.image_width, handle.image_height
            k = min(1.0, MAX_CANVAS / w)
            self.session.set_size((max(1, round(w * k)), max(1, round(h * k))))
        try:
            cam = Camera(tuple(map(float, handle.position)), tuple(map(float, handle.look_at)),
                         tuple(map(float, handle.up_direction)), math.degrees(handle.fov),
                         *self.session.size)
        except UserError:                  # a degenerate pose on the way: keep the last
            return
        self.session.set_camera(cam)
        if hasattr(self, "_fov") and abs(self._fov.value - cam.fov) > 0.25:
            self._fov.value = round(cam.fov, 1)

    # ---------------------------------------------------------------- controls

    def _controls(self, scene):
        gui = self.server.gui
        s = self.session.scene().settings
        opt = self.session.set_options
        self._status = gui.add_markdown("starting ...")
        with gui.add_folder("Look"):
            ex = gui.add_slider("exposure", min=-10.0, max=10.0, step=0.1,
                                initial_value=self.exposure)
            ex.on_update(lambda _: self._display(exposure=ex.value))
            vw = gui.add_dropdown("view", VIEWS,
                                  initial_value=self.view if self.view in VIEWS else "filmic")
            vw.on_update(lambda _: self._display(view=vw.value))
            self._fov = gui.add_slider("fov", min=1.0, max=120.0, step=0.5,
                                       initial_value=round(self.session.camera.fov, 3))
            self._fov.on_update(ordered(lambda: self._set_fov(self._fov.value)))
        self.controls = {"exposure": ex, "view": vw, "fov": self._fov}
        if scene.kind == "volume":
            with gui.add_folder("Volume"):
                ds = gui.add_number("density scale", initial_value=float(s.density_scale),
                                    min=0.0, step=0.1)
                ds.on_update(ordered(lambda: opt(density_scale=float(ds.value))))
                al = gui.add_slider("albedo", min=0.0, max=1.0, step=0.01,
                                    initial_value=float(np.mean(s.albedo)))
                al.on_update(ordered(lambda: opt(albedo=(float(al.value),))))
                from .volume import ESTIMATORS
                given = scene.request.settings.estimator if scene.request else s.estimator
                es = gui.add_dropdown("estimator", ESTIMATORS, initial_value=given)
                es.on_update(ordered(lambda: opt(estimator=es.value)))
            self.controls.update({"density scale": ds, "albedo": al, "estimator": es})
        else:
            from .glass import GLASS_MODELS
            with gui.add_folder("Glass"):
                io_ = gui.add_slider("IOR", min=1.0, max=3.0, step=0.01,
                                     initial_value=float(s.ior))
                io_.on_update(ordered(lambda: opt(ior=float(io_.value))))
                bl = gui.add_number("blend (rebuilds)", initial_value=float(s.blend or 0.0),
                                    min=0.0, step=float(s.blend or 0.01) / 10)
                bl.on_update(ordered(lambda: opt(blend=float(bl.value))))
                gm = gui.add_dropdown("glass model", GLASS_MODELS, initial_value=s.glass_model)
                gm.on_update(ordered(lambda: opt(glass_model=gm.value)))
            self.controls.update({"IOR": io_, "blend": bl, "glass model": gm})
        self._sun_controls(scene)
        with gui.add_folder("Samples"):
            sp = gui.add_number("samples", initial_value=int(s.spp), min=1, max=65536, step=1)
            sp.on_update(ordered(lambda: opt(spp=int(sp.value))))
            from .denoise import unavailable
            dn = gui.add_checkbox("denoise", disabled=unavailable() is not None,
                                  initial_value=s.denoise in ("on", "auto") and not unavailable())
            dn.on_update(ordered(lambda: opt(denoise="on" if dn.value else "off")))
        save = gui.add_button("Save image and camera")
        save.on_click(lambda _: self._save_clicked())
        self.controls.update({"samples": sp, "denoise": dn, "save": save})
        self._saved_text = gui.add_markdown("")

    def _sun_controls(self, scene):
        from .camera import up_frame
        from .lights import PointLight, Sun
        suns = [l for l in scene.lights if isinstance(l, Sun)]
        if not suns:
            return
        up = np.abs(np.asarray(scene.camera.up, np.float64))
        frame = up_frame("z" if up[2] > up[1] else "y")
        az0, el0 = sun_angles(suns[0], frame)
        points = [(*l.position, float(l.intensity)) for l in scene.lights
                  if isinstance(l, PointLight)]
        gui = self.server.gui
        with gui.add_folder("Sun"):
            az = gui.add_slider("azimuth", min=-180.0, max=180.0, step=1.0,
                                initial_value=round(az0, 1))
            el = gui.add_slider("elevation", min=-90.0, max=90.0, step=1.0,
                                initial_value=round(el0, 1))
            e = gui.add_number("irradiance", initial_value=float(suns[0].irradiance), min=0.0,
                               step=0.5)

        def changed(_):   # the first sun turned; the other lights kept
            d = sun_direction(az.value, el.value, frame)
            sun = [(*d, float(e.value))] + [(*l.direction, float(l.irradiance)) for l in suns[1:]]
            self.session.set_options(sun=sun, **({"point_light": points} if points else {}))
        for h in (az, el, e):
            h.on_update(ordered(lambda: changed(None)))
        self.controls.update({"sun azimuth": az, "sun elevation": el, "sun irradiance": e})

    def _set_fov(self, fov):
        for client in self.server.get_clients().values():
            client.camera.fov = math.radians(fov)

    def _display(self, exposure=None, view=None):
        """A display knob (no new render): the last frame shown again."""
        if exposure is not None:
            self.exposure = float(exposure)
        if view is not None:
            self.view = view
        if self.session.frame is not None:
            self.show(self.session.frame)

    # ---------------------------------------------------------------- frames

    def pixels(self, frame) -> np.ndarray:
        """The frame's 8-bit sRGB H x W x 3, as the CLI's opaque PNG."""
        from .image import png_pixels
        img = frame.image
        return png_pixels(img.rgba, self.exposure, self.view,
                          background=img.info.background, alpha="opaque")[..., :3]

    def show(self, frame):
        rgb = self.pixels(frame)
        final = frame.state == "converged"
        self.server.scene.set_background_image(rgb, format="png" if final else "jpeg",
                                               jpeg_quality=None if final else 90)
        now = time.perf_counter()
        if self._shown_at is not None and frame.state == "preview":
            self._fps = 1.0 / max(now - self._shown_at, 1e-6)
        self._shown_at = now
        h, w = rgb.shape[:2]
        what = {"preview": f"moving: {w}x{h}, 1 spp, {self._fps:.1f} frames/s",
                "progressive": f"still: {w}x{h}, {frame.spp} of {frame.target} spp",
                "converged": f"converged: {w}x{h}, {frame.spp} spp"}[frame.state]
        if frame.denoised:
            what += ", denoised"
        if self.session.error:
            what += f"\n\n**error:** {self.session.error}"
        self._status.content = what

    # ---------------------------------------------------------------- saving

    def _save_clicked(self):
        try:
            png, _, cmd = self.save()
            self._saved_text.content = f"saved `{png}`" + (f"; the CLI: `{cmd}`" if cmd else "")
        except UserError as exc:
            self._saved_text.content = f"**not saved:** {exc}"

    def save(self, stem=None):
        """Write the image shown (PNG, as the CLI writes it), its camera (the --camera-out
        format) and the command line that renders it (.sh beside them; None for a scene
        without an input); returns (png, camera file, command)."""
        from .atomic import write_bytes
        from .camera import write_camera_file
        from .progressive import command_line
        frame = self.session.frame
        if frame is None or frame.state == "preview":
            raise UserError("nothing still to save yet", fix="stop moving the camera for a moment")
        if stem is None:
            n = 1
            while (self.save_dir / f"view_{n:04d}.png").exists():
                n += 1
            stem = self.save_dir / f"view_{n:04d}"
        stem = Path(stem)
        png, cam = stem.with_suffix(".png"), stem.with_suffix(".camera.toml")
        frame.image.save(png, exposure=self.exposure, tonemap=self.view)
        write_camera_file(frame.image.camera, cam)
        scene = self.session.scene()
        packed = scene.content.prepare(self.session.dev) if scene.kind == "glass" else None
        cmd = command_line(scene, cam, stem.with_name(stem.name + "_cli.png"), self.exposure,
                           self.view, spp=frame.target, packed=packed)
        if cmd is not None:
            note = ("" if frame.state == "converged" else f"# saved at {frame.spp} of "
                    f"{frame.target} spp: this renders all {frame.target}\n")
            write_bytes(stem.with_suffix(".sh"), f"#!/bin/sh\n{note}{cmd}\n".encode(), "command")
        self.saved.append((png, cam, cmd))
        print(f"volrender: saved {png} and {cam}" + (f"; the CLI: {cmd}" if cmd else ""),
              file=sys.stderr)
        return png, cam, cmd

    # ---------------------------------------------------------------- running

    def run(self):
        """Render until stop() (or KeyboardInterrupt, which stops the server first)."""
        try:
            self.session.run(self.show, stop=self._stopping.is_set)
        finally:
            self._stop_server()

    def start(self) -> "Viewer":
        self._thread = threading.Thread(target=self._run_in_thread, name="volrender-view",
                                        daemon=True)
        self._thread.start()
        return self

    def _run_in_thread(self):
        try:
            self.run()
        except Exception as exc:           # said once; the server is stopped (run's finally)
            process.say(f"volrender: the viewer stopped: {type(exc).__name__}: {exc}")

    def stop(self):
        """Stop rendering and serving (waits for the step under way)."""
        self._stopping.set()
        self.session.wake()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()
        self._stop_server()

    def _stop_server(self):
        server, self.server = getattr(self, "server", None), None
        if server is not None:
            with contextlib.redirect_stdout(io.StringIO()):   # viser's "Server stopped"
                server.stop()
                thread = getattr(getattr(server, "_websock_server", None), "_server_thread",
                                 None)                        # prints as it ends
                if thread is not None:
                    thread.join(timeout=10)

    def show_inline(self, height=600):
        """Show the viewer in a Jupyter notebook (an IFrame of the URL)."""
        from IPython.display import IFrame, display
        display(IFrame(self.url, width="100%", height=height))

    def __repr__(self):
        return f"<volrender.Viewer {self.url}{' (stopped)' if self.server is None else ''}>"


def _in_notebook() -> bool:
    try:
        from IPython import get_ipython
    except ImportError:
        return False
    shell = get_ipython()
    return shell is not None and hasattr(shell, "kernel")


def view(scene, device=None, *, port=DEFAULT_PORT, host=DEFAULT_HOST, size=None, exposure=0.0,
         tonemap="filmic", save_dir=".", **overrides) -> Viewer:
    """Start the viewer of `scene` (a Scene, or what load_scene takes, with its keywords)
    in a background thread and return it (`.url`, `.stop()`, `.save()`); in Jupyter it
    is shown inline. size: the still image's (default: the scene's; "canvas": the
    browser's)."""
    from . import device as device_mod
    from .scene import Scene
    dev = device_mod.resolve(device)
    if not isinstance(scene, Scene):
        from .scene import request
        scene = request(scene, **overrides).load(device=dev)
    elif overrides:
        scene = scene.replace(**overrides, device=dev)
    v = Viewer(scene, dev, port=port, host=host, size=size, exposure=exposure, view=tonemap,
               save_dir=save_dir).start()
    if _in_notebook():
        v.show_inline()
    return v


# -------------------------------------------------------------------- the command

def cmd_view(args) -> int:
    from .device import resolve
    from .scene import request
    overrides = {k: getattr(args, k) for k in args.render_dests
                 if getattr(args, k, None) is not None}
    import_viser()                        # before the scene is read: the cheap errors first
    check_port(args.host, args.port)
    save_dir = Path(args.save_dir)
    if not save_dir.is_dir():
        raise UserError("the save directory does not exist", path=save_dir,
                        fix="create it or give another --save-dir")
    req = request(args.input, **overrides)
    dev = resolve(args.device)
    scene = req.load(device=dev)
    for note in scene.notes:
        process.say(f"volrender: {note}")
    viewer = Viewer(scene, dev, port=args.port, host=args.host,
                    size=overrides.get("size", "canvas"), exposure=args.exposure,
                    view="standard" if args.tonemap == "clamp" else args.tonemap,
                    save_dir=save_dir)
    print(viewer.url, flush=True)
    print(f"volrender: viewing {args.input} on {dev.name}: open {viewer.url} in a browser "
          f"(from another machine: ssh -N -L {viewer.port}:localhost:{viewer.port} THIS_HOST); "
          "Ctrl-C stops", file=sys.stderr, flush=True)
    # stdout carries the URL only: viser's server thread prints "(viser) Server stopped" as
    # it ends, at times after _stop_server's wait (cli.main gives a Python caller its
    # stdout back)
    sys.stdout = open(os.devnull, "w")
    viewer.run()
    return 0
