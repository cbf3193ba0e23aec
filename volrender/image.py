"""Image output: EXR / NPY / PNG writers, tone mapping, and readers for tests and tools.

Formats (see DESIGN.md, "Outputs"):

- ``.exr``: linear float32 RGBA (channels R, G, B, A), ZIP compression, plus one
  float32 channel per AOV. AOV names map to channel names through ``AOV_CHANNELS``
  (``depth`` -> ``Z``, the name OpenEXR tools use for depth; ``transmittance`` -> ``T``);
  any other AOV name is used as the channel name unchanged.
- ``.npy``: linear float32 ``H x W x 4``.
- ``.png``: tone-mapped 8-bit sRGB, RGB only (see ``to_srgb8``).

All arrays are ``H x W x C`` with the top image row first. Every write goes to a
temporary file in the destination directory and is renamed over the destination only
once complete, so a failed write never leaves a half-written image and never touches an
existing file.
"""

from __future__ import annotations

import os
import secrets
import struct
import warnings
import zlib
from pathlib import Path

import numpy as np
import OpenEXR

from .errors import UserError

SUFFIXES = ('.exr', '.npy', '.png')
TONEMAPS = ('filmic', 'clamp')
AOV_CHANNELS = {'depth': 'Z', 'transmittance': 'T'}

# Filmic shoulder: identity up to the knee, then an exponential shoulder that meets the
# line with the same slope (C1) and approaches 1 asymptotically.
_KNEE = 0.5

_PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'


# --------------------------------------------------------------------------- checks

def _aov_channel(name: str) -> str:
    return AOV_CHANNELS.get(name, name)


def check_output(path, aovs=()) -> Path:
    """Validate an output path before a render starts; return it resolved.

    Checks that the suffix is one of ``SUFFIXES``, that the parent directory exists and
    is writable, that ``path`` is not a directory, and that AOVs (extra layers such as
    ``'depth'``, ``'transmittance'``; names or a dict keyed by name) are only asked of
    ``.exr`` and map to distinct channels other than R, G, B, A. Raises ``UserError``.
    """
    out = Path(path).expanduser().resolve()
    suffix = out.suffix.lower()
    if suffix not in SUFFIXES:
        raise UserError(f"unsupported image format {out.suffix or '(no suffix)'!r}", path=out,
                        fix=f"use one of {', '.join(SUFFIXES)}")
    parent = out.parent
    if not parent.is_dir():
        raise UserError(f"output directory {str(parent)!r} does not exist", path=out,
                        fix=f"create it first (mkdir -p {parent})")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UserError(f"output directory {str(parent)!r} is not writable", path=out,
                        fix="choose another directory or fix its permissions")
    if out.is_dir():
        raise UserError("output path is a directory", path=out, fix="give a file name")
    names = [aovs] if isinstance(aovs, str) else list(aovs or ())
    if names and suffix != '.exr':
        raise UserError(f"extra layers ({', '.join(map(str, names))}) need an .exr output",
                        path=out, fix=f"write to {out.with_suffix('.exr').name} or drop the layers")
    channels = [_aov_channel(str(n)) for n in names]
    for name, channel in zip(names, channels):
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
        raise UserError(f"unknown tone map {tonemap!r}", fix=f"use one of {', '.join(TONEMAPS)}")


def to_srgb8(rgb, exposure: float = 0.0, tonemap: str = 'filmic') -> np.ndarray:
    """Linear values -> 8-bit sRGB codes (same shape, uint8).

    Multiplies by ``2**exposure``, clips negatives to 0, applies ``tonemap`` (``'filmic'``:
    identity up to 0.5, then a smooth exponential shoulder towards 1, see ``_filmic``;
    ``'clamp'``: clip to 1), then the exact sRGB
    OETF, and rounds to the nearest code. NaN becomes 0 and +Inf white, with a
    ``RuntimeWarning`` naming how many values were not finite.
    """
    _check_tonemap(tonemap)
    if not np.isfinite(exposure):
        raise ValueError(f"exposure must be finite, got {exposure!r}")
    x = np.asarray(rgb, dtype=np.float64)
    bad = np.count_nonzero(~np.isfinite(x))
    x = x * 2.0 ** exposure  # finite values that overflow here become white, unwarned
    if bad:
        warnings.warn(f"{bad} non-finite value(s) in the image: NaN written as 0, "
                      "+Inf as white, -Inf as 0", RuntimeWarning, stacklevel=2)
        x = np.nan_to_num(x, nan=0.0, posinf=np.inf, neginf=0.0)
    x = np.maximum(x, 0.0)
    x = _filmic(x) if tonemap == 'filmic' else np.minimum(x, 1.0)
    x = np.minimum(x, 1.0)  # +Inf under 'filmic' is exactly 1 already; keep it safe
    return np.floor(_srgb_oetf(x) * 255.0 + 0.5).astype(np.uint8)


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


def _write_exr(tmp: str, rgba, channels: dict, exposure, tonemap, camera=None) -> None:
    # The bindings read the raw buffer and ignore strides: pass C-contiguous arrays only.
    pixels = {'RGBA': np.ascontiguousarray(rgba, dtype=np.float32)}
    for name, data in channels.items():
        pixels[name] = np.ascontiguousarray(data, dtype=np.float32)
    # A fresh header each time: the constructor adds dataWindow/displayWindow to it.
    header = {'compression': OpenEXR.ZIP_COMPRESSION, 'type': OpenEXR.scanlineimage}
    if camera is not None:
        header.update(camera_attributes(camera))
    try:
        OpenEXR.File(header, pixels).write(tmp)
    except RuntimeError as e:  # the library's I/O errors (disk full, permissions)
        raise OSError(str(e)) from e


def _write_npy(tmp: str, rgba, channels: dict, exposure, tonemap, camera=None) -> None:
    with open(tmp, 'wb') as f:
        np.save(f, np.ascontiguousarray(rgba, dtype=np.float32), allow_pickle=False)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return (struct.pack('>I', len(data)) + kind + data
            + struct.pack('>I', zlib.crc32(kind + data) & 0xFFFFFFFF))


def _encode_png(rgb8) -> bytes:
    """Encode an ``H x W x 3`` uint8 sRGB array as PNG (8-bit RGB, filter type 0)."""
    rgb8 = np.ascontiguousarray(rgb8, dtype=np.uint8)
    h, w, _ = rgb8.shape
    rows = np.zeros((h, 1 + 3 * w), dtype=np.uint8)  # leading 0 per row: filter "None"
    rows[:, 1:] = rgb8.reshape(h, 3 * w)
    ihdr = struct.pack('>IIBBBBB', w, h, 8, 2, 0, 0, 0)  # 8-bit, truecolour, no interlace
    return (_PNG_SIGNATURE
            + _png_chunk(b'IHDR', ihdr)
            + _png_chunk(b'sRGB', b'\x00')                     # sRGB, perceptual intent
            + _png_chunk(b'gAMA', struct.pack('>I', 45455))    # companion per the PNG spec
            + _png_chunk(b'IDAT', zlib.compress(rows.tobytes(), 6))
            + _png_chunk(b'IEND', b''))


def _write_png(tmp: str, rgba, channels: dict, exposure: float, tonemap: str, camera=None) -> None:
    data = _encode_png(to_srgb8(rgba[..., :3], exposure, tonemap))
    with open(tmp, 'wb') as f:
        f.write(data)


# suffix -> writer(tmp_path, rgba, channels, exposure, tonemap)
_WRITERS = {'.exr': _write_exr, '.npy': _write_npy, '.png': _write_png}


def _new_temp(out: Path) -> Path:
    """Create an empty, new temporary file beside ``out``: ``.<stem>.tmpXXXXXXXX<suffix>``."""
    while True:
        tmp = out.with_name(f".{out.stem}.tmp{secrets.token_hex(4)}{out.suffix}")
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return tmp
        except FileExistsError:
            continue


def write_image(path, rgba, aovs=None, *, exposure: float = 0.0,
                tonemap: str = 'filmic', camera=None) -> Path:
    """Write a rendered image atomically; return the resolved path.

    ``rgba``: float ``H x W x 4``, linear, row 0 = top of the image. ``aovs``: optional
    dict of layer name -> ``H x W`` float array, ``.exr`` only (channel names:
    ``AOV_CHANNELS``). ``exposure`` and ``tonemap`` apply to ``.png`` only, which stores
    RGB without alpha: the renders already composite the background, so RGB is the
    final picture. ``.exr`` and ``.npy`` store the linear values untouched (NaN/Inf too).
    ``camera``: a camera.Camera recorded in the EXR header (``camera_attributes``).

    Raises ``UserError`` for a bad path or a failed write (disk full, permissions); on any
    failure an existing file at ``path`` is left untouched and no temporary file remains.
    """
    aovs = dict(aovs or {})
    out = check_output(path, aovs)
    _check_tonemap(tonemap)
    rgba = np.asarray(rgba)
    if rgba.ndim != 3 or rgba.shape[2] != 4 or rgba.shape[0] < 1 or rgba.shape[1] < 1:
        raise ValueError(f"rgba must be H x W x 4 with H, W >= 1, got shape {rgba.shape}")
    channels = {}
    for name, data in aovs.items():
        data = np.asarray(data)
        if data.ndim == 3 and data.shape[2] == 1:
            data = data[..., 0]
        if data.shape != rgba.shape[:2]:
            raise ValueError(f"layer {name!r} has shape {data.shape}, expected {rgba.shape[:2]}")
        channels[_aov_channel(name)] = data

    try:
        tmp = _new_temp(out)
    except OSError as e:
        raise UserError(f"cannot create a file in {str(out.parent)!r}: {e.strerror or e}",
                        path=out, fix="check the directory's permissions and free space") from e
    try:
        _WRITERS[out.suffix.lower()](str(tmp), rgba, channels, exposure, tonemap, camera)
        fd = os.open(tmp, os.O_RDWR)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, out)
    except OSError as e:
        raise UserError(f"cannot write image: {e.strerror or e}", path=out,
                        fix="check free disk space and the directory's permissions") from e
    finally:
        try:
            tmp.unlink()  # gone already after a successful replace
        except OSError:
            pass
    return out


# ---------------------------------------------------------------------------- readers

def read_exr_channels(path) -> dict[str, np.ndarray]:
    """Every channel of an EXR file (first part) by name, as ``H x W`` arrays."""
    path = Path(path)
    if not path.is_file():
        raise UserError("file not found", path=path, fix="check the path")
    try:
        f = OpenEXR.File(str(path), separate_channels=True)
    except RuntimeError as e:
        raise UserError(f"not a readable OpenEXR file ({e})", path=path,
                        fix="re-export it as OpenEXR") from e
    return {name: ch.pixels for name, ch in f.channels().items()}


def _unfilter(raw: bytes, h: int, stride: int, bpp: int) -> np.ndarray:
    """Undo PNG per-row filters (all five types) -> ``h x stride`` uint8."""
    data = np.frombuffer(raw, dtype=np.uint8).reshape(h, stride + 1)
    out = np.zeros((h, stride), dtype=np.uint8)
    prev = np.zeros(stride, dtype=np.int32)
    for y in range(h):
        kind, line = data[y, 0], data[y, 1:].astype(np.int32)
        if kind == 0:
            cur = line
        elif kind == 2:
            cur = (line + prev) & 0xFF
        elif kind in (1, 3, 4):
            cur = line.copy()
            for x in range(stride):
                a = cur[x - bpp] if x >= bpp else 0
                b = prev[x]
                c = prev[x - bpp] if x >= bpp else 0
                if kind == 1:
                    pred = a
                elif kind == 3:
                    pred = (a + b) // 2
                else:
                    p = a + b - c
                    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                    pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                cur[x] = (cur[x] + pred) & 0xFF
        else:
            raise ValueError(f"bad PNG filter type {kind}")
        out[y] = cur
        prev = cur
    return out


def _read_png(path: Path) -> np.ndarray:
    """Decode an 8-bit RGB, non-interlaced PNG (what ``write_image`` produces)."""
    blob = path.read_bytes()
    fix = "only 8-bit RGB non-interlaced PNGs are read here; use Pillow for others"
    if not blob.startswith(_PNG_SIGNATURE):
        raise UserError("not a PNG file", path=path, fix=fix)
    pos, header, idat = len(_PNG_SIGNATURE), None, []
    while pos + 12 <= len(blob):
        length, kind = struct.unpack('>I4s', blob[pos:pos + 8])
        if pos + 12 + length > len(blob):
            raise UserError("corrupt PNG (truncated)", path=path, fix="re-render it")
        data = blob[pos + 8:pos + 8 + length]
        (crc,) = struct.unpack('>I', blob[pos + 8 + length:pos + 12 + length])
        if zlib.crc32(kind + data) & 0xFFFFFFFF != crc:
            raise UserError(f"corrupt PNG (bad {kind!r} chunk)", path=path, fix="re-render it")
        if kind == b'IHDR':
            header = struct.unpack('>IIBBBBB', data)
        elif kind == b'IDAT':
            idat.append(data)
        elif kind == b'IEND':
            break
        pos += 12 + length
    if header is None or not idat:
        raise UserError("corrupt PNG (missing IHDR or IDAT)", path=path, fix="re-render it")
    w, h, depth, colour, _, _, interlace = header
    if (depth, colour, interlace) != (8, 2, 0):
        raise UserError(f"unsupported PNG (bit depth {depth}, colour type {colour}, "
                        f"interlace {interlace})", path=path, fix=fix)
    try:
        raw = zlib.decompress(b''.join(idat))
        pixels = _unfilter(raw, h, 3 * w, 3)
    except (zlib.error, ValueError) as e:
        raise UserError(f"corrupt PNG ({e})", path=path, fix="re-render it") from e
    return pixels.reshape(h, w, 3)


def read_image(path) -> np.ndarray:
    """Read an image: ``H x W x 4`` float32 for .exr/.npy, ``H x W x 3`` uint8 for .png.

    An EXR without an A channel reads with alpha 1.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise UserError(f"unsupported image format {path.suffix or '(no suffix)'!r}",
                        path=path, fix=f"use one of {', '.join(SUFFIXES)}")
    if not path.is_file():
        raise UserError("file not found", path=path, fix="check the path")
    if suffix == '.png':
        return _read_png(path)
    if suffix == '.npy':
        try:
            arr = np.load(path, allow_pickle=False)
        except ValueError as e:
            raise UserError(f"not a readable .npy array ({e})", path=path, fix="re-render it") from e
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
