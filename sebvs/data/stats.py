"""``sebvs data stats DIR --plot FILE``: a dataset's summary and the paper's Fig. 3 views.

Nav: control-vector scatter (v against w), mean forward speed per episode, accumulated
events per episode. Arm: end-effector workspace (x-y and x-z scatter of the pre-grasp
poses), accumulated events per episode. Printed: episodes, frames, minutes of simulation,
labelled commands (frames whose target is finite), the share of episodes per named
condition where episodes name theirs (the ``condition`` attribute of a ``sebvs record
--hard-share`` recording), and the coverage: for every scene config key that varies across
episodes (a randomised recording, or batches recorded apart), the episodes and frames per
value (a float key: its range).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..dataset_files import episode_problem
from ..h5named import FileUnreadable
from .episode import open_episode
from .index import INDEX, DatasetIndex

MAX_VALUES = 8          # a coverage row per value up to this many distinct values


@dataclass
class EpisodeStats:
    file: str
    frames: int
    sim_s: float
    labelled: int
    events: int                     # ON + OFF counts summed over the episode (-1: no events)
    mean_target: np.ndarray         # mean of the target over the episode
    mean_abs_v: float = float("nan")    # nav: mean |v| command (speed, either direction)
    robot_speed: float = float("nan")   # mean measured base speed, m/s (nav, from truth/robot)
    conditions: dict = field(default_factory=dict)  # the scene config the episode played
    condition: str | None = None    # the named condition it was recorded under, if it says


@dataclass
class DatasetStats:
    root: Path
    task: str
    episodes: list[EpisodeStats] = field(default_factory=list)
    targets: np.ndarray | None = None   # all targets [N, 2|6]
    damaged: list[str] = field(default_factory=list)    # "<file>: <why>", left out

    @property
    def frames(self) -> int:
        return sum(e.frames for e in self.episodes)

    @property
    def sim_minutes(self) -> float:
        return sum(e.sim_s for e in self.episodes) / 60

    @property
    def labelled(self) -> int:
        return sum(e.labelled for e in self.episodes)

    def condition_shares(self) -> dict[str, int]:
        """Episodes per named condition (the ``condition`` attribute): the hard ones in the
        order they first appear, then "randomised", then "unnamed" for episodes without
        the attribute; empty when no episode names one."""
        names = [e.condition or "unnamed" for e in self.episodes]
        if set(names) <= {"unnamed"}:
            return {}
        last = ("randomised", "unnamed")
        order = [*dict.fromkeys(n for n in names if n not in last),
                 *(n for n in last if n in names)]
        return {n: names.count(n) for n in order}

    def coverage(self) -> dict[str, dict]:
        """key -> {value: (episodes, frames)} for the config keys that vary; a float key with
        more than MAX_VALUES distinct values maps to {"min": x, "max": y} instead."""
        keys = sorted({k for e in self.episodes for k in e.conditions})
        out: dict[str, dict] = {}
        for key in keys:
            values = [e.conditions.get(key) for e in self.episodes]
            if len({json.dumps(v, sort_keys=True) for v in values}) < 2:
                continue
            numbers = [v for v in values if isinstance(v, float)]
            # a float drawn from a range has as many values as episodes: show its range;
            # one drawn from a few choices (belt speeds) gets a row per value
            if numbers and len(numbers) == len(values) and len(set(numbers)) > MAX_VALUES:
                out[key] = {"min": min(numbers), "max": max(numbers)}
                continue
            table: dict = {}
            for e, v in zip(self.episodes, values):
                name = f"{v:g}" if isinstance(v, float) else str(v)
                n, f = table.get(name, (0, 0))
                table[name] = (n + 1, f + e.frames)
            out[key] = dict(sorted(table.items()))
        return out

    def summary(self) -> str:
        lines = [f"dataset {self.root} (task {self.task})",
                 f"  episodes           {len(self.episodes)}",
                 f"  frames             {self.frames}",
                 f"  simulation         {self.sim_minutes:.1f} min",
                 f"  labelled commands  {self.labelled}"]
        if self.episodes:
            ev = [e.events for e in self.episodes if e.events >= 0]
            if ev:
                lines.append(f"  events per episode {np.mean(ev):.0f} mean "
                             f"({min(ev)} .. {max(ev)})")
            if self.task == "nav" and self.targets is not None and len(self.targets):
                v, w = self.targets[:, 0], self.targets[:, 1]
                lines.append(f"  v mean {v.mean():+.3f} sd {v.std():.3f}; "
                             f"w mean {w.mean():+.3f} sd {w.std():.3f}")
        for line in self.damaged:
            lines.append(f"  damaged, left out: {line}")
        shares = self.condition_shares()
        if shares:
            lines.append("  conditions         " + ", ".join(
                f"{c} {n} ({100 * n / len(self.episodes):.0f} %)" for c, n in shares.items()))
        cover = self.coverage()
        if cover:
            lines.append("  coverage (episodes / frames per scene setting)")
        for key, table in cover.items():
            if set(table) == {"min", "max"}:
                lines.append(f"    {key:<14} {table['min']:g} .. {table['max']:g}")
                continue
            cells = ", ".join(f"{v} {n} / {f}" for v, (n, f) in table.items())
            lines.append(f"    {key:<14} {cells}")
        return "\n".join(lines)


def episode_entries(root: Path) -> list[dict]:
    """The indexed episodes' entries (only those: .partial and unindexed files are never
    used); without an index, the episode files on disk, with nothing to check them by."""
    if (root / INDEX).exists():
        return DatasetIndex(root).episodes()
    return [{"file": p.name} for p in sorted(root.glob("episode_*.h5"))]


def episode_files(root: Path) -> list[str]:
    """The names of `episode_entries`."""
    return [e["file"] for e in episode_entries(Path(root))]


def collect(root: str | Path) -> DatasetStats:
    """The statistics of the whole episodes of dataset ``root``; an episode that differs
    from its index or cannot be read is left out and named in ``damaged``."""
    root = Path(root)
    if not root.is_dir():
        raise ValueError(f"{root}: no such dataset folder")
    task, targets, eps, bad = None, [], [], []
    for entry in episode_entries(root):
        name = entry["file"]
        why = episode_problem(root / name, entry)
        if why:
            bad.append(f"{name}: {why}")
            continue
        try:
            ep_stats = _episode_stats(root / name)
        except (FileUnreadable, FileNotFoundError) as exc:
            bad.append(f"{name}: {exc}")
            continue
        task = task or ep_stats[0]
        eps.append(ep_stats[1])
        targets.append(ep_stats[2])
    st = DatasetStats(root, task or "nav", eps, damaged=bad)
    st.targets = np.concatenate(targets) if targets else np.zeros((0, 2), np.float32)
    return st


def _episode_stats(path: Path) -> tuple[str, EpisodeStats, np.ndarray]:
    """(task, the episode's statistics, its finite targets) of one episode file."""
    with open_episode(path) as ep:
        y = ep.target[:]
        t = ep.t_sim[:]
        # an episode covers its frames' span plus one control period
        dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
        sim_s = float(t[-1] - t[0] + dt) if len(t) else 0.0
        events = -1
        if ep.event_frame is not None:
            events = 0
            for s in range(0, len(ep), 256):
                events += int(ep.event_frame[s:s + 256].sum(dtype=np.int64))
        finite = np.isfinite(y).all(axis=1)
        st = EpisodeStats(path.name, len(ep), sim_s, int(finite.sum()), events,
                          y[finite].mean(axis=0) if finite.any()
                          else np.full(y.shape[1], np.nan),
                          conditions=dict(ep.attrs.get("conditions") or {}),
                          condition=str(ep.attrs.get("condition") or "") or None)
        if ep.task == "nav" and finite.any():
            st.mean_abs_v = float(np.abs(y[finite, 0]).mean())
        if "robot" in ep.truth and len(t) > 1:
            xy = ep.truth["robot"][:, :2]
            step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
            ok = np.isfinite(step) & (np.diff(t) > 0)
            if ok.any():
                st.robot_speed = float(step[ok].sum() / np.diff(t)[ok].sum())
        return ep.task, st, y[finite]


def plot(st: DatasetStats, path: str | Path) -> None:
    """Fig. 3 views as one PNG (matplotlib Agg: no display needed)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    y = st.targets
    n = np.arange(len(st.episodes))
    if st.task == "nav":
        ax = axes[0]
        ax.scatter(y[:, 1], y[:, 0], s=3, alpha=0.3)
        ax.set(xlabel="w (yaw rate command)", ylabel="v (forward command)",
               title=f"control vectors ({len(y)} commands)", xlim=(-1.05, 1.05),
               ylim=(-1.05, 1.05))
        ax = axes[1]
        ax.bar(n, [e.mean_abs_v for e in st.episodes], label="mean |v| command")
        ax.set(xlabel="episode", ylabel="mean |v| command", title="mean speed per episode")
        speeds = [e.robot_speed for e in st.episodes]
        if np.isfinite(speeds).any():
            # the commanded speed, and what the base did (the ground truth's robot pose)
            ax2 = ax.twinx()
            ax2.plot(n, speeds, "o-", color="tab:red", label="measured m/s")
            ax2.set_ylabel("measured base speed (m/s)", color="tab:red")
    else:
        ax = axes[0]
        sc = ax.scatter(y[:, 0], y[:, 1], s=4, c=y[:, 2], cmap="viridis", alpha=0.5)
        fig.colorbar(sc, ax=ax, label="z (m)")
        ax.set(xlabel="x (m)", ylabel="y (m)", title=f"end-effector workspace ({len(y)} poses)")
        ax.set_aspect("equal", adjustable="datalim")
        ax = axes[1]
        ax.scatter(y[:, 0], y[:, 2], s=4, alpha=0.5)
        ax.set(xlabel="x (m)", ylabel="z (m)", title="workspace, side view")
    ax = axes[2]
    if all(e.events < 0 for e in st.episodes):
        ax.text(0.5, 0.5, "no event frames recorded\n(RGB-only topology)", ha="center",
                va="center", transform=ax.transAxes)
    ax.bar(n, [max(e.events, 0) for e in st.episodes], color="tab:orange")
    ax.set(xlabel="episode", ylabel="ON + OFF events", title="accumulated events per episode")
    fig.suptitle(f"{st.root.name}: {len(st.episodes)} episodes, {st.frames} frames, "
                 f"{st.sim_minutes:.1f} min simulated")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def cmd_stats(args) -> int:
    """Exit 0; 1 when an episode is damaged (named, left out of the figures); 2 when the
    folder is not a dataset or the plot may not be written."""
    import sys
    from ..output_guard import check_output_file
    try:
        if args.plot:
            check_output_file(args.plot, force=args.force)
        st = collect(args.dir)
    except (ValueError, OSError) as exc:
        print(f"sebvs data stats: {exc}", file=sys.stderr)
        return 2
    print(st.summary())
    if args.plot:
        plot(st, args.plot)
        print(f"plot: {args.plot}")
    for line in st.damaged:
        print(f"sebvs data stats: {line} (left out; `sebvs data check {args.dir}`)",
              file=sys.stderr)
    return 1 if st.damaged else 0
