"""Compile-time features: each field is exactly one always-defined VR_* macro.

Flags describe structure only (which features exist, how many lights of each kind);
per-frame values go in the params buffer, so changing them never rebuilds a program.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class VolumeFeatures:
    n_suns: int = 0
    n_points: int = 0
    shadows: bool = True
    phase_mixed: bool = True
    skip_empty: bool = True
    emission: bool = False
    depth: bool = False

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

    def flags(self) -> dict[str, int]:
        return {f"VR_{k.upper()}": int(v) for k, v in sorted(asdict(self).items())}
