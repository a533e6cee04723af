"""Inference side of the ERP: preloaded variants, and pairing of streams by tick.

    policies = PolicySet(resolve_checkpoints({}, "checkpoints/nav", "nav", ["rgb", "event"]))
    action, prep_ms, infer_ms = policies.act("event", events=frame)
    sync = TickSync(("rgb", "events")); sync.put("events", tick, frame, t_sim)
    tick = sync.ready("event")          # the oldest tick complete for the modality, or None

``PolicySet`` holds one model per modality (all loaded up front, so a modality swap costs
no load time) and turns one observation into one action. ``TickSync`` keeps the latest few
frames of each stream by tick and says which tick is complete for a modality;
``PreviousFrame`` the previous tick's RGB frame for the rgb+diff control. The policy
actor (actors/policy.py) only wires these to the runtime.
"""
from __future__ import annotations

import math
import numbers
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .checkpoint import checkpoint_paths, load_checkpoint
from .graph import check_graph, inference_graph, step_module
from .inputs import PAPER_MODALITIES, Modality, Normalisation, model_input


@dataclass
class LoadedPolicy:
    model: object            # sebvs.policy.model.ERP, eval mode
    config: dict
    norm: Normalisation
    path: str
    run: object              # what act() calls: the model, or its frozen graph (graph.py);
                             # with memory, its step: (x, state) -> (y, state)
    graph: str               # which of the two it is
    state: object = None     # with memory: the state [1, D] the next tick starts from

    @property
    def recurrent(self) -> bool:
        return self.model.state_size > 0


def resolve_checkpoints(checkpoints: dict, directory: str, task: str,
                        modalities: list[Modality | str]) -> dict[Modality, Path]:
    """Either an explicit table modality -> .pt path, or a directory + a list of modalities
    (files ``<task>-<modality>.pt``; none: the paper's three). Returns modality -> path;
    ValueError for an unknown modality, FileNotFoundError for a missing file."""
    if checkpoints and directory:
        raise ValueError("give either 'checkpoints' (modality -> path) or 'directory', not both")
    if checkpoints:
        named = [(m, Path(p)) for m, p in checkpoints.items()]
    elif directory:
        # "checkpoints", the topologies' default, is the shipped folder wherever the
        # working directory has none (sebvs/shipped.py)
        from sebvs.shipped import shipped_path
        directory = str(shipped_path(directory))
        named = [(m, checkpoint_paths(directory, task, m)[0])
                 for m in (modalities or PAPER_MODALITIES)]
    else:
        raise ValueError("no checkpoints: set 'checkpoints' (modality -> path) or 'directory'")
    table = {}
    for m, p in named:
        m = Modality.parse(m)
        if not p.exists():
            raise FileNotFoundError(f"checkpoint for modality {m!r} not found: {p}")
        table[m] = p
    return table


class PolicySet:
    """The loaded variants of one task. ``act`` -> (action float32 [2] or [6], ms).

    ``graph`` says how each model runs (sebvs/policy/graph.py): "eager" as trained, or
    "frozen". A model that cannot be frozen runs eager; ``fallbacks`` says why.
    """

    def __init__(self, table: dict[Modality | str, Path], task: str | None = None,
                 graph: str = "eager"):
        import torch
        self._torch = torch
        check_graph(graph)
        self.policies: dict[Modality, LoadedPolicy] = {}
        self.fallbacks: dict[Modality, str] = {}
        for m, path in table.items():
            m = Modality.parse(m)
            expect = {"modality": m, **({"task": task} if task else {})}
            model, cfg, norm = load_checkpoint(path, expect=expect)
            example = torch.zeros(1, model.in_channels, model.size, model.size)
            if model.state_size:
                run, used, why = inference_graph(step_module(model),
                                                 (example, model.initial_state()), graph)
            else:
                run, used, why = inference_graph(model, example, graph)
            if why:
                self.fallbacks[m] = why
            self.policies[m] = LoadedPolicy(model, cfg, norm, str(path), run, used,
                                            model.initial_state() if model.state_size else None)
        # one input array per modality, refilled every call: no per-tick allocation (the
        # model reads it within act(), and act() returns a copy of the output)
        self._inputs = {m: np.empty((p.model.in_channels, p.norm.size, p.norm.size),
                                    np.float32) for m, p in self.policies.items()}
        tasks = {p.config["task"] for p in self.policies.values()}
        if len(tasks) != 1:
            raise ValueError(f"checkpoints mix tasks {sorted(tasks)}: one policy, one task")
        self.task = tasks.pop()
        self.output = "action" if self.task == "nav" else "pose"
        self.ablated: dict[Modality, tuple[list[int], np.ndarray]] = {}

    def ablate(self, modality: Modality | str, channels: list[int], levels: list[float]
               ) -> None:
        """Hold input ``channels`` of ``modality`` at ``levels`` (model input units) on every
        call from now on: a closed-loop ablation, the stream those channels carry replaced
        by a constant level. ValueError naming what is wrong."""
        if modality not in self.policies:
            raise ValueError(f"ablate: modality {modality!r} has no checkpoint loaded "
                             f"(loaded: {', '.join(self.policies)})")
        n = self.policies[modality].model.in_channels
        if not channels or len(channels) != len(levels):
            raise ValueError(f"ablate {modality}: {len(channels)} channels and {len(levels)} "
                             f"levels; give one level per channel, at least one")
        bad = [c for c in channels if not isinstance(c, int) or isinstance(c, bool)
               or not 0 <= c < n]
        if bad or len(set(channels)) != len(channels):
            raise ValueError(f"ablate {modality}: channels {channels} must be distinct "
                             f"integers in 0..{n - 1} (the model's {n} input channels)")
        if not all(isinstance(v, numbers.Real) and not isinstance(v, bool)
                   and math.isfinite(v) for v in levels):
            raise ValueError(f"ablate {modality}: levels {list(levels)} must be finite "
                             f"numbers")
        values = np.asarray(levels, dtype=np.float32)
        self.ablated[Modality.parse(modality)] = (list(channels), values[:, None, None])

    @property
    def modalities(self) -> list[Modality]:
        return list(self.policies)

    @property
    def recurrent(self) -> list[Modality]:
        """The loaded modalities whose model carries a state across ticks."""
        return [m for m, p in self.policies.items() if p.recurrent]

    def reset(self, modality: Modality | str | None = None) -> None:
        """Forget what the recurrent models remember (an episode's start, a modality
        swap): their next tick starts from the initial state. ``modality`` None: all."""
        for m, p in self.policies.items():
            if p.recurrent and (modality is None or m == modality):
                p.state = p.model.initial_state()

    def warm_up(self) -> None:
        """One inference per variant on zeros: first calls allocate, keep that off tick 0.
        The recurrent models' states are reset after it."""
        for m, p in self.policies.items():
            s, planes = p.norm.size, 2 * p.norm.event_bins
            self.act(m, rgb=np.zeros((s, s, 3), np.uint8),
                     events=np.zeros((planes, s, s), np.uint8),
                     rgb_prev=np.zeros((s, s, 3), np.uint8))
        self.reset()

    def act(self, modality: Modality | str, *, rgb: np.ndarray | None = None,
            events: np.ndarray | None = None,
            rgb_prev: np.ndarray | None = None) -> tuple[np.ndarray, float, float]:
        """Observation -> (output float32 [2] | [6], preprocess ms, inference ms). A
        recurrent model steps its state on (`reset` starts it again)."""
        p = self.policies[modality]
        t0 = time.perf_counter()
        x = model_input(modality, p.norm, rgb=rgb, events=events, rgb_prev=rgb_prev,
                        out=self._inputs[modality])
        if modality in self.ablated:
            channels, levels = self.ablated[modality]
            x[channels] = levels
        t1 = time.perf_counter()
        with self._torch.inference_mode():
            if p.state is not None:
                out, p.state = p.run(self._torch.from_numpy(x)[None], p.state)
            else:
                out = p.run(self._torch.from_numpy(x)[None])
            y = out[0].numpy().astype(np.float32)
        t2 = time.perf_counter()
        return y, (t1 - t0) * 1e3, (t2 - t1) * 1e3


class PreviousFrame:
    """The frame of the previous control tick of the same episode, for the rgb+diff control.

    ``swap(episode, tick, frame)`` returns the frame held for ``tick - 1`` of ``episode``,
    or ``frame`` itself where there is none (an episode's first tick, a skipped tick, a
    new size): no change, as training sees an episode's first row
    (sebvs/policy/dataset.py, `previous_rgb`). It then holds a copy of ``frame``.
    """

    def __init__(self):
        self.episode, self.tick, self.frame = None, None, None

    def swap(self, episode, tick: int, frame: np.ndarray) -> np.ndarray:
        held = self.frame
        follows = (held is not None and episode == self.episode and self.tick is not None
                   and tick == self.tick + 1 and held.shape == frame.shape)
        self.episode, self.tick, self.frame = episode, tick, np.array(frame)
        return held if follows else self.frame


class TickSync:
    """Latest frames per stream, keyed by tick; finds the next tick complete for a modality.

    Frames are copied in (runtime arrays are only valid during a handler). Ticks at or
    below the last one used are stale and dropped; at most ``keep`` ticks are held per
    stream, so a stream that stops cannot grow memory.
    """

    def __init__(self, streams: tuple[str, ...], keep: int = 8):
        self.frames: dict[str, dict[int, tuple[np.ndarray, float | None]]] = \
            {s: {} for s in streams}
        self.keep = keep
        self.last_tick: int | None = None

    def put(self, stream: str, tick: int, array: np.ndarray, t_sim: float | None) -> None:
        if self.last_tick is not None and tick <= self.last_tick:
            return
        buf = self.frames[stream]
        buf[tick] = (np.array(array), t_sim)
        while len(buf) > self.keep:
            del buf[min(buf)]

    def ready(self, modality: Modality | str) -> int | None:
        """Smallest tick after the last used for which every stream of ``modality`` has a frame."""
        needed = [self.frames[s] for s in Modality.parse(modality).streams]
        common = set(needed[0]).intersection(*needed[1:])
        return min(common) if common else None

    def take(self, modality: Modality | str, tick: int
             ) -> dict[str, tuple[np.ndarray, float | None]]:
        """The frames of ``tick`` for ``modality``; everything up to ``tick`` is then dropped."""
        got = {s: self.frames[s][tick] for s in Modality.parse(modality).streams}
        self.last_tick = tick
        for buf in self.frames.values():
            for t in [t for t in buf if t <= tick]:
                del buf[t]
        return got
