"""``sebvs data check DIR``: verify a dataset against its index.

For each indexed episode: the file exists, its sha256 and byte size match, it opens, its
datasets have consistent lengths and shapes (rgb [T,H,W,3] uint8, events/frame [T,2K,h,w],
target [T,2|6|nu], t_sim/tick/latency [T], ticks increasing), T equals the index's frame
count, and the required attributes are present; where an episode holds proprioception
(``proprio`` [T, D]), its rows, their finiteness and its ``proprio_names``. Also reported:
``*.partial`` files (lost in-progress episodes: never used), episode files that the index
does not list, and an index that is missing or unreadable. Any problem makes the exit code
non-zero. Episodes without proprioception (recorded before the recorder stored it) are
named in a note, not a problem: they train as before, but a dataset's
``observation.state`` cannot be filled from them.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .episode import PARTIAL, REQUIRED_ATTRS, TASK_TARGET, open_episode
from .index import EPISODE_RE, INDEX, file_sha256


@dataclass
class CheckReport:
    root: Path
    episodes: int = 0
    frames: int = 0
    problems: list[str] = field(default_factory=list)     # "<file>: <what>"
    lost: list[str] = field(default_factory=list)         # .partial leftovers
    unindexed: list[str] = field(default_factory=list)
    no_proprio: list[str] = field(default_factory=list)   # readable, no proprioception

    @property
    def ok(self) -> bool:
        return not (self.problems or self.lost or self.unindexed)

    def lines(self) -> list[str]:
        out = [f"{p}" for p in self.problems]
        out += [f"{name}: lost in-progress episode (.partial left by a crash; not used)"
                for name in self.lost]
        out += [f"{name}: episode file not in {INDEX} (not used)" for name in self.unindexed]
        if self.no_proprio:
            shown = ", ".join(self.no_proprio[:5]) + (", ..." if len(self.no_proprio) > 5
                                                      else "")
            out.append(f"note: {len(self.no_proprio)} of {self.episodes} episode(s) hold no "
                       f"proprioception (recorded before the recorder stored it, or without "
                       f"sim/proprio wired): observation.state cannot be filled from them "
                       f"({shown})")
        verdict = "OK" if self.ok else \
            f"{len(self.problems)} problem(s), {len(self.lost)} lost, " \
            f"{len(self.unindexed)} unindexed"
        out.append(f"{self.root}: {self.episodes} indexed episode(s), {self.frames} frames: "
                   f"{verdict}")
        return out


def check_episode(path: Path, entry: dict, task: str | None,
                  notes: dict | None = None) -> list[str]:
    """Problems of one indexed episode file (empty list: fine); `notes`, when given, gets
    "no_proprio": True for a readable episode without proprioception."""
    name = entry.get("file", path.name)
    if not path.exists():
        return [f"{name}: missing (listed in {INDEX})"]
    problems = []
    size = path.stat().st_size
    if "bytes" in entry and entry["bytes"] != size:
        problems.append(f"{name}: {size} bytes, index says {entry['bytes']} (truncated "
                        f"or rewritten)")
    if "sha256" in entry and file_sha256(path) != entry["sha256"]:
        problems.append(f"{name}: sha256 differs from the index (corrupt or rewritten)")
    try:
        with open_episode(path) as ep:
            problems += _check_contents(name, ep, entry, task)
            if notes is not None and ep.proprio is None:
                notes["no_proprio"] = True
    except Exception as exc:        # h5py raises OSError, KeyError, ValueError...
        problems.append(f"{name}: cannot be read ({type(exc).__name__}: {exc})")
    return problems


def _check_contents(name: str, ep, entry: dict, task: str | None) -> list[str]:
    problems = []
    T = len(ep)
    if "frames" in entry and entry["frames"] != T:
        problems.append(f"{name}: {T} frames, index says {entry['frames']}")
    missing = [a for a in REQUIRED_ATTRS if a not in ep.attrs]
    if missing:
        problems.append(f"{name}: attributes missing: {', '.join(missing)}")
    if task and ep.attrs.get("task") not in (None, task):
        problems.append(f"{name}: task {ep.attrs.get('task')!r}, dataset is {task!r}")
    if ep.rgb.ndim != 4 or ep.rgb.shape[3] != 3 or ep.rgb.dtype != np.uint8:
        problems.append(f"{name}: rgb is {ep.rgb.dtype} {ep.rgb.shape}, expected uint8 "
                        f"[T, H, W, 3]")
    if ep.event_frame is not None:
        ev = ep.event_frame
        if ev.ndim != 4 or ev.shape[0] != T or ev.shape[1] < 2 or ev.shape[1] % 2:
            problems.append(f"{name}: events/frame is {ev.shape}, expected [{T}, 2K, h, w]")
    dim = TASK_TARGET[ep.task][1]
    if dim is None and ep.target.ndim == 2:
        dim = ep.target.shape[1]        # mjcf: the model's actuators, any number
    if ep.target.shape != (T, dim):
        problems.append(f"{name}: {ep.target_key} is {ep.target.shape}, expected [{T}, "
                        f"{dim or 'nu'}]")
    cols = {"t_sim": ep.t_sim, "tick": ep.tick, **{f"latency/{k}": v for k, v in
                                                     ep.latency.items()},
            **{f"truth/{k}": v for k, v in ep.truth.items()}}
    if ep.modality is not None:
        cols["modality"] = ep.modality
    drive = getattr(ep, "drive", None)
    if drive is not None:       # a DAgger round's: the policy command that drove each tick
        cols["drive"] = drive
        if drive.ndim != 2 or drive.shape[1] != ep.target.shape[-1]:
            problems.append(f"{name}: drive is {drive.shape}, expected [{T}, "
                            f"{ep.target.shape[-1]}] (one command per tick, as "
                            f"{ep.target_key})")
    if ep.proprio is not None:
        cols["proprio"] = ep.proprio
        names = ep.proprio_names
        if ep.proprio.ndim != 2 or (names and ep.proprio.shape[1] != len(names)):
            problems.append(f"{name}: proprio is {ep.proprio.shape}, expected [{T}, "
                            f"{len(names) if names else 'D'}] (proprio_names: "
                            f"{', '.join(names) or 'none'})")
    for key, ds in cols.items():
        if ds.shape[:1] != (T,):
            problems.append(f"{name}: {key} has {ds.shape[0] if ds.ndim else 0} rows, "
                            f"expected {T}")
    if not problems and T:
        # read every frame once: a torn chunk inside the file shows up here
        for key in ("rgb", "events/frame"):
            if key in ep.file:
                ds = ep.file[key]
                for start in range(0, T, 256):
                    ds[start:start + 256]
        ticks = ep.tick[:]
        if (np.diff(ticks) <= 0).any():
            problems.append(f"{name}: ticks are not strictly increasing")
        if not np.isfinite(ep.target[:]).all():
            problems.append(f"{name}: {ep.target_key} holds NaN/inf")
        if ep.proprio is not None:
            bad = int((~np.isfinite(ep.proprio[:])).any(axis=-1).sum())
            if bad:     # the recorder writes a row only once every stream gave its tick
                problems.append(f"{name}: proprio holds NaN/inf in {bad} of {T} rows")
    return problems


def check_dataset(root: str | Path) -> CheckReport:
    root = Path(root)
    rep = CheckReport(root)
    if not root.is_dir():
        rep.problems.append(f"{root}: not a directory")
        return rep
    index_path = root / INDEX
    entries: list[dict] = []
    task = None
    if not index_path.exists():
        rep.problems.append(f"{INDEX}: missing")
    else:
        try:
            data = json.loads(index_path.read_text())
            entries, task = list(data["episodes"]), data.get("task")
        except (ValueError, KeyError, TypeError) as exc:
            rep.problems.append(f"{INDEX}: unreadable ({exc})")
    listed = set()
    for e in entries:
        name = e.get("file", "?")
        if name in listed:
            rep.problems.append(f"{name}: listed twice in {INDEX}")
        listed.add(name)
        rep.episodes += 1
        notes: dict = {}
        problems = check_episode(root / name, e, task, notes)
        rep.problems += problems
        if notes.get("no_proprio"):
            rep.no_proprio.append(name)
        if not problems:
            rep.frames += int(e.get("frames", 0))
    for p in sorted(root.iterdir()):
        m = EPISODE_RE.match(p.name)
        if p.name.endswith(PARTIAL):
            rep.lost.append(p.name)
        elif m and p.name not in listed:
            rep.unindexed.append(p.name)
    return rep


def cmd_check(args) -> int:
    rep = check_dataset(args.dir)
    for line in rep.lines():
        print(line)
    return 0 if rep.ok else 1
