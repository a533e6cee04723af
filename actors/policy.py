"""The ERP policy actor: camera RGB and/or accumulated event frames in, an action out.

Inputs  rgb     from the camera:       arrays["rgb"]   uint8 [H, W, 3], tick
        events  from the accumulator:  arrays["frame"] uint8 [2K, H, W], tick; meta
                representation, bins, window_s and event_sensor are checked against what
                the active checkpoint was trained on (its "event_frames"): a difference is
                counted (stats "event_frame_mismatch") and logged, the frame still used
        (samples with meta control=False, taken between control ticks, are ignored)
        The control modality rgb+diff reads rgb and the RGB frame of the previous control
        tick of the same episode (meta episode), which the actor keeps
Output  action  arrays {"action": float32 [2]} (nav [v, w]) or {"pose": float32 [6]} (arm),
        tick = the input tick, meta {"modality", "input_ticks", "inference_ms", ...}

Every listed checkpoint is loaded in setup; `sebvs ctl RUN policy set modality=event`
swaps between them at the next tick. A modality without a checkpoint, or whose inputs
the topology does not wire, is refused and the current one stays.

A checkpoint with memory (config memory "gru") carries its state from tick to tick. The
state starts afresh at every episode's first tick (the frames' meta episode changes: the
sim's episode end is followed by the next episode's frames) and at a modality swap (the
state of one modality's model means nothing to another's, nor to its own after ticks it
did not see); stats "state_resets" counts both.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Literal

from sebvs.runtime import Actor, Message, Range
from sebvs.runtime.params import short_repr
from sebvs.runtime.stats import summarize

INFERENCE_WINDOW = 2000   # latencies kept for stats()
# a checkpoint's event_frames key -> the accumulator's meta key for the same thing
EVENT_FRAME_META = {"representation": "representation", "bins": "bins",
                    "window_s": "window_s", "sensor": "event_sensor"}


class Policy(Actor):
    inputs = ("rgb", "events")
    outputs = ("action",)

    @dataclass
    class Params:
        checkpoints: dict = field(default_factory=dict)   # modality -> .pt path
        directory: str = ""          # or: a directory of <task>-<modality>.pt ...
        task: str = "nav"            # ... for this task
        modalities: list[str] = field(default_factory=list)   # ... these (default: all three)
        modality: str = "rgb+event"  # the active one
        threads: Annotated[int, Range(ge=1, le=256)] = 1    # torch and OpenCV threads
        # "eager" (as trained; lockstep results reproduce bit for bit), "frozen" (a
        # TorchScript graph: ~0.5 ms less per cold tick at 160 px; sebvs/policy/graph.py),
        # or "auto": frozen on the realtime clock, where the chain's latency is the figure,
        # eager in lockstep, where results must reproduce bit for bit
        graph: Literal["auto", "eager", "frozen"] = "auto"
        # a closed-loop ablation, off unless asked: modality -> {"channels": [int],
        # "levels": [float]}, those input channels held at those levels (model input
        # units) every tick; research/sensors/ablation_levels.py gives a checkpoint's
        # mean levels. Named in every action's meta and in stats, so an ablated row
        # cannot pass for a whole one
        ablate: dict = field(default_factory=dict)

    async def setup(self) -> None:
        from sebvs.policy.infer import PolicySet, PreviousFrame, TickSync, resolve_checkpoints
        from sebvs.policy.inputs import MODALITY_INPUTS
        self._inputs_of = MODALITY_INPUTS
        p = self.params
        _set_threads(p.threads)
        table = resolve_checkpoints(p.checkpoints, p.directory, p.task, p.modalities)
        graph = p.graph if p.graph != "auto" else \
            ("frozen" if self.clock == "realtime" else "eager")
        self.policies = PolicySet(table, task=p.task if p.directory else None, graph=graph)
        for m, why in self.policies.fallbacks.items():
            self.log.warning("%s runs eager, not %s: %s", m, graph, why)
        # the previous tick's RGB frame is kept only where a loaded checkpoint reads it
        self.previous = PreviousFrame() if "rgb" in self.connected and any(
            "rgb_prev" in MODALITY_INPUTS[m] for m in self.policies.modalities) else None
        for m, spec in p.ablate.items():
            if not isinstance(spec, dict) or set(spec) != {"channels", "levels"} \
                    or not all(isinstance(spec[k], list) for k in spec):
                raise ValueError(f"ablate.{m} must be {{channels=[...], levels=[...]}}, "
                                 f"not {short_repr(spec)}")
            self.policies.ablate(m, list(spec["channels"]), list(spec["levels"]))
            self.log.warning("%s runs ablated: input channels %s held at %s", m,
                             spec["channels"], spec["levels"])
        self._check_usable(p.modality)
        self.sync = TickSync(tuple(self._wired()))
        self.policies.warm_up()
        self.emitted = 0
        self.skipped_ticks = 0
        self.event_frame_mismatch: dict[str, int] = {}
        self.swaps: list[dict] = []
        self.inference_ms: list[float] = []
        # the episode of each buffered tick (from its frames' meta), and the episode the
        # active recurrent state belongs to
        self.tick_episode: dict[int, object] = {}
        self.state_episode = None
        self.state_resets = {"episode": 0, "swap": 0}
        graphs = sorted({lp.graph for lp in self.policies.policies.values()})
        self.log.info("loaded %s (%s, %s graph); active %s; inputs wired: %s",
                      ", ".join(self.policies.modalities), self.policies.task,
                      " and ".join(graphs), p.modality,
                      ", ".join(sorted(self.connected)) or "none")

    def _check_usable(self, modality: str) -> None:
        """Raise ValueError unless ``modality`` has a loaded checkpoint and wired inputs."""
        if modality not in self._inputs_of:
            raise ValueError(f"unknown modality {short_repr(modality)} "
                             f"(one of {', '.join(self._inputs_of)})")
        if modality not in self.policies.policies:
            raise ValueError(f"modality {modality!r} has no checkpoint loaded "
                             f"(loaded: {', '.join(self.policies.modalities)})")
        missing = [s for s in self._inputs_of[modality] if s not in self._wired()]
        if missing:
            raise ValueError(f"modality {modality!r} needs input(s) {', '.join(missing)}, "
                             f"which this topology does not wire to {self.name!r}")

    def _wired(self) -> list[str]:
        """The streams this actor can fill: its wired inputs, and rgb_prev (made from rgb)."""
        streams = [s for s in ("rgb", "events") if s in self.connected]
        return streams + (["rgb_prev"] if self.previous is not None else [])

    # ------------------------------------------------------------------ inputs
    async def on_rgb(self, msg: Message) -> None:
        rgb = msg.arrays["rgb"]
        if self.previous is not None and msg.tick is not None \
                and msg.meta.get("control") is not False:
            self.sync.put("rgb_prev", msg.tick,
                          self.previous.swap(msg.meta.get("episode"), msg.tick, rgb), msg.t_sim)
        await self._receive("rgb", msg, rgb)

    async def on_events(self, msg: Message) -> None:
        self._check_event_frame(msg.meta)
        await self._receive("events", msg, msg.arrays["frame"])

    def _check_event_frame(self, meta: dict) -> None:
        """Count frames made otherwise than the active checkpoint's training frames: a
        policy trained on 0.4 s windows sees other inputs through a 0.1 s accumulator,
        though the shapes agree."""
        policy = self.policies.policies.get(self.params.modality)
        trained = policy.config.get("event_frames") if policy is not None else None
        if not isinstance(trained, dict):
            return
        for key, meta_key in EVENT_FRAME_META.items():
            want, got = trained.get(key), meta.get(meta_key)
            if isinstance(got, (list, tuple)):
                got = list(got)
            if want is None or got is None or got == want:
                continue
            n = self.event_frame_mismatch.get(key, 0) + 1
            self.event_frame_mismatch[key] = n
            if n == 1:
                self.log.warning("event frames have %s=%s, the %s checkpoint was trained on "
                                 "%s=%s (counted in stats)", key, short_repr(got),
                                 self.params.modality, key, short_repr(want))

    async def _receive(self, stream: str, msg: Message, array) -> None:
        if msg.tick is None:
            raise ValueError(f"{stream} message from {msg.source} has no tick")
        if msg.meta.get("control") is False:
            return      # a sample between control ticks (camera rgb_hz > control rate)
        if "episode" in msg.meta:
            self.tick_episode[msg.tick] = msg.meta["episode"]
        self.sync.put(stream, msg.tick, array, msg.t_sim)
        await self._step(msg)

    async def _step(self, msg: Message | None) -> None:
        """Run the active modality on every tick now complete, oldest first."""
        while (tick := self.sync.ready(self.params.modality)) is not None:
            modality = self.params.modality
            last = self.sync.last_tick
            if last is not None and tick > last + 1:
                self.skipped_ticks += tick - last - 1
            frames = self.sync.take(modality, tick)
            self._follow_episode(tick)
            y, prep_ms, inf_ms = self.policies.act(
                modality, **{s: a for s, (a, _) in frames.items()})
            t_sim = next(iter(frames.values()))[1]
            meta = {"modality": modality, "input_ticks": {s: tick for s in frames},
                    "inference_ms": round(inf_ms, 4), "preprocess_ms": round(prep_ms, 4)}
            if modality in self.policies.ablated:
                meta["ablated_channels"] = self.policies.ablated[modality][0]
            # the message that completed this tick carries the hop stamps on
            parent = msg if msg is not None and msg.tick == tick else None
            await self.emit("action", {self.policies.output: y}, meta=meta, t_sim=t_sim,
                            tick=tick, parent=parent)
            self.emitted += 1
            self.inference_ms.append(inf_ms)
            if len(self.inference_ms) > INFERENCE_WINDOW:
                del self.inference_ms[:INFERENCE_WINDOW // 2]
            self.telemetry("inference", ms=inf_ms, preprocess_ms=prep_ms, tick=tick,
                           modality=modality)

    def _follow_episode(self, tick: int) -> None:
        """Start the recurrent states afresh where ``tick`` begins another episode than
        the one they remember; forget the episodes of ticks up to ``tick``."""
        episode = self.tick_episode.get(tick, self.state_episode)
        for t in [t for t in self.tick_episode if t <= tick]:
            del self.tick_episode[t]
        if episode != self.state_episode:
            if self.policies.recurrent:
                self.policies.reset()
                self.state_resets["episode"] += 1
            self.state_episode = episode

    # ------------------------------------------------------------------ control
    async def control(self, key: str, value) -> dict:
        if key == "modality":
            if not isinstance(value, str):
                raise ValueError(f"modality must be a string, got {short_repr(value)}")
            self._check_usable(value)       # refused: the current modality stays
            old = self.params.modality
            last = self.sync.last_tick
            effective = 0 if last is None else last + 1
            self.params.modality = value
            swap = {"from": old, "to": value, "effective_tick": effective}
            if value in self.policies.recurrent:
                self.policies.reset(value)
                self.state_resets["swap"] += 1
                swap["state_reset"] = True
            self.swaps.append(swap)
            self.telemetry("modality_swap", **swap)
            self.log.info("modality %s -> %s from tick %d", old, value, effective)
            # frames of the next tick may already be buffered: the new modality takes them
            await self._step(None)
            return {"modality": value, "effective_tick": effective}
        if key == "threads":
            result = await super().control(key, value)
            _set_threads(self.params.threads)
            return result
        raise ValueError(f"{short_repr(key)} cannot change while running "
                         f"(only modality, threads)")

    def stats(self) -> dict:
        return {"modality": self.params.modality, "loaded": self.policies.modalities,
                "graphs": {m: lp.graph for m, lp in self.policies.policies.items()},
                "memory": {m: lp.model.memory for m, lp in self.policies.policies.items()},
                "state_resets": self.state_resets,
                "emitted": self.emitted, "last_tick": self.sync.last_tick,
                "skipped_ticks": self.skipped_ticks, "swaps": self.swaps,
                "event_frame_mismatch": self.event_frame_mismatch,
                "ablated": {m: {"channels": c, "levels": [float(v) for v in lv.ravel()]}
                            for m, (c, lv) in self.policies.ablated.items()},
                "inference_ms": summarize(self.inference_ms, 1.0)}


def _set_threads(n: int) -> None:
    """Threads for torch and OpenCV (input resizing) alike: actors share the cores, and a
    second cv2 thread waiting on a busy core costs more than it saves."""
    import cv2
    import torch
    torch.set_num_threads(max(1, n))
    cv2.setNumThreads(max(1, n))
