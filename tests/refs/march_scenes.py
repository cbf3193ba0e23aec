"""Scenes whose marcher images were stored at the commit before the multiple-scattering
work (b93f561), so `--ms-octaves 1` can be checked bit for bit against the single
scattering of that commit (tests/test_octaves.py).

    PYTHONPATH=. python tests/refs/march_scenes.py     # rewrites tests/refs/march_*.npy

Run it only at a commit whose single scattering is the one to keep: the stored images
are the definition of "today's output". Every scene uses only settings that existed at
b93f561 (no octaves, no environment), so the same call renders the same estimand now.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]


def _noise(shape, seed):
    rng = np.random.default_rng(seed)
    v = rng.random(shape)
    for ax in range(3):
        for _ in range(3):
            v = (np.roll(v, 1, ax) + v + np.roll(v, -1, ax)) / 3
    v = np.clip((v - v.mean()) / v.std() * 0.6 + 0.4, 0.0, None)
    v[[0, -1]], v[:, [0, -1]], v[:, :, [0, -1]] = 0, 0, 0
    return v.astype(np.float32)


def scenes():
    """[(name, bricks, camera, lights, VolumeSettings kwargs)]."""
    from volrender import vdb
    from volrender.bricks import Bricks
    from volrender.camera import Camera, frame_bounds
    from volrender.lights import PointLight, Sun
    m = np.eye(4)
    m[:3, :3] *= 0.1
    m[:3, 3] = (-1.2, -0.9, -1.0)
    v = _noise((24, 18, 20), 3)
    grid = Bricks.from_dense(v, m, emission=np.where(v > 0.5, v, 0).astype(np.float32))
    # the demo cloud is a .vdb: None where OpenVDB's binding is missing (the test skips it)
    demo = vdb.load_volume(ROOT / "scenes" / "demo_cloud.vdb") if _has_vdb() else None
    cam = Camera((1.5, 1.0, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 24, 18)
    lights = [Sun((-0.6, -1.0, -0.5), 4.0), PointLight((0.5, 1.5, 0.5), 2.0)]
    return [
        ("demo", demo, demo and frame_bounds(*demo.world_bounds(), 32, 24, fov=28.0),
         [Sun((-0.6, -1.0, -0.5), 10.0)],
         dict(density_scale=6.0, background=(0.32, 0.42, 0.58), spp=2, seed=4)),
        ("emit", grid, cam, lights,
         dict(density_scale=5.0, emission_scale=2.0, albedo=0.7, phase=(0.5, -0.2, 0.7),
              seed=1, aovs=("depth",))),
        ("emit_noskip_tiled", grid, cam, lights,
         dict(density_scale=5.0, emission_scale=2.0, skip_empty=False, dispatch="tiled",
              tile=(4, 4), step=0.7, shadow_step=1.3, spp=3, seed=2)),
        ("single_lobe_unshadowed", grid, cam, [Sun((0.3, -1.0, 0.2), 3.0)],
         dict(density_scale=3.0, phase=(0.3, 0.0, 1.0), shadows=False, spp=1)),
    ]


def _has_vdb():
    try:
        from volrender.vdb import import_openvdb
        import_openvdb()
        return True
    except Exception:
        return False


def render(dev, name, b, cam, lights, kw, **extra):
    from volrender.volume import VolumeSettings
    from helpers import render_volume
    r = render_volume(b, cam, lights, VolumeSettings(**kw, **extra), dev)
    out = {"rgba": r.rgba}
    if "depth" in r.aovs:
        out["depth"] = r.aovs["depth"]
    return out


def main():
    from volrender import device
    dev = device.get(None)
    meta = {"commit": "b93f561", "device": dev.name, "scenes": []}
    for name, b, cam, lights, kw in scenes():
        out = render(dev, name, b, cam, lights, kw)
        for key, a in out.items():
            np.save(HERE / f"march_{name}_{key}.npy", a)
        meta["scenes"].append(name)
        print(name, {k: float(np.abs(a[np.isfinite(a)]).max()) for k, a in out.items()})
    (HERE / "march_refs.json").write_text(json.dumps(meta, indent=1) + "\n")


if __name__ == "__main__":
    sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
    main()
