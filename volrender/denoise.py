"""Denoising with Intel Open Image Denoise (pyoidn, the `denoise` extra).

`--denoise auto|on|off`: auto denoises 8-bit outputs (PNG), where grain shows and nobody
composites further, and leaves EXR/NPY as rendered (a compositor, or Blender's Denoise
node, can denoise them with the guide layers the EXR carries); on and off force it. From
Python, render(..., denoise="on") denoises; "auto" is off there, since no output is known.

OIDN's RT filter takes the HDR colour and two guides the kernels write (cl/guide_volume.cl,
cl/guide_glass.cl): albedo in [0, 1] and normals in [-1, 1] (0 where nothing was hit),
both noiseless (guides.SPP rays a pixel: clean_aux, OIDN filters them no further). Alpha is not denoised: it is the render's own.
"""
from __future__ import annotations

import numpy as np

MODES = ("auto", "on", "off")
AUTO_SUFFIXES = (".png",)      # what auto denoises: 8-bit (or 16-bit) display images

_missing = None                # why pyoidn does not import (None: not tried or fine)


def unavailable() -> str | None:
    """None when pyoidn imports, else a one-line reason with the fix."""
    global _missing
    if _missing is None:
        try:
            import pyoidn  # noqa: F401
            _missing = ""
        except Exception as exc:          # ImportError, or a missing shared library (OSError)
            _missing = (f"Open Image Denoise is not available ({type(exc).__name__}: "
                        f"{str(exc).splitlines()[0] if str(exc) else 'no message'}); "
                        "`bash run.sh setup` or `pip install 'volrender[denoise]'` installs it")
    return _missing or None


def decide(mode: str, suffix: str | None) -> tuple[bool, str | None]:
    """(denoise?, a note for stderr or None) for --denoise `mode` and an output `suffix`
    (None: from Python, no output known). auto says what it chose."""
    suffix = (suffix or "").lower()
    if mode == "off":
        return False, None
    if mode == "auto":
        if suffix not in AUTO_SUFFIXES:
            if not suffix:
                return False, None
            return False, (f"denoise auto: {suffix[1:].upper()} written as rendered; "
                           "--denoise on denoises it")
        why = unavailable()
        if why:
            return False, f"denoise auto: the PNG is not denoised: {why}"
        return True, ("denoise auto: the PNG is denoised (Open Image Denoise with the "
                      "render's guides); --denoise off writes it as rendered")
    why = unavailable()
    if why:
        return False, f"--denoise on: not denoised: {why}"
    return True, None


def denoise(rgba, albedo=None, normal=None, quality: str = "high") -> np.ndarray:
    """The RGBA image with its colour denoised by OIDN (RT filter, HDR, `quality`: high,
    balanced or fast; the guides, H x W x 3, clean: see the module docstring); alpha
    unchanged. Negative and non-finite colour values read as 0 (OIDN takes non-negative
    HDR colour)."""
    import pyoidn
    rgba = np.asarray(rgba, np.float32)
    colour = np.nan_to_num(rgba[..., :3], nan=0.0, posinf=0.0, neginf=0.0)
    colour = np.ascontiguousarray(np.maximum(colour, 0.0))
    kw = {}
    if albedo is not None:
        kw["albedo"] = np.ascontiguousarray(np.clip(albedo, 0.0, 1.0), np.float32)
        if normal is not None:        # OIDN takes a normal only beside an albedo
            kw["normal"] = np.ascontiguousarray(np.clip(normal, -1.0, 1.0), np.float32)
        kw["clean_aux"] = True
    out = rgba.copy()
    out[..., :3] = pyoidn.denoise(colour, hdr=True, quality=quality, **kw)
    return out
