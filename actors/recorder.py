"""The recorder actor: a tap that writes synchronised episodes to an HDF5 dataset.

Inputs (connect what the topology has; `events` may be absent in RGB-only topologies):
  rgb      camera: arrays["rgb"] (H, W, 3) uint8, meta control (samples with control=False,
           between ticks, are skipped), truth (privileged ground truth, kept per frame)
  events   accumulator: arrays["frame"] (2, H, W) counts or (2K, H, W) time bins; optional
           raw arrays x, y, t, p; meta event_scale (or scale) / event_offset (or offset) /
           emulator (or params) / representation / bins / window_s: the event-to-RGB pixel
           mapping, emulator and accumulator settings, stored as file attributes
  raw      emulator (optional, used with raw_events = true): arrays["events"] structured
           (x, y, t, p) packets; the packets up to and including a control tick's packet
           are that tick's raw events (the accumulator's window ends there too)
  proprio  sim (optional): arrays["proprio"] (D,) float32 at each control tick, meta names:
           the robot's proprioception (sebvs/sim/proprio.py), stored as the dataset
           `proprio` [T, D] with the attribute proprio_names
  action   expert or policy: arrays["action"] (2,) (nav), ["pose"] (6,) (arm) or
           ["action"] (nu,) (mjcf: a policy's, or the sim's scripted command);
           meta modality (where a policy drove)
  episode  sim: meta {event: "start"|"end", episode, seed, reason, scene, config}
  drive    (LockstepRecorder only, optional) policy: arrays as `action`, meta modality: the
           command that should drive the sim, while `action` stays the recorded label
raw_events = true with no `raw` input wired is refused when the topology loads, in one line
naming the input to wire (nothing else would record raw events: the accumulator sends
frames only).
`LockstepRecorder` also has an output `action`: the expert's action of a tick, passed on
once that tick's row is complete. Wire the sim's action to it in lockstep and the sim waits
for the whole recorded chain (emulator and accumulator included), not only for the expert:
otherwise nothing paces the sim to the event chain, which falls behind and drops luma
frames. (A plain Recorder has no output, so the topology loader never prunes the tap.)
With `drive` wired (DAgger, topologies/nav_dagger.toml: drive = "policy/action"), a tick's
row waits for the drive command too, and the action passed on is that command: the policy
drives, the expert labels. The file's `action` (or `pose`) is the expert's label; the
dataset `drive` [T, D] holds the command that drove each tick, `modality` the driving
policy's input. A LockstepRecorder whose output is consumed names the driver in the
episode's attribute `driver`: the driving message's source actor and its modality
("policy:rgb"), or the label's source ("expert") without `drive`. `drive` without `action`
is refused when the topology loads, in one line (there would be no label to record).
One row per control tick once every connected stream delivered that tick (see
sebvs.data.recording.TickJoiner); an episode file per sim episode, finished on its end
marker, then indexed (sebvs.data.index). After `episodes` finished episodes the recorder
ends the run. A kill loses at most the episode in progress (its .partial file).

A write that fails (a full disk, a lost mount: any OSError) stops the recording: the
error is logged in one line naming the dataset and the free space, every finished
episode stays intact and indexed (the index is written again once the episode in
progress has made room, if it must), the episode in progress is left as its .partial file
(what `sebvs data check` lists as lost) and the run ends; `sebvs record` says so.
"""
from __future__ import annotations

import os
import shutil
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import numpy as np

from sebvs.data.recording import (WRITE_STOPPED, EpisodeRecorder, SpaceReserve, TickJoiner,
                                  hop_latencies)
from sebvs.runtime import Actor, Message, Range
from sebvs.runtime.topology import TopologyError, apply_overrides

STREAMS = ("rgb", "events", "raw", "proprio", "action", "drive")
# file attribute <- accumulator meta key (either spelling)
EVENT_ATTRS = {"event_scale": "scale", "event_offset": "offset", "emulator": "params",
               "event_sensor": "sensor", "event_output": "output",
               "event_representation": "representation", "event_window_s": "window_s",
               "event_bins": "bins"}


RAW_DTYPE = np.dtype([("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "i1")])


def emulator_params(topology: dict) -> dict:
    """The emulator actor's settings in a topology (preset resolved when sebvs.dvs can)."""
    for actor in topology.get("actors", {}).values():
        if str(actor.get("run", "")).endswith(":Emulator"):
            name, over = actor.get("preset", "paper"), actor.get("overrides", {})
            out = {"preset": name, "overrides": over}
            try:
                import dataclasses
                from sebvs.dvs.params import preset
                out["resolved"] = dataclasses.asdict(preset(name, **over))
            except Exception:        # an unknown preset fails the emulator itself, not us
                pass
            return out
    return {}


class Recorder(Actor):
    inputs = ("rgb", "events", "raw", "proprio", "action", "episode")

    @classmethod
    def check_wiring(cls, params: "Recorder.Params", connected: frozenset) -> str | None:
        """What the parameters ask for that the wiring cannot give. The topology loader
        refuses such a topology before a process starts.

        Parameters:
            params: the recorder's parameters as the topology sets them.
            connected: the names of its wired inputs.

        Returns:
            One line naming the missing input and how to wire it, or None.
        """
        if params.raw_events and "raw" not in connected:
            return ("raw_events = true, but the input 'raw' is not wired: nothing would "
                    "record raw events; wire it to the emulator's events, e.g. --set "
                    "'recorder.inputs.raw={from=\"emulator/events\", queue=256}'")
        return None

    @dataclass
    class Params:
        out: str = "datasets/nav"        # dataset directory (created; numbering resumes)
        # end the run after this many finished episodes (0: never)
        episodes: Annotated[int, Range(ge=0)] = 0
        raw_events: bool = False         # also store raw events x, y, t, p when sent
        compression: Literal["lzf", "gzip", "none"] = "lzf"
        # auto: "mjcf" for the mjcf scene's episodes, else from the action's array name
        task: Literal["auto", "nav", "arm", "mjcf"] = "auto"
        topology: str = ""               # topology file, stored as an attribute (sebvs record sets it)
        # the overrides the run was started with beyond the file (sebvs record sets them:
        # the sensor pair's and a named condition's as mappings, the --set lines as typed):
        # applied to the file's content before it is stored, so the attributes say what
        # ran, and stored beside it as given
        overrides: list = field(default_factory=list)
        # the named condition the run records (sebvs record --condition sets it), stored as
        # each episode's ``condition`` attribute; "" for a topology's own mix
        condition: str = ""
        # ticks waiting for a stream before they count as lost
        max_pending: Annotated[int, Range(ge=1, le=100_000)] = 256
        # wait this long after an end marker for its last rows
        grace_s: Annotated[float, Range(ge=0, le=3600)] = 2.0

    async def setup(self) -> None:
        p = self.params
        missing = {"rgb", "action", "episode"} - self.connected
        if missing:
            raise ValueError(f"recorder needs inputs {sorted(missing)} connected")
        problem = self.check_wiring(p, frozenset(self.connected))
        if problem:         # a topology built without the loader
            raise ValueError(f"recorder: {problem}")
        self.streams = frozenset(s for s in STREAMS if s in self.connected
                                 and (s != "raw" or p.raw_events))
        self.raw_packets: list[np.ndarray] = []
        self.joiner = TickJoiner(self.streams, p.max_pending)
        topo = {}
        if p.topology:
            try:
                content = apply_overrides(tomllib.loads(Path(p.topology).read_text()),
                                          list(p.overrides), p.topology)
                topo = {"file": p.topology, "content": content,
                        "overrides": list(p.overrides)}
            except (OSError, tomllib.TOMLDecodeError, TopologyError, TypeError) as exc:
                topo = {"file": p.topology, "error": str(exc)}
        base = {"topology": topo, "streams": sorted(self.streams)}
        if p.condition:
            base["condition"] = p.condition
        emulator = emulator_params(topo.get("content", {}))
        if emulator:
            base["emulator"] = emulator
        self.rec = EpisodeRecorder(p.out, None if p.task == "auto" else p.task,
                                   compression=p.compression, grace_s=p.grace_s,
                                   base_attrs=base)
        self.skipped = {"no_tick": 0, "not_control": 0}
        self._warned = 0
        self.write_error: str | None = None     # set once a write failed: nothing more
        Path(p.out).mkdir(parents=True, exist_ok=True)
        self.reserve = SpaceReserve(Path(p.out))
        self.log.info("recording %s into %s (next episode %d)", sorted(self.streams), p.out,
                      self.rec.next_number)

    async def run(self) -> None:
        while not self.stopping.is_set():
            self._finished(self._write(self.rec.poll))
            if not await self.sleep_until(time.monotonic_ns() + 200_000_000):
                return

    # --- streams -------------------------------------------------------------------
    async def _take(self, stream: str, msg: Message, item: dict) -> None:
        if msg.tick is None:
            self.skipped["no_tick"] += 1
            return
        item["latency"] = hop_latencies(msg.stamps, msg.recv_ns, self.name)
        item["t_sim"] = msg.t_sim
        before = self.joiner.incomplete
        done = self.joiner.add(stream, msg.tick, item)
        if self.joiner.incomplete > before and self._warned < 10:
            self._warned += 1      # a few lines, then only the count (in stats and teardown)
            self.log.warning("ticks %s never completed (missing a stream); %d so far",
                             self.joiner.dropped_ticks[-(self.joiner.incomplete - before):],
                             self.joiner.incomplete)
        if done is None:
            return
        tick, row = done
        act = row["action"]
        # what drives the sim: the drive command where one is wired, else the label
        passed = row.get("drive", act)
        if passed["key"] != act["key"]:
            raise ValueError(f"{self.name}: the drive command is {passed['key']!r}, the "
                             f"label {act['key']!r}: the policy and the expert are of "
                             f"different tasks")
        driver = None
        if "action" in self.consumed:
            # first, so the sim steps on while this row is written
            await self.emit("action", {passed["key"]: passed["value"]}, parent=msg,
                            tick=tick, t_sim=passed["t_sim"], meta=passed["meta"])
            driver = passed["source"] + (f":{passed['modality']}"
                                         if passed.get("modality") else "")
        latency = {}
        for s in STREAMS:
            if s in row:
                latency.update(row[s]["latency"])
        rgb = row["rgb"]
        fields = {"rgb": rgb["rgb"], "t_sim": rgb["t_sim"] if rgb["t_sim"] is not None
                  else (row["action"]["t_sim"] or 0.0),
                  "latency": latency, "truth": rgb.get("truth"),
                  "modality": passed.get("modality"),
                  "episode": rgb.get("episode"),
                  row["action"]["key"]: row["action"]["value"]}
        if "drive" in row:
            fields["drive"] = row["drive"]["value"]
        if driver is not None:
            fields["attrs"] = {"driver": driver}
        if "events" in row:
            fields["event_frame"] = row["events"]["frame"]
            if row["events"].get("raw") is not None:
                fields["raw_events"] = row["events"]["raw"]
            if row["events"]["attrs"]:
                fields["attrs"] = {**fields.get("attrs", {}), **row["events"]["attrs"]}
        if "raw" in row:
            fields["raw_events"] = row["raw"]["raw"]
        if "proprio" in row:
            fields["proprio"] = row["proprio"]["proprio"]
            if row["proprio"]["names"]:
                fields["attrs"] = {**fields.get("attrs", {}),
                                   "proprio_names": row["proprio"]["names"]}
        self._finished(self._write(self.rec.row, tick, **fields))

    async def on_rgb(self, msg: Message) -> None:
        if msg.meta.get("control") is False:
            self.skipped["not_control"] += 1
            return
        truth = msg.meta.get("truth")
        await self._take("rgb", msg, {"rgb": np.array(msg.arrays["rgb"]),   # copy out of shm
                                "truth": truth if isinstance(truth, dict) else None,
                                "episode": msg.meta.get("episode")})

    async def on_events(self, msg: Message) -> None:
        if msg.meta.get("control") is False:
            self.skipped["not_control"] += 1
            return
        raw = None
        if self.params.raw_events and all(k in msg.arrays for k in "xytp"):
            raw = {k: np.array(msg.arrays[k]) for k in "xytp"}
        m = msg.meta
        attrs = {k: m[k] if k in m else m[alt] for k, alt in EVENT_ATTRS.items()
                 if k in m or alt in m}
        await self._take("events", msg, {"frame": np.array(msg.arrays["frame"]), "raw": raw,
                                   "attrs": attrs})

    async def on_raw(self, msg: Message) -> None:
        if "raw" not in self.streams:
            return
        ev = msg.arrays.get("events")
        if ev is not None and len(ev):
            self.raw_packets.append(np.array(ev))          # copy out of shm
        if msg.meta.get("control") is False:
            return
        packets, self.raw_packets = self.raw_packets, []
        ev = np.concatenate(packets) if packets else np.zeros(0, RAW_DTYPE)
        await self._take("raw", msg, {"raw": {k: ev[k] for k in "xytp"}})

    async def on_proprio(self, msg: Message) -> None:
        if msg.meta.get("control") is False:
            self.skipped["not_control"] += 1
            return
        names = msg.meta.get("names")
        await self._take("proprio", msg, {
            "proprio": np.array(msg.arrays["proprio"], np.float32),
            "names": [str(n) for n in names] if isinstance(names, (list, tuple)) else None})

    async def on_action(self, msg: Message) -> None:
        await self._take_command("action", msg)

    async def _take_command(self, stream: str, msg: Message) -> None:
        key = "action" if "action" in msg.arrays else "pose"
        if key not in msg.arrays:
            self.log.warning("%s message without 'action' or 'pose' array; skipped", stream)
            return
        await self._take(stream, msg, {"key": key,
                                       "value": np.array(msg.arrays[key], np.float32),
                                       "modality": msg.meta.get("modality"),
                                       "meta": msg.meta, "source": msg.source})

    async def on_episode(self, msg: Message) -> None:
        m = msg.meta
        tick = msg.tick if msg.tick is not None else -1
        if m.get("event") == "start":
            self._write(self.rec.start, m, tick)
        elif m.get("event") == "end":
            self._finished(self._write(self.rec.end, str(m.get("reason", "")), tick))

    # --- episodes --------------------------------------------------------------------
    def _finished(self, entries: list[dict]) -> None:
        for e in entries:
            self.telemetry("episode_recorded", file=e["file"], frames=e["frames"],
                           reason=e["reason"])
        n = self.params.episodes
        if entries and n and len(self.rec.finished) >= n and not self.stopping.is_set():
            self.request_stop(f"{len(self.rec.finished)} episode(s) recorded")

    def _write(self, fn, *args, **kw) -> list:
        """Run one of the EpisodeRecorder's writes; a failed one stops the recording."""
        if self.write_error is not None:
            return []
        try:
            return fn(*args, **kw) or []
        except OSError as exc:
            self._stop_writing(exc)
            return []

    def _stop_writing(self, exc: OSError) -> None:
        out = Path(self.params.out)
        try:
            free = f"{shutil.disk_usage(out).free:,} bytes free"
        except OSError:
            free = "free space unknown"
        self.reserve.release()                  # room to close the file and write the index
        partials = []
        for ep in list(self.rec.open):          # kept as .partial files, not deleted
            if ep.writer is not None:
                ep.writer.abandon()
                partials.append(ep.writer.partial.name)
            self.rec.open.remove(ep)
        try:
            adopted = self.rec.index.adopt_unindexed()   # one renamed but not indexed
        except OSError:
            # no room even for the index: the unfinished episodes give their space back
            for name in partials:
                (out / name).unlink(missing_ok=True)
            partials = [f"{name} (removed to make room for the index)" for name in partials]
            adopted = self.rec.index.adopt_unindexed()
        why = os.strerror(exc.errno) if exc.errno else str(exc).splitlines()[0][:200]
        self.write_error = (
            f"{WRITE_STOPPED}writing into {out} failed ({why}; {free}); "
            f"{len(self.rec.index.episodes())} finished episode(s) intact and indexed"
            + (f" ({len(adopted)} indexed now)" if adopted else "")
            + (f"; the episode in progress is left as {', '.join(partials)}" if partials
               else ""))
        self.log.error("%s", self.write_error)
        self.telemetry("recording_stopped", error=self.write_error)
        self.request_stop(self.write_error)

    async def teardown(self) -> None:
        self._finished(self._write(self.rec.close))
        self.reserve.release()
        j = self.joiner
        self.log.info("recorded %d episode(s), %d frames; ticks incomplete %d (last %s), "
                      "late %d, outside episodes %d; episodes discarded %d",
                      len(self.rec.finished), self.rec.frames, j.incomplete, j.dropped_ticks,
                      j.late, self.rec.outside, self.rec.discarded)

    def stats(self) -> dict:
        r, j = self.rec, self.joiner
        cur = r.current
        return {"episodes": len(r.finished), "target_episodes": self.params.episodes,
                "frames": r.frames, "frames_in_progress": r.in_progress_frames(),
                "sim_s": r.sim_s + sum(e.writer.sim_seconds for e in r.open if e.writer),
                "current_episode": cur.number if cur else None,
                "incomplete_ticks": j.incomplete, "late": j.late, "pending": len(j.pending),
                "outside_episodes": r.outside, "discarded": r.discarded,
                "skipped": dict(self.skipped), "out": self.params.out,
                "write_error": self.write_error,
                "done": bool(self.params.episodes and len(r.finished) >= self.params.episodes)}


class LockstepRecorder(Recorder):
    """A Recorder that passes each recorded tick's action on (wire the sim's action here):
    the label's, or with `drive` wired the drive command's (module docstring)."""
    inputs = (*Recorder.inputs, "drive")
    outputs = ("action",)

    @classmethod
    def check_wiring(cls, params: "Recorder.Params", connected: frozenset) -> str | None:
        """Recorder.check_wiring, and `drive` refused without `action`.

        Parameters:
            params: the recorder's parameters as the topology sets them.
            connected: the names of its wired inputs.

        Returns:
            One line naming the missing input and how to wire it, or None.
        """
        if "drive" in connected and "action" not in connected:
            return ("the input 'drive' is wired but 'action' is not: the drive command "
                    "would drive the sim with no label to record; wire 'action' to the "
                    "expert, e.g. inputs.action = \"expert/action\"")
        return super().check_wiring(params, connected)

    async def setup(self) -> None:
        await super().setup()
        if "drive" in self.connected and "action" not in self.consumed:
            self.log.warning("'drive' is wired but nothing consumes this recorder's "
                             "action: the drive commands are recorded, they drive nothing")

    async def on_drive(self, msg: Message) -> None:
        await self._take_command("drive", msg)
