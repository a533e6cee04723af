#!/usr/bin/env python3
"""Render cost per sample against the tile count (sebvs/sim/tiles.py, docs/sim.md "Tiled
renders"): the camera's per-sample renders one by one, as it makes them today, beside K
samples drawn into one framebuffer's layers and read back once, K = 1, 2, 4, 8, 16.

Content: the nav scene (indoor by default) with the robot turning, a state every 5 ms
(the event sensor's 200 Hz), at the shipped luma size (160 px: nav_record and nav_policy
run luma_scale 1.0, and the physical sensor renders its radiance at the RGB size, 160 px,
on the arm as well). Per sample each path poses the model (set_state, kinematics) and
updates the scene, then renders:
  radiance  the physical sensor's luma: RadianceRenderer.luminance (cd/m^2, decoded)
            against RadianceTiles
  rgb       the 8-bit path: FrameRenderer.rgb against TileRenderer.rgb
  pose      the pose and scene update alone, the part no tile saves
  rgb_viewports  for reference, what sebvs.sim.tiles does not do: the K views side by
            side as viewports of MuJoCo's own offscreen buffer, one mjr_readPixels; it
            reports how many pixels differ from the single renders (it is not bit for
            bit on llvmpipe), and runs only where the grid fits the model's buffer
Reported per sample: wall ms and CPU ms (time.process_time, which counts llvmpipe's
rasteriser threads), medians over the repeats, the paths alternated within each repeat;
each tiled path's first tile is checked to be the single renders' bytes. The GL vendor,
renderer and version say which GL ran (MUJOCO_GL=egl is llvmpipe on a machine without a
GPU).

    MUJOCO_GL=egl tools/bench/bench_render_tiles.py [--quick] [--json FILE [--force]]
"""
import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[var] = "1"
os.environ.setdefault("MUJOCO_GL", "egl")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from sebvs.sim.render import FrameRenderer  # noqa: E402  (selects MUJOCO_GL first)
import mujoco  # noqa: E402

from sebvs.output_guard import OutputRefused, check_output_file  # noqa: E402
from sebvs.sim import make_scene  # noqa: E402
from sebvs.sim.radiance import RadianceRenderer  # noqa: E402
from sebvs.sim.tiles import RadianceTiles, TileRenderer  # noqa: E402
from tools.benchio import counts_arg, print_report  # noqa: E402

cv2.setNumThreads(1)
TILES = (1, 2, 4, 8, 16)


class Bench:
    """One scene, its states and the renderers every path shares."""

    def __init__(self, size: int, variant: str, n_states: int) -> None:
        self.scene = make_scene("nav", variant=variant, width=size, height=size)
        self.model = self.scene.compile()
        self.data = mujoco.MjData(self.model)
        self.scene.reset(self.model, self.data, np.random.default_rng(0))
        self.states = []
        steps = max(1, round(0.005 / self.model.opt.timestep))
        for _ in range(n_states):
            for _ in range(steps):
                self.scene.apply_command(self.model, self.data, np.array([0.3, 1.2]))
                self.scene.scripted(self.model, self.data)
                mujoco.mj_step(self.model, self.data)
            self.states.append(self.scene.state(self.data))
        self.size = size
        self.colour = FrameRenderer(self.model, size, size)
        self.radiance = RadianceRenderer(self.model, self.scene.photometry(), size, size)
        self.rgb_out = np.empty((size, size, 3), np.uint8)
        self.lum_out = np.empty((size, size), np.float32)
        self.tiles: dict[tuple[str, int], object] = {}

    def gl_strings(self) -> dict:
        from OpenGL import GL
        self.colour._canvas.gl.make_current()
        return {k: GL.glGetString(e).decode() for k, e in (
            ("vendor", GL.GL_VENDOR), ("renderer", GL.GL_RENDERER),
            ("version", GL.GL_VERSION))}

    def pose(self, i: int) -> None:
        self.scene.set_state(self.model, self.data, self.states[i % len(self.states)])
        self.scene.kinematics(self.model, self.data)

    def light(self, i: int) -> float:
        light = self.states[i % len(self.states)].get("light")
        return 1.0 if light is None else float(light[0])

    # -- the paths: n samples each ------------------------------------------------------
    def single(self, kind: str, n: int) -> None:
        for i in range(n):
            self.pose(i)
            if kind == "radiance":
                self.radiance.update(self.data, "front", self.light(i))
                self.radiance.luminance(self.lum_out)
            elif kind == "rgb":
                self.colour.update(self.data, "front")
                self.colour.rgb(self.rgb_out)
            else:
                self.colour.update(self.data, "front")

    def tiled(self, kind: str, k: int, n: int) -> np.ndarray:
        """n samples in tiles of k; returns the last tile's images."""
        key = (kind, k)
        if key not in self.tiles:
            self.tiles[key] = (RadianceTiles(self.radiance, k) if kind == "radiance"
                               else TileRenderer(self.colour, k))
        tiles = self.tiles[key]
        out = np.empty((k, self.size, self.size) + ((3,) if kind == "rgb" else ()),
                       np.float32 if kind == "radiance" else np.uint8)
        for i in range(n):
            self.pose(i)
            if kind == "radiance":
                tiles.draw(self.data, "front", self.light(i))
            else:
                self.colour.update(self.data, "front")
                tiles.draw()
            if tiles.pending == k:
                tiles.luminance(out) if kind == "radiance" else tiles.rgb(out)
        return out

    def viewports(self, k: int, n: int) -> np.ndarray:
        """n samples as tiles of k viewports in a grid of 4 columns; the last tile's
        images, top row first."""
        size, cols = self.size, min(k, 4)
        rows = -(-k // cols)
        canvas = self.colour._canvas
        grid = np.empty((rows * size, cols * size, 3), np.uint8)
        out = np.empty((k, size, size, 3), np.uint8)
        for i in range(n):
            self.pose(i)
            self.colour.update(self.data, "front")
            row, col = divmod(i % k, cols)
            canvas.gl.make_current()
            mujoco.mjr_render(mujoco.MjrRect(col * size, row * size, size, size),
                              canvas.scene, canvas.ctx)
            if i % k == k - 1:
                mujoco.mjr_readPixels(grid, None, mujoco.MjrRect(0, 0, cols * size,
                                                                 rows * size), canvas.ctx)
                for j in range(k):
                    r, c = divmod(j, cols)
                    out[j] = grid[r * size:(r + 1) * size, c * size:(c + 1) * size][::-1]
        return out

    def viewports_fit(self, k: int) -> bool:
        g = self.model.vis.global_
        cols = min(k, 4)
        return cols * self.size <= g.offwidth and -(-k // cols) * self.size <= g.offheight

    def differing_px(self, k: int) -> int:
        """Pixels of the first viewport tile of k that differ from the single renders."""
        tile = self.viewports(k, k)
        n = 0
        for i in range(k):
            self.pose(i)
            self.colour.update(self.data, "front")
            n += int(np.count_nonzero((self.colour.rgb() != tile[i]).any(-1)))
        return n

    def identical(self, kind: str, k: int) -> bool:
        """The first tile of k against k single renders, byte for byte."""
        tile = self.tiled(kind, k, k)
        for i in range(k):
            self.pose(i)
            if kind == "radiance":
                self.radiance.update(self.data, "front", self.light(i))
                one = self.radiance.luminance()
            else:
                self.colour.update(self.data, "front")
                one = self.colour.rgb()
            if one.tobytes() != tile[i].tobytes():
                return False
        return True

    def path(self, kind: str, k: int | None, n: int) -> None:
        """n samples along one path: single renders (k None), tiles of k, viewports."""
        if k is None:
            self.single(kind, n)
        elif kind == "rgb_viewports":
            self.viewports(k, n)
        else:
            self.tiled(kind, k, n)

    def close(self) -> None:
        for tiles in self.tiles.values():
            tiles.close()
        self.radiance.close()
        self.colour.close()


def timed(fn) -> tuple[float, float]:
    w0, c0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w0, time.process_time() - c0


def run(size: int, variant: str, samples: int, repeats: int, tiles: tuple[int, ...],
        kinds: tuple[str, ...]) -> dict:
    """The report (module docstring): per kind, the single path's and each tile count's
    wall and CPU ms per sample, medians of `repeats`."""
    load0 = os.getloadavg()
    b = Bench(size, variant, n_states=64)
    try:
        gl = b.gl_strings()
        grids = [k for k in tiles if b.viewports_fit(k)] if "rgb" in kinds else []
        paths = [("pose", None)] + [(kind, None) for kind in kinds] + \
            [(kind, k) for kind in kinds for k in tiles] + \
            [("rgb_viewports", k) for k in grids]
        identical = {f"{kind}_x{k}": b.identical(kind, k) for kind in kinds for k in tiles}
        differing = {k: b.differing_px(k) for k in grids}
        for kind, k in paths:                       # warm: JIT'd shaders, first uploads
            b.path(kind, k, 2 * (k or 4))
        times: dict[tuple[str, int | None], list[tuple[float, float]]] = {p: [] for p in paths}
        for rep in range(repeats):
            order = paths[rep % len(paths):] + paths[:rep % len(paths)]
            for kind, k in order:
                times[(kind, k)].append(timed(lambda: b.path(kind, k, samples)))
    finally:
        b.close()

    def row(kind, k) -> dict:
        t = np.array(times[(kind, k)]) * 1e3 / samples
        return {"wall_ms_per_sample": round(float(np.median(t[:, 0])), 4),
                "cpu_ms_per_sample": round(float(np.median(t[:, 1])), 4),
                "wall_ms_repeats": [round(float(v), 4) for v in t[:, 0]],
                "cpu_ms_repeats": [round(float(v), 4) for v in t[:, 1]]}

    def against(kind, k, single) -> dict:
        r = row(kind, k)
        for what in ("wall", "cpu"):
            r[f"{what}_vs_single"] = round(r[f"{what}_ms_per_sample"]
                                           / single[f"{what}_ms_per_sample"], 3)
        return r

    results = {"pose_and_scene_update_only": row("pose", None)}
    for kind in kinds:
        single = row(kind, None)
        rows = {"single": single}
        for k in tiles:
            rows[f"tiles_{k}"] = r = against(kind, k, single)
            r["bit_identical"] = identical[f"{kind}_x{k}"]
        results[kind] = rows
    if grids:
        rows = {}
        for k in grids:
            r = against("rgb_viewports", k, results["rgb"]["single"])
            r["px_differing_from_single_in_first_tile"] = differing[k]
            r["px_in_first_tile"] = k * size * size
            rows[f"tiles_{k}"] = r
        results["rgb_viewports"] = rows
    return {
        "gl": {**gl, "MUJOCO_GL": os.environ.get("MUJOCO_GL"),
               "PYOPENGL_PLATFORM": os.environ.get("PYOPENGL_PLATFORM"),
               "LP_NUM_THREADS": os.environ.get("LP_NUM_THREADS")},
        "machine": {"cpus": os.cpu_count(), "loadavg_before": [round(v, 2) for v in load0],
                    "loadavg_after": [round(v, 2) for v in os.getloadavg()]},
        "config": {"scene": f"nav {variant}", "size_px": size, "samples_per_repeat": samples,
                   "repeats": repeats, "tiles": list(tiles), "state_every_s": 0.005},
        "results": results,
        "when": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="48 samples, 3 repeats")
    ap.add_argument("--size", type=int, default=160, help="px, square (160)")
    ap.add_argument("--variant", choices=("indoor", "outdoor"), default="indoor")
    ap.add_argument("--tiles", type=counts_arg("--tiles"), default=TILES, help="1,2,4,8,16")
    ap.add_argument("--kinds", default="radiance,rgb", help="radiance,rgb")
    ap.add_argument("--samples", type=int, default=160, help="per repeat and path")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", metavar="FILE")
    ap.add_argument("--force", action="store_true", help="replace --json FILE if it exists")
    args = ap.parse_args()
    kinds = tuple(args.kinds.split(","))
    samples, repeats = (48, 3) if args.quick else (args.samples, args.repeats)
    bad = [k for k in kinds if k not in ("radiance", "rgb")]
    problem = (f"--kinds: unknown {bad}; known: radiance, rgb" if bad else
               f"--size {args.size}: give 8 to 640 px" if not 8 <= args.size <= 640 else
               f"--repeats {repeats}: give >= 1" if repeats < 1 else
               f"--samples {samples}: give a multiple of every --tiles count "
               f"{list(args.tiles)}" if samples < 1 or any(samples % k for k in args.tiles)
               else None)
    if problem:
        print(f"bench_render_tiles: {problem}", file=sys.stderr)
        return 2
    if args.json:
        try:
            check_output_file(args.json, force=args.force)
        except OutputRefused as e:
            print(f"bench_render_tiles: {e}", file=sys.stderr)
            return 2
    report = run(args.size, args.variant, samples, repeats, args.tiles, kinds)
    print_report(report, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
