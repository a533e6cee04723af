#!/usr/bin/env python3
"""Will another machine record the same episodes as this one? Its pieces, one by one.

Lockstep runs are the same for any worker count on one machine (docs/scale.md). Across
machines three things could differ: the physics (MuJoCo's build), the random streams the
sensors draw from (numpy's Generator), and the renders (the GL implementation: Mesa's
llvmpipe, NVIDIA's driver, ...). `snapshot` writes each of them to an NPZ file on one
machine; `compare` says which differ between two snapshots and by how much.

    tools/checks/machine_parity.py snapshot here.npz           # on each machine
    tools/checks/machine_parity.py compare here.npz there.npz [--json OUT]

What a snapshot holds, per scene (nav indoor, nav outdoor, arm): the state after 200
physics steps from a seeded reset (qpos), and four poses' ideal 8-bit render (rgb) and
linear luminance (sebvs.sim.radiance, what the physical sensors see); beside them a
Poisson and a normal draw from a seeded Generator, as the frame camera's shot and read
noise draw them (sebvs/sensors/framecam.py), and the stack (Python, numpy, MuJoCo, GL
vendor and renderer). Compare exits 0 when every array is the same, 1 when any differs,
2 when a file is not a snapshot.

A Poisson draw with large means is made by rejection, so it takes a varying number of
uniforms: one pixel whose mean differs shifts the stream for every pixel after it. Two
renders that differ in a few pixels by 1 DN therefore give physical frames whose noise
differs nearly everywhere.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import zipfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tools.benchio import print_report  # noqa: E402

SCENES = (("nav", {"variant": "indoor"}), ("nav", {"variant": "outdoor"}), ("arm", {}))
SIZE = 160
POSES = 4
STEPS_PER_POSE = 50
SEED = 7


def scene_tag(task: str, config: dict) -> str:
    return "_".join([task, *map(str, config.values())])


def snapshot() -> dict[str, np.ndarray]:
    """Every array of a snapshot, by name (module docstring)."""
    import sebvs.sim.render  # noqa: F401  (sets MUJOCO_GL before mujoco is imported)
    import mujoco
    from sebvs.sim import make_scene
    from sebvs.sim.radiance import RadianceRenderer
    from sebvs.sim.render import FrameRenderer

    arrays: dict[str, np.ndarray] = {}
    gl = ""
    for task, config in SCENES:
        scene = make_scene(task, width=SIZE, height=SIZE, **config)
        model = scene.compile()
        data = mujoco.MjData(model)
        scene.reset(model, data, np.random.default_rng(SEED))
        camera = scene.cameras[0]
        rgb, lum = [], []
        with FrameRenderer(model, SIZE, SIZE) as colour, \
                RadianceRenderer(model, scene.photometry(), SIZE, SIZE) as radiance:
            for _ in range(POSES):
                mujoco.mj_step(model, data, STEPS_PER_POSE)
                colour.update(data, camera)
                rgb.append(colour.rgb().copy())
                radiance.update(data, camera)
                lum.append(radiance.luminance().copy())
            if not gl:
                from OpenGL import GL
                gl = " / ".join(GL.glGetString(k).decode() for k in
                                (GL.GL_VENDOR, GL.GL_RENDERER, GL.GL_VERSION))
        tag = scene_tag(task, config)
        arrays[f"{tag}/qpos"] = data.qpos.copy()
        arrays[f"{tag}/rgb"] = np.stack(rgb)
        arrays[f"{tag}/luminance"] = np.stack(lum)
    rng = np.random.default_rng(1234)
    means = np.random.default_rng(5).uniform(5.0, 500.0, (SIZE, SIZE))
    arrays["rng/poisson"] = rng.poisson(means)
    arrays["rng/normal"] = rng.normal(0.0, 2.0, (SIZE, SIZE))
    stack = {"python": platform.python_version(), "numpy": np.__version__,
             "mujoco": mujoco.__version__, "MUJOCO_GL": os.environ.get("MUJOCO_GL", ""),
             "gl": gl, "machine": platform.machine()}
    arrays["stack"] = np.array(json.dumps(stack))
    return arrays


def difference(a: np.ndarray, b: np.ndarray) -> dict:
    """How two arrays of one name differ: equal, the share of values that differ, and the
    size of the differences (DN for 8-bit images, relative for luminance, absolute else)."""
    if a.shape != b.shape or a.dtype != b.dtype:
        return {"equal": False, "shapes": [list(a.shape), list(b.shape)]}
    unequal = a != b
    row = {"equal": not unequal.any(), "share_differing": round(float(unequal.mean()), 4)}
    if row["equal"]:
        return row
    if a.dtype == np.uint8:
        dn = np.abs(a.astype(np.int16) - b.astype(np.int16))
        row |= {"max_dn": int(dn.max()), "mean_dn": round(float(dn.mean()), 3)}
    elif a.dtype.kind == "f":
        rel = np.abs(a - b) / np.maximum(np.abs(a), np.finfo(a.dtype).tiny)
        row |= {"max_relative": float(rel.max()), "median_relative": float(np.median(rel))}
    else:
        row |= {"max_abs": float(np.abs(a.astype(np.float64) - b).max())}
    return row


def compare(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> dict:
    names = sorted((set(a) | set(b)) - {"stack"})
    items = {n: difference(a[n], b[n]) if n in a and n in b else {"equal": False,
             "only_in": "a" if n in a else "b"} for n in names}
    stacks = [json.loads(str(s["stack"])) if "stack" in s else {} for s in (a, b)]
    return {"stack_a": stacks[0], "stack_b": stacks[1],
            "identical": all(r["equal"] for r in items.values()), "items": items}


def load(path: str) -> dict[str, np.ndarray]:
    try:
        f = np.load(path, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile) as e:
        f, why = None, str(e)
    else:
        why = "one array, not an NPZ of named arrays"
    if not isinstance(f, np.lib.npyio.NpzFile):
        print(f"machine_parity: {path}: not a snapshot ({why})", file=sys.stderr)
        raise SystemExit(2)
    with f:
        return {k: f[k] for k in f.files}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("snapshot", help="write this machine's physics, random streams and "
                                        "renders to an NPZ file")
    s.add_argument("out", help="the NPZ file to write")
    c = sub.add_parser("compare", help="which pieces differ between two snapshots; exit 1 "
                                       "when any does")
    c.add_argument("a")
    c.add_argument("b")
    c.add_argument("--json", metavar="FILE", help="also write the report here")
    args = ap.parse_args()
    if args.cmd == "snapshot":
        arrays = snapshot()
        np.savez_compressed(args.out, **arrays)
        print(f"wrote {args.out}: {len(arrays) - 1} arrays; {arrays['stack']}")
        return 0
    report = compare(load(args.a), load(args.b))
    print_report(report, args.json)
    return 0 if report["identical"] else 1


if __name__ == "__main__":
    sys.exit(main())
