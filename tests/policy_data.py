"""Tiny synthetic behaviour-cloning datasets for the policy tests, in the recorded layout.

Each frame shows a bright square on a dim noisy background; the square drifts. The
expert's action is a function of what the image shows, so a policy can learn it:
    w = (x_centre / W) * 2 - 1,   v = (y_centre / H) * 2 - 1        (nav, both in [-1, 1])
    pose = [x, y, 0.1, 0, 0, y - x] in normalised image units       (arm)
or, with target="gain", from the square's brightness (see make_dataset).
Event frames: ON counts where the square is now and was not, OFF where it was and is not,
so an event-only policy can localise the square too; with event_bins K > 1 a histogram of
K time bins per polarity (the ON counts in the newest bin, the OFF counts in the oldest).
Written with sebvs/data's EpisodeWriter and DatasetIndex, as the recorder writes them.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from sebvs.data.episode import EpisodeWriter
from sebvs.data.index import DatasetIndex, make_entry


def _frames(rng: np.random.Generator, frames: int, h: int, w: int, side: int, vary_gain: bool,
            shown: int = 0):
    """-> rgb [T, H, W, 3], events [T, 2, H, W], centre [T, 2] in [0, 1], gain [T] in [0.2, 1].
    ``shown`` > 0: the square stands still and shows in the first ``shown`` frames only."""
    x, y = rng.uniform(0, w - side), rng.uniform(0, h - side)
    vx, vy = rng.uniform(-2, 2, 2) * max(1, w // 32)
    if shown:
        vx = vy = 0.0
    rgb = np.empty((frames, h, w, 3), np.uint8)
    events = np.zeros((frames, 2, h, w), np.uint8)
    centre = np.empty((frames, 2), np.float32)
    prev = None
    gain = rng.uniform(0.2, 1.0, frames).astype(np.float32) if vary_gain else \
        np.ones(frames, np.float32)
    for t in range(frames):
        x, y = x + vx, y + vy
        if not 0 <= x <= w - side:
            vx, x = -vx, float(np.clip(x, 0, w - side))
        if not 0 <= y <= h - side:
            vy, y = -vy, float(np.clip(y, 0, h - side))
        mask = np.zeros((h, w), bool)
        if not shown or t < shown:
            mask[int(y):int(y) + side, int(x):int(x) + side] = True
        rgb[t] = rng.integers(0, 40, (h, w, 3), dtype=np.uint8)
        if vary_gain:   # the background's level follows the gain: a global cue, quick to learn
            rgb[t] += np.uint8(100 * gain[t])
        rgb[t][mask] = (np.array([250, 240, 80]) * gain[t]).astype(np.uint8)
        n = int(round(1 + 7 * gain[t]))     # a brighter square fires more events
        if prev is not None:
            events[t, 0][mask & ~prev] = n
            events[t, 1][prev & ~mask] = n
        events[t, 0][mask] = np.maximum(events[t, 0][mask], n)
        prev = mask
        centre[t] = ((x + side / 2) / w, (y + side / 2) / h)
    return rgb, events, centre, gain


def make_dataset(root: str | Path, *, episodes: int = 6, frames: int = 24, height: int = 32,
                 width: int = 32, seed: int = 0, task: str = "nav",
                 target: str = "position", event_bins: int = 1,
                 compression: str = "none", truth: bool = False) -> Path:
    """Write ``episodes`` episode files and index.json under ``root``.

    target "position": nav [v, w] from the square's centre (learnt only after a few hundred
    steps: attention must first find the square's patch);
    "gain": v = w = the square's brightness mapped to [-1, 1], visible in the mean of every
    channel, so a few epochs show the loss falling;
    "remember": as "position", but the square stands still and shows in the first 2
    frames only: after them the action is what the first frames showed, which a policy
    without memory cannot know.
    ``truth``: record the sim's truth as nav scenes give it (truth/centroid px,
    truth/visible, truth/image), for the target head.
    """
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    index = DatasetIndex(root, task)
    for e in range(episodes):
        shown = 2 if target == "remember" else 0
        rgb, events, centre, gain = _frames(rng, frames, height, width, max(4, width // 5),
                                            vary_gain=target == "gain", shown=shown)
        if task == "nav":
            if target == "gain":
                targets = np.stack([gain * 2 - 1.2, gain * 2 - 1.2], axis=1)
            else:
                targets = np.stack([centre[:, 1] * 2 - 1, centre[:, 0] * 2 - 1], axis=1)
        else:
            cx, cy = centre[:, 0], centre[:, 1]
            targets = np.stack([cx, cy, np.full_like(cx, 0.1), 0 * cx, 0 * cx, cy - cx], axis=1)
        if event_bins > 1:
            hist = np.zeros((frames, 2 * event_bins, height, width), np.uint8)
            hist[:, event_bins - 1], hist[:, event_bins] = events[:, 0], events[:, 1]
            events = hist
        attrs = {"seed": seed * 1000 + e, "scene": "synthetic", "event_window_s": 0.1,
                 "event_representation": "counts" if event_bins == 1 else "histogram",
                 "event_sensor": [width // 2, height // 2]}   # frames: the sensor upsampled
        path = index.path_for(index.next_episode_number())
        with EpisodeWriter(path, task, attrs, compression=compression) as w:
            for t in range(frames):
                seen = not shown or t < shown
                told = ({"truth": {"centroid": [float(centre[t, 0] * width),
                                                float(centre[t, 1] * height)]
                                   if seen else [-1.0, -1.0],
                                   "visible": seen, "image": [width, height]}}
                        if truth else {})
                w.append(rgb=rgb[t], event_frame=events[t], t_sim=t / 30.0, tick=t,
                         **{"action" if task == "nav" else "pose": targets[t]}, **told)
            w.finish("synthetic")
        index.add(make_entry(path))
    return root


def copy_without(root: str | Path, out: str | Path, file: str) -> Path:
    """A copy of the dataset at ``root`` in ``out`` whose index lacks the episode ``file``
    (the file itself stays): a recording missing one episode a checkpoint names."""
    import json
    import shutil
    out = Path(out)
    shutil.copytree(root, out)
    index = json.loads((out / "index.json").read_text())
    index["episodes"] = [e for e in index["episodes"] if e["file"] != file]
    (out / "index.json").write_text(json.dumps(index))
    return out


def recorded_again(root: str | Path, out: str | Path, tick_offset: int = 100) -> Path:
    """A copy of the dataset at ``root`` in ``out`` as a second run of the same recording
    makes it: the same frames, events and targets, other hop latencies (measured on the wall
    clock) and ticks counted from another run's start, so other files and another index."""
    import shutil

    import h5py

    from sebvs.data.index import DatasetIndex, make_entry
    out = Path(out)
    shutil.copytree(root, out)
    old = DatasetIndex(out)
    task, episodes = old.data.get("task"), old.episodes()
    (out / "index.json").unlink()
    index = DatasetIndex(out, task)
    for k, e in enumerate(episodes):
        with h5py.File(out / e["file"], "r+") as f:
            f["tick"][...] = f["tick"][()] + tick_offset
            f.create_dataset("latency/sim|camera", data=np.full(f["tick"].shape, 100.0 + k,
                                                                np.float32))
        index.add(make_entry(out / e["file"]))
    return out


def reindex(root: str | Path) -> Path:
    """Rewrite ``root``'s index entries from its files as they are now: a test that edits an
    episode in place stands for a recording made anew, whose index a recorder would write
    (an edited file the index does not know of is refused as damaged, sebvs/dataset_files.py)."""
    from sebvs.data.index import write_json_atomic
    index = DatasetIndex(root)
    index.data["episodes"] = [make_entry(Path(root) / e["file"], reason=e.get("reason"))
                              for e in index.episodes()]
    write_json_atomic(index.path, index.data)
    return Path(root)
