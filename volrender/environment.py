"""The environment (`--env`, shared by glass and volumes): radiance L_env(w) arriving from
world direction w, a uniform R,G,B (a 1x1 map) or an equirectangular map (cl/env.h:
u = 0.5 + atan2(w_x, -w_z) / 2 pi, v = acos(w_y) / pi, bilinear between texel centres)."""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import UserError
from .files import check_memory
from .settings import MAX_VALUE


@dataclass(frozen=True, eq=False)
class Environment:
    """An equirectangular environment: float32 (H, W, 3) radiance; row 0 looks up, the
    image centre looks along -z (cl/env.h). A uniform radiance is a 1x1 map."""
    texels: np.ndarray
    source: str = ""

    @property
    def uniform(self):
        """The radiance (3 floats) when every texel holds the same, else None."""
        t = self.texels.reshape(-1, 3)
        return tuple(float(v) for v in t[0]) if np.all(t == t[0]) else None


def uniform(rgb) -> Environment:
    """A uniform radiance as a 1x1 map."""
    texels = np.asarray(rgb, np.float32).reshape(1, 1, 3)
    return Environment(texels, "uniform " + ",".join(f"{v:g}" for v in rgb))


HDR_SUFFIXES = (".hdr", ".pic", ".rgbe")      # Radiance RGBE


def read_hdr(path) -> np.ndarray:
    """float32 (H, W, 3) radiance of a Radiance RGBE file (.hdr), row 0 the top, through
    OpenImageIO."""
    try:
        import OpenImageIO as oiio
    except ImportError:
        raise UserError("reading a Radiance HDR image needs OpenImageIO, which is not installed",
                        path=path, fix="pip install OpenImageIO, or convert the map to .exr") from None
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        reason = oiio.geterror().strip().splitlines()[-1:] or ["unreadable"]
        raise UserError(f"cannot read the Radiance HDR image ({reason[0]})", path=path,
                        fix="re-export it as .hdr or .exr")
    try:
        spec = inp.spec()
        img = inp.read_image(0, 0, 0, min(spec.nchannels, 3), "float")
        err = inp.geterror()
    finally:
        inp.close()
    if img is None or err or spec.nchannels < 3:
        raise UserError(f"cannot read the Radiance HDR image ({err or 'fewer than 3 channels'})",
                        path=path, fix="re-export it as .hdr or .exr")
    return np.asarray(img, np.float32).reshape(spec.height, spec.width, 3)


def load_environment(path):
    """float32 (H, W, 3) texels of an equirectangular .exr/.npy/.hdr: NaN/Inf and negative
    texels become 0, texels above settings.MAX_VALUE are clamped to it (a warning counts
    them), so every radiance the kernel reads is finite."""
    from .image import read_image
    hdr = Path(path).suffix.lower() in HDR_SUFFIXES
    size = _header_size(path, hdr)
    if size is not None:              # its header's size, before any texel is read
        w, h, nch = size
        check_memory(w * h * (8 * nch + 64), path, f"the {w}x{h} environment map",
                     "give a smaller map (or one whose header is not damaged), or free memory")
    try:
        img = read_hdr(path) if hdr else np.asarray(read_image(path))
    except MemoryError:
        raise UserError("out of host memory while reading the environment map", path=path,
                        fix="give a smaller map, or free memory") from None
    if img.dtype.kind != "f" or img.ndim != 3 or img.shape[2] < 3:
        raise UserError("the environment must be a float image (.exr, .hdr or .npy)", path=path,
                        fix="convert it to an equirectangular .exr or .hdr")
    rgb = img[..., :3].astype(np.float64)
    bad = int(np.count_nonzero(~np.isfinite(rgb) | (rgb < 0) | (rgb > MAX_VALUE)))
    if bad:
        warnings.warn(f"{path}: {bad} environment texel values are NaN/Inf, negative or above "
                      f"{MAX_VALUE:g}; read as 0 (NaN/Inf, negative) or {MAX_VALUE:g}",
                      stacklevel=2)
    rgb = np.clip(np.nan_to_num(rgb, nan=0.0, posinf=0.0, neginf=0.0), 0.0, MAX_VALUE)
    return rgb.astype(np.float32)


def env_mode(environment) -> int:
    """VR_ENV of the volume kernels: 0 none (or black), 1 a uniform radiance, 2 a map."""
    if environment is None or not np.any(environment.texels > 0):
        return 0
    return 1 if environment.uniform is not None else 2


def texels(environment):
    """(float32 (H*W, 4) texels, width, height) for the kernels; a 1-texel stand-in and
    0 x 0 without a map."""
    if environment is None:
        return np.zeros((1, 4), np.float32), 0, 0
    img = environment.texels
    h, w = img.shape[:2]
    tex = np.zeros((h * w, 4), np.float32)
    tex[:, :3] = img.reshape(-1, 3)
    return tex, w, h


def env_weights(texels) -> np.ndarray:
    """Sampling weight per texel: the largest luminance among it and its 8 neighbours
    (wrapping in u), which bounds the bilinear lookup over the texel's cell, so a small
    bright spot is not under-sampled where it bleeds into its neighbours, times
    sin(theta) at the row centre (the solid angle the texel covers)."""
    t = np.asarray(texels, np.float64)
    h = t.shape[0]
    lum = np.maximum(t[..., :3] @ np.array([0.2126, 0.7152, 0.0722]), 0.0)
    m = np.maximum(lum, np.maximum(np.roll(lum, 1, axis=1), np.roll(lum, -1, axis=1)))
    m = np.maximum(m, np.maximum(np.vstack([m[:1], m[:-1]]), np.vstack([m[1:], m[-1:]])))
    return m * np.sin(np.pi * (np.arange(h) + 0.5) / h)[:, None]


def env_distribution(texels) -> np.ndarray:
    """float32 CDFs for cl/env.h vr_env_sample from env_weights: H + 1 row CDF values,
    then per row W + 1 column CDF values. Rows without weight get a uniform column CDF."""
    wts = env_weights(texels)
    h, w = wts.shape
    rows = wts.sum(axis=1)
    total = rows.sum()
    row_cdf = np.concatenate([[0.0], np.cumsum(rows)]) / (total if total > 0 else 1.0)
    row_cdf[-1] = 1.0
    col = np.concatenate([np.zeros((h, 1)), np.cumsum(wts, axis=1)], axis=1)
    col = np.where(rows[:, None] > 0, col / np.where(rows > 0, rows, 1.0)[:, None],
                   np.linspace(0.0, 1.0, w + 1)[None, :])
    col[:, -1] = 1.0
    return np.concatenate([row_cdf, col.ravel()]).astype(np.float32)


def _header_size(path, hdr: bool):
    """(width, height, channels) of an .exr or .hdr map from its header alone; None for a
    .npy (its reader checks its header) or a header that cannot be read (the reader says
    why)."""
    try:
        if hdr:
            import OpenImageIO as oiio
            inp = oiio.ImageInput.open(str(path))
            if inp is None:
                return None
            spec = inp.spec()
            inp.close()
            return spec.width, spec.height, spec.nchannels
        if str(path).lower().endswith(".exr"):
            import OpenEXR
            head = OpenEXR.File(str(path), header_only=True).header()
            lo, hi = head["dataWindow"]
            return int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1), len(head["channels"])
    except Exception:                 # noqa: BLE001 (a damaged header: the reader reports it)
        return None
    return None
