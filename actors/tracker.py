"""Tracking metrics in closed loop (the paper's Table 4), from the sim's privileged truth.

Inputs  rgb      from the camera: only meta is read (truth: centroid, bbox, visible, image;
                 episode; t_ep; control) of the samples taken at control ticks
        action   from the policy or expert: meta modality (absent for the expert)
        episode  from the sim: start / end with seed and reason
Each finished episode is appended as one JSON line to `path` (so an interrupted evaluation
keeps what it finished), with the metrics over the whole episode and per modality segment
(a live modality swap splits an episode).
"""
from __future__ import annotations

import asyncio
import json
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

from sebvs.eval.metrics import nav_episode_metrics
from sebvs.runtime import Actor, Message

FINALIZE_AFTER_S = 1.0   # frames of an episode may trail its end message (they pass the camera)


class NavTracker(Actor):
    inputs = ("rgb", "action", "episode")

    @dataclass
    class Params:
        path: str = ""                        # JSON lines, one per finished episode
        label: dict = field(default_factory=dict)   # copied into every line (condition...)
        control_hz: float = 20.0              # for the trial duration of an episode

    async def setup(self) -> None:
        self.frames: dict[int, list] = defaultdict(list)   # episode -> [(tick, truth, t_ep)]
        self.modality_at: dict[int, str] = {}              # tick -> modality that acted
        self.inference_ms: dict[int, float] = {}           # tick -> policy latency
        self.episodes: dict[int, dict] = {}                # episode -> start/end meta
        self.finished: list[dict] = []
        self._timers: dict[int, asyncio.TimerHandle] = {}

    async def on_rgb(self, msg: Message) -> None:
        m = msg.meta
        if not m.get("control", True) or not m.get("truth"):
            return
        ep = m.get("episode")
        self.frames[ep].append((msg.tick, m["truth"], float(m.get("t_ep", 0.0))))
        for done in [e for e in self.episodes if e < ep and self.episodes[e].get("ended")]:
            self._finalize(done)

    async def on_action(self, msg: Message) -> None:
        self.modality_at[msg.tick] = msg.meta.get("modality", "expert")
        if "inference_ms" in msg.meta:
            self.inference_ms[msg.tick] = float(msg.meta["inference_ms"])

    async def on_episode(self, msg: Message) -> None:
        m = msg.meta
        ep = m.get("episode")
        info = self.episodes.setdefault(ep, {})
        if m.get("event") == "start":
            info.update(seed=m.get("seed"), start_tick=msg.tick)
        elif m.get("event") == "end":
            info.update(ended=True, reason=m.get("reason", ""))
            loop = asyncio.get_running_loop()
            self._timers[ep] = loop.call_later(FINALIZE_AFTER_S, self._finalize, ep)

    def _metrics(self, rows: list) -> dict:
        truths = [t for _, t, _ in rows]
        w, h = truths[0]["image"]
        centroids = [t["centroid"] for t in truths]
        widths = [t["bbox"][2] - t["bbox"][0] for t in truths]
        visible = [t["visible"] for t in truths]
        # the sim publishes a control sample at both ends of an episode
        duration = rows[-1][2] - rows[0][2] if len(rows) > 1 else 1 / self.params.control_hz
        return nav_episode_metrics(centroids, widths, visible, (w, h), duration).as_dict()

    def _finalize(self, ep: int) -> None:
        info = self.episodes.get(ep)
        if info is None or info.get("written"):
            return
        info["written"] = True
        timer = self._timers.pop(ep, None)
        if timer is not None:
            timer.cancel()
        rows = sorted(self.frames.pop(ep, []), key=lambda r: r[0])
        if not rows:
            self.log.warning("episode %s ended with no control frames", ep)
            return
        segments = defaultdict(list)
        last = None
        for row in rows:
            last = self.modality_at.get(row[0], last)
            segments[last or "none"].append(row)
        record = {**self.params.label, "episode": ep, "seed": info.get("seed"),
                  "reason": info.get("reason", ""), "ticks": len(rows),
                  "metrics": self._metrics(rows),
                  "by_modality": {mod: self._metrics(r) for mod, r in segments.items()},
                  "trace_error_px": [_centre_error(t) for _, t, _ in rows],
                  "inference_ms": [self.inference_ms.pop(k) for k, _, _ in rows
                                   if k in self.inference_ms]}
        for k, _, _ in rows:
            self.modality_at.pop(k, None)
        self.finished.append(record)
        self.telemetry("episode_metrics", **{k: record[k] for k in ("episode", "ticks")},
                       success=record["metrics"]["success"])
        if self.params.path:
            path = Path(self.params.path)
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(path, "a") as f:
                f.write(json.dumps(record) + "\n")

    async def teardown(self) -> None:
        for ep in sorted(self.episodes):
            if self.episodes[ep].get("ended"):
                self._finalize(ep)

    def stats(self) -> dict:
        return {"episodes_finished": len(self.finished),
                "last": self.finished[-1] if self.finished else None}


def _centre_error(truth: dict) -> float | None:
    """Distance of the target centroid from the image centre, px (None when not visible)."""
    if not truth["visible"]:
        return None
    (u, v), (w, h) = truth["centroid"], truth["image"]
    return round(((u - w / 2) ** 2 + (v - h / 2) ** 2) ** 0.5, 2)
