"""Scenes: everything a render needs, resolved before it starts.

    scene = volrender.load_scene("smoke.vdb", size=(320, 240), density_scale=2.0)
    scene = volrender.load_scene("bunny.ply", radius=0.002, bounces=4)
    scene = volrender.load_scene("scenes/molten_glass.toml", spp=4)

`source` is a volume (.vdb, .npz), a point cloud (.ply, .xyz, .csv, .txt, .npy), a
generator `NAME:COUNT` (blob:2000), a scene file (.toml) or a numpy array (a dense 3-D
volume, voxel (i, j, k) at world (i, j, k); points (N, 3) or (N, 4) with radii). Override keys are the command
line's option names with underscores (`density_scale=2.0`, `no_tree=True`, `origin=(0, 0, 4)`,
`sun=[(-1, -1, 0, 3)]`, or `lights=[Sun(...), PointLight(...)]`); they win over the scene
file, whose values win over the defaults, which live once, in the settings classes
(VolumeSettings, GlassSettings, camera.View). An option the scene's kind does not read is
an error naming it (pbrt's unused-parameter rule).

Scene files (TOML) are validated in two steps: `scene_file.read`/`parse` check each key's type and
reject unknown keys and sections by full path (`[material].iro`); `load_scene` then checks
ranges and kinds (overrides.py), naming the file and `[section].key`. Paths resolve
relative to the file.

Long file: the Scene model with its per-kind loading, Request and load_scene; the option
checking lives in overrides.py, the scene-file reader in scene_file.py. The fire defaults
(_fire_defaults, _fire_loaded) are the next seam, beside fire.py, once the volume work on
them has landed.

    [volume]                 # a volume: file = ..., plus any VolumeSettings key
    file = "smoke.vdb"
    density_scale = 2.0

    [points]                 # or a point cloud: file = ..., or generator = ... with count
    generator = "glass_gather"
    count = 2000
    radius = 0.02            # overrides per-point radii

    [material]               # molten glass: color, ior, absorption, reflectivity, glow, shininess
    [camera]                 # origin, target, up, fov (default framing fits the content)
    [[lights]]               # type = "sun" (direction, irradiance) or "point" (position, intensity)
    [environment]            # map = "sky.exr" or map = [r, g, b] (uniform radiance)
    [render]                 # size, spp, seed, shadows, dispatch, tile, and glass's tracing keys
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np

from . import device as device_mod
from .camera import View, check_conflicts, read_camera_file, up_frame
from .cloud import finish_cloud
from .dispatch import upload
from .environment import Environment, load_environment, uniform
from .errors import KEYWORDS, UserError
from .files import check_input
from .glass import GlassSettings
from .lights import FIRE_LIGHT, default_sky, default_suns, glass_sky_texels
from .overrides import (check_kinds, explicit_keys, field_values, given_from_file,
                        given_from_overrides, lights_given)
from .scene_file import EXTRA_KEYS, LIGHT_KEYS, MAX_COUNT, options, read
from .spheres import BuildCache, blend_width, pack_scene, scan_defaults, sphere_bounds, sphere_radii
from .volume import VolumeSettings, auto_estimator

VOLUME_SUFFIXES = (".vdb", ".npz")
POINT_SUFFIXES = (".ply", ".xyz", ".csv", ".txt", ".npy", ".las", ".laz")


# --------------------------------------------------------------------------- the Scene

@dataclass(frozen=True, eq=False)
class VolumeContent:
    """A volume's bricks and settings. The bricks' arrays are uploaded on the first render
    on a device and kept there (`buffer`): later renders of the scene upload none of them."""
    bricks: object                    # bricks.Bricks
    settings: object                  # volume.VolumeSettings
    store: dict = field(default_factory=dict, compare=False, repr=False)
    kind: ClassVar[str] = "volume"

    def bounds(self):
        return self.bricks.world_bounds()

    def extent(self):
        """(points, radii) the default camera fits (framing.fit): the corners of the boxes
        of its non-zero voxels (bricks.Bricks.occupied_corners)."""
        return self.bricks.occupied_corners(), 0.0

    def buffer(self, device, name):
        """The device copy of bricks.<name> ("table", "data", "emission" or
        "temperature"), uploaded once per device."""
        key = (device.device.int_ptr, name)
        if key not in self.store:
            dtype = np.int32 if name == "table" else np.float32
            self.store[key] = upload(device.context, np.asarray(getattr(self.bricks, name), dtype))
        return self.store[key]

    @classmethod
    def load(cls, req, reuse=None, device=None):
        """(content, notes, fire, None: no radii measured) of a volume Request: the bricks (those of `reuse`, a
        Scene, when they are what req would read), the fire defaults of a Mantaflow cache
        (its exposure, or smoke for an all-zero flame grid) and the automatic estimator
        (for the request's pixels on `device`)."""
        from . import vdb
        settings, notes, fire = req.settings, [], False
        if req.origin != "array":
            path = req.doc["volume"]["file"] if req.doc else Path(req.source)
            settings, note = _fire_defaults(path, settings, req.given)
            fire = note is not None
            notes += [note] if note else []
        old = req._reusable(reuse, settings)
        if old is not None:
            bricks = old.bricks
        elif req.origin == "array":
            bricks = _array_content(req.array, "volume")
        else:
            bricks = vdb.load_volume(path, grid=settings.grid,
                                     emission_grid=settings.emission_grid,
                                     temperature_grid=settings.temperature_grid)
        if fire:
            bricks, settings, more, fire = _fire_loaded(bricks, settings, req.given)
            notes = (notes if fire else [n for n in notes if not n.startswith("fire:")]) + more
        w, h = req.view.size
        settings, note = auto_estimator(bricks, settings, int(w) * int(h), device)
        notes += [note] if note else []
        return cls(bricks, settings, **({"store": old.store} if old else {})), notes, fire, None


@dataclass(frozen=True, eq=False)
class GlassContent:
    """A point cloud and its glass settings. The packed spheres, tree and support cells
    are built on the first render on a device and kept (`prepare`): renders with another
    camera, size, spp or lights reuse them; `dataclasses.replace` keeps the store, so
    settings the acceleration does not read (spheres.ACCEL_FIELDS) reuse it too."""
    cloud: object                     # cloud.PointCloud
    settings: object                  # glass.GlassSettings
    store: BuildCache = field(default_factory=BuildCache, compare=False, repr=False)
    kind: ClassVar[str] = "glass"

    def bounds(self):
        return sphere_bounds(self.cloud, sphere_radii(self.cloud, self.settings))

    def extent(self):
        """(points, radii) the default camera fits (framing.fit): the spheres, each grown by
        how far the smooth union's surface reaches beyond them (framing.blend_growth)."""
        from .framing import blend_growth
        centres = np.asarray(self.cloud.centers, np.float64)
        radii = sphere_radii(self.cloud, self.settings)
        k = blend_width(radii, self.settings) if len(radii) else 0.0
        return centres, radii + blend_growth(centres, radii, k)

    def prepare(self, device=None, samples=None, max_runs=None, tree_on="auto"):
        """The spheres.PackedSpheres of this cloud and settings on `device`, built once (the
        first call's samples, pixels x spp, set the automatic cell edge's budget, and its
        max_runs caps the cells' list runs: cells.build, and its tree_on where the tree is
        built: spheres.pack_scene); later calls return it."""
        dev = device_mod.resolve(device)
        return self.store.packed_for(self.cloud, self.settings, dev, lambda: pack_scene(
            self.cloud, self.settings, dev, samples, max_runs, tree_on))

    @property
    def builds(self) -> int:
        """How many times `prepare` built the acceleration."""
        return self.store.builds

    @classmethod
    def load(cls, req, reuse=None, device=None):
        """(content, notes, False, radii_s) of a glass Request: the cloud (that of `reuse`,
        a Scene, when it is what req would read) and, for a cloud without radii, the radius
        and blend of its spacing (spheres.scan_defaults; radii_s its seconds, else None)."""
        from . import generators, points
        settings = req.settings
        old = req._reusable(reuse, settings)
        if old is not None:
            cloud = old.cloud
        elif req.origin == "array":
            cloud = _array_content(req.array, "glass")
        elif req.origin == "scene":
            pts = req.doc["points"]
            if "file" in pts:
                cloud = points.load_points(pts["file"])
            else:
                cloud = generators.generate(pts["generator"], pts["count"], pts.get("seed", 0))
        elif req.origin == "generator":
            cloud = generated_cloud(req.source, settings.seed)
        else:
            cloud = points.load_points(req.source)
        notes, radii_s = list(cloud.notes), None
        if cloud.radii is None and (settings.radius is None or settings.blend is None):
            t1 = time.perf_counter()
            settings, note = scan_defaults(cloud, settings, old.store if old else None)
            radii_s = time.perf_counter() - t1
            notes.append(note)
        return (cls(cloud, settings, **({"store": old.store} if old else {})), notes, False,
                radii_s)


@dataclass(frozen=True)
class Timings:
    """Seconds load_scene took: reading the content and the rest of resolving (load), and
    measuring the spacing of a cloud without radii (radii; None when not measured)."""
    load: float = 0.0
    radii: float | None = None


@dataclass(frozen=True, eq=False)
class Scene:
    camera: object                    # camera.Camera
    lights: tuple                     # lights.Sun / lights.PointLight
    content: VolumeContent | GlassContent
    environment: Environment | None = None
    source: str = ""
    inputs: tuple = ()                # every file the scene reads (resolved paths)
    notes: tuple = ()                 # choices made while resolving (the CLI prints them)
    timings: Timings = field(default_factory=lambda: Timings(), compare=False)
    request: object = field(default=None, compare=False, repr=False)   # what load_scene read

    @property
    def kind(self) -> str:
        return self.content.kind

    @property
    def settings(self):
        return self.content.settings

    @classmethod
    def of(cls, camera, lights, content, environment=None) -> "Scene":
        """A Scene from parts already resolved (tests, benchmarks); settings.env is read
        here."""
        if environment is None and content.settings.env is not None:
            environment = _environment(content.settings.env, "env")
        return cls(camera, tuple(lights), content, environment)

    def replace(self, *, device=None, **changes) -> "Scene":
        """A Scene with some keywords changed: load_scene's (density_scale=2, size=(64, 48),
        sun=...) or the Scene's own fields (camera=..., lights=...). Option keywords are
        checked as load_scene checks them and resolved again (framing, defaults, notes;
        --estimator auto for `device`, as Request.load); the volume's bricks, the cloud and
        what the first render built (uploads, tree, cells) are reused whenever the changed
        options do not change them."""
        own = {f.name for f in dataclasses.fields(self)}
        fields = {k: v for k, v in changes.items() if k in own}
        opts = {k: v for k, v in changes.items() if k not in own}
        scene = self
        if opts:
            if self.request is None:
                scene = self._with_settings(opts)
            else:
                scene = self.request.again(opts).load(reuse=self, device=device)
        return dataclasses.replace(scene, **fields) if fields else scene

    def _with_settings(self, opts) -> "Scene":
        """replace() of a Scene.of scene (no request to resolve again): settings only."""
        given = given_from_overrides(opts)
        other = [k for k, _ in given.items() if k in EXTRA_KEYS or options()[k].owner == "view"]
        if other:
            raise UserError(f"{given[other[0]][1]} cannot change a Scene made by Scene.of "
                            "(it has no camera framing or lights to resolve again)",
                            fix="pass camera=... or lights=... (Scene fields), or use load_scene")
        check_kinds(given, self.kind, "the scene")
        values = field_values(given, ("common", self.kind))
        content = dataclasses.replace(self.content, settings=dataclasses.replace(
            self.content.settings, **values))
        return dataclasses.replace(self, content=content)


# --------------------------------------------------------------------------- resolving

def source_kind(source) -> str:
    """'volume', 'points', 'scene' or 'generator' for a render input."""
    from . import generators
    if isinstance(source, np.ndarray):
        return "array"
    if not isinstance(source, (str, Path)) and not hasattr(source, "__fspath__"):
        raise UserError(f"the source must be a file path, GENERATOR:COUNT or a numpy array, got "
                        f"{type(source).__name__}")
    text = str(source)
    suffix = Path(text).suffix.lower()
    if suffix in VOLUME_SUFFIXES:
        return "volume"
    if suffix in POINT_SUFFIXES:
        return "points"
    if suffix == ".toml":
        return "scene"
    if ":" in text and text.split(":", 1)[0] in generators.GENERATORS:
        return "generator"
    raise UserError(f"unsupported input type {suffix or '(none)'!r}", path=text,
                    fix=f"give a volume ({', '.join(VOLUME_SUFFIXES)}), points "
                        f"({', '.join(POINT_SUFFIXES)}), a scene (.toml) or GENERATOR:COUNT "
                        f"with GENERATOR one of {', '.join(generators.GENERATORS)}")


def check_array(a) -> str:
    """'volume' for a dense 3-D array, 'glass' for points (N, 3) or (N, 4: x, y, z, radius);
    else a UserError."""
    if a.dtype.kind not in "biuf":
        raise UserError(f"a numpy array source must hold real numbers, got dtype {a.dtype}")
    if a.ndim == 3 and a.size:
        return "volume"
    if a.ndim == 2 and a.shape[1] in (3, 4) and len(a):
        return "glass"
    raise UserError(f"a numpy array source is a dense volume (nx, ny, nz) or points (N, 3) "
                    f"or (N, 4: x, y, z, radius), got shape {a.shape}")


def _array_content(a, kind):
    """Bricks of a dense volume (voxel (i, j, k) at world (i, j, k)) or the PointCloud of
    an (N, 3) / (N, 4) array."""
    label = f"array {'x'.join(map(str, a.shape))}"
    if kind == "volume":
        from .bricks import Bricks
        return Bricks.from_dense(np.asarray(a, np.float32))
    a = np.asarray(a, np.float64)
    return finish_cloud(label, a[:, :3], a[:, 3].copy() if a.shape[1] == 4 else None, None)


def generated_cloud_count(text: str) -> int:
    """The COUNT of GENERATOR:COUNT, checked."""
    name, _, count = text.partition(":")
    try:
        n = float(count)
        n = int(n) if math.isfinite(n) else -1
    except ValueError:
        raise UserError(f"expected GENERATOR:COUNT such as {name}:2000, got {text!r}") from None
    if not 1 <= n <= MAX_COUNT:
        raise UserError(f"point count must be in [1, 5e7], got {count!r}", path=text)
    return n


def generated_cloud(text: str, seed: int = 0):
    """PointCloud from GENERATOR:COUNT."""
    from . import generators
    return generators.generate(text.partition(":")[0], generated_cloud_count(text), seed)


def _fire_defaults(path, settings, given):
    """(settings, note): a Blender Mantaflow cache (vdb_header.mantaflow_cache, by its grid set)
    with non-empty `flame` and `temperature` grids renders as fire unless told otherwise:
    emission from flame, each voxel's blackbody colour and brightness (the intensity law,
    blackbody.py) at 1000 K per temperature unit, Blender's Principled Volume default (the
    cache stores temperature in units of it; it carries no kelvin of its own). Naming
    either grid yourself on such a cache gives the same (issue 33): the other grid and the
    1000 K are filled in unless given. --emission-grid none turns it off. The exposure
    and an all-zero flame grid are decided once the grids are read (_fire_loaded)."""
    from . import vdb, vdb_header
    if settings.emission_grid in ("", "none"):
        return dataclasses.replace(settings, emission_grid=None), None
    if Path(path).suffix.lower() != ".vdb":
        return settings, None
    grids = vdb.list_grids(path)
    why = vdb_header.mantaflow_cache(grids)
    by = {g.name: g for g in grids}
    emission = settings.emission_grid or "flame"
    temperature = settings.temperature_grid or "temperature"
    if not why or emission not in by or temperature not in by \
            or by[emission].value_type != "float" or by[temperature].value_type != "float" \
            or not by[emission].active_voxels:
        return settings, None
    if settings.emission_grid is not None and settings.temperature_grid is None:
        return settings, None          # an emission grid named alone: coloured, as asked
    changes = {"emission_grid": emission, "temperature_grid": temperature}
    if "temperature_scale" not in given:
        changes["temperature_scale"] = 1000.0
    settings = dataclasses.replace(settings, **changes)
    return settings, (f"fire: {why}; emission from grid {emission!r}, blackbody colour and "
                      f"brightness (T^4) of {settings.temperature_offset:g} + "
                      f"{settings.temperature_scale:g} K x {temperature!r}; --emission-grid none "
                      "turns it off")


def _fire_loaded(bricks, settings, given):
    """(bricks, settings, notes, fire) once the grids are read: an emission grid of zeros
    is smoke (the emission dropped, the normal sky); else, unless --emission-scale is
    given, the exposure chosen from the emission's statistics (volrender/fire.py)."""
    from . import fire
    if fire.is_empty(bricks):
        bricks = dataclasses.replace(bricks, emission=None, emission_max=None, temperature=None,
                                     emission_grid_name=None, temperature_grid_name=None)
        note = (f"fire: none: grid {settings.emission_grid!r} holds only zeros: rendered as "
                "smoke under the normal sky")
        settings = dataclasses.replace(settings, emission_grid=None, temperature_grid=None)
        return bricks, settings, [note], False
    if "emission_scale" in given:
        return bricks, settings, [], True
    scale, note = fire.exposure(bricks, settings)
    if scale is None:
        return bricks, settings, [], True
    return bricks, dataclasses.replace(settings, emission_scale=scale), [note], True


def _environment(path, where):
    """Environment from settings.env: a uniform R,G,B (a 1x1 map) or a map file."""
    if isinstance(path, tuple):
        return uniform(path)
    try:
        p = check_input(path, "environment map")
    except UserError as exc:
        raise UserError(f"{where}: {exc}") from None
    return Environment(load_environment(p), str(p))


@dataclass(frozen=True, eq=False)
class Request:
    """A scene's options, checked but nothing loaded (only a .toml is read): `load()`
    reads the content and frames the camera."""
    source: str
    kind: str                         # "volume" or "glass"
    origin: str                       # "volume", "points", "generator" or "scene"
    doc: dict                         # the parsed scene file ({} without one)
    view: View
    lights: tuple | None              # None: the default lights
    settings: object                  # VolumeSettings or GlassSettings
    given: dict                       # {option key: (value, where)}
    camera_file: Path | None = None   # --camera FILE
    overrides: dict = field(default_factory=dict)   # the keywords as given (Scene.replace)
    array: object = None              # the numpy array of an array source

    def again(self, changes) -> "Request":
        """This request with some keywords changed (lights given replace the lights)."""
        keep = {k: v for k, v in self.overrides.items()
                if not (k in LIGHT_KEYS and any(c in LIGHT_KEYS for c in changes))}
        return request(self.array if self.origin == "array" else self.source,
                       **{**keep, **changes})

    def _reusable(self, reuse, settings):
        """The content of `reuse` (a Scene) when it holds what this request would read."""
        req = getattr(reuse, "request", None)
        if req is None or reuse.kind != self.kind or req.source != self.source \
                or req.origin != self.origin or req.array is not self.array:
            return None
        if self.kind == "volume":
            same = all(getattr(reuse.settings, f) == getattr(settings, f)
                       for f in ("grid", "emission_grid", "temperature_grid"))
        else:
            same = self.origin != "generator" or reuse.settings.seed == settings.seed
        return reuse.content if same else None

    @property
    def inputs(self) -> tuple:
        """Every file the request names (the content and environment files too)."""
        out = []
        if self.origin == "array":
            return ()
        if self.origin in ("volume", "points", "scene"):
            out.append(Path(self.source))
        for section in ("volume", "points"):
            if "file" in self.doc.get(section, {}):
                out.append(Path(self.doc[section]["file"]))
        if isinstance(self.settings.env, str):
            out.append(Path(self.settings.env))
        if self.camera_file is not None:
            out.append(self.camera_file)
        return tuple(dict.fromkeys(p.resolve() for p in out))

    def load(self, reuse=None, device=None) -> Scene:
        """The Scene; `reuse`: a Scene whose bricks or cloud (and device builds) serve this
        one when they are what it would read (Scene.replace); `device`: the one it will
        render on, which --estimator auto weighs (None: a CPU)."""
        t0 = time.perf_counter()
        notes = []
        environment = None
        cls = VolumeContent if self.kind == "volume" else GlassContent
        content, load_notes, fire, radii_s = cls.load(self, reuse, device)
        notes += load_notes
        settings = content.settings
        if settings.env is not None:
            environment = _environment(settings.env, self.given["env"][1])
        lo, hi = content.bounds()
        held = content.bricks if self.kind == "volume" else content.cloud
        hint, why = getattr(held, "up_axis", None), getattr(held, "up_axis_reason", "")
        if self.view.up_axis == "auto" and hint and self.view.origin is None and self.view.up is None:
            notes.append(f"up axis {hint}: {why}; set --up-axis y to override")
        framed = self.view.origin is None            # a given camera needs no content extent
        camera = self.view.camera(lo, hi, hint, extent=content.extent() if framed else None)
        if environment is None and self.kind == "volume":      # the default sky (issue #22)
            dim = FIRE_LIGHT if fire and self.lights is None else 1.0
            environment = Environment(default_sky(up_frame(self.view.axis(hint)), dim),
                                      "default sky")
            if self.lights is None:
                notes.append("lights: the default sun and sky" + (f" at {dim:g} (dusk: the fire's "
                             "own light dominates)" if dim != 1.0 else "") + " (--env 0 for no "
                             "sky, --sun or --no-lights for other lights)")
        if environment is None and self.kind == "glass" and self.view.axis(hint) != "y":
            # glass's procedural sky, turned to the up axis
            environment = Environment(glass_sky_texels(up_frame(self.view.axis(hint))),
                                      "default sky (z up)")
        lights = self.lights
        if lights is None:                # the default sun, from above along the up axis
            lights = default_suns(up_frame(self.view.axis(hint)), FIRE_LIGHT if fire else 1.0)
        timings = Timings(time.perf_counter() - t0 - (radii_s or 0.0), radii_s)
        return Scene(camera, lights, content, environment, self.source, self.inputs,
                     tuple(notes), timings, request=self)


def request(source, **overrides) -> Request:
    """Check `source` and the overrides (kinds, types, ranges) without loading anything
    but a scene file; see load_scene."""
    given = given_from_overrides(overrides)
    origin = source_kind(source)
    array = None
    if origin == "array":
        array, source = source, f"array {'x'.join(map(str, source.shape))}"
        array_kind = check_array(array)
    doc = {}
    if origin == "scene":
        doc = read(source)
        given = {**given_from_file(doc, Path(source)), **given}
    if origin == "generator":
        generated_cloud_count(str(source))
    camera_file = None
    if "camera" in given:               # a camera file: above the scene file, below the options
        camera_file = Path(given.pop("camera")[0])
        by_field = {o.field: o.key for o in options().values() if o.owner == "view"}
        explicit = explicit_keys(overrides)
        for name, value in read_camera_file(camera_file).items():
            if by_field[name] not in explicit:
                given[by_field[name]] = value
    kind = "volume" if origin == "volume" or "volume" in doc else "glass"
    if origin == "array":
        kind = array_kind
    check_kinds(given, kind, str(source))
    check_conflicts({options()[k].field: where for k, (_, where) in given.items()
                     if k not in EXTRA_KEYS and options()[k].owner == "view"})
    view = View(**field_values(given, ("view",)))
    lights = lights_given(given, doc, Path(source) if origin == "scene" else None)
    values = field_values(given, ("common", kind))
    if kind == "volume":
        settings = VolumeSettings(**values)
    else:
        settings = GlassSettings(**values)
    if isinstance(settings.env, str):
        try:
            check_input(settings.env, "environment map")
        except UserError as exc:
            raise UserError(f"{given['env'][1]}: {exc}") from None
    return Request(str(source), kind, origin, doc, view, lights, settings, given, camera_file,
                   dict(overrides), array)


def load_scene(source, **overrides) -> Scene:
    """Resolve `source` and the overrides into a Scene (see the module docstring)."""
    return request(source, **overrides).load()


# the flags errors.spell writes as Python keywords: the options, the lights and the
# keywords of render_sequence and Image.save that the CLI has as flags
KEYWORDS.update(options(), EXTRA_KEYS, ("frames", "workers", "scheduler", "chunk",
                                        "skip_existing", "device", "exposure", "tonemap",
                                        "png_bits"))
