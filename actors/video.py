"""Episode videos of a closed-loop run (`sebvs eval --video`): one file per episode.

Inputs  rgb      from the camera: arrays["rgb"] uint8 [H, W, 3] and meta truth, episode of
                 the samples at control ticks (meta control=False samples are ignored)
        events   optional, from the accumulator: arrays["frame"] of its representation
                 (meta representation; drawn as ON/OFF counts, sebvs.dvs.render
                 .event_counts), tick = the control tick; not wired: the video shows the
                 RGB alone; a frame that is no event frame is counted in ignored_events
        episode  from the sim: meta event start / end; the end's tick is the episode's
                 last control tick
Writes <directory>/<prefix>__ep<k>.mp4 (sebvs/eval/video.py composes and encodes) for
episodes k < `episodes`. directory "" writes nothing. No topology carries this actor:
`sebvs eval --video` adds it to a run with `--set video.run=...` (sebvs/eval/run.py).

The RGB and the event frame of a tick arrive on separate inputs in either order; ticks
are written in order once both have arrived. A tick whose event frame is lost (one of a
later tick is already here, or MAX_PENDING ticks wait behind it: as deep as the inputs'
queues) is written without overlay; anything arriving for a tick already written is
dropped and counted.
"""
from __future__ import annotations

import asyncio
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np

from sebvs.dvs.render import event_counts
from sebvs.runtime import Actor, Message, Range

# ticks held waiting for their partner frame (25.6 s at 10 Hz, ~20 MB of 160 px RGB). As
# deep as the inputs' queues (sebvs/eval/run.py: 256): a writer that falls behind drains
# one socket's backlog before the other's, so a shorter bound took event frames still
# queued on their socket for lost (8 of 32 ticks without overlay on a loaded machine)
MAX_PENDING = 256


class VideoWriter(Actor):
    inputs = ("rgb", "events", "episode")

    @dataclass
    class Params:
        directory: str = ""        # "" = write nothing
        prefix: str = "episode"    # files are <prefix>__ep<k>.mp4
        episodes: Annotated[int, Range(ge=0)] = 1       # the first K episodes of the run
        label: str = ""            # first word of the caption (the modality)
        # = the sim's control_hz: the video plays in sim time
        fps: Annotated[float, Range(gt=0, le=1000)] = 10.0
        scale: Annotated[int, Range(ge=1, le=16)] = 3   # nearest-neighbour upscaling
        # how long after an episode's end message its trailing frames (they pass the camera
        # and emulator) are waited for; the run must outlast it (sebvs/eval/run.py)
        finalize_after_s: Annotated[float, Range(gt=0, le=60)] = 1.0

    async def setup(self) -> None:
        p = self.params
        self.active = bool(p.directory) and p.episodes > 0
        if p.scale < 1 or p.fps <= 0:
            raise ValueError(f"video: scale must be >= 1 and fps > 0, got {p.scale}, {p.fps}")
        self.rgb: dict[int, tuple[int, np.ndarray, dict | None]] = {}   # tick -> ep, rgb, truth
        self.events: dict[int, np.ndarray] = {}                         # tick -> [2, H, W]
        self.last_written = -1
        self.end_tick: dict[int, int] = {}
        self.videos: dict = {}                  # episode -> EpisodeVideo, open
        self.closed: set[int] = set()
        self.files: list[dict] = []
        self.counts = {"frames": 0, "without_overlay": 0, "late": 0, "ignored_events": 0}
        self._timers: dict[int, asyncio.TimerHandle] = {}
        self._warned_repr = False
        if self.active:
            # imported here: a run without videos does not pay for OpenCV in this process
            from sebvs.eval.video import EpisodeVideo, caption, compose_frame
            self._video_cls, self._caption, self._compose = EpisodeVideo, caption, compose_frame
            self.log.info("video: first %d episode(s) to %s/%s__ep<k>.mp4; events %s",
                          p.episodes, p.directory, p.prefix,
                          "overlaid" if "events" in self.connected else "not wired")

    async def on_rgb(self, msg: Message) -> None:
        m = msg.meta
        if not self.active or msg.tick is None or m.get("control") is False:
            return
        ep = m.get("episode")
        if ep is None or ep >= self.params.episodes or ep in self.closed:
            return
        if msg.tick <= self.last_written:
            self.counts["late"] += 1
            return
        self.rgb[msg.tick] = (ep, np.array(msg.arrays["rgb"]), m.get("truth"))
        self._flush()

    async def on_events(self, msg: Message) -> None:
        if not self.active or msg.tick is None or msg.meta.get("control") is False:
            return
        if len(self.closed) >= self.params.episodes:
            return      # every video written: the rest of the run is not ours to copy
        representation = str(msg.meta.get("representation", "counts"))
        try:
            # histograms, voxel grids and time surfaces drawn as the viewer draws them
            frame = event_counts(np.array(msg.arrays["frame"]), representation)
        except (KeyError, ValueError) as exc:
            if not self._warned_repr:
                self.log.warning("video: %s event frames not overlaid: %s", representation,
                                 exc)
                self._warned_repr = True
            self.counts["ignored_events"] += 1
            return
        if msg.tick <= self.last_written:
            self.counts["late"] += 1
            return
        self.events[msg.tick] = frame
        while len(self.events) > MAX_PENDING:
            del self.events[min(self.events)]
        self._flush()

    async def on_episode(self, msg: Message) -> None:
        m = msg.meta
        ep = m.get("episode")
        if not self.active or m.get("event") != "end" or ep is None or msg.tick is None:
            return
        if ep >= self.params.episodes or ep in self.closed:
            return
        self.end_tick[ep] = msg.tick
        if self.last_written >= msg.tick:
            self._close(ep)
        else:
            loop = asyncio.get_running_loop()
            self._timers[ep] = loop.call_later(self.params.finalize_after_s,
                                              self._finalize, ep)

    def _flush(self, through: int | None = None) -> None:
        """Write every tick now complete, oldest first; ticks <= `through` in any case."""
        wait_for_events = "events" in self.connected
        for tick in sorted(self.rgb):
            ev = self.events.get(tick)
            if wait_for_events and ev is None:
                lost = any(t > tick for t in self.events) or len(self.rgb) > MAX_PENDING
                if not (lost or (through is not None and tick <= through)):
                    break
            self._write(tick, ev)

    def _write(self, tick: int, ev: np.ndarray | None) -> None:
        ep, rgb, truth = self.rgb.pop(tick)
        for t in [t for t in self.events if t <= tick]:
            del self.events[t]
        self.last_written = tick
        for old in [e for e in self.videos if e < ep]:
            self._close(old)            # ticks are written in order: that episode is done
        video = self.videos.get(ep)
        if video is None:
            path = Path(self.params.directory) / f"{self.params.prefix}__ep{ep}.mp4"
            video = self.videos[ep] = self._video_cls(path, self.params.fps)
        text = self._caption(self.params.label, tick, truth)
        video.write(self._compose(rgb, ev, truth, text, self.params.scale))
        self.counts["frames"] += 1
        if ev is None and "events" in self.connected:
            self.counts["without_overlay"] += 1
        if tick >= self.end_tick.get(ep, tick + 1):
            self._close(ep)

    def _finalize(self, ep: int) -> None:
        self._timers.pop(ep, None)
        if ep not in self.closed:
            self._flush(through=self.end_tick.get(ep))
            self._close(ep)

    def _close(self, ep: int) -> None:
        self.closed.add(ep)
        timer = self._timers.pop(ep, None)
        if timer is not None:
            timer.cancel()
        video = self.videos.pop(ep, None)
        if video is None:
            return
        frames = video.close()
        self.files.append({"episode": ep, "path": str(video.path), "frames": frames})
        self.telemetry("video", episode=ep, path=str(video.path), frames=frames)
        self.log.info("episode %d: %d frames to %s", ep, frames, video.path)

    async def teardown(self) -> None:
        if not self.active:
            return
        if self.rgb:
            self._flush(through=max(self.rgb))
        for ep in sorted(self.videos):
            self._close(ep)
        for timer in self._timers.values():
            timer.cancel()
        self.log.info("video: %s", self.counts)

    def stats(self) -> dict:
        return {**self.counts, "files": self.files}
