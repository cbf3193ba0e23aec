"""The environment for volumes: importance sampling of a map (cl/env.h) against its own
density, and the environment's light in the marcher against closed forms."""
import numpy as np
import pyopencl as cl
import pytest

import reference
from volrender.camera import Camera
from volrender.dispatch import upload
from volrender.errors import UserError
from volrender.image import write_image
from volrender.environment import (Environment, env_distribution, env_mode, env_weights,
                                  load_environment)
from volrender.scene import Scene
from volrender.bricks import Bricks
from volrender.volume import VolumeSettings

from helpers import chi2_sf, render_points, render_volume, sky, top_camera

SRC = """
#include "common.h"
#include "env.h"
__kernel void sample(__global const float* cdf, int w, int h, uint seed, __global float4* out)
{
    int i = get_global_id(0);
    float pdf;
    float3 d = vr_env_sample(cdf, w, h, vr_rand(seed, i, 0, 0), vr_rand(seed, i, 0, 1), &pdf);
    out[i] = (float4)(d, pdf);
}
__kernel void pdf(__global const float* cdf, int w, int h, __global const float4* dirs,
                  __global float* out)
{
    int i = get_global_id(0);
    out[i] = vr_env_pdf(cdf, w, h, dirs[i].xyz);
}
__kernel void lookup(__global const float4* env, int w, int h, __global const float4* dirs,
                     __global float4* out)
{
    int i = get_global_id(0);
    out[i] = (float4)(vr_env_map(env, w, h, dirs[i].xyz), 0.0f);
}
"""


def run(dev, name, size, *args, out_shape):
    prg = dev.build(SRC, {}, "env probe")
    out = np.empty(out_shape, np.float32)
    d_out = cl.Buffer(dev.context, cl.mem_flags.WRITE_ONLY, out.nbytes)
    cl.Kernel(prg, name)(dev.queue, (size,), None, *args, d_out)
    cl.enqueue_copy(dev.queue, out, d_out)
    return out.astype(np.float64)


def uniform_dirs(n, seed=2):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def texel_of(d, w, h):
    u = 0.5 + np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi)
    v = np.arccos(np.clip(d[:, 1], -1, 1)) / np.pi
    return np.clip((v * h).astype(int), 0, h - 1), np.clip((u * w).astype(int), 0, w - 1)


def test_map_sampling_follows_its_density(cl_device):
    """Texels are drawn in proportion to luminance x sin(theta) (chi-square over all
    texels), each sample's density is what vr_env_pdf gives, and that density is
    p_texel W H / (2 pi^2 sin theta): it integrates to 1 over the sphere."""
    t = sky()
    h, w = t.shape[:2]
    cdf = env_distribution(t)
    ctx = cl_device.context
    n = 400_000
    out = run(cl_device, "sample", n, upload(ctx, cdf), np.int32(w), np.int32(h), np.uint32(7),
              out_shape=(n, 4))
    d, pdf = out[:, :3], out[:, 3]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-5)
    i, j = texel_of(d, w, h)
    p = env_weights(t)
    p /= p.sum()
    # the weights bound the bilinear map's luminance over every texel's cell
    lum = bilinear(t, uniform_dirs(200_000)) @ np.array([0.2126, 0.7152, 0.0722])
    ii, jj = texel_of(uniform_dirs(200_000), w, h)
    assert np.all(lum <= env_weights(t)[ii, jj] / np.sin(np.pi * (ii + 0.5) / h) * (1 + 1e-9))
    counts = np.bincount(i * w + j, minlength=h * w).reshape(h, w)
    expected = n * p
    assert chi2_sf(((counts - expected) ** 2 / expected).sum(), h * w - 1) > 1e-3
    st = np.sqrt(1 - d[:, 1] ** 2)
    ok = st > 1e-3               # float32 directions next to the poles
    assert ok.mean() > 0.999
    np.testing.assert_allclose(pdf[ok], p[i, j][ok] * w * h / (2 * np.pi ** 2 * st[ok]), rtol=2e-3)
    # the density over the sphere (midpoint rule on a fine theta-phi grid) integrates to 1
    th = (np.arange(400) + 0.5) / 400 * np.pi
    ph = (np.arange(800) + 0.5) / 800 * 2 * np.pi
    T, P = np.meshgrid(th, ph, indexing="ij")
    dirs = np.stack([np.sin(T) * np.sin(P), np.cos(T), -np.sin(T) * np.cos(P)], -1).reshape(-1, 3)
    d4 = np.zeros((len(dirs), 4), np.float32)
    d4[:, :3] = dirs
    dens = run(cl_device, "pdf", len(dirs), upload(ctx, cdf), np.int32(w), np.int32(h),
               upload(ctx, d4), out_shape=(len(dirs),))
    total = (dens.reshape(T.shape) * np.sin(T)).sum() * (np.pi / 400) * (2 * np.pi / 800)
    assert total == pytest.approx(1.0, abs=2e-3)


def test_env_map_lookup_is_the_glass_convention(cl_device):
    """u = 0.5 + atan2(x, -z) / 2 pi, v = acos(y) / pi, bilinear between texel centres:
    at a texel's centre direction the lookup returns that texel."""
    t = sky()
    h, w = t.shape[:2]
    tex = np.zeros((h * w, 4), np.float32)
    tex[:, :3] = t.reshape(-1, 3)
    ii, jj = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    th, ph = np.pi * (ii.ravel() + 0.5) / h, ((jj.ravel() + 0.5) / w - 0.5) * 2 * np.pi
    d4 = np.zeros((h * w, 4), np.float32)
    d4[:, :3] = np.stack([np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)], -1)
    got = run(cl_device, "lookup", h * w, upload(cl_device.context, tex), np.int32(w), np.int32(h),
              upload(cl_device.context, d4), out_shape=(h * w, 4))
    np.testing.assert_allclose(got[:, :3], t.reshape(-1, 3), rtol=2e-4, atol=1e-5)


def test_env_modes(tmp_path):
    assert env_mode(None) == 0
    assert env_mode(Environment(np.zeros((1, 1, 3), np.float32))) == 0
    assert env_mode(Environment(np.full((1, 1, 3), 0.5, np.float32))) == 1
    assert env_mode(Environment(np.full((4, 8, 3), 0.5, np.float32))) == 1   # a constant map
    assert env_mode(Environment(sky())) == 2
    assert VolumeSettings(env=0.5).env == (0.5, 0.5, 0.5)
    with pytest.raises(UserError, match="env"):
        VolumeSettings(env=(-1.0, 0.0, 0.0))


VOX = 0.1


def thin_slab(n=24, k0=10, k1=13):
    v = np.zeros((n, n, n), np.float32)
    v[:, :, k0:k1 + 1] = 1.0
    m = np.eye(4)
    m[:3, :3] *= VOX
    m[:3, 3] = -(n - 1) / 2 * VOX
    return Bricks.from_dense(v, m)


@pytest.mark.parametrize("g", [0.0, 0.6])
def test_march_env_single_scattering_in_a_thin_slab(cl_device, tmp_path, g):
    """An optically thin slab (tau 4e-3) under a map: the scattered light is
    albedo alpha int p(w . d) L(w) dw to first order in tau (the map hidden behind, so
    the pixel holds the scattered light alone). The integral is a quadrature of the
    same map."""
    t = sky()
    write_image(tmp_path / "sky.exr", np.concatenate([t, np.ones_like(t[..., :1])], -1))
    b = thin_slab()
    cam = top_camera(12, fov=4.0)
    s = VolumeSettings(density_scale=0.01, albedo=0.8, phase=(g, 0.0, 1.0), env=str(tmp_path / "sky.exr"),
                       spp=256, seed=5, step=0.5, shadow_step=0.5, hide_env=True)
    rgba = render_volume(b, cam, [], s, cl_device).rgba.astype(np.float64)
    h, w = t.shape[:2]
    th = (np.arange(256) + 0.5) / 256 * np.pi
    ph = (np.arange(512) + 0.5) / 512 * 2 * np.pi
    T, P = np.meshgrid(th, ph, indexing="ij")
    dirs = np.stack([np.sin(T) * np.sin(P), np.cos(T), -np.sin(T) * np.cos(P)], -1).reshape(-1, 3)
    lum = bilinear(t, dirs)
    dA = (np.sin(T) * (np.pi / 256) * (2 * np.pi / 512)).ravel()
    pix = cam.pixel_dirs().reshape(-1, 3)
    alpha = rgba[..., 3].ravel()
    want = 0.8 * alpha[:, None] * ((reference.hg(pix @ dirs.T, g) * dA) @ lum)
    ratio = rgba.reshape(-1, 4)[:, :3] / want
    # per pixel: the direction noise (~2.5% here); over all pixels: within 5 standard
    # errors, plus the first-order shadowing a thin slab still has (-tau/2 ~ -0.4%)
    n = len(ratio)
    assert np.all(np.abs(ratio - 1) < 0.15)
    for ch in range(3):
        m, se = ratio[:, ch].mean(), ratio[:, ch].std(ddof=1) / np.sqrt(n)
        assert abs(m - 0.996) < 5 * se + 0.003, (ch, m, se)


def bilinear(t, d):
    """The map at directions d (cl/env.h's lookup in numpy)."""
    h, w = t.shape[:2]
    u = 0.5 + np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi)
    v = np.arccos(np.clip(d[:, 1], -1, 1)) / np.pi
    fx, fy = u * w - 0.5, np.clip(v * h - 0.5, 0, h - 1)
    x0, y0 = np.floor(fx), np.floor(fy)
    ax, ay = (fx - x0)[:, None], (fy - y0)[:, None]
    x0 = x0.astype(int) % w
    x1 = (x0 + 1) % w
    y0 = y0.astype(int)
    y1 = np.minimum(y0 + 1, h - 1)
    a = (1 - ax) * t[y0, x0] + ax * t[y0, x1]
    b = (1 - ax) * t[y1, x0] + ax * t[y1, x1]
    return (1 - ay) * a + ay * b


def test_env_is_seen_behind_unless_hidden(cl_device):
    """Pixels that miss the volume show the environment (plus --background); --hide-env
    shows the background alone, and the medium is lit the same either way."""
    b = thin_slab()
    cam = Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 60.0, 16, 16)
    for est in ("march", "path"):
        base = dict(density_scale=3.0, env=(0.2, 0.3, 0.5), background=(0.1, 0.0, 0.0),
                    estimator=est, spp=4, seed=3)
        shown = render_volume(b, cam, [], VolumeSettings(**base), cl_device).rgba
        hidden = render_volume(b, cam, [], VolumeSettings(**base, hide_env=True), cl_device).rgba
        miss = shown[..., 3] == 0
        assert miss.sum() > 20
        np.testing.assert_allclose(shown[miss][:, :3], np.broadcast_to([0.3, 0.3, 0.5], (miss.sum(), 3)),
                                   rtol=1e-6)
        np.testing.assert_allclose(hidden[miss][:, :3], np.broadcast_to([0.1, 0.0, 0.0], (miss.sum(), 3)),
                                   rtol=1e-6)
        # same random numbers: the difference is exactly T * env behind
        diff = shown[..., :3] - hidden[..., :3]
        np.testing.assert_allclose(diff, (1 - shown[..., 3:]) * [0.2, 0.3, 0.5], atol=1e-5)


def test_volume_scene_files_take_an_environment(tmp_path):
    from volrender import scene
    thin_slab().save_npz(tmp_path / "v.npz")
    (tmp_path / "s.toml").write_text('[volume]\nfile = "v.npz"\nalbedo = 0.95\n'
                                     '[environment]\nmap = [0.2, 0.3, 0.5]\n')
    sc = scene.load_scene(tmp_path / "s.toml")
    assert sc.environment.uniform == pytest.approx((0.2, 0.3, 0.5))
    assert sc.settings.albedo == (0.95, 0.95, 0.95)
    sc = scene.load_scene(tmp_path / "v.npz", env=(0.7,))
    assert sc.environment.uniform == pytest.approx((0.7, 0.7, 0.7))
    t = sky()
    write_image(tmp_path / "sky.exr", np.concatenate([t, np.ones_like(t[..., :1])], -1))
    (tmp_path / "m.toml").write_text('[volume]\nfile = "v.npz"\n[environment]\nmap = "sky.exr"\n')
    sc = scene.load_scene(tmp_path / "m.toml")
    assert sc.environment.texels.shape == t.shape and env_mode(sc.environment) == 2
    assert (tmp_path / "sky.exr").resolve() in sc.inputs


def test_glass_takes_a_uniform_env_as_a_one_texel_map(cl_device):
    """--env R,G,B for glass: a 1x1 map, so every ray that leaves the glass sees R,G,B
    (here every pixel that misses the spheres)."""
    from volrender import generators, glass
    cloud = generators.generate("blob", 40, seed=1)
    cam = glass.default_camera(cloud, 24, 18)
    s = glass.GlassSettings(env=(0.2, 0.4, 0.6), refraction=False)
    sc = Scene.of(cam, [], glass_content(cloud, s))
    assert sc.environment.texels.shape == (1, 1, 3)
    rgba = render_points(cloud, cam, [], s, cl_device).rgba
    miss = rgba[..., 3] == 0
    assert miss.sum() > 20
    np.testing.assert_allclose(rgba[miss][:, :3], np.broadcast_to([0.2, 0.4, 0.6], (miss.sum(), 3)),
                               rtol=1e-6)


def glass_content(cloud, s):
    from volrender.scene import GlassContent
    return GlassContent(cloud, s)


def test_a_missing_env_map_is_a_user_error(tmp_path):
    from volrender import scene
    thin_slab().save_npz(tmp_path / "v.npz")
    with pytest.raises(UserError, match="env=: .*nope.exr: no such file"):
        scene.request(tmp_path / "v.npz", env=str(tmp_path / "nope.exr"))
    with pytest.raises(UserError, match="env"):
        scene.request(tmp_path / "v.npz", env=(1.0, 2.0))


def needs_oiio():
    """Skip where OpenImageIO (a dependency of `pip install volrender`, which reads .hdr) is
    missing, e.g. where the package was installed with --no-deps."""
    pytest.importorskip("OpenImageIO", reason="needs OpenImageIO (Radiance .hdr maps are read "
                        "through it; pip install OpenImageIO)")


def write_rgbe(path, texels):
    import OpenImageIO as oiio
    out = oiio.ImageOutput.create(str(path))
    h, w = texels.shape[:2]
    out.open(str(path), oiio.ImageSpec(w, h, 3, "float"))
    out.write_image(np.ascontiguousarray(texels, np.float32))
    out.close()


def test_a_radiance_hdr_environment_reads_as_the_map_it_holds(tmp_path, cl_device):
    """RGBE keeps 8 bits of mantissa under a shared exponent: every channel within 2^-7 of
    its texel's largest; row 0 stays the top (the sun spot where it was); rendering with the
    .hdr equals rendering with the same texels as an .exr."""
    from volrender import render, scene
    needs_oiio()
    t = sky()
    write_rgbe(tmp_path / "sky.hdr", t)
    got = load_environment(tmp_path / "sky.hdr")
    assert got.shape == t.shape and got.dtype == np.float32
    assert np.all(np.abs(got - t) <= t.max(axis=-1, keepdims=True) * 2.0 ** -7)
    assert np.unravel_index(np.argmax(got[..., 0]), got.shape[:2]) == (3, 20)
    write_image(tmp_path / "same.exr", np.concatenate([got, np.ones_like(got[..., :1])], -1))
    thin_slab().save_npz(tmp_path / "v.npz")
    imgs = [render(scene.load_scene(tmp_path / "v.npz", env=str(tmp_path / f), size=(24, 16),
                                    spp=1, density_scale=0.01), cl_device).rgba
            for f in ("sky.hdr", "same.exr")]
    assert np.array_equal(imgs[0], imgs[1]) and imgs[0][..., :3].max() > 0


def test_a_broken_hdr_environment_is_a_user_error(tmp_path):
    needs_oiio()
    p = tmp_path / "cut.hdr"
    p.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 8 +X 16\n\x02\x02")
    with pytest.raises(UserError, match=r"cut\.hdr: cannot read the Radiance HDR image"):
        load_environment(p)


def test_an_hdr_environment_without_openimageio_is_a_user_error(tmp_path, monkeypatch):
    """Without OpenImageIO a .hdr map is one error line naming the missing package."""
    import sys
    monkeypatch.setitem(sys.modules, "OpenImageIO", None)        # import fails
    p = tmp_path / "sky.hdr"
    p.write_bytes(b"#?RADIANCE\n")
    with pytest.raises(UserError, match=r"sky\.hdr: reading a Radiance HDR image needs OpenImageIO"):
        load_environment(p)
