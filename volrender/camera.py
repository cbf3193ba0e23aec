"""Pinhole camera (DESIGN.md conventions) and its packing for kernels."""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import layout
from .atomic import write_bytes
from .errors import UserError
from .files import read_toml
from .settings import NUM, SIZE, VEC3, check_fields, floats, in_range, knob, one_of, pair, rgb

# Default framing: the camera looks at the bounding box's centre from this direction
# (from the centre towards the camera: in front (+z), a little right and above).
DEFAULT_VIEW = (0.25, 0.35, 1.0)
DEFAULT_FOV = 40.0
# The default framing: the content's projected bounds cover this fraction of the frame's
# smaller side at DEFAULT_FOV (a margin of 5% each side), and --fov zooms from there.
DEFAULT_FILL = 0.9


def _unit(v, what):
    v = np.asarray(v, dtype=np.float64)
    n = float(np.linalg.norm(v))
    if not np.isfinite(n) or n == 0.0:
        raise UserError(f"{what} must be a non-zero finite vector, got {tuple(v)}")
    return v / n


@dataclass(frozen=True)
class Camera:
    origin: tuple          # world position of the eye
    target: tuple          # world point looked at
    up: tuple = (0.0, 1.0, 0.0)
    fov: float = DEFAULT_FOV   # vertical field of view, degrees
    width: int = 640       # pixels
    height: int = 480

    def __post_init__(self):
        if not (0.0 < self.fov < 180.0):
            raise UserError(f"--fov must be in (0, 180) degrees, got {self.fov}")
        if self.width < 1 or self.height < 1:
            raise UserError(f"image size must be at least 1x1, got {self.width}x{self.height}")
        fwd = np.subtract(self.target, self.origin)
        _unit(fwd, "the view direction (target - origin)")
        up = _unit(self.up, "--up")
        if np.linalg.norm(np.cross(fwd / np.linalg.norm(fwd), up)) < 1e-6:
            raise UserError("--up is parallel to the view direction; choose another up vector")

    def basis(self):
        """(forward, right, up) world unit vectors."""
        f = _unit(np.subtract(self.target, self.origin), "view direction")
        r = _unit(np.cross(f, self.up), "right")
        return f, r, np.cross(r, f)

    def pixel_vectors(self):
        """(pixel00, du, dv): dir(x, y) = pixel00 + x*du + y*dv, row 0 at the top."""
        f, r, u = self.basis()
        half_h = math.tan(math.radians(self.fov) / 2.0)
        half_w = half_h * self.width / self.height
        pixel00 = f - half_w * r + half_h * u
        return pixel00, (2.0 * half_w / self.width) * r, (-2.0 * half_h / self.height) * u

    def pixel_dirs(self):
        """Unit world direction through each pixel centre, float64 (H, W, 3)."""
        p00, du, dv = self.pixel_vectors()
        x = np.arange(self.width) + 0.5
        y = np.arange(self.height) + 0.5
        d = p00 + x[None, :, None] * du + y[:, None, None] * dv
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def pack(self, world_to_frame=None, spp=1, seed=0):
        """Camera struct; the origin is mapped into the render frame (4x4 affine)."""
        m = np.eye(4) if world_to_frame is None else np.asarray(world_to_frame, np.float64)
        origin = m[:3, :3] @ np.asarray(self.origin, np.float64) + m[:3, 3]
        p00, du, dv = self.pixel_vectors()
        return layout.record("Camera", origin=[*origin, 0.0], pixel00=[*p00, 0.0],
                             du=[*du, 0.0], dv=[*dv, 0.0], width=self.width,
                             height=self.height, spp=spp, seed=seed & 0xFFFFFFFF)


def frame_bounds(lo, hi, width, height, fov=DEFAULT_FOV, view=DEFAULT_VIEW, up=(0.0, 1.0, 0.0),
                 fill=1.0, fit_fov=None, distance=None):
    """Camera looking at the box centre from `view`. Its distance: `distance`, else where the
    box's bounding sphere covers `fill` of the image height at `fit_fov` (default: `fov`;
    fill 1: the sphere exactly fills the vertical field of view)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-12 * max(1.0, float(np.abs(centre).max())))
    dist = distance if distance is not None else framing_distance(radius, fit_fov or fov, fill)
    origin = centre + dist * _unit(view, "view")
    return Camera(tuple(origin), tuple(centre), tuple(up), fov, width, height)


def framing_distance(radius, fov, fill=1.0):
    """Distance at which a sphere of `radius`, centred in view, covers `fill` of the image
    height at vertical field of view `fov`: its silhouette's half-angle a has
    tan(a) = fill * tan(fov / 2), and sin(a) = radius / distance."""
    half = math.radians(fov) / 2.0
    a = half if fill == 1.0 else math.atan(fill * math.tan(half))
    return radius / math.sin(a)


def projected_fill(radius, dist, fov):
    """The fraction of the image height a centred sphere covers (framing_distance's inverse)."""
    return math.tan(math.asin(min(radius / dist, 1.0))) / math.tan(math.radians(fov) / 2.0)


# Options that place the default framing's camera, which an explicit origin replaces, and
# pairs that set the same thing twice: giving both is an error, never a silent choice.
CONFLICTS = (("origin", "azimuth", "--origin places the camera; --azimuth orbits the default framing"),
             ("origin", "elevation", "--origin places the camera; --elevation orbits the default framing"),
             ("origin", "fill", "--origin places the camera; --fill sets the default framing's distance"),
             ("origin", "distance", "--origin places the camera; --distance sets the default framing's"),
             ("fill", "distance", "both set the default framing's distance"))


# the options that only shape the default framing (gone once the camera is resolved)
FRAMING = ("azimuth", "elevation", "fill", "distance")


def check_conflicts(where: dict):
    """Raise UserError for two camera options that conflict. where: {View field: how the
    user wrote it (`--origin`, `cam.toml: [camera].origin`, `origin=`)} of the given ones."""
    for a, b, why in CONFLICTS:
        if a in where and b in where:
            raise UserError(f"{where[a]} and {where[b]} conflict ({why})",
                            fix="give only one of them")


def describe(camera) -> str:
    """One line for -v: origin, target, up, fov, size and the distance."""
    def show(v):                 # 10 digits: survey coordinates keep their centimetres
        return ",".join(f"{float(c):.10g}" for c in v)
    d = float(np.linalg.norm(np.subtract(camera.origin, camera.target)))
    return (f"camera origin {show(camera.origin)} target {show(camera.target)} up {show(camera.up)} "
            f"fov {camera.fov:g} distance {d:g} size {camera.width}x{camera.height}")


def _size(v):
    ok = isinstance(v, tuple) and len(v) == 2 and all(
        isinstance(c, numbers.Integral) and not isinstance(c, bool) and 1 <= c <= 32768 for c in v)
    return None if ok else "must be WxH with integers 1..32768"



def _vec3_or_none(v):
    return None if v is None else rgb(-1e30, 1e30)(v)


UP_AXES = ("auto", "y", "z")
# frame (y up, the default view in front along +z) -> world with z up (Blender): y -> z,
# z -> -y, so the default camera looks from the front (-y), a little right and above
_Y_TO_Z = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def up_frame(axis: str):
    """The rotation from the y-up frame to a world whose up axis is `axis` (None for y)."""
    return _Y_TO_Z if axis == "z" else None


def view_direction(azimuth=None, elevation=None):
    """Direction from the target towards the camera in the y-up frame: DEFAULT_VIEW (not
    normalised), or azimuth (degrees from +z towards +x) and elevation (degrees above the
    horizon), as a unit vector."""
    if azimuth is None and elevation is None:
        return np.asarray(DEFAULT_VIEW, np.float64)
    d = np.asarray(DEFAULT_VIEW, np.float64)
    az = math.degrees(math.atan2(d[0], d[2])) if azimuth is None else azimuth
    el = math.degrees(math.asin(d[1] / np.linalg.norm(d))) if elevation is None else elevation
    a, e = math.radians(az), math.radians(el)
    return np.array([math.sin(a) * math.cos(e), math.sin(e), math.cos(a) * math.cos(e)])


@dataclass(frozen=True)
class View:
    """The camera a user asks for; `camera(lo, hi)` resolves it against the scene's bounds
    (defaults, ranges and CLI/scene names: settings.knob)."""
    size: tuple = knob((640, 480), "image size", metavar="WxH", parse=pair("--size"),
                       toml=("render", "size"), kind=SIZE, check=_size)
    origin: tuple | None = knob(None, "camera position (default: fit the content: seen from "
                                "--azimuth/--elevation, centred, its projected bounds covering "
                                "--fill of the frame's smaller side)", metavar="X,Y,Z",
                                parse=floats(3, name="--origin"), check=_vec3_or_none,
                                toml=("camera", "origin"), kind=VEC3, show_default=False)
    target: tuple | None = knob(None, "point looked at (default: the content's centre in the frame)",
                                metavar="X,Y,Z", parse=floats(3, name="--target"),
                                check=_vec3_or_none, toml=("camera", "target"), kind=VEC3,
                                show_default=False)
    up: tuple | None = knob(None, "camera up vector (default: the up axis)", metavar="X,Y,Z",
                            parse=floats(3, name="--up"), check=_vec3_or_none,
                            toml=("camera", "up"), kind=VEC3, show_default=False)
    fov: float = knob(DEFAULT_FOV, "vertical field of view, degrees: it zooms, from the same "
                      "place (the default framing stands where the content fills 0.9 at 40 "
                      "degrees; --fill fits it to this fov instead)", check=in_range(1e-3, 179),
                      toml=("camera", "fov"))
    fill: float | None = knob(None, "default framing: the fraction of the frame's smaller side "
                              "the content's projected bounds cover at --fov (default: 0.9 at 40 "
                              "degrees, and --fov zooms from there)", check=in_range(1e-3, 1e3, allow_none=True),
                              metavar="F", toml=("camera", "fill"), kind=NUM, show_default=False)
    distance: float | None = knob(None, "default framing: the camera's distance from the target "
                                  "(default: set by --fill; the content stays centred)", check=in_range(1e-20, 1e30, allow_none=True),
                                  metavar="D", toml=("camera", "distance"), kind=NUM,
                                  show_default=False)
    up_axis: str = knob("auto", "the world's up axis: y, z (Blender caches are Z-up), or "
                        "auto: z when the file says Blender wrote it, else y",
                        check=one_of(UP_AXES), choices=UP_AXES, toml=("camera", "up_axis"))
    azimuth: float | None = knob(None, "default framing: orbit around the up axis, degrees "
                                 "from the front towards the right (default: 14.04)",
                                 check=in_range(-1e4, 1e4, allow_none=True), metavar="DEG",
                                 toml=("camera", "azimuth"), kind=NUM, show_default=False)
    elevation: float | None = knob(None, "default framing: degrees above the horizon "
                                   "(default: 18.73)", check=in_range(-89.9, 89.9, allow_none=True),
                                   metavar="DEG", toml=("camera", "elevation"), kind=NUM,
                                   show_default=False)

    def __post_init__(self):
        check_fields(self)
        check_conflicts({f: f"{f}=" for f in ("origin", "azimuth", "elevation", "fill", "distance")
                         if getattr(self, f) is not None})

    def axis(self, hint=None) -> str:
        """The up axis: up_axis, or with "auto" the file's hint (else y)."""
        return self.up_axis if self.up_axis != "auto" else (hint or "y")

    def camera(self, lo, hi, up_hint=None, extent=None) -> "Camera":
        """The Camera: origin/target as given, else framing the content from
        azimuth/elevation around the up axis (up_hint: the file's suggestion for auto):
        `extent` = (points (N, 3), radii) of the content (Content.extent), else the box
        lo..hi; see volrender/framing.py and docs/camera.md."""
        from . import framing
        frame = up_frame(self.axis(up_hint))
        view = view_direction(self.azimuth, self.elevation)
        up = self.up or ((0.0, 1.0, 0.0) if frame is None else tuple(frame[:, 1]))
        view = _unit(view if frame is None else frame @ view, "view")
        w, h = self.size
        if self.origin is not None:
            lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
            return Camera(tuple(self.origin), tuple(self.target or 0.5 * (lo + hi)), tuple(up),
                          self.fov, w, h)
        if self.fill is None:           # fixed place: --fov zooms
            fill, fit = DEFAULT_FILL, DEFAULT_FOV
        else:
            fill, fit = self.fill, self.fov
        points, radii = extent if extent is not None else (framing.box_corners(lo, hi), 0.0)
        points = np.asarray(points, np.float64).reshape(-1, 3)
        if self.target is not None:
            centre = np.asarray(self.target, np.float64)
        else:
            centre = 0.5 * np.add(*framing.box(points))
        f = -view
        r = _unit(np.cross(f, up), "--up")
        basis = (f, r, np.cross(r, f))
        target, dist = framing.fit(points, radii, basis, centre, fit, w, h, fill,
                                   centred=self.target is None, distance=self.distance)
        return Camera(tuple(target + dist * view), tuple(target), tuple(up), self.fov, w, h)


def _num(v):
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) \
        else None


def read_camera_file(path) -> dict:
    """{View field: (value, where)} from a camera file written by write_camera_file (or
    any TOML with [camera] origin/target/up/fov and [render] size)."""
    p = Path(path)
    if not p.is_file():
        raise UserError("no such camera file", path=p, fix="give a file written by --camera-out")
    doc = read_toml(p, "camera file")
    out = {}
    allowed = {"camera": ("origin", "target", "up", "fov"), "render": ("size",)}
    for section, table in doc.items():
        if section not in allowed or not isinstance(table, dict):
            raise UserError(f"unknown section [{section}] in a camera file", path=p,
                            fix="a camera file holds [camera] origin, target, up, fov and [render] size")
        for key, value in table.items():
            where = f"{p}: [{section}].{key}"
            if key not in allowed[section]:
                raise UserError(f"unknown key {where}", fix=f"known keys: {', '.join(allowed[section])}")
            if key == "fov":
                value = _num(value)
            elif key == "size":
                ok = isinstance(value, list) and len(value) == 2 and all(
                    isinstance(v, int) and not isinstance(v, bool) for v in value)
                value = tuple(value) if ok else None
            else:
                ok = isinstance(value, list) and len(value) == 3 and all(_num(v) is not None for v in value)
                value = tuple(float(v) for v in value) if ok else None
            if value is None:
                raise UserError(f"{where} has the wrong type", fix="rewrite it with --camera-out")
            out[key] = (value, where)
    return out


def write_camera_file(camera: "Camera", path) -> Path:
    """Write a camera as TOML (floats exact), atomically; `--camera` reads it back."""
    p = Path(path)
    text = ("# volrender camera: volrender render IN --camera " + p.name + "\n[camera]\n"
            + "".join(f"{k} = [{', '.join(repr(float(v)) for v in getattr(camera, k))}]\n"
                      for k in ("origin", "target", "up"))
            + f"fov = {float(camera.fov)!r}\n\n[render]\nsize = [{camera.width}, {camera.height}]\n")
    return write_bytes(p, text.encode(), "camera file")
