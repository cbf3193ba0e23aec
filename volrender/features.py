"""Compile-time features: each field is exactly one always-defined VR_* macro.

Flags describe structure only (which features exist, how many lights of each kind);
per-frame values go in the params buffer, so changing them never rebuilds a program.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass


# Occupied bricks one tile's local list holds (tiled dispatch). A tile whose frustum
# meets more falls back to the full march: correct, only slower. 16 bytes each (4 KB).
VOLUME_TILE_CAP = 256


@dataclass(frozen=True)
class VolumeFeatures:
    n_suns: int = 0
    n_points: int = 0
    shadows: bool = True
    phase_mixed: bool = True
    skip_empty: bool = True
    emission: bool = False
    depth: bool = False
    # tiled dispatch (volrender.dispatch): work-groups of tile_w x tile_h pixels cull the
    # occupied bricks against their tile's frustum into a local list of tile_cap entries.
    # Fragment dispatch keeps the defaults, so it compiles no local-memory code.
    tiled: bool = False
    tile_w: int = 1
    tile_h: int = 1
    tile_cap: int = 0

    @staticmethod
    def dispatch_fields(dispatch) -> dict:
        """The tiled/tile_* fields for a volrender.dispatch.Dispatch."""
        if not dispatch.tiled:
            return {}
        return {"tiled": True, "tile_w": int(dispatch.tile[0]), "tile_h": int(dispatch.tile[1]),
                "tile_cap": int(VOLUME_TILE_CAP)}

    def flags(self) -> dict[str, int]:
        return {f"VR_{k.upper()}": int(v) for k, v in sorted(asdict(self).items())}


@dataclass(frozen=True)
class GlassFeatures:
    tree: bool = True          # partition tree traversal (False: brute force over all spheres)
    n_suns: int = 0
    n_points: int = 0
    shadows: bool = True       # sphere-traced hard shadows toward lights
    refraction: bool = True    # False: opaque shading, no refraction code
    absorption: bool = True    # Beer-Lambert inside glass
    glow: bool = False         # hot-glass emission inside glass
    env_map: bool = False      # equirectangular image (False: procedural sky)
    colors: bool = False       # per-point colours
    tiled: bool = False        # tiled dispatch: per-tile sphere lists in local memory
    tile_w: int = 0            # tile size (work-group) and list capacity, tiled only
    tile_h: int = 0
    tile_cap: int = 0
    uber: bool = False         # every feature compiled in, chosen at run time
    tree_stack: int = 48       # traversal stack entries: tree depth + 1 (private memory)
    stats: bool = False        # diagnostics: rgb = evaluations, node and sphere tests per pixel

    def flags(self) -> dict[str, int]:
        return {f"VR_{k.upper()}": int(v) for k, v in sorted(asdict(self).items())}
