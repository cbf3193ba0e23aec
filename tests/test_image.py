import errno
import io
import os
import warnings

import numpy as np
import pytest

from volrender import image
from volrender.errors import UserError
from volrender.image import check_output, read_exr_channels, read_image, to_srgb8, write_image


def decode_png(blob):
    """Pillow's reading of a PNG written here: 8-bit RGBA, non-interlaced."""
    from PIL import Image as PILImage
    with PILImage.open(io.BytesIO(blob)) as im:
        assert im.format == 'PNG' and im.mode == 'RGBA', (im.format, im.mode)
        return np.asarray(im)


def marked_image(rng, h=5, w=7):
    rgba = rng.standard_normal((h, w, 4)).astype(np.float32) * 1e3
    rgba[0] = [1.0, 2.0, 3.0, 4.0]  # marker in the top row
    rgba[1, 2] = [np.float32(1e-40), -0.0, np.float32(np.pi), 0.25]  # denormal, -0
    return rgba


# ---------------------------------------------------------------------- round trips

def test_exr_round_trip_bit_exact_with_aovs(tmp_path, rng):
    rgba = marked_image(rng)
    depth = rng.random((5, 7), dtype=np.float32) * 100
    trans = rng.random((5, 7), dtype=np.float32)
    out = write_image(tmp_path / 'a.exr', rgba, {'depth': depth, 'transmittance': trans,
                                                 'samples': trans[::-1]})
    back = read_image(out)
    assert back.dtype == np.float32 and back.shape == (5, 7, 4)
    assert back.tobytes() == rgba.tobytes()
    assert (back[0] == [1, 2, 3, 4]).all()  # rows not flipped
    ch = read_exr_channels(out)
    assert set(ch) == {'R', 'G', 'B', 'A', 'Z', 'T', 'samples'}
    assert ch['Z'].dtype == np.float32 and ch['Z'].tobytes() == depth.tobytes()
    assert ch['T'].tobytes() == trans.tobytes()
    assert ch['samples'].tobytes() == np.ascontiguousarray(trans[::-1]).tobytes()
    import OpenEXR
    assert OpenEXR.File(str(out), header_only=True).header()['compression'] == \
        OpenEXR.ZIP_COMPRESSION


def test_exr_non_contiguous_input(tmp_path, rng):
    # The bindings ignore strides; the writer must hand them contiguous arrays.
    base = marked_image(rng, 6, 8)
    view = base[::-1, ::2]
    write_image(tmp_path / 'v.exr', view)
    assert read_image(tmp_path / 'v.exr').tobytes() == np.ascontiguousarray(view).tobytes()


def test_exr_keeps_non_finite(tmp_path):
    rgba = np.zeros((2, 2, 4), np.float32)
    rgba[0, 0, 0], rgba[0, 1, 1] = np.nan, np.inf
    back = read_image(write_image(tmp_path / 'n.exr', rgba))
    assert np.isnan(back[0, 0, 0]) and back[0, 1, 1] == np.inf


def test_npy_round_trip(tmp_path, rng):
    rgba = marked_image(rng)
    out = write_image(tmp_path / 'a.npy', rgba)
    back = read_image(out)
    assert back.dtype == np.float32 and back.tobytes() == rgba.tobytes()
    assert np.load(out).shape == (5, 7, 4)


def test_write_overwrites_and_leaves_no_temp(tmp_path):
    for value in (0.25, 0.75):
        for suffix in image.SUFFIXES:
            write_image(tmp_path / f'o{suffix}', np.full((3, 4, 4), value, np.float32))
    assert sorted(p.name for p in tmp_path.iterdir()) == ['o.exr', 'o.npy', 'o.png']
    assert (read_image(tmp_path / 'o.npy') == 0.75).all()


# ------------------------------------------------------------------------------ PNG

def test_png_known_values(tmp_path):
    rgba = np.zeros((2, 3, 4), np.float32)
    rgba[..., 3] = 1.0
    rgba[0, 0, :3] = [0.0, 1.0, 0.5]
    rgba[0, 1, :3] = [2.0, 0.001, 0.0031308]
    rgba[1, 2, :3] = [1.0, 0.0, 0.0]  # bottom right is red
    out = write_image(tmp_path / 'k.png', rgba, tonemap='clamp')
    px = decode_png(out.read_bytes())
    assert px.shape == (2, 3, 4) and px.dtype == np.uint8
    assert px[0, 0].tolist() == [0, 255, 188, 255]
    # 2.0 clamps; 0.001 * 12.92 * 255 = 3.29 -> 3; threshold 0.0031308 -> 10.3 -> 10
    assert px[0, 1].tolist() == [255, 3, 10, 255]
    assert px[1, 2].tolist() == [255, 0, 0, 255] and px[1, 0].tolist() == [0, 0, 0, 255]
    assert (read_image(out) == px).all()


def test_png_straight_alpha(tmp_path, rng):
    """A premultiplied render c * alpha is written as colour c and alpha alpha (8 bits:
    within one code); alpha 0 keeps the render's RGB (what lies behind); a known
    background composited behind is taken out before the division."""
    c = rng.random((6, 5, 3))
    a = rng.random((6, 5))
    a[0, 0], a[0, 1] = 0.0, 1.0
    rgba = np.concatenate([c * a[..., None], a[..., None]], -1).astype(np.float32)
    rgba[0, 0, :3] = [0.2, 0.3, 0.4]              # nothing covers it: the background
    px = decode_png(write_image(tmp_path / 's.png', rgba, tonemap='clamp',
                                png_alpha='straight').read_bytes())
    assert (px[..., 3] == np.floor(a * 255 + 0.5)).all()
    want = to_srgb8(c, 0.0, 'clamp').astype(int)
    want[0, 0] = to_srgb8(np.array([0.2, 0.3, 0.4]), 0.0, 'clamp')
    covered = a > 0.02                          # c * a rounds to float32: tiny alpha amplifies
    assert np.abs(px[..., :3].astype(int) - want)[covered].max() <= 1
    assert (px[0, 0, :3] == want[0, 0]).all()
    bg = np.array([0.5, 0.1, 0.3])
    over = rgba.copy()
    over[..., :3] += (1 - a[..., None]) * bg    # composited over a background
    px2 = decode_png(write_image(tmp_path / 'b.png', over, tonemap='clamp',
                                 background=bg, png_alpha='straight').read_bytes())
    assert np.abs(px2[..., :3].astype(int) - px[..., :3])[covered].max() <= 1


def test_png_is_opaque_by_default(tmp_path, rng):
    """The default PNG is the picture as rendered: the premultiplied RGB (background, sky
    and environment included) tone-mapped, alpha 1, whatever the render's alpha; 16 bits
    alike. EXR keeps the premultiplied RGBA."""
    rgba = rng.random((6, 5, 4)).astype(np.float32)
    rgba[0, 0] = [0.2, 0.3, 0.4, 0.0]                # the sky, where nothing covers it
    for bits in (8, 16):
        px = read_image(write_image(tmp_path / f'o{bits}.png', rgba, tonemap='clamp',
                                    png_bits=bits))
        assert (px[..., 3] == (1 << bits) - 1).all()
        assert (px[..., :3] == image.to_srgb(rgba[..., :3], 0.0, 'clamp', bits)).all()
    back = read_image(write_image(tmp_path / 'o.exr', rgba))
    np.testing.assert_array_equal(back, rgba)
    with pytest.raises(UserError, match="alpha"):
        write_image(tmp_path / 'x.png', rgba, png_alpha='premultiplied')


def test_png_16_bit(tmp_path, rng):
    rgba = rng.random((7, 9, 4)).astype(np.float32)
    rgba[..., 3] = 1.0
    out = write_image(tmp_path / 'd.png', rgba, tonemap='clamp', png_bits=16)
    back = read_image(out)
    assert back.dtype == np.uint16 and back.shape == (7, 9, 4)
    assert (back[..., :3] == image.to_srgb(rgba[..., :3], 0.0, 'clamp', 16)).all()
    assert (back[..., 3] == 65535).all()
    eight = image.to_srgb8(rgba[..., :3], 0.0, 'clamp').astype(int)
    assert np.abs(back[..., :3] / 257.0 - eight).max() <= 0.5 + 1e-9   # same curve, finer codes
    with pytest.raises(UserError, match='bit depth'):
        write_image(tmp_path / 'e.png', rgba, png_bits=12)


def test_png_exposure(tmp_path):
    assert to_srgb8(np.array([0.25]), exposure=1.0, tonemap='clamp')[0] == 188
    assert to_srgb8(np.array([1.0]), exposure=-1.0, tonemap='clamp')[0] == 188


def test_srgb_matches_formula():
    v = np.linspace(0, 1, 10001)
    expected = np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
    assert (to_srgb8(v, 0.0, 'clamp') == np.floor(expected * 255 + 0.5)).all()


def test_filmic_monotonic_and_bounded():
    x = np.linspace(0, 10, 100001)
    y = image._filmic(x)
    assert y[0] == 0 and (np.diff(y) > 0).all() and (y < 1).all()
    x = np.concatenate([x, np.geomspace(11, 1e30, 1000)])  # far out: rounds to 1.0
    y = image._filmic(x)
    assert (np.diff(y) >= 0).all() and (y <= 1).all() and y[-1] == 1.0
    assert image._filmic(np.inf) == 1.0
    codes = to_srgb8(x, 0.0, 'filmic')
    assert codes[0] == 0 and (np.diff(codes.astype(int)) >= 0).all()
    assert codes[-1] == 255 and to_srgb8(np.array([0.5]))[0] == 188  # knee: mid-tones kept
    # continuous slope at the knee
    k, e = image._KNEE, 1e-6
    assert abs((image._filmic(k + e) - image._filmic(k)) / e - 1) < 1e-5


def test_png_non_finite_does_not_crash(tmp_path):
    rgba = np.zeros((2, 2, 4), np.float32)
    rgba[0, 0] = np.nan
    rgba[0, 1] = np.inf
    rgba[1, 0] = -np.inf
    rgba[1, 1] = [0.5, 0.5, 0.5, 1]
    rgba[..., 3] = 1
    for tonemap in ('filmic', 'clamp', 'standard', 'aces'):     # agx needs $OCIO's config
        with pytest.warns(RuntimeWarning, match='non-finite'):
            out = write_image(tmp_path / f'{tonemap}.png', rgba, tonemap=tonemap)
        px = decode_png(out.read_bytes())[..., :3]
        assert px[0, 0].tolist() == [0, 0, 0] and px[0, 1].tolist() == [255, 255, 255]
        grey = 165 if tonemap == 'aces' else 188       # ACES darkens mid-tones
        assert px[1, 0].tolist() == [0, 0, 0] and px[1, 1].tolist() == [grey] * 3


def test_png_finite_input_does_not_warn(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        write_image(tmp_path / 'f.png', np.full((2, 2, 4), 1e30, np.float32), exposure=8.0)


def test_png_reads_other_pngs(tmp_path, rng):
    """read_image takes any PNG Pillow reads (filtered rows, greyscale, palette), as RGBA."""
    PIL = pytest.importorskip('PIL.Image')
    px = rng.integers(0, 256, (9, 11, 3), dtype=np.uint8)
    px[:, :5] = 7  # smooth part so the encoder picks several filter types
    PIL.fromarray(px).save(tmp_path / 'pil.png', optimize=True)
    back = read_image(tmp_path / 'pil.png')
    assert (back[..., :3] == px).all() and (back[..., 3] == 255).all()
    PIL.fromarray(px[..., 0]).save(tmp_path / 'grey.png')
    assert (read_image(tmp_path / 'grey.png')[..., 1] == px[..., 0]).all()


def test_unknown_tonemap(tmp_path):
    with pytest.raises(UserError, match="unknown view transform 'filmc'; use one of filmic, "):
        write_image(tmp_path / 'x.png', np.zeros((1, 1, 4), np.float32), tonemap='filmc')
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------ atomicity

@pytest.mark.parametrize('suffix', image.SUFFIXES)
def test_failed_write_leaves_existing_file(tmp_path, monkeypatch, suffix):
    out = tmp_path / f'keep{suffix}'
    write_image(out, np.full((4, 4, 4), 0.5, np.float32))
    before = out.read_bytes()

    def failing(f, *args):
        f.write(b'half an image')
        raise OSError(errno.ENOSPC, 'No space left on device')

    monkeypatch.setitem(image._WRITERS, suffix, failing)
    with pytest.raises(UserError, match='No space left') as info:
        write_image(out, np.zeros((4, 4, 4), np.float32))
    assert str(out) in str(info.value) and '\n' not in str(info.value)
    assert out.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == [out.name]


def test_unexpected_error_also_cleans_up(tmp_path, monkeypatch):
    def failing(f, *args):
        f.write(b'x')
        raise KeyboardInterrupt

    monkeypatch.setitem(image._WRITERS, '.npy', failing)
    with pytest.raises(KeyboardInterrupt):
        write_image(tmp_path / 'x.npy', np.zeros((1, 1, 4), np.float32))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize('suffix', image.SUFFIXES)
def test_real_disk_full_is_user_error(tmp_path, monkeypatch, suffix):
    """The real writers (OpenEXR, numpy, Pillow) on a full disk: the temporary file's
    writes go to /dev/full, which fails every write with ENOSPC."""
    if not os.path.exists('/dev/full'):
        pytest.skip('no /dev/full')
    from volrender import atomic
    out = tmp_path / f'x{suffix}'
    out.write_bytes(b'old')
    real_fdopen = os.fdopen

    def full(fd, mode='r', *args, **kw):
        os.close(fd)
        return real_fdopen(os.open('/dev/full', os.O_WRONLY), mode, *args, **kw)

    monkeypatch.setattr(atomic.os, 'fdopen', full)
    with pytest.raises(UserError, match='No space left|space') as info:
        write_image(out, np.zeros((64, 64, 4), np.float32))
    assert 'free some disk space' in str(info.value)
    assert out.read_bytes() == b'old' and sorted(p.name for p in tmp_path.iterdir()) == [out.name]


def test_temporary_files_are_ours_and_stale_ones_are_swept(tmp_path):
    """Temporary names carry the writer's pid; a write removes those of processes that
    are gone (SIGKILL), never a live one's or anyone else's."""
    from volrender import atomic
    import subprocess
    import sys
    dead = subprocess.run([sys.executable, '-c', 'import os; print(os.getpid())'],
                          capture_output=True, text=True).stdout.strip()
    stale = tmp_path / f'.volrender-{dead}-0123abcd.tmp.png'
    alive = tmp_path / f'.volrender-{os.getppid()}-0123abcd.tmp.png'
    other = tmp_path / '.o.png.tmp1234'
    for p in (stale, alive, other):
        p.write_bytes(b'x')
    atomic._SWEPT.discard(tmp_path)
    write_image(tmp_path / 'o.png', np.zeros((2, 2, 4), np.float32))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(['o.png', alive.name, other.name])
    assert atomic.TEMP_RE.match(alive.name) and not atomic.TEMP_RE.match(other.name)


def test_outputs_symlinks_modes_and_what_is_refused(tmp_path):
    """Written through a symlink (the link stays); a replaced file keeps its mode, a new
    one gets 0666 minus the umask; read-only files, FIFOs and symlink loops are refused."""
    target = tmp_path / 'real.npy'
    link = tmp_path / 'link.npy'
    target.write_bytes(b'old')
    link.symlink_to(target.name)
    assert write_image(link, np.ones((2, 2, 4), np.float32)) == target
    assert link.is_symlink() and (read_image(target) == 1).all()
    target.chmod(0o640)
    write_image(link, np.zeros((2, 2, 4), np.float32))
    assert (target.stat().st_mode & 0o777) == 0o640
    mask = os.umask(0o022)
    try:
        fresh = write_image(tmp_path / 'new.npy', np.zeros((1, 1, 4), np.float32))
    finally:
        os.umask(mask)
    assert (fresh.stat().st_mode & 0o777) == 0o644
    # a read-only output: test_a_read_only_output_is_refused_and_kept
    os.mkfifo(tmp_path / 'pipe.png')
    with pytest.raises(UserError, match='FIFO'):
        check_output(tmp_path / 'pipe.png')
    (tmp_path / 'a.png').symlink_to('b.png')
    (tmp_path / 'b.png').symlink_to('a.png')
    with pytest.raises(UserError, match='symlink loop'):
        check_output(tmp_path / 'a.png')
    with pytest.raises(UserError, match='bytes long'):
        check_output(tmp_path / ('x' * 300 + '.png'))


def test_any_file_name_is_written(tmp_path):
    """Names that are not UTF-8 (the EXR library takes str paths only) and names with
    control characters, which messages escape."""
    odd = os.fsdecode(b'x\xff\x1b[2J.exr')
    out = write_image(tmp_path / odd, np.ones((2, 2, 4), np.float32))
    assert (read_image(out) == 1).all()
    with pytest.raises(UserError) as info:
        check_output(tmp_path / os.fsdecode(b'y\x1b]0;owned\x07.jpg'))
    assert '\x1b' not in str(info.value) and '\\x1b' in str(info.value)


# ------------------------------------------------------------------------ validation

def test_check_output_ok(tmp_path):
    assert check_output(tmp_path / 'a.png') == (tmp_path / 'a.png').resolve()
    assert check_output(tmp_path / 'a.EXR', ['depth', 'transmittance']).name == 'a.EXR'


def test_check_output_bad_suffix(tmp_path):
    for name in ('a.jpg', 'a', 'a.exr.gz'):
        with pytest.raises(UserError, match=r'\.exr, \.npy, \.png'):
            check_output(tmp_path / name)


def test_check_output_missing_directory(tmp_path):
    with pytest.raises(UserError, match='does not exist.*mkdir'):
        check_output(tmp_path / 'nope' / 'a.exr')
    (tmp_path / 'file').write_text('x')
    with pytest.raises(UserError, match='does not exist'):
        check_output(tmp_path / 'file' / 'a.exr')
    (tmp_path / 'dir.exr').mkdir()
    with pytest.raises(UserError, match='is a directory'):
        check_output(tmp_path / 'dir.exr')


REFUSE = """
import sys
from volrender.errors import UserError
from volrender.image import {call}
try:
    {call}(sys.argv[1]{extra})
except UserError as exc:
    print("REFUSED", exc)
else:
    print("ACCEPTED")
"""


@pytest.fixture
def shared_tmp():
    """A folder the unprivileged user of run_unprivileged may enter (pytest's tmp_path
    is private to root) and own."""
    import shutil
    import tempfile
    from helpers import unprivileged_uid
    base = tempfile.mkdtemp(prefix='volrender-perm-')
    os.chmod(base, 0o755)
    try:
        os.chown(base, unprivileged_uid(), -1)
    except (OSError, KeyError):
        pass                        # not root: it is ours already
    yield __import__('pathlib').Path(base)
    shutil.rmtree(base, ignore_errors=True)


def test_check_output_unwritable_directory(shared_tmp):
    """A folder its user may not write: refused, as a user whom permission bits bind
    (this one, or `nobody` when the tests run as root, who may write anywhere)."""
    from helpers import run_unprivileged
    ro = shared_tmp / 'ro'
    ro.mkdir()
    ro.chmod(0o555)
    out = run_unprivileged(REFUSE.format(call='check_output', extra=''), ro / 'a.png')
    assert out.startswith('REFUSED') and 'not writable' in out, out
    assert list(ro.iterdir()) == []


def test_a_read_only_output_is_refused_and_kept(shared_tmp):
    """A read-only file in a folder the user may write: refused and left as it was (as
    an unprivileged user, for whom the mode means what it says)."""
    from helpers import run_unprivileged
    ro = shared_tmp / 'ro.npy'
    ro.write_bytes(b'keep')
    ro.chmod(0o444)
    out = run_unprivileged(REFUSE.format(call='write_image', extra=', __import__("numpy").zeros('
                                         '(1, 1, 4), "float32")'), ro)
    assert out.startswith('REFUSED') and 'read-only' in out, out
    assert ro.read_bytes() == b'keep'
    assert sorted(p.name for p in shared_tmp.iterdir()) == ['ro.npy']


def test_aovs_only_for_exr(tmp_path):
    for suffix in ('.npy', '.png'):
        with pytest.raises(UserError, match=r'need an \.exr'):
            check_output(tmp_path / f'a{suffix}', ['depth'])
        with pytest.raises(UserError, match=r'need an \.exr'):
            write_image(tmp_path / f'a{suffix}', np.zeros((1, 1, 4), np.float32),
                        {'depth': np.zeros((1, 1), np.float32)})
    with pytest.raises(UserError, match='taken'):
        check_output(tmp_path / 'a.exr', ['A'])
    with pytest.raises(UserError, match='taken'):
        check_output(tmp_path / 'a.exr', ['depth', 'Z'])
    assert list(tmp_path.iterdir()) == []


def test_bad_shapes(tmp_path):
    with pytest.raises(ValueError, match='H x W x 4'):
        write_image(tmp_path / 'a.npy', np.zeros((2, 2, 3), np.float32))
    with pytest.raises(ValueError, match='depth'):
        write_image(tmp_path / 'a.exr', np.zeros((2, 2, 4), np.float32),
                    {'depth': np.zeros((2, 3), np.float32)})
    assert list(tmp_path.iterdir()) == []


def test_read_errors(tmp_path):
    with pytest.raises(UserError, match='no such file'):
        read_image(tmp_path / 'missing.exr')
    (tmp_path / 'junk.exr').write_bytes(b'junk')
    with pytest.raises(UserError, match='OpenEXR'):
        read_image(tmp_path / 'junk.exr')
    good = write_image(tmp_path / 'g.png', np.zeros((2, 2, 4), np.float32)).read_bytes()
    bad = bytearray(good)
    bad[-20] ^= 0xFF  # inside IDAT
    (tmp_path / 'bad.png').write_bytes(bytes(bad))
    with pytest.raises(UserError, match='corrupt PNG'):
        read_image(tmp_path / 'bad.png')
    (tmp_path / 'cut.png').write_bytes(good[:40])
    with pytest.raises(UserError, match='corrupt PNG'):
        read_image(tmp_path / 'cut.png')


def test_exr_bytes_do_not_depend_on_threads(tmp_path, rng):
    import OpenEXR
    rgba = rng.random((70, 90, 4)).astype(np.float32)
    rgba[:, :30] = 0.0
    before = OpenEXR.global_thread_count()
    try:
        OpenEXR.set_global_thread_count(1)
        write_image(tmp_path / "one.exr", rgba)
        OpenEXR.set_global_thread_count(0)
        assert image.exr_threads() >= 1
        write_image(tmp_path / "all.exr", rgba)
    finally:
        OpenEXR.set_global_thread_count(before)
    assert (tmp_path / "one.exr").read_bytes() == (tmp_path / "all.exr").read_bytes()
