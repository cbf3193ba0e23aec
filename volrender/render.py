"""One render path for both integrators: features -> program -> packed params -> launch
-> read back.

    scene = volrender.load_scene("smoke.vdb", size=(320, 240))
    image = volrender.render(scene)          # PoCL, or device="nvidia"
    image.save("smoke.exr")

The integrator modules (volume.py, glass.py) turn a Scene into a Plan: the kernel entry,
its features, the arrays it reads and the outputs it writes. Everything else, the same for
both, happens here. Each work-item owns its pixel (no float atomics), so an image depends
only on the scene and its seed.
"""
from __future__ import annotations

import base64
import dataclasses
import io
import math
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import device as device_mod, glass, volume
from .dispatch import Launch, PastDeadline, run_rows, upload
from .errors import ImageWarning, UserError, spell
from .progress import say
from .render_info import RenderInfo
from .scene import Scene, load_scene

VARIANTS = (None, "uber", "stats")     # comparison builds (bench): glass only
BUILD_NOTE = 100_000                   # clouds from which the build says so (seconds on PoCL)


@dataclass(frozen=True, eq=False)
class Image:
    """A rendered image: `rgba` is H x W x 4 float32, linear, top row first (premultiplied:
    alpha = 1 - transmittance for volumes, coverage for glass); `aovs` the extra layers by
    name (H x W float32)."""
    rgba: np.ndarray
    aovs: dict
    kernel_ms: float                 # OpenCL profiling events, summed over launches
    wall_ms: float                   # host time from the first launch to the read-back
    cpu_ms: float                    # process CPU time over the same span (PoCL's work)
    device: str
    flags: dict
    camera: object = None
    info: RenderInfo = field(default_factory=RenderInfo)
    noisy: np.ndarray | None = None  # the beauty before denoising (denoise="on"), else None

    @property
    def width(self) -> int:
        return self.rgba.shape[1]

    @property
    def height(self) -> int:
        return self.rgba.shape[0]

    def save(self, path, *, exposure: float = 0.0, view: str | None = None,
             tonemap: str = "filmic", png_bits: int = 8, transparent: bool | None = None) -> Path:
        """Write .exr (linear RGBA plus the AOVs), .npy or .png (sRGB through the view
        transform `view`, image.VIEWS; `tonemap` is its older name: opaque, or with
        transparent (default: the scene's --transparent) straight alpha:
        image.png_pixels), atomically."""
        from .image import write_image
        from .image import GUIDE_LAYERS
        tonemap = view or tonemap
        if transparent is None:
            transparent = self.info.transparent
        layers = dict(self.aovs)
        if Path(path).suffix.lower() != ".exr":     # guides and the noisy image: EXR only
            layers = {k: v for k, v in layers.items() if k not in GUIDE_LAYERS}
        elif self.noisy is not None:
            layers["noisy"] = self.noisy
        return write_image(path, self.rgba, layers or None, exposure=exposure, tonemap=tonemap,
                           camera=self.camera, png_bits=png_bits,
                           background=self.info.background,
                           png_alpha="straight" if transparent else "opaque")

    @property
    def seconds(self) -> float:
        """The render's time as the CLI reports it: set-up (packing, program, uploads)
        plus the launches up to the read-back, plus the guides and OIDN when denoised."""
        return (self.info.setup_ms + self.wall_ms + self.info.guides_ms
                + self.info.denoise_ms) / 1e3

    def __repr__(self) -> str:
        """One line: `<volrender.Image 320x240, 4 spp, pthread-..., 1.23 s>`."""
        spp = self.info.spp
        return (f"<volrender.Image {self.width}x{self.height}"
                + (f", {spp} spp" if spp is not None else "")
                + f", {self.device}, {self.seconds:.2f} s>")

    def __array__(self, dtype=None, copy=None):
        """np.asarray(image): the H x W x 4 linear premultiplied RGBA (float32)."""
        out = self.rgba if dtype is None else self.rgba.astype(dtype, copy=False)
        return out.copy() if copy else out

    def to_pil(self, *, exposure: float = 0.0, view: str | None = None, tonemap: str = "filmic"):
        """A PIL.Image (RGBA, 8-bit sRGB): what `save` writes to a .png (opaque unless the
        scene is transparent)."""
        from PIL import Image as PILImage
        from .image import png_pixels
        tonemap = view or tonemap
        alpha = "straight" if self.info.transparent else "opaque"
        codes = png_pixels(self.rgba, exposure, tonemap, background=self.info.background,
                           alpha=alpha)
        return PILImage.fromarray(codes, "RGBA")

    def _repr_png_(self) -> bytes:
        """The image as PNG bytes (Jupyter shows an Image with it): `to_pil`'s pixels."""
        buf = io.BytesIO()
        self.to_pil().save(buf, format="PNG")
        return buf.getvalue()

    def _repr_html_(self) -> str:
        """The picture with the repr's line under it (Jupyter prefers it to the PNG)."""
        import html
        data = base64.b64encode(self._repr_png_()).decode("ascii")
        return (f'<div><img src="data:image/png;base64,{data}" width="{self.width}" '
                f'height="{self.height}"/><br/><code>{html.escape(repr(self))}</code></div>')


PLANNERS = {"volume": volume.plan, "glass": glass.plan}


def render(scene, device=None, *, progress=None, variant=None, launch: Launch | None = None,
           **overrides) -> Image:
    """Render a Scene (volrender.load_scene) on `device` (a spec such as "nvidia", a
    device.Device, or None for the default). `scene` may also be what load_scene takes (a
    path, GENERATOR:COUNT, a numpy array), loaded with the `overrides`; with a Scene they
    change it (Scene.replace). `progress`: a bar on stderr (None: when it is a terminal).
    `variant`: "uber" or "stats" builds of the glass kernel (benchmarks). `launch`: how the
    image is cut into launches (dispatch.Launch; the default adapts). An image that came out
    empty, a solid silhouette or overexposed warns (errors.ImageWarning), saying the fix."""
    if not isinstance(scene, Scene):
        if not isinstance(scene, (str, os.PathLike, np.ndarray)):
            raise UserError(f"render() takes a Scene (volrender.load_scene), a file path or a "
                            f"numpy array, got {type(scene).__name__}")
        scene = load_scene(scene, **overrides)
    elif overrides:
        scene = scene.replace(**overrides)
    img = _render(scene, device, progress=progress, variant=variant, launch=launch)
    for problem in image_problems(img, scene.kind):
        warnings.warn(problem, ImageWarning, stacklevel=2)
    return img


SAMPLED_PIXELS = 1 << 16             # image_problems' shares are read on about this many


def image_problems(img, kind) -> list[str]:
    """Warnings for an image that came out empty, a solid silhouette or overexposed, each
    with its fix (kind: "volume" or "glass"). Empty is read on every pixel; the shares
    (opaque, overexposed) of an image over SAMPLED_PIXELS on a regular grid of about that
    many pixels: at 1080p the whole image's median took 40-140 ms of every render (a
    sequence's launching thread included) for a warning's threshold."""
    alpha = img.rgba[..., 3]
    what = "volume" if kind == "volume" else "point cloud"
    if not np.isfinite(alpha).all() or float(alpha.max()) < 1e-3:
        fix = ("raise --density-scale (`volrender info FILE` suggests one) or check the camera"
               if kind == "volume" else "check the camera (--origin, --target, --fov)")
        return [spell(f"the image is empty: the {what} covers no pixel (alpha < 0.001 "
                      f"everywhere); {fix}")]
    out = []
    step = max(1, math.isqrt(alpha.size // SAMPLED_PIXELS))
    grid = img.rgba[::step, ::step]
    alpha = grid[..., 3]
    covered = alpha > 0.01
    if kind == "volume" and covered.sum() >= 16 and float((alpha[covered] > 0.999).mean()) > 0.98:
        out.append("the volume renders as a solid silhouette (opaque in 98% of the pixels it "
                   "covers); lower --density-scale (`volrender info FILE` suggests one)")
    rgb = grid[..., :3][covered]
    if rgb.size and float(np.median(rgb.max(axis=-1))) > 4.0:
        out.append("the image is overexposed (half the covered pixels are above 4); lower the "
                   "lights' irradiance or --exposure")
    return [spell(p) for p in out]


def _render(scene, device=None, *, progress=None, variant=None, launch=None) -> Image:
    """render() of a Scene, without the image warnings (adaptive passes call it per pass),
    denoised when the scene's denoise is "on"."""
    if variant not in VARIANTS:
        raise UserError(f"unknown render variant {variant!r}", fix="use None, 'uber' or 'stats'")
    dev = device_mod.resolve(device)
    if scene.kind == "volume" and volume.adaptive(scene.settings):     # passes (issue #22)
        img = render_passes(scene, dev, progress=progress, launch=launch)
    else:
        img = _beauty(scene, dev, progress=progress, variant=variant, launch=launch)
    if getattr(scene.settings, "denoise", "off") == "on":
        img = denoised(scene, dev, img)
    return img


def denoised(scene, dev, img) -> Image:
    """`img` denoised by OIDN (volrender.denoise) with the scene's guides (volrender.guides:
    albedo, and normal for glass), which join its AOVs; the noisy beauty stays as Image.noisy. Without
    pyoidn: `img` unchanged, a one-line warning, and info.denoise_note saying why."""
    from . import denoise as denoise_mod, guides
    why = denoise_mod.unavailable()
    if why:
        warnings.warn(f"not denoised: {why}", ImageWarning, stacklevel=3)
        return dataclasses.replace(img, info=img.info.replace(denoised=False, denoise_note=why))
    base = scene
    if scene.kind == "volume":          # one plan of one pass (the guides ignore the samples)
        base = scene.replace(content=dataclasses.replace(
            scene.content, settings=dataclasses.replace(
                scene.content.settings, noise_target=None, time_limit=None, denoise="off")))
    t0, c0 = time.perf_counter(), time.process_time()
    plan = PLANNERS[scene.kind](base, dev, None, None)
    g = guides.render_guides(base, dev, plan)
    t1, c1 = time.perf_counter(), time.process_time()
    # volumes: the albedo guide only (the density-gradient normal made OIDN keep the noise
    # as detail: WDAS 4 spp 17 % -> 48 % relative RMSE, docs/error_time.md); glass: both
    normal = g["normal"] if scene.kind == "glass" else None
    rgba = denoise_mod.denoise(img.rgba, g["albedo"], normal)
    t2, c2 = time.perf_counter(), time.process_time()
    return dataclasses.replace(
        img, rgba=rgba, noisy=img.rgba, aovs={**img.aovs, **g},
        info=img.info.replace(denoised=True, guides_ms=1e3 * (t1 - t0),
                              denoise_ms=1e3 * (t2 - t1), guides_cpu_ms=1e3 * (c1 - c0),
                              denoise_guides="albedo, normal" if normal is not None else "albedo",
                              denoise_cpu_ms=1e3 * (c2 - c1)))


@dataclass
class Setup:
    """A render's set-up (_setup): its plan, kernel, argument buffers and output buffers,
    made on one queue; _launch runs it on another queue of the same context."""
    plan: object
    kernel: object
    args: list
    outs: dict
    setup_ms: float


def _setup(scene, dev, *, progress=None, variant=None, launch=None) -> Setup:
    """Everything before a pass's launches: the plan (the acceleration's build runs on
    dev.queue), the program, the uploads; dev.queue is finished, so another queue of the
    context may launch with it."""
    import pyopencl as cl
    cam = scene.camera
    t_plan = time.perf_counter()
    if scene.kind == "glass" and scene.content.builds == 0 and len(scene.content.cloud) >= BUILD_NOTE:
        say(f"building the acceleration for {len(scene.content.cloud)} spheres ...", progress)
    plan = PLANNERS[scene.kind](scene, dev, variant, launch)
    check_image_memory(cam.width, cam.height, dev, len(plan.aovs))
    kernel = dev.kernel(plan.entry, plan.features.flags(), options=plan.build_options)
    ctx, q = dev.context, dev.queue
    args = [upload(ctx, a, q) if isinstance(a, np.ndarray) else a for _, a in plan.inputs]
    outs = {name: cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, 4 * int(np.prod(shape)))
            for name, shape in plan.outputs}
    args += list(outs.values())
    args += [upload(ctx, a, q) if isinstance(a, np.ndarray) else a for _, a in plan.extra]
    dev.queue.finish()                  # the uploads done (their arrays live until here)
    # packing, program (cached after the first), uploads
    return Setup(plan, kernel, args, outs, 1e3 * (time.perf_counter() - t_plan))


def _beauty(scene, dev, *, progress=None, variant=None, launch=None, deadline=None,
            profile=None) -> Image:
    """One render of a Scene's beauty (and AOVs) in one pass of settings.spp samples
    (deadline: a time.perf_counter() past which its launches stop, dispatch.PastDeadline)."""
    setup = _setup(scene, dev, progress=progress, variant=variant, launch=launch)
    return _launch(scene, dev, setup, progress=progress, launch=launch, deadline=deadline,
                   profile=profile)


def _launch(scene, dev, setup: Setup, *, progress=None, launch=None, deadline=None,
            profile=None) -> Image:
    """A set-up pass's launches on dev.queue, and the read-back."""
    import pyopencl as cl
    cam, plan, outs = scene.camera, setup.plan, setup.outs
    t0, c0 = time.perf_counter(), time.process_time()
    run = run_rows(dev, setup.kernel, setup.args, cam.width, cam.height, plan.band_pixels,
                   progress, dispatch=plan.dispatch, spp=plan.spp,
                   launch=launch, deadline=deadline, profile=profile)
    host = {}
    for name, shape in plan.outputs:
        if name == "rgba" or name in plan.aovs:
            host[name] = np.empty(shape, np.float32)
            cl.enqueue_copy(dev.queue, host[name], outs[name])
    dev.queue.finish()
    wall_ms, cpu_ms = 1e3 * (time.perf_counter() - t0), 1e3 * (time.process_time() - c0)
    rgba = host.pop("rgba")
    aovs = {}
    for name in plan.aovs:
        if name in host:                  # (value, weight) pairs keep the value
            aovs[name] = host[name][..., 0].copy() if host[name].ndim == 3 else host[name]
        else:
            aovs[name] = _derived_aov(name, rgba)
    return Image(rgba=rgba, aovs=aovs, kernel_ms=run.kernel_ms, wall_ms=wall_ms, cpu_ms=cpu_ms,
                 device=dev.name, flags=plan.features.flags(), camera=cam,
                 info=plan.info.replace(
                     transparent=bool(getattr(scene.settings, "transparent", False)),
                     setup_ms=setup.setup_ms, launches=run.launches, spp=plan.spp,
                     row_cost=run.profile,
                     samples_taken=sum(r * k for _, r, k in run.took) // cam.height,
                     launch_s=tuple(t for t, _, _ in run.took),
                     launch_ends_s=tuple(run.ends)))


@dataclass(eq=False)
class Prepared:
    """A render split in two (render.prepare): the set-up done, the launches left to
    finish(). A sequence builds and uploads frame n+1 in one thread while frame n's
    launches run in another (volrender/pipeline.py)."""
    scene: Scene
    device: object
    setup: Setup | None = None       # None: a render that does not split (passes, denoise)

    def finish(self, *, progress=None) -> Image:
        """The launches and the read-back on the device's queue: render()'s Image, and its
        warnings."""
        if self.setup is None:
            img = _render(self.scene, self.device, progress=progress)
        else:
            img = _launch(self.scene, self.device, self.setup, progress=progress)
        self.setup = None                 # the device buffers go with it
        for problem in image_problems(img, self.scene.kind):
            warnings.warn(problem, ImageWarning, stacklevel=2)
        return img


def prepare(scene: Scene, device=None, *, builder=None) -> Prepared:
    """The first half of render(scene, device): the plan, the acceleration's build, the
    program and the uploads, made on `builder`'s queue (a Device sharing the device's
    context, Device.side(); default: the device itself); Prepared.finish() renders on the
    device's own queue, so the same bytes as render(). Adaptive passes and denoised renders
    do all their work in finish()."""
    dev = device_mod.resolve(device)
    if (scene.kind == "volume" and volume.adaptive(scene.settings)) or \
            getattr(scene.settings, "denoise", "off") == "on":
        return Prepared(scene, dev)
    return Prepared(scene, dev, _setup(scene, builder or dev))


def _derived_aov(name, rgba):
    if name == "transmittance":
        return 1.0 - rgba[..., 3]
    raise AssertionError(f"no kernel output for AOV {name!r}")


def check_image_memory(width: int, height: int, dev, n_layers: int = 0):
    """Refuse an image whose buffers cannot exist, before anything is allocated: the RGBA
    float32 buffer (plus one float per extra layer) must fit in one device allocation
    and in the device's memory, and a few copies of it in host memory (`dev` None: host
    memory only, for a sequence whose frames render on workers' devices)."""
    pixels = width * height
    need = pixels * 4 * (4 + n_layers)
    gib = 1 << 30
    limit, where = float("inf"), ""
    if dev is not None:
        d = dev.device
        limit = min(int(d.max_mem_alloc_size) * (4 + n_layers) // 4, int(d.global_mem_size) // 2)
        where = f"on {dev.name}"
    try:
        host = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") // 3
    except (ValueError, OSError, AttributeError):
        host = None
    if host is not None and host < limit:
        limit, where = host, "in this machine's memory"
    if need > limit and limit != float("inf"):
        side = int(math.sqrt(limit / (4 * (4 + n_layers)) * width / height))
        hint = f"e.g. {max(1, side)}x{max(1, side * height // width)}"
        raise UserError(f"a {width}x{height} image needs {need / gib:.1f} GiB of buffers, more than "
                        f"fits {where} ({limit / gib:.1f} GiB)",
                        fix=f"render a smaller size (--size, or [render].size; {hint} at most)")


def render_passes(scene, device=None, *, progress=None, launch=None):
    """Render a volume scene in independent passes (seeds seed, seed + 1, ...) until the
    estimated relative error of the covered pixels (volume.noise_estimate) is at most
    settings.noise_target (after volume.ADAPTIVE_MIN_PASSES passes), settings.max_spp
    samples per pixel are taken (with a target), or settings.time_limit seconds have
    passed. With a time limit the first pass is one sample per pixel (the least an image
    needs; said when even that overran the limit) and later passes are sized to fit from the
    measured seconds per sample; a pass still running at the limit is dropped (its launches
    stop, dispatch.PastDeadline). Without one, passes of settings.spp samples. After the
    minimum passes each is sized to reach the target from the noise so far (noise ~
    1/sqrt(N)), at most doubling the samples. The image is the sample-weighted mean of the
    passes; info (RenderInfo): spp (the samples taken, also counted launch by launch in
    samples_taken), noise (the covered pixels' estimate), noise_whole (the whole
    image's, for comparison), history ((spp, noise, noise_whole) after each pass),
    noise_map (the per-pixel standard error, H x W), stopped (why)."""
    # auto resolved once, with the passes' settings: per pass it would plan its own samples
    # (volume.auto_estimator) and the passes would take more than they count
    scene, note = volume.resolved(scene, device)
    s = scene.content.settings
    base = dataclasses.replace(s, noise_target=None, time_limit=None, denoise="off")
    target, limit = s.noise_target, s.time_limit
    cap = min(s.max_spp, volume.ADAPTIVE_MAX_SPP) if target is not None else volume.ADAPTIVE_MAX_SPP
    t0 = time.perf_counter()
    deadline = None if limit is None else t0 + limit
    batch = 1 if limit is not None else max(1, min(s.spp, cap))
    mean = m2 = None
    aovs = {}
    n = passes = taken = 0
    kernel_ms = cpu_ms = 0.0
    noise, whole, why, last, history = math.inf, math.inf, "", None, []
    while True:
        st = dataclasses.replace(base, spp=batch, seed=s.seed + passes)
        content = dataclasses.replace(scene.content, settings=st)
        try:
            img = _beauty(scene.replace(content=content), device, progress=progress,
                          launch=launch, deadline=deadline if passes else None,
                          profile=last.info.row_cost if last is not None else None)
        except PastDeadline:
            why = f"time limit {limit:g} s (the pass under way then, {batch} spp, dropped)"
            break
        x = img.rgba.astype(np.float64)
        if mean is None:
            mean, m2 = x, np.zeros_like(x)
        else:                             # Chan et al.: merge (n, mean) with (batch, x)
            d = x - mean
            tot = n + batch
            mean = mean + d * (batch / tot)
            m2 = m2 + d * d * (n * batch / tot)
        for k, v in img.aovs.items():
            aovs[k] = v if k not in aovs else aovs[k] + (v - aovs[k]) * (batch / (n + batch))
        n += batch
        taken += img.info.samples_taken
        passes += 1
        kernel_ms += img.kernel_ms
        cpu_ms += img.cpu_ms
        last = img
        elapsed = time.perf_counter() - t0
        if passes >= 2:
            _, noise = volume.noise_estimate(mean, m2, passes, n)
            _, whole = volume.noise_estimate(mean, m2, passes, n, np.ones(mean.shape[:2], bool))
            history.append((n, noise, whole))
        if target is not None and passes >= volume.ADAPTIVE_MIN_PASSES and noise <= target:
            why = f"noise {noise:.3g} <= target {target:g}"
            break
        per_spp = elapsed / n
        left = math.inf if limit is None else limit - elapsed
        if passes == 1 and left <= 0:
            why = (f"time limit {limit:g} s: one sample per pixel took {elapsed:.2f} s, the "
                   "least an image needs")
            break
        if left < per_spp:
            why = f"time limit {limit:g} s"
            break
        if n >= cap:
            why = (f"the cap of {cap} spp (--max-spp)" if target is not None and cap == s.max_spp
                   else f"{cap} spp")
            break
        want = max(1, min(s.spp, cap))
        if target is not None and passes >= volume.ADAPTIVE_MIN_PASSES and math.isfinite(noise):
            want = int(math.ceil(n * ((noise / target) ** 2 - 1.0) * 1.05))
        elif passes >= volume.ADAPTIVE_MIN_PASSES:
            want = n                      # a time limit alone: doubling passes
        elif limit is not None:           # the minimum passes share what time is left
            want = min(want, int(left / per_spp / (volume.ADAPTIVE_MIN_PASSES - passes + 1)))
        batch = int(max(1, min(want, n if passes >= volume.ADAPTIVE_MIN_PASSES else want,
                               left / per_spp if math.isfinite(left) else math.inf, cap - n)))
    se = volume.noise_estimate(mean, m2, passes, n)[0] if passes >= 2 else None
    if target is not None and noise > target and math.isfinite(noise):
        why += f" before the target {target:g}"
    info = last.info.replace(
        estimator_note=note or last.info.estimator_note, spp=n, samples_taken=taken,
        passes=passes, noise=noise, noise_whole=whole, history=tuple(history), stopped=why,
        adaptive=f"{passes} passes, {n} spp in {time.perf_counter() - t0:.2f} s: "
                 f"stopped at {why}; estimated error of the covered pixels "
                 + (f"{noise:.3g}" if math.isfinite(noise) else "unknown (one pass)"),
        noise_map=(np.sqrt((se ** 2).mean(axis=-1)).astype(np.float32)
                   if se is not None else None))
    return Image(rgba=mean.astype(np.float32), aovs=aovs, kernel_ms=kernel_ms,
                 wall_ms=1e3 * (time.perf_counter() - t0), cpu_ms=cpu_ms, device=last.device,
                 flags=last.flags, camera=last.camera, info=info)
