"""Episode-file compression and write/read speed on recorded frames.

    python tools/bench/bench_data.py DATASET_DIR [--frames 400]

Takes the rgb (and event) frames of a recorded dataset's first episodes and writes them
again with EpisodeWriter under each compression, timing the writes (append + finish) and a
full sequential read of the rgb frames. Prints size, ratio against uncompressed, frames/s.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from sebvs.data.episode import COMPRESSIONS, EpisodeWriter, open_episode
from sebvs.data.index import DatasetIndex


def load_frames(root: Path, n: int):
    rgb, ev = [], []
    for path in DatasetIndex(root).episode_paths():
        with open_episode(path) as ep:
            rgb.append(ep.rgb[:])
            ev.append(ep.event_frame[:] if ep.event_frame is not None else None)
        if sum(len(r) for r in rgb) >= n:
            break
    rgb = np.concatenate(rgb)[:n]
    ev = None if any(e is None for e in ev) else np.concatenate(ev)[:n]
    return rgb, ev


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("--frames", type=int, default=400)
    args = ap.parse_args()
    rgb, ev = load_frames(Path(args.dataset), args.frames)
    n = len(rgb)
    raw = rgb[0].nbytes + (ev[0].nbytes if ev is not None else 0)
    print(f"{n} frames rgb {rgb.shape[1:]}" + (f", events {ev.shape[1:]}" if ev is not None
                                              else ", no event frames"))
    with tempfile.TemporaryDirectory() as tmp:
        for comp in COMPRESSIONS:
            path = Path(tmp) / f"{comp}.h5"
            t0 = time.perf_counter()
            w = EpisodeWriter(path, "nav", {}, compression=comp)
            for t in range(n):
                w.append(rgb=rgb[t], event_frame=None if ev is None else ev[t],
                         action=[0.0, 0.0], t_sim=t * 0.1, tick=t,
                         latency={"camera->recorder": 100.0}, truth={"centroid": [1.0, 2.0]})
            w.finish("bench")
            wt = time.perf_counter() - t0
            t0 = time.perf_counter()
            with open_episode(path) as e:
                for t in range(n):
                    e.rgb[t]
            rt = time.perf_counter() - t0
            size = path.stat().st_size
            print(f"{comp:5s} {size / 1e6:8.2f} MB  ratio {n * raw / size:5.2f}  "
                  f"write {n / wt:6.0f} frames/s  read {n / rt:6.0f} frames/s (one at a time)")


if __name__ == "__main__":
    main()
