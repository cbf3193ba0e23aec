"""The VDB file's header, grid descriptors and grid metadata, parsed by hand (no voxels:
what `volrender info`, up-axis detection and a sequence's bounds need, and a check of the
file before OpenVDB reads it). A fuzz target (fuzz/targets.py)."""
from __future__ import annotations

import os
import re
import struct
from dataclasses import dataclass
from pathlib import Path

from .errors import UserError

VDB_MAGIC = 0x56444220
_MIN_DESCRIPTOR = 3 * 4 + 3 * 8   # three empty strings and three offsets
# Grid names Blender's Mantaflow writes into its caches (gas and liquid domains): a file
# whose float grids include several of these, one of them a Mantaflow-only name, is a
# Mantaflow cache whatever its metadata says (older Blenders write no
# 'file_base_resolution', e.g. fluid_data_0190.vdb).
MANTAFLOW_GAS = frozenset({"density", "flame", "temperature", "heat", "fuel", "react", "shadow",
                           "color_r", "color_g", "color_b", "velocity", "velocity_previous", "density_inflow",
                           "heat_inflow", "temperature_inflow", "fuel_inflow", "react_inflow", "phi_obstacle",
                           "phi_inflow", "phi_out", "flags", "emission"})


MANTAFLOW_LIQUID = frozenset({"phi", "phi_previous", "phi_particles", "phi_obstacle", "phi_inflow",
                              "phi_out", "velocity", "velocity_previous", "flags", "particles"})


# names no other writer we know of uses for a density-like grid
MANTAFLOW_ONLY = frozenset({"shadow", "react", "fuel", "phi_obstacle", "phi_out", "phi_inflow",
                            "phi_particles", "density_inflow", "heat_inflow"})

@dataclass(frozen=True)
class GridInfo:
    name: str
    value_type: str            # 'float', 'vec3s', 'int32', 'double', 'ptdataidx32', ...
    grid_class: str            # 'fog volume', 'level set', 'staggered' or 'unknown'
    active_voxels: int | None = None
    creator: str = ""          # the file's 'creator' metadata (the writing application)
    metadata_keys: tuple = ()  # names of the grid's metadata entries
    memory_bytes: int | None = None   # 'file_mem_bytes': the grid's size in memory

    def describe(self) -> str:
        return f"{self.name} ({self.value_type}, {self.grid_class})"


class _Corrupt(Exception):
    pass


class _Reader:
    def __init__(self, f, size):
        self.f, self.size = f, size

    def read(self, n):
        b = self.f.read(n)
        if len(b) != n:
            raise _Corrupt("unexpected end of file")
        return b

    def unpack(self, fmt):
        v = struct.unpack("<" + fmt, self.read(struct.calcsize("<" + fmt)))
        return v[0] if len(v) == 1 else v

    def string(self):
        n = self.unpack("I")
        if n > self.size - self.f.tell():
            raise _Corrupt(f"string of {n} bytes runs past the end of the file")
        return self.read(n).decode("utf-8", "replace")


def _read_metamap(r: _Reader) -> dict:
    """MetaMap: count, then (name, type name, uint32 size, value bytes) each."""
    meta = {}
    count = r.unpack("I")
    if count * 12 > r.size - r.f.tell():
        raise _Corrupt(f"{count} metadata entries cannot fit in the rest of the file")
    for _ in range(count):
        name, type_name = r.string(), r.string()
        n = r.unpack("I")
        if n > r.size - r.f.tell():
            raise _Corrupt(f"metadata {name!r} runs past the end of the file")
        raw = r.read(n)
        if type_name == "string":
            meta[name] = raw.decode("utf-8", "replace")
        elif (type_name, n) in (("int32", 4), ("int64", 8)):
            meta[name] = struct.unpack("<i" if n == 4 else "<q", raw)[0]
        elif (type_name, n) == ("vec3i", 12):
            meta[name] = struct.unpack("<3i", raw)
        else:
            meta[name] = None          # present, value not decoded
    return meta


def _value_type(tree_type: str) -> str:
    """'Tree_float_5_4_3' -> 'float'."""
    m = re.fullmatch(r"Tree_(.+?)((?:_\d+)+)", tree_type)
    return m.group(1) if m else tree_type


def parse_vdb(path: Path) -> list[GridInfo] | None:
    """Grid descriptors straight from the file; None when only OpenVDB can tell."""
    with open(path, "rb") as f:
        return parse_vdb_header(f, os.fstat(f.fileno()).st_size, path)


def _int_or_none(v):
    return v if isinstance(v, int) and v >= 0 else None


def parse_vdb_header(f, size: int, path) -> list[GridInfo] | None:
    """The grid descriptors and per-grid metadata of the .vdb stream `f` (`size` bytes: a
    file or io.BytesIO; `path` names it in messages), reading no voxel data; None for
    files only OpenVDB can tell about (headers before version 222, no grid offsets)."""
    r = _Reader(f, size)
    if size < 8 or r.unpack("q") != VDB_MAGIC:
        raise UserError("not an OpenVDB file (bad magic number)", path=path,
                        fix="give a .vdb written by OpenVDB, Houdini, Blender or EmberGen")
    try:
        version = r.unpack("I")
        if version < 222:              # older headers vary; let OpenVDB read them
            return None
        r.unpack("II")                 # library major, minor
        has_offsets = r.read(1) != b"\0"
        r.read(36)                     # UUID as text
        creator = _read_metamap(r).get("creator") or ""    # file metadata
        if not has_offsets:
            return None
        count = r.unpack("i")
        if count < 0:
            raise _Corrupt("negative grid count")
        if count * _MIN_DESCRIPTOR > size - f.tell():
            raise _Corrupt(f"{count} grid descriptors cannot fit in the rest of the file")
        grids = []
        for _ in range(count):
            name = r.string().split("\x1e")[0]   # '\x1e<n>' marks duplicate names
            tree = r.string().removesuffix("_HalfFloat")
            r.string()                 # instance parent
            grid_pos, block_pos, end_pos = r.unpack("qqq")
            # each grid lies after its descriptor, in order: never trust an offset
            # that points backwards (it would make this loop read the same bytes forever)
            if not f.tell() <= grid_pos <= block_pos <= end_pos:
                raise _Corrupt(f"grid {name!r} has offsets out of order "
                               f"({grid_pos}, {block_pos}, {end_pos})")
            if end_pos > size:
                raise _Corrupt(f"grid {name!r} ends past the end of the file")
            f.seek(grid_pos)
            r.unpack("I")              # per-grid compression flags
            meta = _read_metamap(r)
            grid_class = meta.get("class")
            grids.append(GridInfo(name, _value_type(tree),
                                  grid_class if isinstance(grid_class, str) else "unknown",
                                  _int_or_none(meta.get("file_voxel_count")), str(creator),
                                  tuple(meta), _int_or_none(meta.get("file_mem_bytes"))))
            f.seek(end_pos)
        return grids
    except (_Corrupt, struct.error, UnicodeError) as e:
        raise UserError(f"truncated or corrupt OpenVDB file ({e})", path=path,
                        fix="re-export or re-download it") from None


def mantaflow_cache(grids) -> str:
    """Why the file is a Blender Mantaflow cache ('' when it is not): recognised by its grid
    set (at least three Mantaflow grid names, one of them Mantaflow's own, all of the file's
    grids from the gas or the liquid set), or by the 'file_base_resolution' grid metadata
    that newer Blenders add."""
    names = {g.name for g in grids}
    for kind, known in (("gas", MANTAFLOW_GAS), ("liquid", MANTAFLOW_LIQUID)):
        own = sorted(names & MANTAFLOW_ONLY)
        if len(names) >= 3 and names <= known and own:
            return (f"a Blender Mantaflow {kind} cache (grids "
                    f"{', '.join(sorted(names & {'density', 'flame', 'temperature', 'phi'} | set(own[:2])))})")
    if any("file_base_resolution" in g.metadata_keys for g in grids):
        return "a Blender (Mantaflow) cache: its grids carry 'file_base_resolution'"
    return ""


def up_axis_hint(grids) -> tuple[str | None, str]:
    """(axis, reason): 'z' for files that Blender wrote (Blender is Z-up): a 'creator'
    naming Blender, or a Mantaflow cache (mantaflow_cache: by its grid set; its caches carry
    no 'creator'); None when the file does not say."""
    creator = next((g.creator for g in grids if g.creator), "")
    if "blender" in creator.lower():
        return "z", f"written by {creator!r}"
    why = mantaflow_cache(grids)
    if why:
        return "z", why
    return None, ""
