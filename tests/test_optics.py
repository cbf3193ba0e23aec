"""Glass optics against closed forms: the exact Fresnel equations (s and p) through the
kernel, total internal reflection inside a sphere in a white furnace and from outside
(IOR < 1), the fast model's walk through two spheres against the same walk in float64, the
shading of one opaque sphere, and IOR-1 glass whose chords give Beer-Lambert and the glow
integral.

Renders go through the public path (render.render of a Scene) with single spheres at
blend 0, where the smooth union is the sphere's exact distance. Tolerances come from
the error each quantity can have (float32 arithmetic; hit points within the threshold
eps (base + t) of the surface plus the ray offsets of 4 eps max(path, |p|)); each is
derived where it is used."""
import dataclasses
import math

import numpy as np
import pytest
from glass_probe import optics

from helpers import env_lookup, fresnel, look_at, ray_sphere, render_glass, texel_dirs
import reference
from volrender.glass import GlassSettings
from volrender.lights import PointLight, Sun
from volrender.cloud import PointCloud

ETAS = (1 / 1.5, 1 / 1.33, 1 / 2.4, 1 / 16, 1.5, 1.33, 2.4, 16.0)   # n_incident / n_transmitted
SPHERE = PointCloud(np.zeros((1, 3)), np.array([1.0]))              # radius 1 at the origin


def fresnel_angles(theta_i, eta):
    """F, rs, rp from the angle forms (independent of the kernel's cosine forms):
    rs = -sin(ti - tt) / sin(ti + tt), rp = tan(ti - tt) / tan(ti + tt), Snell
    sin tt = eta sin ti; the limit ((eta - 1) / (eta + 1))^2 at normal incidence, 1 past
    the critical angle."""
    theta_i = np.asarray(theta_i, np.float64)
    s = eta * np.sin(theta_i)
    tir = s >= 1.0
    tt = np.arcsin(np.minimum(s, 1.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        rs = -np.sin(theta_i - tt) / np.sin(theta_i + tt)
        rp = np.tan(theta_i - tt) / np.tan(theta_i + tt)
    normal = theta_i == 0.0
    r0 = (eta - 1.0) / (eta + 1.0)
    rs = np.where(normal, -r0, np.where(tir, 1.0, rs))
    rp = np.where(normal, r0, np.where(tir, 1.0, rp))
    return 0.5 * (rs * rs + rp * rp), rs, rp


def kernel_fresnel(dev, theta, eta):
    """(F, cos_i as float32 passed) from the probe's glass_fresnel, normal +z."""
    d = np.stack([np.sin(theta), 0 * theta, -np.cos(theta)], axis=1).astype(np.float32)
    out = optics(dev, d, eta)
    return out[:, 3].astype(np.float64), -d[:, 2].astype(np.float64)


def float32_bound(cos_i, eta):
    """How far float32 can put the kernel's F from the exact F at this cos_i: s2 =
    eta^2 (1 - cos^2) carries a few ulps (relative 4e-7), which move cos_t = sqrt(1 - s2)
    by up to 4e-7 s2 / (2 cos_t) (or sqrt(4e-7 s2) where cos_t -> 0, the critical angle),
    plus ~1e-6 of rounding in the quotients and the mean of squares."""
    s2 = eta * eta * (1 - cos_i * cos_i)
    ct = np.sqrt(np.maximum(1 - s2, 0.0))
    dct = np.minimum(4e-7 * s2 / (2 * np.maximum(ct, 1e-12)), np.sqrt(4e-7 * s2))

    def f_of(ct_):
        rs = (eta * cos_i - ct_) / (eta * cos_i + ct_)
        rp = (cos_i - eta * ct_) / (cos_i + eta * ct_)
        return 0.5 * (rs * rs + rp * rp)
    spread = np.abs(f_of(np.maximum(ct - dct, 0.0)) - f_of(ct + dct))
    return np.where(s2 >= 1, 0.0, spread) + 1e-6


@pytest.mark.parametrize("eta", ETAS)
def test_fresnel_is_exact_over_all_angles(cl_device, eta):
    """F(theta) on 2000 angles from 0 to 90 degrees against the angle forms of rs and
    rp, within float32's error at each angle (float32_bound): the unpolarised mean of
    the two, not either alone (s alone is off by up to 0.1 at 60 degrees from glass)."""
    theta = np.linspace(0.0, 0.5 * np.pi * (1 - 1e-6), 2000)
    f_k, cos_i = kernel_fresnel(cl_device, theta, eta)
    f_ref, _, _ = fresnel_angles(np.arccos(np.clip(cos_i, -1, 1)), eta)
    tol = float32_bound(cos_i, eta)
    bad = np.abs(f_k - f_ref) > tol
    assert not bad.any(), (f"eta {eta:.4g}: {bad.sum()} angles off, worst at "
                           f"{np.degrees(theta[np.argmax(np.abs(f_k - f_ref) - tol)]):.2f} deg")
    # the two forms are one physics: the cosine forms in float64 agree to rounding
    np.testing.assert_allclose(fresnel(cos_i, eta)[2], f_ref, atol=1e-12)
    assert f_k[0] == pytest.approx(((eta - 1) / (eta + 1)) ** 2, abs=1e-6)


@pytest.mark.parametrize("eta", [e for e in ETAS if e != 16.0 and e != 1 / 16])
def test_brewster_angle_zeroes_rp(cl_device, eta):
    """At Brewster's angle tan(theta_B) = 1 / eta the p-polarised reflection vanishes and
    theta_i + theta_t = 90 degrees, so F = rs^2 / 2 = cos^2(2 theta_B) / 2. Around it, the
    kernel's F minus the s half (rs^2 / 2 from the angle form) is rp^2 / 2, which has its
    zero there (rp = rs would double F at theta_B)."""
    tb = math.atan(1.0 / eta)
    f_k, cos_i = kernel_fresnel(cl_device, np.array([tb]), eta)
    assert f_k[0] == pytest.approx(0.5 * math.cos(2 * tb) ** 2, abs=2e-6)
    theta = tb + np.linspace(-0.3, 0.3, 61)
    theta = theta[(theta > 0) & (theta < 0.5 * np.pi) & (eta * np.sin(theta) < 0.999)]
    f_k, cos_i = kernel_fresnel(cl_device, theta, eta)
    _, rs, rp = fresnel_angles(np.arccos(cos_i), eta)
    rp2 = 2 * f_k - rs * rs
    np.testing.assert_allclose(rp2, rp * rp, atol=4e-6)
    assert abs(theta[np.argmin(rp2)] - tb) <= 0.3 / 60 + 1e-9        # the zero, to the grid


@pytest.mark.parametrize("n", [1.33, 1.5, 2.4])
def test_fresnel_is_reciprocal(cl_device, n):
    """Stokes: light crossing a surface either way at the paired angles (Snell) reflects
    the same fraction, F(theta_i; 1/n) = F(theta_t; n)."""
    ti = np.linspace(0.0, 0.5 * np.pi * 0.999, 400)
    tt = np.arcsin(np.sin(ti) / n)
    f_in, _ = kernel_fresnel(cl_device, ti, 1 / n)
    f_out, _ = kernel_fresnel(cl_device, tt, n)
    # float32 as in float32_bound, at the larger of the two sides' errors
    tol = np.maximum(float32_bound(np.cos(ti), 1 / n), float32_bound(np.cos(tt), n))
    assert np.all(np.abs(f_in - f_out) <= 2 * tol)


def impact(o, d, c=np.zeros(3)):
    """Distance from c to the line o + t d (unit d)."""
    oc = np.asarray(o) - c
    return np.linalg.norm(oc - (d @ oc)[..., None] * d, axis=-1)


@pytest.mark.parametrize("ior", [1.5, 2.4])
def test_trapped_rays_return_the_white_furnace_exactly(cl_device, ior):
    """The eye inside a glass sphere (radius 1) in a uniform environment of radiance 1,
    no absorption, glow or lights. A ray whose line passes the centre at distance b > 1/n
    meets the surface beyond the critical angle, and so does every reflection of it (b is
    kept): it is trapped until the bounce budget runs out and, still inside glass,
    returns 0 (a path tracer's depth: nothing it carries escapes). A ray with b < 1/n
    leaves at
    cos_i = sqrt(1 - b^2) keeping at least its transmitted share 1 - F (what it sees
    beyond is 1) and at most all of it (the furnace is lossless). Float error: the hit
    point lies within eps (base + t) ~ 2e-5 of the surface (epsilon 1e-5, base + t ~ 2),
    so its normal, and the b it implies, by up to db = 5e-5 (x 2.5): the bound is
    1 - F(b + db) (F grows with b), and rays within 1e-3 of the critical b are left out,
    where F changes too fast for that to be a useful bound."""
    eye = np.array([0.8, 0.1, 0.0])
    cam = look_at(eye, target=eye + (-1.0, 0.0, -1.0), fov=100.0, n=24)
    s = GlassSettings(env=(1.0, 1.0, 1.0), absorption=(0.0, 0.0, 0.0), glow=0.0, ior=ior,
                      blend=0.0, bounces=8, epsilon=1e-5, glass_model="fast")
    img = render_glass(SPHERE, cam, [], s, cl_device).rgba.astype(np.float64)
    assert (img[..., 3] == 1).all()                      # every primary ray starts in glass
    b = impact(eye, cam.pixel_dirs())
    trapped = b > 1 / ior + 1e-3
    leaves = b < 1 / ior - 1e-3
    assert trapped.sum() > 50 and leaves.sum() > 50, (trapped.sum(), leaves.sum())
    np.testing.assert_allclose(img[trapped][:, :3], 0.0, atol=1e-6)
    f = fresnel(np.sqrt(1 - np.minimum(b[leaves] + 5e-5, 1.0) ** 2), ior)[2]
    got = img[leaves][:, :3]
    assert np.all(got >= (1 - f)[:, None] - 1e-5), np.min(got - (1 - f)[:, None])
    assert np.all(got <= 1 + 1e-6)
    # the full model (the default) follows each exit's reflection too: trapped rays, which
    # never split, are exactly 0 again; a leaving ray's reflections keep F^k inside after
    # k events, so it returns 1 - F^N (N = bounces), up to the roulette of weak branches
    # (at most roulette per event); F^N is N times as sensitive to b: rays within 8e-3 of
    # the critical b are left out
    full = dataclasses.replace(s, glass_model="full")
    img = render_glass(SPHERE, cam, [], full, cl_device).rgba.astype(np.float64)
    np.testing.assert_allclose(img[trapped][:, :3], 0.0, atol=1e-6)
    lo = 1 - fresnel(np.sqrt(1 - np.minimum(b[leaves] + 5e-5, 1.0) ** 2), ior)[2] ** full.bounces
    hi = 1 - fresnel(np.sqrt(1 - np.maximum(b[leaves] - 5e-5, 0.0) ** 2), ior)[2] ** full.bounces
    tol = full.roulette * full.bounces
    got = img[leaves][:, :3]
    far = np.abs(b[leaves] - 1 / ior) > 8e-3
    lo, hi, got = lo[far], hi[far], got[far]
    assert np.all(got >= lo[:, None] - tol) and np.all(got <= hi[:, None] + tol)


@pytest.mark.parametrize("model", ["full", "fast"])
def test_total_reflection_from_outside_is_the_mirror_share(cl_device, model):
    """IOR 1/2 (glass thinner than air), a uniform environment L, reflectivity rho: a ray
    from outside meeting the sphere (radius 1) at impact parameter b > 1/2 is past the
    critical angle (sin_t = 2 b > 1), so F = 1 and all of it is reflected, once (the
    sphere is convex), into the environment: rho L exactly, in either model. Float error:
    only near the critical b (the normal is within ~5e-5 / cos_i of the true one: rays
    within 1e-3 of b = 1/2 are left out) and at grazing rays (b > 0.99, which may miss)."""
    L, rho = np.array([0.2, 0.3, 0.4]), 0.7
    cam = look_at((0.0, 0.0, 4.0), fov=35.0, n=24)
    s = GlassSettings(ior=0.5, env=tuple(L), reflectivity=rho, absorption=(0.0, 0.0, 0.0),
                      glow=0.0, blend=0.0, bounces=4, epsilon=1e-5, glass_model=model)
    img = render_glass(SPHERE, cam, [], s, cl_device).rgba.astype(np.float64)
    b = impact(cam.origin, cam.pixel_dirs())
    tir = (b > 0.5 + 1e-3) & (b < 0.99)
    assert tir.sum() > 50, tir.sum()
    np.testing.assert_allclose(img[tir][:, :3], np.broadcast_to(rho * L, (tir.sum(), 3)),
                               rtol=1e-5)


def union_hit(o, d, spheres, inside):
    """The next surface event of o + t d (unit d) on the exact union of spheres (blend 0):
    (t, centre, radius) of the sphere whose surface it is, or None. Outside: the nearest
    entry; inside: the end of the union's interval containing o (each sphere's chord that
    starts before it ends extends it)."""
    ivs = []
    for c, r in spheres:
        oc = o - c
        b = d @ oc
        disc = b * b - (oc @ oc - r * r)
        if disc > 0:
            ivs.append((-b - math.sqrt(disc), -b + math.sqrt(disc), c, r))
    if not inside:
        ahead = [(t0, c, r) for t0, _, c, r in ivs if t0 > 1e-7]
        return min(ahead, key=lambda h: h[0]) if ahead else None
    end, hit, grown = 0.0, None, True
    while grown:
        grown = False
        for t0, t1, c, r in ivs:
            if t0 <= end + 1e-7 and t1 > end + 1e-7:
                end, hit, grown = t1, (t1, c, r), True
    return hit


def fast_walk(o, d, spheres, ior, rho, L, bounces):
    """cl/shade_glass.h's fast glass_walk in float64 on a union of spheres in a uniform
    environment L (no lights, absorption or glow): at an outer surface F rho L is added
    and 1 - F refracts in; inside, total internal reflection keeps everything and any
    other exit refracts 1 - F out; a path that meets its bounces + 1st event returns what
    it has. Returns (radiance, whether a totally reflected path escaped, the smallest
    |eta^2 sin_i^2 - 1| and cos_i of its events, how close an event came to another
    sphere's surface)."""
    inside = any(np.linalg.norm(o - c) < r for c, r in spheres)
    rgb, thr, tir = 0.0 * L, 1.0, False
    near_crit = grazing = crease = np.inf
    for events in range(bounces + 1):
        h = union_hit(o, d, spheres, inside)
        if h is None:
            return rgb + thr * L, tir, near_crit, grazing, crease
        if events == bounces:
            break
        t, c, r = h
        o = o + t * d
        n = (o - c) / r
        crease = min([crease] + [abs(np.linalg.norm(o - c2) - r2) for c2, r2 in spheres
                                 if c2 is not c])
        nf = -n if inside else n
        cos_i = min(max(-(d @ nf), 0.0), 1.0)
        eta = ior if inside else 1.0 / ior
        s2 = eta * eta * (1.0 - cos_i * cos_i)
        near_crit, grazing = min(near_crit, abs(s2 - 1.0)), min(grazing, cos_i)
        f = fresnel(cos_i, eta)[2]
        if not inside:
            rgb = rgb + thr * f * rho * L
        if s2 >= 1.0:
            if not inside:
                break
            tir = True
            d = d - 2.0 * (d @ nf) * nf
        else:
            thr *= 1.0 - f
            d = eta * d + (eta * cos_i - math.sqrt(1.0 - s2)) * nf
            d /= np.linalg.norm(d)
            inside = not inside
    return rgb, False, near_crit, grazing, crease


def test_fast_model_against_a_path_walk_through_two_spheres(cl_device):
    """The fast model's walk on two overlapping spheres (blend 0: their exact union), the
    eye inside the larger, against fast_walk per pixel. Rays totally reflected inside the
    large sphere ride around its rim until they reach the cap inside the small one and
    leave through it: the test asserts some 20 such pixels, which see everything TIR kept.
    Error: a hit point lies within ~1e-4 of the surface (the threshold eps (base + t) and
    the offsets 4 eps |p|), so a normal within ~1.5e-4 rad (radius 0.7); |dF/dcos_i| <=
    11.5 where |eta^2 sin_i^2 - 1| >= 0.05 and cos_i >= 0.2 (IOR 1.5): <= 2e-3 per event
    near the critical angle, a few such events per path: 5e-3 (measured 1.9e-3). Pixels
    with an event closer than that to the critical angle or grazing, or within 0.02 of
    the crease where the spheres meet (normals jump there), are left out."""
    spheres = [(np.zeros(3), 1.0), (np.array([1.3, 0.0, 0.0]), 0.7)]
    L, rho, ior, bounces = np.array([0.2, 0.3, 0.4]), 0.7, 1.5, 8
    eye = np.array([-0.3, 0.2, 0.1])
    cam = look_at(eye, target=eye + (1.0, 0.0, -0.6), fov=120.0, n=32)
    cloud = PointCloud(np.array([c for c, _ in spheres]), np.array([r for _, r in spheres]))
    s = GlassSettings(ior=ior, env=tuple(L), reflectivity=rho, absorption=(0.0, 0.0, 0.0),
                      glow=0.0, blend=0.0, bounces=bounces, epsilon=1e-5, glass_model="fast")
    img = render_glass(cloud, cam, [], s, cl_device).rgba.astype(np.float64)
    dirs = cam.pixel_dirs()
    want = np.zeros(dirs.shape)
    tir, use = np.zeros(dirs.shape[:2], bool), np.zeros(dirs.shape[:2], bool)
    for i, j in np.ndindex(*dirs.shape[:2]):
        d = dirs[i, j] / np.linalg.norm(dirs[i, j])
        want[i, j], tir[i, j], near_crit, grazing, crease = fast_walk(
            eye, d, spheres, ior, rho, L, bounces)
        use[i, j] = near_crit >= 0.05 and grazing >= 0.2 and crease >= 0.02
    assert use.sum() > 800 and (use & tir).sum() >= 20, (use.sum(), (use & tir).sum())
    err = np.abs(img[..., :3] - want).max(-1)
    assert err[use].max() <= 5e-3, (err[use].max(), np.unravel_index(np.argmax(err * use), err.shape))


def shade_opaque(cam, spheres, lights, env, col, ior, rho, shin):
    """Closed form of every pixel of opaque spheres (cl/shade_glass.h, refraction off)
    that do not overlap (blend 0: the union is exact): at the first hit, the
    Fresnel-weighted mirror reflection of the environment, F rho env(r); the
    Fresnel-weighted normalised Blinn-Phong highlights, F sum E (n.l) (s + 8) / (8 pi)
    (n.h)^s; the transmitted share of the tint lit diffusely, (1 - F) col (env(n) +
    sum E (n.l) / pi) (Lambert). Each light (E: a sun's irradiance, a point light's I / r^2)
    counts where n.l > 0 and its shadow ray meets no sphere. env(w): radiance along w.
    Returns (rgb, hit sphere index or -1, cos_i, how close a shadow ray passes to a
    sphere's silhouette, the smaller |z| of n and r)."""
    d = cam.pixel_dirs()
    o = np.asarray(cam.origin, np.float64)
    ts = np.stack([ray_sphere(o, d, np.asarray(c), r) for c, r in spheres], -1)
    idx = np.where(np.isfinite(ts.min(-1)), ts.argmin(-1), -1)
    t = ts.min(-1)
    centre = np.array([spheres[i][0] for i in range(len(spheres))])[np.maximum(idx, 0)]
    radius = np.array([spheres[i][1] for i in range(len(spheres))])[np.maximum(idx, 0)]
    p = o + np.where(np.isfinite(t), t, 0.0)[..., None] * d
    n = (p - centre) / radius[..., None]
    v = -d
    cos_i = np.clip((n * v).sum(-1), 0.0, 1.0)
    F = fresnel(cos_i, 1.0 / ior)[2]
    r = d - 2 * (d * n).sum(-1)[..., None] * n
    spec = np.zeros(d.shape[:2])
    diff = np.zeros(d.shape[:2])
    edge = np.full(d.shape[:2], np.inf)
    for light in lights:
        if isinstance(light, Sun):
            l = np.broadcast_to(-np.asarray(light.direction), d.shape)
            E, dist = np.full(d.shape[:2], light.irradiance), np.full(d.shape[:2], np.inf)
        else:
            to = np.asarray(light.position) - p
            dist = np.linalg.norm(to, axis=-1)
            l = to / dist[..., None]
            E = light.intensity / dist ** 2
        ndl = (n * l).sum(-1)
        vis = np.ones(d.shape[:2])
        for c, rad in spheres:
            hit = ray_sphere(p, l, np.asarray(c), rad)
            vis = np.where((hit > 1e-6) & (hit < dist), 0.0, vis)
            # distance of the shadow ray's line from the sphere's centre, against r
            oc = np.asarray(c) - p
            along = (oc * l).sum(-1)
            miss = np.linalg.norm(oc - along[..., None] * l, axis=-1)
            edge = np.where((ndl > 0) & (along > 0), np.minimum(edge, np.abs(miss - rad)), edge)
        lit = (ndl > 0) * vis
        h = (l + v) / np.linalg.norm(l + v, axis=-1, keepdims=True)
        ndh = np.maximum((n * h).sum(-1), 0.0)
        spec += lit * E * ndl * (shin + 8) / (8 * np.pi) * ndh ** shin
        diff += lit * E * ndl / np.pi
    rgb = (F * rho)[..., None] * env(r) + (F * spec)[..., None] \
        + (1 - F)[..., None] * col * (env(n) + diff[..., None])
    return rgb, idx, cos_i, edge, np.minimum(np.abs(n[..., 2]), np.abs(r[..., 2]))


def test_opaque_centre_pixel_by_hand(cl_device):
    """--opaque (refraction off), one sphere, a uniform environment L and a sun 60
    degrees off the view axis: at the centre pixel (normal incidence: F = 0.04, n.l =
    cos 60, n.h = cos 30) the radiance is F rho L + F E cos60 (s + 8) / (8 pi) cos30^s +
    (1 - F) col (L + E cos60 / pi). The hit lies on the axis, where the normal is exact:
    float32 rounding only (1e-5)."""
    E, L, col, ior, rho, shin = 2.0, np.array([0.2, 0.3, 0.4]), np.array([0.9, 0.6, 0.3]), 1.5, 0.7, 10.0
    sun = Sun((-math.sin(math.radians(60)), 0.0, -math.cos(math.radians(60))), E)
    cam = look_at((0.0, 0.0, 4.0), fov=35.0, n=21)
    s = GlassSettings(refraction=False, roulette=0.0, env=tuple(L), color=tuple(col), ior=ior,
                      reflectivity=rho, shininess=shin, blend=0.0, epsilon=1e-5)
    img = render_glass(SPHERE, cam, [sun], s, cl_device).rgba.astype(np.float64)
    F = 0.04
    by_hand = F * rho * L + F * E * 0.5 * (shin + 8) / (8 * np.pi) * math.cos(math.radians(30)) ** shin \
        + (1 - F) * col * (L + E * 0.5 / np.pi)
    np.testing.assert_allclose(img[10, 10, :3], by_hand, rtol=1e-5)
    want = shade_opaque(cam, [((0.0, 0.0, 0.0), 1.0)], [sun], lambda w: np.broadcast_to(L, w.shape),
                        col, ior, rho, shin)[0]
    np.testing.assert_allclose(want[10, 10], by_hand, rtol=1e-12)


def test_highlight_roulette_is_unbiased(cl_device):
    """A highlight whose unshadowed lobe is below --roulette is shadow-tested with
    probability lobe / roulette and weighted back (cl/shade_glass.h glass_highlights):
    with roulette 1 (nearly every highlight rouletted) the image averages to roulette 0's
    (the same pixel jitter: the per-pixel differences have mean zero within 5 standard
    errors) and is not the same image (the roulette ran)."""
    sun = Sun((-0.5, -0.3, -1.0), 4.0)
    cam = look_at((0.0, 0.0, 4.0), fov=35.0, n=21)
    s = GlassSettings(refraction=False, env=(0.2, 0.3, 0.4), shininess=10.0, blend=0.0,
                      roulette=0.0, spp=64)
    exact = render_glass(SPHERE, cam, [sun], s, cl_device).rgba.astype(np.float64)
    rr = render_glass(SPHERE, cam, [sun], dataclasses.replace(s, roulette=1.0),
                      cl_device).rgba.astype(np.float64)
    d = (rr - exact)[exact[..., 3] > 0][:, :3]
    assert np.abs(d).max() > 1e-3
    assert abs(d.mean()) <= 5 * d.std() / np.sqrt(d.size)


def front_back_map(h=32, w=64):
    """A map that is one colour towards +z (where the camera is) and another towards -z,
    with a gradient in y: texel centres decide."""
    d = texel_dirs(h, w)
    front, back = np.array([0.9, 0.5, 0.2]), np.array([0.1, 0.3, 0.8])
    t = np.where(d[..., 2:] > 0, front, back) * (1.0 + 0.5 * d[..., 1:2])
    return t.astype(np.float32)


@pytest.mark.parametrize("light", ["sun", "point"])
def test_opaque_spheres_are_their_closed_form(cl_device, light):
    """Two opaque spheres (blend 0) under an environment map and one light that the
    small sphere shadows on the big one: every pixel of the big sphere from shade_opaque.
    It sees the map along its mirror direction and along its normal (which differ: the
    map is another colour behind the sphere), the light's highlight and Lambert term,
    with a sun's E or a point light's I / r^2, and none of either in the shadow. Error:
    the hit lies within eps (base + t) ~ 5e-5 of the surface along the ray, so normals
    are within 5e-5 / cos_i radians, and |dL/dn| <= E / pi + F E (s + 8)/(8 pi) s + the
    map's slope (~2 over a texel of 0.1 rad) ~ 3.5: 2e-4 at cos_i >= 0.3, leaving out
    pixels whose shadow ray passes within 0.01 of a silhouette or whose n or r lie
    within 0.1 of the map's front/back seam (z = 0)."""
    col, ior, rho, shin = np.array([0.9, 0.6, 0.3]), 1.5, 0.7, 10.0
    spheres = [((0.0, 0.0, 0.0), 1.0), ((1.6, 0.9, 1.2), 0.45)]
    lights = {"sun": [Sun((-1.0, -0.55, -0.75), 2.0)],
              "point": [PointLight((3.0, 1.7, 2.3), 12.0)]}[light]
    env = front_back_map()
    cam = look_at((0.0, 0.0, 4.0), fov=40.0, n=32)
    cloud = PointCloud(np.array([c for c, _ in spheres]), np.array([r for _, r in spheres]))
    s = GlassSettings(refraction=False, roulette=0.0, glass_model="fast", color=tuple(col), ior=ior,
                      reflectivity=rho,
                      shininess=shin, blend=0.0, epsilon=1e-5)
    img = render_glass(cloud, cam, lights, s, cl_device, environment=env).rgba.astype(np.float64)
    want, idx, cos_i, edge, seam = shade_opaque(cam, spheres, lights, lambda w: env_lookup(env, w),
                                                col, ior, rho, shin)
    np.testing.assert_array_equal(img[..., 3] == 1, idx >= 0)
    use = (idx == 0) & (cos_i >= 0.3) & (edge > 0.01) & (seam > 0.1)
    shadowed = use & (want.sum(-1) < shade_opaque(cam, spheres[:1], lights,
                                                  lambda w: env_lookup(env, w), col, ior, rho,
                                                  shin)[0].sum(-1) - 1e-3)
    assert use.sum() > 250 and shadowed.sum() > 20, (use.sum(), shadowed.sum())
    err = np.abs(img[..., :3] - want).max(-1)
    assert err[use].max() <= 2e-4, (err[use].max(), np.unravel_index(np.argmax(err * use), err.shape))


@pytest.mark.parametrize("absorbs", [True, False])
@pytest.mark.parametrize("relax", [1.0, 1.6])
def test_ior_one_glass_is_beer_lambert_and_the_glow_integral(cl_device, relax, absorbs):
    """IOR 1: no reflection (F = 0) and no bending, so each pixel's ray crosses the sphere
    along its chord c and sees L exp(-a c) + glow col (1 - exp(-a c)) / a (the glow
    emitted along the chord, attenuated on the rest of the way: the integral of
    glow col exp(-a s) over [0, c]), per channel; without absorption L + glow col c.
    Absorption and glow are given per material unit 2 (world a = given / 2). Pixels that
    miss see L exactly. Chord error: the entry offset (4 eps max(path, |p|)) and the two
    hit thresholds (eps (base + t)) shorten it by at most 6 eps |o| / cos_i = 1.2e-3 at
    eps 1e-5, cos_i >= 0.3; |dL/dc| = exp(-a c) |glow col - a L| <= 1.2: 1.5e-3
    (measured: 1.4e-4 at relax 1)."""
    L, glow, col = np.array([0.2, 0.3, 0.4]), 0.7, np.array([1.0, 0.5, 0.25])
    a = np.array([0.5, 1.0, 2.0]) if absorbs else np.zeros(3)
    unit = 2.0
    cam = look_at((0.3, 0.2, 4.0), fov=35.0, n=21)
    s = GlassSettings(ior=1.0, env=tuple(L), absorption=tuple(a * unit), glow=glow * unit,
                      color=tuple(col), material_unit=unit, blend=0.0, bounces=3,
                      epsilon=1e-5, relax=relax)
    img = render_glass(SPHERE, cam, [], s, cl_device).rgba.astype(np.float64)
    d = cam.pixel_dirs().reshape(-1, 3)
    o = np.asarray(cam.origin)
    c = reference.sphere_chord(o, d, np.zeros(3), 1.0).reshape(21, 21)[..., None]
    cos_i = np.sqrt(np.clip(1 - impact(o, cam.pixel_dirs()) ** 2, 0, 1))
    if absorbs:
        want = L * np.exp(-a * c) + glow * col * (1 - np.exp(-a * c)) / a
    else:
        want = L + glow * col * c
    use = (c[..., 0] > 0) & (cos_i >= 0.3)
    assert use.sum() > 150
    np.testing.assert_allclose(img[use][:, :3], want[use], atol=1.5e-3)
    miss = c[..., 0] == 0
    np.testing.assert_allclose(img[miss][:, :3], np.broadcast_to(L, (miss.sum(), 3)), rtol=1e-6)
    assert miss.sum() > 20
