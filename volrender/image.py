"""Image output: EXR / NPY / PNG writers, tone mapping, and readers for tests and tools.

Formats (see DESIGN.md, "Outputs"):

- ``.exr``: linear float32 RGBA (channels R, G, B, A), ZIP compression, plus one
  float32 channel per AOV. AOV names map to channel names through ``AOV_CHANNELS``
  (``depth`` -> ``Z``, the name OpenEXR tools use for depth; ``transmittance`` -> ``T``);
  any other AOV name is used as the channel name unchanged.
- ``.npy``: linear float32 ``H x W x 4``.
- ``.png``: tone-mapped sRGB, 8 bits per channel (Pillow, zlib level 1: docs/benchmarks.md) or 16 on request
  (``png_bits=16``, pypng: Pillow writes no 16-bit colour PNGs). Opaque by default
  (``png_alpha='opaque'``: the picture as rendered, background, sky and environment
  included, alpha 1, as Blender's film is unless made transparent); ``'straight'``
  (``--transparent``) keeps straight alpha for compositing, see ``png_pixels``.

All arrays are ``H x W x C`` with the top image row first. Every write goes through
``volrender.atomic`` (a temporary file renamed over the destination once complete), so a
failed or interrupted write never leaves a half-written image and never touches an
existing file.

Long file: the writers, their checks and the PNG's view transforms (their float64
definition, `_codes`, and the table path of float32 renders, `_fast_codes8`) change
together; the tables themselves are in quantise.py.
"""

from __future__ import annotations

import functools
import io
import os
import warnings
from pathlib import Path

import numpy as np

from . import atomic
from .errors import ImageWarning, UserError
from .files import check_input

SUFFIXES = ('.exr', '.npy', '.png')
# View transforms (--view; --tonemap is its older name). 'filmic': volrender's own shoulder
# (below), the default; 'standard' and 'aces' through OpenColorIO's built-in ACES config
# (OCIO_VIEWS); 'agx' through the config $OCIO names (Blender's has it: the built-in
# configs do not); 'clamp': 'standard' computed here exactly (the older name).
VIEWS = ('filmic', 'standard', 'agx', 'aces')
TONEMAPS = VIEWS + ('clamp',)
OCIO_CONFIG = 'cg-config-v2.2.0_aces-v1.3_ocio-v2.4'
OCIO_SOURCE = 'Linear Rec.709 (sRGB)'
OCIO_DISPLAY = 'sRGB - Display'
OCIO_VIEWS = {'standard': 'Un-tone-mapped', 'aces': 'ACES 1.0 - SDR Video'}
OCIO_LARGEST = 65504.0            # inputs are clipped here (half float's largest; ACES's too)
PNG_BITS = (8, 16)
PNG_ALPHAS = ('opaque', 'straight')
AOV_CHANNELS = {'depth': 'Z', 'transmittance': 'T'}
# Layers of several channels (H x W x C): Blender's Denoising Data passes and its noisy
# beauty, as Cycles writes them to a multilayer EXR (without the view-layer prefix), so its
# Denoise node and OIDN's tools find them (volrender.guides).
LAYERS = {'albedo': ('Denoising Albedo', 'RGB'), 'normal': ('Denoising Normal', 'XYZ'),
          'noisy': ('Noisy Image', 'RGBA')}
GUIDE_LAYERS = tuple(LAYERS)
# Z where a ray meets nothing (the render's depth is +inf there): finite, as compositors
# expect (Blender/Cycles write the same 1e10), and named in the header as `depthFar`.
DEPTH_FAR = 1.0e10

# Filmic shoulder: identity up to the knee, then an exponential shoulder that meets the
# line with the same slope (C1) and approaches 1 asymptotically.
_KNEE = 0.5

_PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'


# --------------------------------------------------------------------------- checks

def _aov_channel(name: str) -> str:
    return AOV_CHANNELS.get(name, name)


def _layer_channels(name: str) -> list:
    """The EXR channels of a layer: one (AOV_CHANNELS), or a LAYERS layer's 'Name.R' ..."""
    if name in LAYERS:
        layer, parts = LAYERS[name]
        return [f"{layer}.{c}" for c in parts]
    return [_aov_channel(name)]


def check_output(path, aovs=(), create: bool = False) -> Path:
    """Validate an output path before a render starts; return the file a write replaces
    (absolute, symlinks followed: see ``atomic.destination``).

    Checks that the suffix is one of ``SUFFIXES``, that the parent directory exists and
    is writable (with ``create``: that the folders missing above it can be made there), that ``path`` is no directory, FIFO, device, symlink loop or read-only
    file, and that AOVs (extra layers such as ``'depth'``, ``'transmittance'``; names or a
    dict keyed by name) are only asked of ``.exr`` and map to distinct channels other
    than R, G, B, A. Raises ``UserError``.
    """
    shown = Path(path)
    suffix = shown.suffix.lower()
    if suffix not in SUFFIXES:
        raise UserError(f"unsupported image format {shown.suffix or '(no suffix)'!r}", path=path,
                        fix=f"use one of {', '.join(SUFFIXES)}")
    out = atomic.destination(path)
    parent = out.parent
    if create and not parent.exists():       # made by the write: check where it would go
        parent = next(p for p in parent.parents if p.exists())
    if not parent.is_dir():
        raise UserError(f"output directory {str(out.parent)!r} does not exist", path=out,
                        fix=f"create it first (mkdir -p {out.parent})")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UserError(f"output directory {str(parent)!r} is not writable", path=out,
                        fix="choose another directory or fix its permissions")
    names = [aovs] if isinstance(aovs, str) else list(aovs or ())
    if names and suffix != '.exr':
        raise UserError(f"extra layers ({', '.join(map(str, names))}) need an .exr output",
                        path=out, fix=f"write to {out.with_suffix('.exr').name} or drop the layers")
    channels = [c for n in names for c in _layer_channels(str(n))]
    for name, channel in zip([n for n in names for _ in _layer_channels(str(n))], channels):
        if channel in ('R', 'G', 'B', 'A') or channels.count(channel) > 1:
            raise UserError(f"layer {name!r} would be EXR channel {channel!r}, which is taken",
                            path=out, fix="rename the layer")
    return out


# ----------------------------------------------------------------------- tone mapping

def _filmic(x):
    """Shoulder curve: ``x`` below the knee k=0.5, else ``k + (1-k)(1 - exp(-(x-k)/(1-k)))``.

    Continuous with continuous slope at the knee, strictly increasing, 0 -> 0, +inf -> 1,
    below 1 for every finite input. Leaves mid-tones untouched; compresses highlights.
    """
    x = np.asarray(x, dtype=np.float64)
    over = np.maximum(x - _KNEE, 0.0)
    shoulder = _KNEE + (1.0 - _KNEE) * -np.expm1(-over / (1.0 - _KNEE))
    return np.where(x <= _KNEE, x, shoulder)


def _srgb_oetf(v):
    """Exact sRGB encoding of linear values in [0, 1] (IEC 61966-2-1, piecewise)."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v <= 0.0031308, 12.92 * v,
                    1.055 * np.power(np.maximum(v, 0.0031308), 1.0 / 2.4) - 0.055)


def _check_tonemap(tonemap: str) -> None:
    if tonemap not in TONEMAPS:
        raise UserError(f"unknown view transform {tonemap!r}", fix=f"use one of {', '.join(VIEWS)}")


def check_view(view: str) -> None:
    """Refuse an unknown view, or one OpenColorIO cannot provide here, before a render
    starts (UserError)."""
    _check_tonemap(view)
    if view not in ('filmic', 'clamp'):
        ocio_processor(view)


_PROCESSORS = {}


def ocio_processor(view: str):
    """OpenColorIO's CPU processor from linear Rec.709 to sRGB display codes (0..1) for
    `view`: 'standard' and 'aces' from the built-in config OCIO_CONFIG, 'agx' from the
    config $OCIO names (its display's 'AgX' view, from its scene_linear role)."""
    if view in _PROCESSORS:
        return _PROCESSORS[view]
    try:
        import PyOpenColorIO as ocio
    except ImportError as exc:
        raise UserError(f"the view {view!r} needs OpenColorIO ({exc})",
                        fix="pip install opencolorio (bash run.sh setup installs it)") from None
    if view == 'agx':
        path = os.environ.get('OCIO')
        if not path:
            raise UserError("the view 'agx' is in none of OpenColorIO's built-in configs",
                            fix="point $OCIO at a config that has it (Blender's: "
                                "datafiles/colormanagement/config.ocio), or use filmic, "
                                "standard or aces")
        try:
            cfg = ocio.Config.CreateFromFile(path)
            display = cfg.getDefaultDisplay()
            name = next((v for v in cfg.getViews(display) if v.lower() == 'agx'), None)
            if name is None:
                raise UserError(f"the OpenColorIO config has no AgX view on display {display!r}",
                                path=path, fix="use Blender's config.ocio")
            proc = cfg.getProcessor(ocio.ROLE_SCENE_LINEAR, display, name,
                                    ocio.TRANSFORM_DIR_FORWARD)
        except ocio.Exception as exc:
            raise UserError(f"OpenColorIO cannot use it ({exc})", path=path,
                            fix="point $OCIO at a valid config") from None
    else:
        cfg = ocio.Config.CreateFromBuiltinConfig(OCIO_CONFIG)
        proc = cfg.getProcessor(ocio.DisplayViewTransform(src=OCIO_SOURCE, display=OCIO_DISPLAY,
                                                          view=OCIO_VIEWS[view]))
    _PROCESSORS[view] = proc.getDefaultCPUProcessor()
    return _PROCESSORS[view]


def _ocio_codes(x, view):
    """Display codes in [0, 1] of linear values >= 0 (last axis R, G, B; any other shape
    is grey) through OpenColorIO."""
    grey = x.shape[-1:] != (3,)
    rgb = np.repeat(x[..., None], 3, axis=-1) if grey else x
    flat = np.ascontiguousarray(np.minimum(rgb, OCIO_LARGEST), np.float32).reshape(-1, 3)
    ocio_processor(view).applyRGB(flat)
    out = np.clip(flat.reshape(rgb.shape).astype(np.float64), 0.0, 1.0)
    return out[..., 0] if grey else out


def to_srgb(rgb, exposure: float = 0.0, tonemap: str = 'filmic', bits: int = 8) -> np.ndarray:
    """Linear values -> sRGB codes of `bits` (8: uint8, 16: uint16), same shape.

    Multiplies by ``2**exposure``, clips negatives to 0, applies the view transform
    ``tonemap`` (``'filmic'``: identity up to 0.5, then a smooth exponential shoulder
    towards 1, see ``_filmic``, then the exact sRGB OETF; ``'clamp'``: clip to 1, then the
    OETF; ``'standard'``, ``'aces'``, ``'agx'``: OpenColorIO, see ``ocio_processor``,
    clipped to 0..1), and rounds to the nearest code (``_codes``: the definition, in
    float64). float32 values to 8 bits take a table of the definition's thresholds
    (volrender/quantise.py), with the same codes.
    NaN becomes 0 and +Inf white, with a ``RuntimeWarning`` naming how many values were
    not finite.
    """
    _check_tonemap(tonemap)
    if not np.isfinite(exposure):
        raise ValueError(f"exposure must be finite, got {exposure!r}")
    if bits not in PNG_BITS:
        raise ValueError(f"bits must be one of {PNG_BITS}, got {bits!r}")
    x = np.asarray(rgb)
    if x.dtype != np.float32:
        x = np.asarray(x, np.float64)
    bad = x.size - np.count_nonzero(np.isfinite(x))
    if bad:
        warnings.warn(f"{bad} non-finite value(s) in the image: NaN written as 0, "
                      "+Inf as white, -Inf as 0", RuntimeWarning, stacklevel=2)
    if bits == 8 and x.dtype == np.float32:
        fast = _fast_codes8(x, float(exposure), tonemap, bad > 0)
        if fast is not None:
            return fast
    return _codes(x, exposure, tonemap, bits)


def _codes(rgb, exposure, tonemap, bits) -> np.ndarray:
    """to_srgb's definition, in float64 (no checks, no warning)."""
    x = np.asarray(rgb, dtype=np.float64)
    with np.errstate(over='ignore'):
        x = x * 2.0 ** exposure  # finite values that overflow here become white, unwarned
    x = np.nan_to_num(x, nan=0.0, posinf=np.inf, neginf=0.0)
    x = np.maximum(x, 0.0)
    top = (1 << bits) - 1
    if tonemap in ('filmic', 'clamp'):
        x = _filmic(x) if tonemap == 'filmic' else np.minimum(x, 1.0)
        x = np.minimum(x, 1.0)  # +Inf under 'filmic' is exactly 1 already; keep it safe
        codes = _srgb_oetf(x)
    else:
        codes = _ocio_codes(x, tonemap)
    return np.floor(codes * top + 0.5).astype(np.uint8 if bits == 8 else np.uint16)


def _round8(v):
    """The 8-bit code of display values v (float32, OpenColorIO's output): as _ocio_codes
    and _codes round them."""
    return np.floor(np.clip(np.asarray(v, np.float64), 0.0, 1.0) * 255 + 0.5)


@functools.lru_cache(maxsize=16)
def _table8(tonemap: str, exposure: float):
    """quantise.table of _codes at 8 bits for a per-value view (filmic, clamp) and
    exposure, or of _round8 (tonemap None); None where no table fits."""
    from . import quantise
    if tonemap is None:
        cuts = quantise.thresholds(_round8)
    else:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            cuts = quantise.thresholds(lambda v: _codes(v, exposure, tonemap, 8))
    return quantise.table(cuts)


def _fast_codes8(x, exposure, tonemap, nan):
    """_codes(x, exposure, tonemap, 8) of float32 x through quantise tables; None where
    it does not apply (OpenColorIO views of grey values, or no table fits)."""
    from . import quantise
    if tonemap in ('filmic', 'clamp'):
        tab = _table8(tonemap, exposure)
        return None if tab is None else quantise.apply(x, *tab, nan=nan)
    if x.shape[-1:] != (3,) or _table8(None, 0.0) is None:
        return None
    shape = x.shape
    x = x[None] if x.ndim == 1 else x
    y = np.empty(x.shape, np.float32)       # what _ocio_codes hands OpenColorIO, exactly
    flat = y.reshape(-1, 3)
    proc = ocio_processor(tonemap)

    def run(r0, r1):
        part = y[r0:r1]
        with np.errstate(over='ignore', invalid='ignore'):
            part[...] = x[r0:r1] if exposure == 0.0 else \
                np.asarray(x[r0:r1], np.float64) * 2.0 ** exposure
        if nan:
            np.nan_to_num(part, copy=False, nan=0.0, posinf=np.inf, neginf=0.0)
        np.clip(part, 0.0, OCIO_LARGEST, out=part)
        proc.applyRGB(flat[r0 * per:r1 * per])      # per pixel: any split gives the same

    per = x[0].size // 3
    quantise.in_blocks(run, len(x), x[0].size)
    return quantise.apply(y, *_table8(None, 0.0), nan=False).reshape(shape)


def to_srgb8(rgb, exposure: float = 0.0, tonemap: str = 'filmic') -> np.ndarray:
    """`to_srgb` with 8-bit codes."""
    return to_srgb(rgb, exposure, tonemap, 8)


def png_pixels(rgba, exposure=0.0, tonemap='filmic', bits=8, background=None,
               alpha='straight') -> np.ndarray:
    """The PNG's H x W x 4 codes (uint8 or uint16) of a premultiplied linear render.

    alpha='opaque': the render's RGB as it is (what the picture shows: the background,
    sky and environment composited behind), tone-mapped and sRGB-encoded, alpha 1.
    alpha='straight' (below): for compositing.

    Alpha is the render's alpha, linear. The colour is straight: the covering part of the
    pixel, (RGB - (1 - alpha) * background) / alpha, tone-mapped and sRGB-encoded, where
    `background` is the radiance the render composited behind (a volume's --background;
    None = 0, as for glass, whose sky is not known per pixel here). Where alpha is 0 the
    colour is the render's RGB as it is, i.e. what lies behind (the background, the sky
    or environment), so a viewer that ignores alpha still shows the whole picture. Light
    with no opacity (emission where the density is 0) cannot be expressed with straight
    alpha: it survives in EXR/NPY only.

    A float32 render keeps its values (to_srgb's fast path); with straight alpha the
    colour is computed in float64 and rounded to float32 for 8 bits, which moves a code by
    at most 1 where it lies on a threshold.
    """
    if alpha not in PNG_ALPHAS:
        raise ValueError(f"alpha must be one of {PNG_ALPHAS}, got {alpha!r}")
    rgba = np.asarray(rgba)
    single = rgba.dtype == np.float32 and bits == 8
    rgba = rgba if single else np.asarray(rgba, np.float64)
    top = (1 << bits) - 1
    if alpha == 'opaque':
        out = np.empty(rgba.shape[:2] + (4,), np.uint8 if bits == 8 else np.uint16)
        out[..., :3] = to_srgb(rgba[..., :3], exposure, tonemap, bits)
        out[..., 3] = top
        return out
    out = np.empty(rgba.shape[:2] + (4,), np.uint8 if bits == 8 else np.uint16)
    if not single:
        colour, out[..., 3] = _straight(np.asarray(rgba, np.float64), background, top)
        out[..., :3] = to_srgb(colour, exposure, tonemap, bits)
        return out
    from . import quantise
    colour = np.empty(rgba.shape[:2] + (3,), np.float32)

    def run(r0, r1):                    # float64 a block at a time, on the pool's threads
        c, out[r0:r1, :, 3] = _straight(np.asarray(rgba[r0:r1], np.float64), background, top)
        colour[r0:r1] = np.minimum(c, float(np.finfo(np.float32).max))  # finite stays finite
    quantise.in_blocks(run, len(rgba), rgba[0].size)
    out[..., :3] = to_srgb(colour, exposure, tonemap, bits)
    return out


def _straight(rgba, background, top):
    """png_pixels' straight colour (float64) and alpha codes of float64 pixels."""
    rgb, alpha = rgba[..., :3], rgba[..., 3]
    a = np.where(np.isfinite(alpha), np.clip(alpha, 0.0, 1.0), 1.0)
    covered = a > 0
    colour = rgb.copy()
    if np.any(covered):
        part = rgb
        if background is not None:
            part = rgb - (1.0 - a)[..., None] * np.asarray(background, np.float64)[:3]
        with np.errstate(over='ignore', invalid='ignore', divide='ignore'):
            straight = part / np.where(covered, a, 1.0)[..., None]
        colour = np.where(covered[..., None], straight, rgb)
    return colour, np.floor(a * top + 0.5)


# ---------------------------------------------------------------------------- writers

def camera_attributes(camera) -> dict:
    """EXR header attributes of the camera that made an image: OpenEXR's standard
    `worldToCamera` (Imath row-vector convention: [x y z 1] @ M; camera space x right, y
    up, +z the view direction, as RenderMan's) and volrender's own origin, target, up and
    vertical fov (degrees), which `volrender render --camera` can read back."""
    f, r, u = camera.basis()
    o = np.asarray(camera.origin, np.float64)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = r, u, f
    m[3, :3] = -o @ m[:3, :3]
    return {'worldToCamera': m.astype(np.float32),
            'volrender:origin': np.asarray(camera.origin, np.float32),
            'volrender:target': np.asarray(camera.target, np.float32),
            'volrender:up': np.asarray(camera.up, np.float32),
            'volrender:fov': float(camera.fov)}


def exr_threads() -> int:
    """Let OpenEXR compress on every core this process may use (its default is none; the
    bytes written are the same for any count)."""
    import OpenEXR          # here, not at the top: a PNG or NPY command need not load it
    if OpenEXR.global_thread_count() == 0:
        try:
            n = len(os.sched_getaffinity(0))
        except AttributeError:
            n = os.cpu_count() or 1
        OpenEXR.set_global_thread_count(max(1, n))
    return OpenEXR.global_thread_count()


def _write_exr(f, rgba, channels: dict, options: dict) -> None:
    import OpenEXR
    exr_threads()
    # The bindings read the raw buffer and ignore strides: pass C-contiguous arrays only.
    pixels = {'RGBA': np.ascontiguousarray(rgba, dtype=np.float32)}
    for name, data in channels.items():
        data = np.ascontiguousarray(data, dtype=np.float32)
        if name == 'Z':
            data = np.where(np.isposinf(data), np.float32(DEPTH_FAR), data)
        pixels[name] = data
    # A fresh header each time: the constructor adds dataWindow/displayWindow to it.
    header = {'compression': OpenEXR.ZIP_COMPRESSION, 'type': OpenEXR.scanlineimage}
    if 'Z' in pixels:
        header['depthFar'] = float(DEPTH_FAR)
    if options.get('camera') is not None:
        header.update(camera_attributes(options['camera']))
    try:
        OpenEXR.File(header, pixels).write(f)     # a file object: any path, any encoding
    except RuntimeError as e:  # the library's I/O errors (disk full, permissions)
        raise OSError(str(e)) from e


def _write_npy(f, rgba, channels: dict, options: dict) -> None:
    np.save(f, np.ascontiguousarray(rgba, dtype=np.float32), allow_pickle=False)


def _write_png(f, rgba, channels: dict, options: dict) -> None:
    bits = options.get('png_bits', 8)
    px = png_pixels(rgba, options.get('exposure', 0.0), options.get('tonemap', 'filmic'), bits,
                    options.get('background'), options.get('png_alpha', 'opaque'))
    h, w = px.shape[:2]
    if bits == 8:
        from PIL import Image as PILImage
        from PIL import PngImagePlugin
        info = PngImagePlugin.PngInfo()
        info.add(b'sRGB', b'\x00')                  # sRGB, perceptual intent
        PILImage.fromarray(px, 'RGBA').save(f, format='PNG', pnginfo=info, compress_level=1)
    else:
        import png                                  # pypng: 16-bit colour PNGs
        png.Writer(w, h, greyscale=False, alpha=True, bitdepth=16, compression=6).write(
            f, px.reshape(h, w * 4))


# suffix -> writer(file object, rgba, channels, options)
_WRITERS = {'.exr': _write_exr, '.npy': _write_npy, '.png': _write_png}


def write_image(path, rgba, aovs=None, *, exposure: float = 0.0, tonemap: str = 'filmic',
                camera=None, png_bits: int = 8, background=None,
                png_alpha: str = 'opaque') -> Path:
    """Write a rendered image atomically; return the file written (symlinks followed).

    ``rgba``: float ``H x W x 4``, linear, premultiplied, row 0 = top of the image.
    ``aovs``: optional dict of layer name -> ``H x W`` float array, ``.exr`` only (channel
    names: ``AOV_CHANNELS``). ``exposure``, ``tonemap``, ``png_bits`` (8 or 16) and
    ``background`` (the radiance composited behind, see ``png_pixels``) and ``png_alpha``
    (``'opaque'``, the default, or ``'straight'``) apply to ``.png`` only. ``.exr`` and ``.npy`` store the linear values untouched (NaN/Inf too),
    except the EXR's ``Z`` where nothing was hit (+inf): ``DEPTH_FAR`` (1e10), also in the
    header as ``depthFar``.
    ``camera``: a camera.Camera recorded in the EXR header (``camera_attributes``).

    Raises ``UserError`` for a bad path or a failed write (disk full, permissions); on any
    failure or interruption an existing file at ``path`` is left untouched and no
    temporary file remains (``volrender.atomic``).
    """
    aovs = dict(aovs or {})
    out = check_output(path, aovs, create=True)
    _check_tonemap(tonemap)
    if png_bits not in PNG_BITS:
        raise UserError(f"PNG bit depth {png_bits!r} is not supported", fix="use 8 or 16")
    if png_alpha not in PNG_ALPHAS:
        raise UserError(f"PNG alpha {png_alpha!r} is not supported",
                        fix=f"use one of {', '.join(PNG_ALPHAS)}")
    rgba = np.asarray(rgba)
    if rgba.ndim != 3 or rgba.shape[2] != 4 or rgba.shape[0] < 1 or rgba.shape[1] < 1:
        raise ValueError(f"rgba must be H x W x 4 with H, W >= 1, got shape {rgba.shape}")
    channels = {}
    for name, data in aovs.items():
        data = np.asarray(data)
        if data.ndim == 3 and data.shape[2] == 1:
            data = data[..., 0]
        names_ = _layer_channels(name)
        want = rgba.shape[:2] + ((len(names_),) if name in LAYERS else ())
        if data.shape != want:
            raise ValueError(f"layer {name!r} has shape {data.shape}, expected {want}")
        if name in LAYERS:
            for i, channel in enumerate(names_):
                channels[channel] = data[..., i]
        else:
            channels[_aov_channel(name)] = data
    options = dict(exposure=exposure, tonemap=tonemap, camera=camera, png_bits=png_bits,
                   background=background, png_alpha=png_alpha)
    if not out.parent.exists():                  # as sequences do: -o new/x.png
        try:
            out.parent.mkdir(parents=True)
        except OSError as exc:
            raise UserError(f"cannot create the output folder ({exc.strerror or exc})",
                            path=out.parent, fix="write somewhere you can") from None
    if png_alpha == 'straight' and out.suffix.lower() == '.png':
        _warn_if_invisible(rgba, png_bits)
    with atomic.replace(out, "image") as f:
        _WRITERS[out.suffix.lower()](f, rgba, channels, options)
    return out


def _warn_if_invisible(rgba, bits):
    """A straight-alpha PNG whose alpha rounds to at most 2 codes where light was rendered
    (fire, whose emission has almost no opacity): viewers show it (nearly) invisible."""
    a = np.asarray(rgba[..., 3], np.float64)
    lit = np.nan_to_num(np.asarray(rgba[..., :3], np.float64)).max(axis=-1) > 1e-3
    top = (1 << bits) - 1
    if lit.any():
        most = float(np.nanmax(np.clip(a[lit], 0.0, 1.0)))
        if np.floor(most * top + 0.5) <= 2 * (top // 255):
            warnings.warn(f"the transparent PNG's alpha is at most {most:.2g} where the image "
                          "has light (emission with almost no opacity, as fire): viewers will "
                          "show it (nearly) invisible; drop --transparent for the opaque picture, "
                          "or write .exr", ImageWarning, stacklevel=3)


# ---------------------------------------------------------------------------- readers

def read_exr_channels(path) -> dict[str, np.ndarray]:
    """Every channel of an EXR file (first part) by name, as ``H x W`` arrays."""
    import OpenEXR
    path = check_input(path, "image")
    try:
        with open(path, 'rb') as fh:            # a file object: any path, any encoding
            f = OpenEXR.File(io.BytesIO(fh.read()), separate_channels=True)
            return {name: ch.pixels for name, ch in f.channels().items()}
    except (RuntimeError, ValueError) as e:     # a damaged file: no parts, bad chunks
        raise UserError(f"not a readable OpenEXR file ({e})", path=path,
                        fix="re-export it as OpenEXR") from e


def _read_png(path: Path) -> np.ndarray:
    """H x W x 4 codes of a PNG (uint8, or uint16 for a 16-bit file), any colour type."""
    from PIL import Image as PILImage
    with open(path, 'rb') as fh:
        blob = fh.read()
    if not blob.startswith(_PNG_SIGNATURE):
        raise UserError("not a PNG file", path=path, fix="re-render it")
    try:
        if len(blob) > 24 and blob[12:16] == b'IHDR' and blob[24] == 16:
            import png                          # Pillow reads 16-bit colour as 8 bits
            w, h, rows, info = png.Reader(bytes=blob).asRGBA()
            return np.vstack([np.asarray(r, np.uint16) for r in rows]).reshape(h, w, 4)
        with PILImage.open(io.BytesIO(blob)) as im:
            im.load()
            return np.asarray(im.convert('RGBA'))
    except Exception as e:                      # Pillow and pypng raise many kinds
        raise UserError(f"corrupt PNG ({type(e).__name__}: {e})", path=path,
                        fix="re-render it") from None


def read_image(path) -> np.ndarray:
    """Read an image: ``H x W x 4`` float32 for .exr/.npy, ``H x W x 4`` uint8 (uint16
    for 16-bit files) sRGB codes (opaque, or straight alpha) for .png.

    An EXR without an A channel reads with alpha 1.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise UserError(f"unsupported image format {path.suffix or '(no suffix)'!r}",
                        path=path, fix=f"use one of {', '.join(SUFFIXES)}")
    path = check_input(path, "image")
    if suffix == '.png':
        return _read_png(path)
    if suffix == '.npy':
        from .points import load_npy_checked
        arr = load_npy_checked(path, "re-render it")
    else:
        ch = read_exr_channels(path)
        if not all(c in ch for c in 'RGB'):
            raise UserError(f"EXR has no R, G, B channels (has {', '.join(ch)})", path=path,
                            fix="use read_exr_channels for other layouts")
        alpha = ch['A'] if 'A' in ch else np.ones_like(ch['R'], dtype=np.float32)
        arr = np.stack([ch['R'], ch['G'], ch['B'], alpha], axis=-1)
    if arr.ndim != 3 or arr.shape[2] != 4:
        raise UserError(f"expected an H x W x 4 image, got shape {arr.shape}", path=path,
                        fix="re-render it")
    return arr.astype(np.float32, copy=False)
