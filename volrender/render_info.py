"""What a render records besides its pixels (Image.info): a frozen record, read by attribute
(`img.info.spp`). Fields a render did not fill stay None (or 0 for times and counts).

Image.info was a dict; `img.info.spp` and `img.info.spp` still work and
warn (DeprecationWarning): a field that is None reads as missing there, as an absent key did.
"""
from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass

_MISSING = object()


@dataclass(frozen=True, eq=False)
class RenderInfo:
    """Image.info. The planners (glass.plan, volume.plan) fill their integrator's fields
    (dispatch.Plan.info names them), render the launch's, denoising and adaptive passes
    theirs."""
    # every render (render._beauty)
    spp: int | None = None               # samples per pixel taken: Plan.spp (passes: summed)
    samples_taken: int = 0               # counted launch by launch
    setup_ms: float = 0.0                # packing, program (cached after the first), uploads
    launches: int = 0
    launch_s: tuple = ()                 # each launch's seconds
    launch_ends_s: tuple = ()            # each launch's end, from the first's start
    row_cost: object = None              # per-row cost profile (the next pass's launch sizes)
    transparent: bool = False            # the scene's --transparent (Image.save's default)
    spp_target: int | None = None        # progressive.Progressive: the samples it accumulates to
    # glass (glass.plan)
    accel: str | None = None             # "grid" or "tree": what the field read
    model: str | None = None             # the glass model, said in the status line
    tree_ms: float = 0.0                 # builds made for this render (0 when reused)
    cells_ms: float = 0.0
    cells: dict | None = None            # cells.Cells.summary()
    note: str | None = None              # why the acceleration fell back
    # volume (volume.plan)
    background: tuple | None = None      # what PNGs are composited on
    estimator: str | None = None         # march, track or path (auto resolved)
    ms_octaves: int | None = None
    estimator_note: str | None = None    # auto's choice, said
    light_cache: str | None = None       # the light cache's choice, said
    light_cache_baked: bool = False      # baked for this render (not reused)
    light_cache_bake_ms: float = 0.0
    light_cache_bytes: int = 0
    light_cache_cell: int | None = None  # node spacing in voxels (None: no cache)
    # denoising (render.denoised)
    denoised: bool | None = None         # None: not asked
    denoise_note: str | None = None      # why not, where it was asked and could not be
    denoise_guides: str | None = None
    guides_ms: float = 0.0
    denoise_ms: float = 0.0
    guides_cpu_ms: float = 0.0
    denoise_cpu_ms: float = 0.0
    # adaptive passes (render.render_passes)
    passes: int | None = None
    noise: float | None = None           # the covered pixels' relative noise estimate
    noise_whole: float | None = None     # the whole image's
    history: tuple = ()                  # (spp, noise, noise_whole) after each pass
    stopped: str | None = None           # why the passes stopped
    adaptive: str | None = None          # the summary line
    noise_map: object = None             # per-pixel standard error, H x W float32

    def replace(self, **changes) -> "RenderInfo":
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------- the dict of before (deprecated)
    def _old(self, key, default=_MISSING):
        warnings.warn(f"Image.info[{key!r}] is deprecated: read Image.info.{key}",
                      DeprecationWarning, stacklevel=3)
        value = getattr(self, key, None) if key in FIELDS else None
        if value is None:
            if default is _MISSING:
                raise KeyError(key)
            return default
        return value

    def __getitem__(self, key):
        return self._old(key)

    def get(self, key, default=None):
        return self._old(key, default)

    def __contains__(self, key) -> bool:
        warnings.warn(f"`{key!r} in Image.info` is deprecated: read Image.info.{key}",
                      DeprecationWarning, stacklevel=2)
        return key in FIELDS and getattr(self, key) is not None


FIELDS = frozenset(f.name for f in dataclasses.fields(RenderInfo))
