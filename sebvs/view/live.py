"""The live tap: one more read-only subscriber on a running topology's outputs.

It finds the run through run.json as `sebvs profile` does, and reads the outputs with the
runtime's own input code (``sebvs.runtime.inputs.Inputs``: the same decoder, sequence
bookkeeping, CURVE keys on tcp and shared-memory ring reads an actor's input has). Nothing
in the run changes: no control message is sent, a PUB socket drops a slow subscriber's
copies (counted here, never the run's), and the rings are mapped read-only.

Which outputs: those named in SHOWN_OUTPUTS, of every actor that has them. A message is
shown by what it carries (an "rgb" image, an accumulator's "frame", an "action" or "pose"
command, the sim's truth), not by which actor sent it, so a user's own actors show too.
"""
from __future__ import annotations

import asyncio
import collections
import functools
import json
import os
import time
from pathlib import Path

import numpy as np
import zmq

from sebvs.data.recording import hop_latencies
from sebvs.runtime.inputs import Inputs
from sebvs.runtime.wire import Message

from .entities import COMMAND_NAMES, ViewLog

SHOWN_OUTPUTS = ("rgb", "frames", "action", "state", "episode")
QUEUE = 64            # messages per output queued for the viewer before its copies drop
TRUTH_TICKS = 64      # ticks of the sim's truth kept to join the frames of those ticks
RUN_CHECK_S = 1.0     # how often run.json is read to see whether the run has ended
# the viewer's own losses, per output: never arrived (its queue was full), arrived after
# the ring slot was reused or torn while copied, or did not decode
DROP_KEYS = ("dropped_gap", "dropped_overwritten", "torn", "malformed")


class LiveView:
    """Subscribes to a run's outputs and writes what arrives through a ViewLog."""

    def __init__(self, info: dict, view: ViewLog, outputs=SHOWN_OUTPUTS) -> None:
        self.info = info
        self.view = view
        self.sources: dict[str, str] = {}        # "actor/output" -> its PUB endpoint
        for actor, entry in info["actors"].items():
            for out, endpoint in (entry.get("outputs") or {}).items():
                if out in outputs and isinstance(endpoint, str):
                    self.sources[f"{actor}/{out}"] = endpoint
        self.truth: collections.OrderedDict = collections.OrderedDict()   # tick -> truth
        self.inputs: Inputs | None = None
        self.stopping: asyncio.Event | None = None   # Inputs reads it as the actor's
        self.seconds = 0.0

    # Inputs binds input <name> to the actor's `on_<name>`; ours are "actor/output"
    def __getattr__(self, name: str):
        if name.startswith("on_") and name[3:] in self.__dict__.get("sources", {}):
            return functools.partial(self.on_message, name[3:])
        raise AttributeError(name)

    def image_sources(self) -> list[str]:
        """The outputs that carry images in the topologies (camera rgb, accumulator and
        synthetic frames), for the layout; others are shown by content all the same."""
        return [s for s in self.sources if s.split("/", 1)[1] in ("rgb", "frames")]

    def _specs(self) -> dict:
        return {src: {"topic": src, "endpoint": ep, "hwm": QUEUE, "queue": QUEUE}
                for src, ep in self.sources.items()}

    async def run(self, duration_s: float | None) -> None:
        """Attach for ``duration_s`` seconds (None: until the run ends or Ctrl-C)."""
        ctx = zmq.Context()
        self.stopping = asyncio.Event()
        self.inputs = Inputs()
        t0 = time.monotonic()
        try:
            self.inputs.connect(self._specs(), ctx, self, self.info["run_id"],
                                self.info.get("token"))
            self.inputs.start()
            next_check = t0 + RUN_CHECK_S
            while duration_s is None or time.monotonic() - t0 < duration_s:
                left = RUN_CHECK_S if duration_s is None else duration_s - (time.monotonic() - t0)
                await asyncio.sleep(max(0.0, min(0.2, left)))
                self.inputs.take_records()     # telemetry records: an actor's, not ours
                if time.monotonic() >= next_check:
                    next_check = time.monotonic() + RUN_CHECK_S
                    if run_over(self.info):
                        break
        finally:
            self.seconds = time.monotonic() - t0
            self.stopping.set()
            self.inputs.stop_reading()
            await self.inputs.cancel_handlers()
            self.inputs.close()
            ctx.term()

    async def on_message(self, source: str, msg: Message) -> None:
        # copy what is shown before anything else: a ring slot may be reused at any time,
        # and a copy taken while it was (the slot's generation moved) is dropped, not shown
        arrays = {k: np.array(v) for k, v in msg.arrays.items()
                  if k in ("rgb", "frame") or k in COMMAND_NAMES}
        reader = self.inputs.reader
        if msg.shm_locs and not all(reader.still_valid(loc[0], loc[1], loc[3])
                                    for loc in msg.shm_locs.values()):
            return          # Inputs counts it in `torn` when this handler returns
        view, meta = self.view, msg.meta
        view.at(msg.tick, msg.t_sim)
        if msg.output == "episode":
            view.episode(meta)
            return
        if msg.output == "state":
            truth = meta.get("truth")
            if meta.get("control") and isinstance(truth, dict) and msg.tick is not None:
                self.truth[msg.tick] = truth
                while len(self.truth) > TRUTH_TICKS:
                    self.truth.popitem(last=False)
                view.truth_scalars(truth)
            return
        # the sim's truth of this tick, else the truth the frame carries (camera/rgb does)
        truth = self.truth.get(msg.tick) or meta.get("truth")
        rgb = arrays.get("rgb")
        if rgb is not None and rgb.ndim == 3 and rgb.shape[2] == 3 and rgb.dtype == np.uint8:
            view.image(source, rgb, truth)
        frame = arrays.get("frame")
        if frame is not None and frame.ndim == 3 and "representation" in meta:
            view.events(source, frame, str(meta["representation"]), truth)
        for key in COMMAND_NAMES:
            if key in arrays and arrays[key].ndim == 1:
                view.command(f"commands/{source}", key, arrays[key])
        # the hops this message came through; the hop into the viewer is not the run's
        view.latency(hop_latencies(msg.stamps, 0, ""), msg.tick)

    def summary(self) -> dict:
        """Per output: messages received and the viewer's own losses (DROP_KEYS), and the
        rows written per entity."""
        stats = self.inputs.stats() if self.inputs else {}
        outputs = {}
        for src in self.sources:
            st = stats.get(src, {})
            outputs[src] = {k: st.get(k, 0) for k in ("received",) + DROP_KEYS}
        return {"run": self.info.get("name"), "run_id": self.info.get("run_id"),
                "seconds": round(self.seconds, 3), "outputs": outputs,
                "entities": dict(self.view.rows)}


def run_over(info: dict) -> bool:
    """Whether the run has ended: run.json says so, or its supervisor is gone."""
    try:
        status = json.loads((Path(info["rundir"]) / "run.json").read_text()).get("status")
    except (OSError, ValueError, AttributeError):
        return True         # its run directory is gone with it
    if status not in ("starting", "running"):
        return True
    pid = info.get("supervisor_pid")
    if isinstance(pid, int) and not isinstance(pid, bool) and pid > 0:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        except PermissionError:
            pass
    return False
