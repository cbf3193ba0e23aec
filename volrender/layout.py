"""Host/kernel structs: one field table per struct -> numpy dtype and C typedef.

`python -m volrender.layout` regenerates `cl/structs.h`; a test checks that the committed
header is current and that the device agrees on sizes and offsets.

Rules: no float3 in buffers (float4 instead), explicit `_pad` fields, every struct a
multiple of 16 bytes, field names identical in Python and C.
"""
from __future__ import annotations


import numpy as np

from . import process
from .paths import cl_dir

# (C type) -> (numpy base, count, size in bytes, alignment)
_TYPES = {
    "float": ("f4", 1, 4, 4),
    "int": ("i4", 1, 4, 4),
    "uint": ("u4", 1, 4, 4),
    "float4": ("f4", 4, 16, 16),
    "int4": ("i4", 4, 16, 16),
}

# Constants shared by host and kernels, emitted into cl/structs.h as VR_<NAME>.
BRICK = 8                  # brick edge, voxels (volrender/vdb.py layout)
APRON = BRICK + 1          # stored brick edge: one extra voxel on the + side
MAX_LIGHTS = 64            # lights per render (volrender/lights.py)
# uber-kernel runtime feature bits (GlassParams.uber; glass.UBER_BITS)
UBER_BITS = {"shadows": 1, "refraction": 2, "absorption": 4, "glow": 8, "env_map": 16,
             "colors": 32}
# Samples along one ray at most (primary or shadow march): past 2^24, (float)k no longer
# resolves single steps; the host refuses steps that would need more (volume.plan).
MAX_RAY_SAMPLES = 1 << 24
# One sample's radiance is clamped to this (NaN, reachable only through an overflow the
# knobs' ranges exclude, reads 0): a sum over 65536 samples stays finite in float32.
SAMPLE_MAX = 1e33
CELL_BRICK = 8             # glass support cells: a brick holds CELL_BRICK^3 cells (cells.py)
CELL_OUTSIDE, CELL_INSIDE = -1, -2   # codes of skippable cells and bricks (cl/cells.h)
CELL_BOUNDS_J = 4          # sub-intervals of [M, U] in the cells' field bounds (build_cells.cl)
BLEND_MIN = 1e-20          # a blend k at or below: the plain union (sdf.h, build_cells.cl)
MAX_TREE_DEPTH = 47        # deepest partition tree (the traversal stacks: depth + 1 entries)
SHADOW_TAU_STOP = 25.0     # the march's shadow rays stop at this optical depth (exp(-25))
CONSTANTS = {"BRICK": BRICK, "APRON": APRON, "BRICK_VALUES": APRON ** 3,
             "MAX_LIGHTS": MAX_LIGHTS, "MAX_RAY_SAMPLES": MAX_RAY_SAMPLES,
             "SAMPLE_MAX": SAMPLE_MAX, "CELL_BRICK": CELL_BRICK,
             "CELL_OUTSIDE": CELL_OUTSIDE, "CELL_INSIDE": CELL_INSIDE,
             "CELL_BOUNDS_J": CELL_BOUNDS_J, "BLEND_MIN": BLEND_MIN,
             "MAX_TREE_STACK": MAX_TREE_DEPTH + 1, "SHADOW_TAU_STOP": SHADOW_TAU_STOP,
             **{f"BIT_{k.upper()}": v for k, v in UBER_BITS.items()}}


def tree_stack(first_leaf: int) -> int:
    """Traversal stack entries for a tree whose leaves start at first_leaf = 2^depth:
    depth + 1 (one push per level), at least 2."""
    return max(2, int(first_leaf).bit_length())

STRUCTS: dict[str, list[tuple[str, str]]] = {
    # Pinhole camera in the render frame. `origin` is in render-frame coordinates; the
    # pixel directions are world-space vectors: dir = pixel00 + (x+jx)*du + (y+jy)*dv.
    "Camera": [
        ("origin", "float4"),
        ("pixel00", "float4"),
        ("du", "float4"),
        ("dv", "float4"),
        ("width", "int"),
        ("height", "int"),
        ("spp", "int"),
        ("seed", "uint"),
    ],
    # Suns first, then point lights. Sun: `vec` = unit propagation direction (world).
    # Point light: `vec` = position (render frame). `radiance` = colour * E (or * I).
    "Light": [
        ("vec", "float4"),
        ("radiance", "float4"),
    ],
    # Volume: render frame = the brick layout's local index space.
    "VolumeParams": [
        ("world_to_local0", "float4"),   # rows of the linear part, world -> local index
        ("world_to_local1", "float4"),
        ("world_to_local2", "float4"),
        ("local_to_world0", "float4"),   # rows of the linear part, local index -> world
        ("local_to_world1", "float4"),
        ("local_to_world2", "float4"),
        ("box_hi", "float4"),            # local box is [0, box_hi] (voxel-centre coords)
        ("background", "float4"),        # rgb radiance behind the volume
        ("emission_color", "float4"),    # rgb per unit emission-grid value
        ("phase", "float4"),             # g1, g2, w, unused
        ("dims", "int4"),                # bricks per axis
        ("albedo_rgb", "float4"),        # per-channel albedo (VR_CHROMATIC); w unused
        ("extinction", "float4"),        # per-channel sigma_t scale s (VR_CHROMATIC); w unused
        ("env_radiance", "float4"),      # uniform environment radiance (VR_ENV 1); w unused
        ("ms", "float4"),                # octaves: G, C, unused, shadow tau stop (VR_MS_OCTAVES > 1)
        ("ms_decay", "float4"),          # octaves: ln A_inf per channel (the closing band's depth scale)
        ("density_scale", "float"),      # sigma_t = density_scale * s * grid value
        ("albedo", "float"),             # grey albedo (VR_CHROMATIC 0)
        ("step", "float"),               # primary step, world units
        ("shadow_step", "float"),        # shadow step, world units
        ("point_r2_min", "float"),       # clamp for I / r^2 near point lights
        ("env_width", "int"),            # environment map (VR_ENV 2), texels
        ("env_height", "int"),
        ("env_visible", "float"),        # 1: the camera sees the environment behind; 0: hidden
        ("emission_scale", "float"),     # emission per grid value (VR_TEMPERATURE)
        ("temp_scale", "float"),         # kelvin = temp_offset + temp_scale * temperature value
        ("temp_offset", "float"),
        ("bb_a", "float"),               # blackbody table entry = bb_a / kelvin + bb_b
        ("bb_b", "float"),
        ("max_depth", "int"),            # path estimator: scattering events per path
        ("rr_depth", "int"),             # path estimator: Russian roulette from this event on
        ("bb_n", "int"),                 # blackbody table entries
        ("cache_near", "float"),         # light cache: exact shadow march this far (world), the cache beyond
        ("_pad0", "float"), ("_pad1", "float"), ("_pad2", "float"),
    ],
    # Partition tree node (heap index: root 1, children 2i, 2i+1). Bounds are the AABB of
    # the node's spheres (centre +- radius) in the render frame, rounded outwards; empty
    # nodes have lo = +inf, hi = -inf. Spheres of a node: spheres[start : start+count].
    "TreeNode": [
        ("lo_x", "float"), ("lo_y", "float"), ("lo_z", "float"),
        ("start", "int"),
        ("hi_x", "float"), ("hi_y", "float"), ("hi_z", "float"),
        ("count", "int"),
    ],
    # Glass: render frame = world minus the scene centre (float64 on the host).
    "GlassParams": [
        ("box_lo", "float4"),            # clip box for rays (root box + blend bulge)
        ("box_hi", "float4"),
        ("absorption", "float4"),        # rgb Beer-Lambert coefficient, per world unit
        ("color", "float4"),             # rgb glow colour (and diffuse tint when opaque)
        ("blend", "float"),              # smooth-union k, world units
        ("ior", "float"),
        ("reflectivity", "float"),       # scale on the Fresnel-weighted environment reflection
        ("glow", "float"),               # emission per unit length inside glass
        ("epsilon", "float"),            # relative hit threshold and ray offset
        ("shininess", "float"),          # Blinn-Phong exponent
        ("scale", "float"),              # scene radius, world units (offsets, thresholds)
        ("n_spheres", "int"),
        ("first_leaf", "int"),           # 2^depth: nodes >= first_leaf are leaves
        ("bounces", "int"),              # surface events per path
        ("max_steps", "int"),            # sphere-tracing steps per segment
        ("env_width", "int"),
        ("env_height", "int"),
        ("tile_margin", "float"),        # tiled dispatch: spheres farther from a tile's frustum are left out
        ("shadow_cone", "float"),        # tan of the lights' angular radius; 0: hard shadows
        ("uber", "int"),                 # uber-kernel: runtime feature bits (glass.UBER_BITS)
        ("n_suns", "int"),               # uber-kernel: light counts at run time
        ("n_points", "int"),
        ("relax", "float"),              # over-relaxed sphere tracing factor, 1 = off
        ("hit_len", "float"),            # the hit threshold eps (base + t) stops growing here
        # support cells (volrender/cells.py, cl/cells.h), unused without them
        ("grid_lo", "float4"),           # xyz: the grid's min corner (render frame); w: cell size
        ("grid_dims", "int4"),           # cells per axis
        ("brick_dims", "int4"),          # bricks (CELL_BRICK^3 cells) per axis
        ("grid_inv", "float"),           # 1 / cell size
        ("grid_nudge", "float"),         # step past a skipped cell's exit face, world units
        ("grid_skips", "int"),           # most skips per ray segment
        ("roulette", "float"),           # --glass-model full: weaker branches play Russian roulette
        ("eye_color", "float4"),         # rgb glow tint at the eye (per-point colours, eye in glass)
        ("split_events", "int"),         # --glass-model full: events that trace both branches
        ("_pad0", "int"),
        ("_pad1", "int"),
        ("_pad2", "int"),
    ],
    # Support-cell builder (cl/build_cells.cl): boxes are cells or bricks of the grid.
    "CellBuild": [
        ("grid_lo", "float4"),           # xyz: min corner (render frame); w: cell size
        ("blend", "float"),              # k
        ("pad", "float"),                # lists keep spheres with lo_i <= U + k + pad (rounding)
        ("tau", "float"),                # skippable: field bound beyond +-tau (> every hit threshold)
        ("n_spheres", "int"),
        ("first_leaf", "int"),
        ("box_cells", "int"),            # edge of a box in cells: CELL_BRICK (bricks) or 1 (cells)
        ("_pad0", "int"),
        ("_pad1", "int"),
    ],
}


def _offsets(fields):
    off, out = 0, []
    for name, ctype in fields:
        _, _, size, align = _TYPES[ctype]
        if off % align:
            raise ValueError(f"field {name} would need implicit padding; add a _pad field")
        out.append(off)
        off += size
    if off % 16:
        raise ValueError(f"struct size {off} is not a multiple of 16; add _pad fields")
    return out, off


def dtype(name: str) -> np.dtype:
    fields = STRUCTS[name]
    offsets, size = _offsets(fields)
    formats = [(_TYPES[t][0], (_TYPES[t][1],)) if _TYPES[t][1] > 1 else _TYPES[t][0]
               for _, t in fields]
    return np.dtype({"names": [f for f, _ in fields], "formats": formats,
                     "offsets": offsets, "itemsize": size})


def record(name: str, count: int = 1, **values) -> np.ndarray:
    """A zeroed array of `count` structs with the given fields set (count 1 -> shape (1,))."""
    arr = np.zeros(count, dtype(name))
    for key, val in values.items():
        if key not in arr.dtype.names:
            raise KeyError(f"{name} has no field {key!r}")
        arr[key] = val
    return arr


def _c_literal(value) -> str:
    """A C literal: floats as float constants with a point or exponent (25.0f, 1e-20f)."""
    if not isinstance(value, float):
        return str(value)
    text = f"{value:.9g}"
    return text + ("f" if any(c in text for c in ".e") else ".0f")


def c_header() -> str:
    lines = ["/* GENERATED by `python -m volrender.layout` from volrender/layout.py. Do not edit. */",
             "#ifndef VR_STRUCTS_H", "#define VR_STRUCTS_H", ""]
    lines += [f"#define VR_{name} {_c_literal(value)}" for name, value in CONSTANTS.items()] + [""]
    for name, fields in STRUCTS.items():
        _, size = _offsets(fields)
        lines.append(f"typedef struct {{  /* {size} bytes */")
        lines += [f"    {ctype} {field};" for field, ctype in fields]
        lines += [f"}} {name};", ""]
    lines.append("#endif")
    return "\n".join(lines) + "\n"


def header_path():
    return cl_dir() / "structs.h"


if __name__ == "__main__":
    header_path().write_text(c_header())
    process.say(f"wrote {header_path()}")
