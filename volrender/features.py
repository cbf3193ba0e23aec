"""Compile-time features: each field is exactly one always-defined VR_* macro.

Flags describe structure only (which features exist, how many lights of each kind);
per-frame values go in the params buffer, so changing them never rebuilds a program.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

from . import layout
from .environment import env_mode
from .lights import counts


# Occupied bricks one tile's local list holds (tiled dispatch). A tile whose frustum
# meets more falls back to the full march: correct, only slower. 16 bytes each (4 KB).
VOLUME_TILE_CAP = 256
# Spheres one glass tile's list holds (a power of two: sorted in place); 20 bytes each.
GLASS_TILE_CAP = 512


@dataclass(frozen=True)
class VolumeFeatures:
    n_suns: int = 0
    n_points: int = 0
    shadows: bool = True
    phase_mixed: bool = True
    skip_empty: bool = True
    skip_runs: bool = False    # skipping crosses a whole run of empty bricks (CPUs) or one (GPUs)
    emission: bool = False
    depth: bool = False
    chromatic: bool = False    # albedo or sigma_t scale differs between channels
    env: int = 0               # environment light: 0 none, 1 uniform, 2 a map (environment.env_mode)
    ms_octaves: int = 1        # marcher: multiple-scattering octaves (1: single scattering)
    temperature: bool = False  # per-voxel blackbody colour from a temperature grid
    light_cache: int = 0       # marcher: the baked light's node spacing in voxels (0: exact shadow marches)
    ms_cache: bool = False     # marcher: orders 2+ read from the light cache (its ms channels)
    # tiled dispatch (volrender.dispatch): work-groups of tile_w x tile_h pixels cull the
    # occupied bricks against their tile's frustum into a local list of tile_cap entries.
    # Fragment dispatch keeps the defaults, so it compiles no local-memory code.
    tiled: bool = False
    tile_w: int = 1
    tile_h: int = 1
    tile_cap: int = 0

    @staticmethod
    def dispatch_fields(dispatch, tile_cap=None) -> dict:
        """The tiled/tile_* fields for a volrender.dispatch.Dispatch (tile_cap: the list's
        capacity, default VOLUME_TILE_CAP)."""
        if not dispatch.tiled:
            return {}
        return {"tiled": True, "tile_w": int(dispatch.tile[0]), "tile_h": int(dispatch.tile[1]),
                "tile_cap": int(tile_cap or VOLUME_TILE_CAP)}

    @classmethod
    def from_scene(cls, scene, dispatch, gpu=False, tile_cap=None) -> "VolumeFeatures":
        """What a volume Scene compiles in (dispatch: the resolved Dispatch; gpu: whether
        the device is a GPU, which picks how skipping crosses empty bricks; tile_cap: the
        tiled list's capacity, dispatch.Launch)."""
        n_suns, n_points = counts(scene.lights)
        s, bricks = scene.content.settings, scene.content.bricks
        emission = bricks.emission is not None
        return cls(n_suns=n_suns, n_points=n_points, shadows=s.shadows,
                   phase_mixed=s.phase[2] < 1.0, skip_empty=s.skip_empty,
                   skip_runs=s.skip_empty and (not gpu if s.skip_runs is None else s.skip_runs),
                   emission=emission, depth=s.depth, chromatic=s.chromatic,
                   env=env_mode(scene.environment),
                   ms_octaves=s.octaves if s.estimator == "march" else 1,
                   temperature=emission and s.temperature_grid is not None,
                   **cls.dispatch_fields(dispatch, tile_cap))

    def flags(self) -> dict[str, int]:
        return {f"VR_{k.upper()}": int(v) for k, v in sorted(asdict(self).items())}


@dataclass(frozen=True)
class GlassFeatures:
    tree: bool = True          # the field walks the partition tree
    grid: bool = False         # the field folds support-cell lists (cl/cells.h); neither: brute force
    n_suns: int = 0
    n_points: int = 0
    shadows: bool = True       # sphere-traced hard shadows toward lights
    refraction: bool = True    # False: opaque shading, no refraction code
    full: bool = True          # both Fresnel branches traced (--glass-model full); else fast
    absorption: bool = True    # Beer-Lambert inside glass
    glow: bool = False         # hot-glass emission inside glass
    env_map: bool = False      # equirectangular image (False: procedural sky)
    colors: bool = False       # per-point colours
    tiled: bool = False        # tiled dispatch: per-tile sphere lists in local memory
    tile_w: int = 0            # tile size (work-group) and list capacity, tiled only
    tile_h: int = 0
    tile_cap: int = 0
    uber: bool = False         # every feature compiled in, chosen at run time
    tree_stack: int = layout.MAX_TREE_DEPTH + 1   # traversal stack entries: depth + 1
    stats: bool = False        # diagnostics: rgb = evaluations, node and sphere tests per pixel

    @classmethod
    def from_scene(cls, scene, packed, dispatch, variant=None) -> "GlassFeatures":
        """What a glass Scene compiles in. packed: its spheres.PackedSpheres; dispatch: the
        resolved Dispatch; variant "uber": everything, light counts and feature bits read
        at run time instead; "stats": count the field's work."""
        n_suns, n_points = counts(scene.lights)
        s = scene.content.settings
        refr = s.refraction
        tree = packed.accel == "tree"
        grid = packed.accel == "grid"
        tiled = dispatch.tiled
        tiling = dict(tiled=tiled, tile_w=dispatch.tile[0] if tiled else 0,
                      tile_h=dispatch.tile[1] if tiled else 0,
                      tile_cap=GLASS_TILE_CAP if tiled else 0,
                      # the stack serves the tree walks (the field's, or the tile lists'):
                      # elsewhere a constant, so one program serves every sphere count
                      tree_stack=layout.tree_stack(packed.first_leaf)
                      if tree or (tiled and grid) else 2,
                      stats=variant == "stats")
        if variant == "uber":
            return cls(tree=tree, grid=grid, shadows=True, refraction=True, absorption=True,
                       glow=True, full=s.glass_model == "full",
                       env_map=True, colors=True, uber=True, **tiling)
        return cls(tree=tree, grid=grid, n_suns=n_suns, n_points=n_points,
                   shadows=s.shadows and n_suns + n_points > 0, refraction=refr,
                   full=s.glass_model == "full",
                   absorption=refr and any(a > 0 for a in s.absorption),
                   glow=refr and s.glow > 0, env_map=scene.environment is not None,
                   colors=packed.colors is not None, **tiling)

    def flags(self) -> dict[str, int]:
        return {f"VR_{k.upper()}": int(v) for k, v in sorted(asdict(self).items())}
