"""What a render records besides its pixels (Image.info): a frozen record, read by attribute
(`img.info.spp`). Fields a render did not fill stay None (or 0 for times and counts).

Image.info was a dict; `img.info["spp"]`, `img.info.get("spp")` and `"spp" in img.info`
still work and warn (DeprecationWarning, dict_reads.py).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from .dict_reads import DictReads


@dataclass(frozen=True, eq=False)
class RenderInfo(DictReads):
    """Image.info. The planners (glass.plan, volume.plan) fill their integrator's fields
    in Plan.info, a RenderInfo that render then replaces the launch's fields in;
    denoising and adaptive passes add theirs."""
    WHAT = "Image.info"                  # in the dict reads' warnings
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
    cells: object = None                 # cells.CellsSummary
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


FIELDS = frozenset(f.name for f in dataclasses.fields(RenderInfo))
