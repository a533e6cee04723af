"""Recording logic, free of the runtime: join streams by tick, route rows to episodes.

The recorder actor (actors/recorder.py) feeds messages in; this module decides what is a
complete row, which episode it belongs to, and when an episode is finished.

Joining relies on one property of the transport: each stream arrives in tick order
(ZeroMQ keeps order per connection). So when the row of tick k completes, every stream
has passed k, and any pending row below k can never complete: it is dropped and counted
at once instead of waiting for a timeout.
"""
from __future__ import annotations

import logging
import os
import shutil
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .episode import TASK_TARGET, EpisodeWriter
from .index import DatasetIndex, make_entry

log = logging.getLogger("sebvs.data.recording")


class TickJoiner:
    """Collects one item per stream per tick; yields a row once every stream delivered.

    ``streams``: names that must all be present (the connected inputs). ``max_pending``
    bounds memory when a stream stalls: the oldest pending tick is dropped beyond it.
    Counters: ``incomplete`` (ticks dropped without all streams), ``late`` (an item for a
    tick already completed or dropped), ``duplicate`` (a second item for one tick/stream).
    """

    def __init__(self, streams: set[str] | frozenset[str], max_pending: int = 256):
        if not streams:
            raise ValueError("nothing to join: no stream given")
        self.streams = frozenset(streams)
        self.max_pending = max_pending
        self.pending: dict[int, dict[str, Any]] = {}
        self.last_done = -1 << 62          # highest tick completed or dropped
        self.completed = self.incomplete = self.late = self.duplicate = 0
        self.dropped_ticks: list[int] = []  # the last few, for the log

    def add(self, stream: str, tick: int, item: Any) -> tuple[int, dict[str, Any]] | None:
        """Add one item; returns (tick, {stream: item}) when that tick's row completes."""
        if tick <= self.last_done:
            self.late += 1
            return None
        row = self.pending.setdefault(tick, {})
        if stream in row:
            self.duplicate += 1
        row[stream] = item
        if len(row) < len(self.streams):
            if len(self.pending) > self.max_pending:
                self._drop(min(self.pending))
            return None
        del self.pending[tick]
        for k in [k for k in self.pending if k < tick]:
            self._drop(k)   # in-order streams: these can no longer complete
        self.last_done = tick
        self.completed += 1
        return tick, row

    def _drop(self, tick: int) -> None:
        self.pending.pop(tick, None)
        self.incomplete += 1
        self.last_done = max(self.last_done, tick)
        self.dropped_ticks = (self.dropped_ticks + [tick])[-8:]


@dataclass
class OpenEpisode:
    """An episode between its start marker and its last row."""
    number: int
    start_tick: int
    info: dict
    writer: EpisodeWriter | None = None      # created on the first row
    end_tick: int | None = None
    reason: str = ""
    ended_at: float = 0.0                    # monotonic s when the end marker came
    last_tick: int = -1
    extra_attrs: dict = field(default_factory=dict)
    # the last rows placed here by their tick alone (no episode number in them) before the
    # end marker came: if it comes late, those past the end go to the next episode
    by_tick: deque = field(default_factory=deque)


class EpisodeRecorder:
    """Writes rows into per-episode files of dataset ``root`` and indexes them.

    ``start(info, tick)`` / ``end(reason, tick)`` come from the sim's episode markers;
    ``row(tick, ...)`` from the joiner. An episode is finished (file renamed, index
    updated last) when its last tick was written, when a later row arrives, or
    ``grace_s`` after its end marker if the last rows never complete. A row without the
    sim's episode number goes by tick; if the end marker comes after rows of the next
    episode went there, they are moved to it (``_move_past_end``).
    """

    def __init__(self, root: str | Path, task: str | None = None, *, compression: str = "lzf",
                 base_attrs: dict | None = None, grace_s: float = 2.0,
                 max_orphans: int = 32):
        self.root = Path(root)
        self.index = DatasetIndex(self.root, task)
        for name in self.index.adopt_unindexed():
            log.warning("%s: finished but not indexed (a crash after its rename); indexed now",
                        name)
        self.task = task or self.index.task
        self.compression = compression
        self.base_attrs = dict(base_attrs or {})
        self.grace_s = grace_s
        self.open: list[OpenEpisode] = []
        self.finished: list[dict] = []             # index entries written by this recorder
        self.discarded = 0                         # episodes dropped (no rows, no end marker)
        self.outside = 0                           # rows outside any episode
        self.frames = 0                            # rows written in finished episodes
        self.sim_s = 0.0                           # simulated seconds in finished episodes
        self._next = self.index.next_episode_number()
        self.orphans: list[tuple[int, dict]] = []  # rows that came before their start marker
        self.max_orphans = max_orphans
        self.started_ids: set = set()              # sim episode numbers seen starting

    # --- markers -------------------------------------------------------------------
    def start(self, info: dict, tick: int) -> None:
        for ep in [e for e in self.open if e.end_tick is None]:
            # a start without the previous end: the sim restarted or the marker was lost;
            # the episode's extent is unknown, so it is not kept
            log.warning("episode %d: new start before its end marker; discarded", ep.number)
            self._discard(ep, "no end marker")
        self.open.append(OpenEpisode(self._next, tick, dict(info)))
        self._next += 1
        if info.get("episode") is not None:
            self.started_ids.add(info["episode"])
        # rows that beat the start marker here (it travels on its own socket) belong to it
        orphans, self.orphans = self.orphans, []
        for t, fields in orphans:
            if fields.get("episode") is None and t < tick:
                self.outside += 1
            else:
                self.row(t, **fields)

    def end(self, reason: str, tick: int) -> list[dict]:
        """Mark the open episode's end; returns entries of episodes finished now."""
        ep = next((e for e in reversed(self.open) if e.end_tick is None), None)
        if ep is None:
            log.warning("episode end marker (tick %d) without a start; ignored", tick)
            return []
        ep.end_tick, ep.reason, ep.ended_at = tick, reason, time.monotonic()
        if ep.last_tick > tick:
            self._move_past_end(ep)
        if ep.last_tick >= tick:
            return [self._finish(ep)]
        return []

    def _move_past_end(self, ep: OpenEpisode) -> None:
        """Rows of the next episode that beat this one's end marker (it travels on its own
        socket) and carried no episode number, so went by tick into this episode: take
        them out and hold them for the next start marker, as rows that beat it are."""
        ticks = ep.writer.ticks
        keep = sum(t <= ep.end_tick for t in ticks)
        held = [(t, f) for t, f in ep.by_tick if t > ep.end_tick]
        ep.writer.truncate(keep)
        ep.last_tick = ticks[keep - 1] if keep else -1
        ep.by_tick.clear()
        unheld = len(ticks) - keep - len(held)  # past by_tick's bound: never held
        self.outside += unheld
        lost = unheld + self._hold(held, first=True)    # the earliest ticks of what waits
        log.warning("episode %d: its end marker (tick %d) came after %d row(s) of the next "
                    "episode; moved to it%s", ep.number, ep.end_tick, len(ticks) - keep,
                    f" ({lost} no longer held: counted outside any episode)" if lost else "")

    def _hold(self, rows: list[tuple[int, dict]], first: bool = False) -> int:
        """Hold rows for a start marker still in flight (before those held already when
        ``first``: earlier ticks). Beyond max_orphans the earliest are dropped and counted
        outside any episode; returns how many."""
        self.orphans = rows + self.orphans if first else self.orphans + rows
        over = max(0, len(self.orphans) - self.max_orphans)
        del self.orphans[:over]
        self.outside += over
        return over

    # --- rows ----------------------------------------------------------------------
    def row(self, tick: int, **fields) -> list[dict]:
        """Append one joined row (EpisodeWriter.append fields; ``attrs`` sets file
        attributes; ``episode``: the sim's episode number the row shows, when known).

        Returns entries of episodes finished by this row.
        """
        done = []
        for ep in list(self.open):
            if ep.end_tick is not None and tick > ep.end_tick:
                done.append(self._finish(ep))      # later rows: its last ones are lost
        sim_ep = fields.pop("episode", None)
        if sim_ep is not None:
            # the row says which episode it shows (camera meta): exact even when a row of
            # the next episode arrives before this episode's end marker
            ep = next((e for e in self.open if e.info.get("episode") == sim_ep), None)
            stale = ep is None and sim_ep in self.started_ids
        else:
            ep = next((e for e in self.open if e.start_tick <= tick
                       and (e.end_tick is None or tick <= e.end_tick)), None)
            stale = ep is None and bool(self.open) and \
                tick < max(e.start_tick for e in self.open)
        if ep is None:
            if stale:
                self.outside += 1                  # of an episode already finished
            else:
                # maybe the next episode's start marker is still in flight: hold a few rows
                self._hold([(tick, {**fields, "episode": sim_ep})])
            return [d for d in done if d]
        attrs = fields.pop("attrs", None) or {}
        if ep.writer is None:
            # an mjcf scene's commands travel as "action" too, any number of them
            task = self.task or ("mjcf" if ep.info.get("scene") == "mjcf" else
                                 "nav" if fields.get("action") is not None else "arm")
            if self.index.task not in (None, task):
                raise ValueError(f"{self.root}: dataset holds task {self.index.task!r}, "
                                 f"the stream sends {task!r} targets")
            self.task = self.index.data["task"] = task
            info = ep.info
            a = {**self.base_attrs, "scene": info.get("scene", ""),
                 "conditions": info.get("conditions", info.get("config", {})),
                 "seed": info.get("seed", ""), "sim_episode": info.get("episode", "")}
            ep.writer = EpisodeWriter(self.index.path_for(ep.number), task, a,
                                      compression=self.compression)
        if attrs and attrs != ep.extra_attrs:      # the accumulator repeats them every tick
            ep.writer.set_attrs(attrs)
            ep.extra_attrs = attrs
        ep.writer.append(tick=tick, **fields)
        ep.last_tick = tick
        if sim_ep is None and ep.end_tick is None:
            ep.by_tick.append((tick, {**fields, "attrs": attrs}))
            if len(ep.by_tick) > self.max_orphans:
                ep.by_tick.popleft()
        if ep.end_tick is not None and tick >= ep.end_tick:
            done.append(self._finish(ep))
        return [d for d in done if d]

    def poll(self) -> list[dict]:
        """Finish episodes whose end marker is older than grace_s."""
        now = time.monotonic()
        return [d for d in (self._finish(e) for e in list(self.open)
                            if e.end_tick is not None and now - e.ended_at > self.grace_s) if d]

    def close(self) -> list[dict]:
        """At shutdown: finish ended episodes, discard the one still in progress."""
        done = [self._finish(e) for e in list(self.open) if e.end_tick is not None]
        for ep in list(self.open):
            log.warning("episode %d still in progress at shutdown; discarded", ep.number)
            self._discard(ep, "run stopped mid-episode")
        return [d for d in done if d]

    @property
    def next_number(self) -> int:
        return self._next

    @property
    def current(self) -> OpenEpisode | None:
        return self.open[-1] if self.open else None

    # --- ending ----------------------------------------------------------------------
    def _finish(self, ep: OpenEpisode) -> dict | None:
        if ep.writer is None or ep.writer.frames == 0:
            self._discard(ep, "no rows")
            return None
        frames, sim_s = ep.writer.frames, ep.writer.sim_seconds
        # the entry (hash, attributes) before the rename: a fan-out driver adopts the file
        # the moment it has its final name (sebvs/data/record.py), and it is gone from here.
        # A write that fails here (a full disk) raises with the episode still open, so
        # whoever handles it can close its file.
        entry = make_entry(ep.writer.close(ep.reason), ep.reason, name=ep.writer.path.name)
        path = ep.writer.publish()
        self.open.remove(ep)
        self.index.add(entry)            # last: only a complete, renamed file is indexed
        self.finished.append(entry)
        self.frames += frames
        self.sim_s += sim_s
        log.info("episode %s: %d frames, %.1f s simulated, %s", path.name, frames, sim_s,
                 ep.reason)
        return entry

    def _discard(self, ep: OpenEpisode, why: str, removed: bool = False) -> None:
        if not removed:
            self.open.remove(ep)
        if ep.writer is not None:
            ep.writer.abort()
        self.discarded += 1
        log.info("episode %d discarded: %s", ep.number, why)

    def in_progress_frames(self) -> int:
        return sum(e.writer.frames for e in self.open if e.writer is not None)


# the tasks a command's array name tells apart (mjcf's "action" is told by its scene)
TASK_OF_KEY = {key: task for task, (key, dim) in TASK_TARGET.items() if dim is not None}


class SpaceReserve:
    """A file of allocated blocks in the dataset's directory, given back when a write
    fails for lack of space: then HDF5 can flush and close the episode in progress and
    the index can be written, instead of failing again (and crashing at exit).

    Its size: 10 % of the free space at the start, between 1 and 64 MiB."""

    NAME = ".space_reserve"

    def __init__(self, root: Path) -> None:
        self.path = Path(root) / self.NAME
        self.bytes = 0
        try:
            free = shutil.disk_usage(root).free
            size = int(min(64 << 20, max(1 << 20, free // 10)))
            fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            try:
                os.posix_fallocate(fd, 0, size)
            finally:
                os.close(fd)
            self.bytes = size
        except OSError as exc:
            self.release()
            log.warning("%s: no space reserve (%s): a full disk may cost the episode in "
                        "progress its file", root, exc)

    def release(self) -> int:
        """Give the space back; returns how much was held."""
        held, self.bytes = self.bytes, 0
        self.path.unlink(missing_ok=True)
        return held
# how the recorder actor's log line begins when a write failed and it stopped the
# recording (a full disk): `sebvs record` finds it in the run's logs and prints it
WRITE_STOPPED = "recording stopped: "


def hop_latencies(stamps: list, recv_ns: int, me: str) -> dict[str, float]:
    """Per-hop transport latencies of one message, microseconds.

    ``stamps``: the message's [actor, recv_ns, send_ns] per hop; ``recv_ns`` when this
    actor (``me``) got it. Keys "a->b" for each edge, e.g. "sim->camera", "camera->recorder".
    """
    out = {}
    prev = None
    for actor, recv, send in stamps:
        if prev is not None and recv:
            out[f"{prev[0]}->{actor}"] = (recv - prev[1]) / 1e3
        prev = (actor, send)
    if prev is not None and recv_ns:
        out[f"{prev[0]}->{me}"] = (recv_ns - prev[1]) / 1e3
    return out
