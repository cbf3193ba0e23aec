"""Lights (DESIGN.md conventions) and their packing for kernels."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import layout
from .errors import UserError


@dataclass(frozen=True)
class Sun:
    """Directional light: propagation direction (normalised here) and irradiance E on a
    plane perpendicular to it."""
    direction: tuple
    irradiance: float = 1.0
    color: tuple = (1.0, 1.0, 1.0)

    def __post_init__(self):
        d = np.asarray(self.direction, np.float64)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or not np.any(d):
            raise UserError(f"sun direction must be a non-zero finite vector, got {self.direction}")
        if not np.isfinite(self.irradiance) or self.irradiance < 0:
            raise UserError(f"sun irradiance must be finite and >= 0, got {self.irradiance}")
        d = d / np.abs(d).max()             # first: |d|^2 neither overflows nor underflows
        object.__setattr__(self, "direction", tuple(d / np.linalg.norm(d)))


@dataclass(frozen=True)
class PointLight:
    """Point light: position and intensity I; irradiance I / r^2."""
    position: tuple
    intensity: float = 1.0
    color: tuple = (1.0, 1.0, 1.0)

    def __post_init__(self):
        if not np.all(np.isfinite(self.position)) or len(self.position) != 3:
            raise UserError(f"point light position must be 3 finite numbers, got {self.position}")
        if not np.isfinite(self.intensity) or self.intensity < 0:
            raise UserError(f"point light intensity must be finite and >= 0, got {self.intensity}")


MAX_LIGHTS = layout.MAX_LIGHTS    # VR_MAX_LIGHTS in cl/structs.h

# Used when the user gives no light: from above, over the viewer's left shoulder.
DEFAULT_LIGHTS = (Sun((-0.6, -1.0, -0.5), 6.0),)

# The sky volumes get when no --env is given (issue #22; glass has its own procedural one,
# cl/glass.h): radiance from a bright horizon to a blue zenith (glass's colours at
# SKY_SCALE) over a hazy ground, as an equirectangular map turned to the up axis. Its
# irradiance on a horizontal plane is about 0.17 of the default sun's. Fire (a Mantaflow
# cache with flame) gets both at FIRE_LIGHT: dusk, so that its own light dominates.
SKY_SCALE = 0.5
SKY_HORIZON = (0.85, 0.9, 1.0)
SKY_ZENITH = (0.2, 0.4, 0.85)
SKY_GROUND = (0.55, 0.52, 0.48)
SKY_SIZE = (128, 64)
FIRE_LIGHT = 0.1


def sky_texels(up=(0.0, 1.0, 0.0), size=SKY_SIZE, scale=SKY_SCALE) -> np.ndarray:
    """float32 (H, W, 3) equirectangular texels of the default volume sky (cl/env.h's
    convention: row 0 looks along +y, the centre along -z), its zenith along `up`."""
    w, h = size
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(w) + 0.5) / w
    theta, phi = np.pi * v[:, None], (u[None, :] - 0.5) * 2.0 * np.pi
    d = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta) * np.ones_like(phi),
                  -np.sin(theta) * np.cos(phi)], axis=-1)
    up = np.asarray(up, np.float64)
    e = d @ (up / np.linalg.norm(up))
    hor, zen, gnd = (np.asarray(c, np.float64) for c in (SKY_HORIZON, SKY_ZENITH, SKY_GROUND))
    t = np.sqrt(np.clip(e, 0.0, 1.0))[..., None]
    sky = hor + (zen - hor) * t
    g = 1.0 - np.exp(-4.0 * np.clip(-e, 0.0, 1.0))[..., None]
    ground = hor + (gnd - hor) * g
    out = np.where((e >= 0)[..., None], sky, ground) * scale
    return out.astype(np.float32)


GLASS_SKY_SIZE = (1024, 512)


def glass_sky_texels(frame, size=GLASS_SKY_SIZE) -> np.ndarray:
    """float32 (H, W, 3) equirectangular texels of glass's procedural sky (cl/glass.h,
    glass_sky: a horizon-to-zenith gradient over a grey checker ground fading into haze)
    in a world whose frame is `frame` (camera.up_frame: the y-up frame's axes as columns),
    for a z-up world: the kernel's sky is y-up."""
    w, h = size
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(w) + 0.5) / w
    theta, phi = np.pi * v[:, None], (u[None, :] - 0.5) * 2.0 * np.pi
    world = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta) * np.ones_like(phi),
                      -np.sin(theta) * np.cos(phi)], axis=-1)
    d = world @ np.asarray(frame, np.float64)          # frame^T world: the y-up direction
    hor, zen = np.array(SKY_HORIZON), np.array(SKY_ZENITH)
    up = d[..., 1]
    sky = hor + (zen - hor) * np.sqrt(np.clip(up, 0.0, 1.0))[..., None]
    dn = np.maximum(-up, 1e-6)
    q = np.clip(d[..., [0, 2]] / dn[..., None], -1e6, 1e6)
    check = np.abs(np.fmod(np.floor(q[..., 0]) + np.floor(q[..., 1]), 2.0)) > 0.5
    ground = np.where(check[..., None], (0.35, 0.33, 0.3), (0.12, 0.11, 0.1))
    ground = hor + (ground - hor) * (1.0 - np.exp(-12.0 * np.maximum(-up, 0.0)))[..., None]
    return np.where((up >= 0)[..., None], sky, ground).astype(np.float32)


def default_sky(frame=None, dim: float = 1.0) -> np.ndarray:
    """The default volume sky's texels (sky_texels at SKY_SCALE * dim), its zenith along the
    second column of `frame` (camera.up_frame: world from y-up; None: y is up)."""
    up = (0.0, 1.0, 0.0) if frame is None else tuple(frame[:, 1])
    return sky_texels(up, scale=SKY_SCALE * dim)


def default_suns(frame=None, dim: float = 1.0) -> tuple:
    """DEFAULT_LIGHTS turned by `frame` (as default_sky) and dimmed by `dim`."""
    return tuple(Sun(tuple(frame @ np.asarray(l.direction)) if frame is not None
                     else l.direction, l.irradiance * dim, l.color) for l in DEFAULT_LIGHTS)


def counts(lights) -> tuple[int, int]:
    return (sum(isinstance(l, Sun) for l in lights), sum(isinstance(l, PointLight) for l in lights))


def pack(lights, world_to_frame=None):
    """Light structs, suns first; point positions mapped into the render frame. Never
    empty (a zero record stands in when there are no lights)."""
    m = np.eye(4) if world_to_frame is None else np.asarray(world_to_frame, np.float64)
    ordered = [l for l in lights if isinstance(l, Sun)] + [l for l in lights if isinstance(l, PointLight)]
    if len(ordered) > MAX_LIGHTS:
        raise UserError(f"at most {MAX_LIGHTS} lights are supported, got {len(ordered)}")
    out = layout.record("Light", max(1, len(ordered)))
    for i, light in enumerate(ordered):
        if isinstance(light, Sun):
            out[i]["vec"] = [*light.direction, 0.0]
            out[i]["radiance"] = [*(np.asarray(light.color) * light.irradiance), 0.0]
        else:
            pos = m[:3, :3] @ np.asarray(light.position, np.float64) + m[:3, 3]
            out[i]["vec"] = [*pos, 1.0]
            out[i]["radiance"] = [*(np.asarray(light.color) * light.intensity), 0.0]
    return out
