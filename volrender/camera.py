"""Pinhole camera (DESIGN.md conventions) and its packing for kernels."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import layout
from .errors import UserError
from .settings import SIZE, VEC3, floats, in_range, knob, one_of, pair, rgb

# Default framing: the camera looks at the bounding box's centre from this direction
# (from the centre towards the camera: in front (+z), a little right and above).
DEFAULT_VIEW = (0.25, 0.35, 1.0)
DEFAULT_FOV = 40.0


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


def frame_bounds(lo, hi, width, height, fov=DEFAULT_FOV, view=DEFAULT_VIEW, up=(0.0, 1.0, 0.0)):
    """Camera looking at the box centre from `view`, at the distance where the box's
    bounding sphere exactly fills the vertical field of view."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-12 * max(1.0, float(np.abs(centre).max())))
    dist = radius / math.sin(math.radians(fov) / 2.0)
    origin = centre + dist * _unit(view, "view")
    return Camera(tuple(origin), tuple(centre), tuple(up), fov, width, height)


def _vec3_or_none(v):
    return None if v is None else rgb(-1e30, 1e30)(v)


UP_AXES = ("auto", "y", "z")


@dataclass(frozen=True)
class View:
    """The camera a user asks for; `camera(lo, hi)` resolves it against the scene's bounds
    (defaults, ranges and CLI/scene names: settings.knob)."""
    size: tuple = knob((640, 480), "image size", metavar="WxH", parse=pair("--size"),
                       toml=("render", "size"), kind=SIZE)
    origin: tuple | None = knob(None, "camera position (default: frame the bounds: look at their "
                                "centre from --azimuth/--elevation at the distance where their "
                                "bounding sphere fills --fov)", metavar="X,Y,Z",
                                parse=floats(3, name="--origin"), check=_vec3_or_none,
                                toml=("camera", "origin"), kind=VEC3, show_default=False)
    target: tuple | None = knob(None, "point looked at (default: the bounds' centre)",
                                metavar="X,Y,Z", parse=floats(3, name="--target"),
                                check=_vec3_or_none, toml=("camera", "target"), kind=VEC3,
                                show_default=False)
    up: tuple | None = knob(None, "camera up vector (default: the up axis)", metavar="X,Y,Z",
                            parse=floats(3, name="--up"), check=_vec3_or_none,
                            toml=("camera", "up"), kind=VEC3, show_default=False)
    fov: float = knob(DEFAULT_FOV, "vertical field of view, degrees", check=in_range(1e-3, 179),
                      toml=("camera", "fov"))

    def __post_init__(self):
        from .settings import check_fields
        check_fields(self)

    def camera(self, lo, hi) -> "Camera":
        """The Camera: origin/target as given, else framing the box lo..hi."""
        up = self.up or (0.0, 1.0, 0.0)
        w, h = self.size
        cam = frame_bounds(lo, hi, w, h, fov=self.fov, up=up)
        if self.origin is not None or self.target is not None:
            cam = Camera(tuple(self.origin or cam.origin), tuple(self.target or cam.target),
                         tuple(up), self.fov, w, h)
        return cam
