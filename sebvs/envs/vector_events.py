"""The event chain of N environments in one process, run as one batch per light sample.

An ERPEnv calls its SensorStream (emulator) and FrameStream (accumulator) as each luma
sample is rendered (sebvs/envs/erp.py, `_sample`). In a shared-process vector env
(sebvs/envs/vector.py) those calls are recorded instead (`DeferredChain`), and once
every env has stepped, the k-th samples of all envs go through the emulator together
(`emulate_batch`): the per-pixel model over the N sensors stacked as one (N*H, W) array,
each env's fixed pattern and random stream its own. Then each env's accumulator takes
its packets in order and the tick's event frame is written where the env's observation
already holds it.

    chain = DeferredChain(env)            # installs itself as env.sensor / env.frames
    env.step(action)                      # physics, renders; the event chain recorded
    run_chains([chain, ...])              # every recorded sample, batched across envs

Nothing downstream of the renders feeds back into a step (the reward and the truth come
from the sim), so deferring the chain to the end of the vector step changes no number:
each emulator sees its frames in the order it would have, and tests/test_vector_env.py
checks the observations equal those of separate envs, bit for bit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from sebvs.dvs.emulator import (EventEmulator, linlog, linlog_linear,
                                pixel_time_order)

# event rows are uint16 (EVENT_DTYPE's "y"): a stack holds at most this many rows
MAX_STACK_ROWS = 2 ** 16


@dataclass
class _Sample:
    """One recorded luma sample of one env: the SensorStream.frame call's arguments and,
    on a control tick, the event frame's time and the array its observation holds."""
    frame: np.ndarray
    t_sim: float | None
    episode: object
    units: str | None
    window_t: float | None = None
    window_out: np.ndarray | None = None


class _SensorStandIn:
    """What ERPEnv._sample calls as env.sensor: records the sample."""

    def __init__(self, chain: "DeferredChain") -> None:
        self.chain = chain

    def frame(self, frame, t_sim, episode, units=None) -> _Sample:
        sample = _Sample(frame, t_sim, episode, units)
        self.chain.pending.append(sample)
        return sample

    def geometry_meta(self, frame) -> None:
        return None           # the real stream's, once the sample has been emulated


class _FramesStandIn:
    """What ERPEnv._sample calls as env.frames: the tick's event frame is an array of the
    observation's shape, filled when the chain runs."""

    def __init__(self, chain: "DeferredChain") -> None:
        self.chain = chain

    def add(self, events, episode, geometry) -> None:
        # every recorded sample is added to the accumulator, in order, when it runs
        if not self.chain.pending or events is not self.chain.pending[-1]:
            raise RuntimeError("vector env: an event packet that is not the last sample's")

    def frame(self, t_sim) -> np.ndarray:
        sample = self.chain.pending[-1]
        space = self.chain.events_space
        sample.window_t = t_sim
        sample.window_out = np.empty(space.shape, space.dtype)
        return sample.window_out


class DeferredChain:
    """Records one ERPEnv's event chain calls and runs them later (module docstring).

    Parameters:
        env: the ERPEnv (unwrapped); its sensor and frames are replaced by stand-ins,
            and put back by `install()` after a reset(seed=...) built new ones.
    """

    def __init__(self, env) -> None:
        self.env = env
        self.pending: list[_Sample] = []
        self.events_space = env.observation_space.spaces.get("events")
        self.sensor = self.frames = None
        self._sensor_in, self._frames_in = _SensorStandIn(self), _FramesStandIn(self)
        self.install()

    def install(self) -> None:
        """Take the env's current SensorStream and FrameStream (new after a seeded
        reset) and put the stand-ins in their place."""
        env = self.env
        if env.sensor is not self._sensor_in:
            self.sensor = env.sensor
        if env.frames is not self._frames_in:
            self.frames = env.frames
        env.sensor, env.frames = self._sensor_in, self._frames_in

    def restore(self) -> None:
        """Give the env its own streams back (it then runs its chain as it always did)."""
        self.env.sensor, self.env.frames = self.sensor, self.frames

    def take(self) -> list[_Sample]:
        pending, self.pending = self.pending, []
        return pending

    def begin(self, sample: _Sample) -> int:
        """What SensorStream.frame does before its emulator step: a new episode restarts
        the emulator with that episode's random stream; the time in int ns."""
        stream = self.sensor
        if sample.episode != stream.episode:
            stream.emulator.reset()
            if isinstance(sample.episode, int) and sample.episode >= 0:
                stream.emulator.rng = np.random.default_rng(
                    [stream.emulator.params.seed, sample.episode])
            stream.episode = sample.episode
        return round((sample.t_sim or 0.0) * 1e9)

    def finish(self, sample: _Sample, events: np.ndarray) -> None:
        """The emulated packet into the accumulator; the tick's frame into its place."""
        self.frames.add(events, sample.episode, self.sensor.geometry_meta(sample.frame))
        if sample.window_out is not None:
            frame = self.frames.frame(sample.window_t)
            if frame.shape != sample.window_out.shape or frame.dtype != sample.window_out.dtype:
                raise RuntimeError(f"vector env: the event frame is {frame.dtype} "
                                   f"{frame.shape}, the observation space says "
                                   f"{sample.window_out.dtype} {sample.window_out.shape}")
            np.copyto(sample.window_out, frame)


def run_chains(chains: list[DeferredChain], batch: bool = True,
               stacks: "Stacks | None" = None) -> None:
    """Run every recorded sample of `chains`: round k emulates the k-th sample of each
    env (batched across envs where `batch`), then feeds each env's accumulator.

    Parameters:
        chains: the envs' chains; each env's samples run in the order recorded.
        batch: emulate each round as one stack (False: env by env, the single env's path).
        stacks: the cache of stacked states to reuse between calls (None: none kept).
    """
    queues = [c.take() for c in chains]
    for k in range(max((len(q) for q in queues), default=0)):
        live = [(c, q[k]) for c, q in zip(chains, queues) if k < len(q)]
        times = [c.begin(s) for c, s in live]
        emulators = [c.sensor.emulator for c, _ in live]
        frames = [s.frame for _, s in live]
        linear = [s.units == "cd/m2" for _, s in live]
        if batch:
            packets = emulate_batch(emulators, frames, times, linear, stacks)
        else:
            packets = [_step_one(e, f, t, lin) for e, f, t, lin in
                       zip(emulators, frames, times, linear)]
        for (c, s), events in zip(live, packets):
            c.finish(s, events)


def _checked(emu: EventEmulator, frame, t_ns: int, linear: bool):
    """The frame and time as EventEmulator.step / step_luminance check and scale them
    before their model step: (frame, t_ns, log)."""
    if linear:
        if isinstance(frame, np.ndarray) and frame.dtype.kind != "f":
            raise ValueError(f"luminance dtype {frame.dtype} is not float (cd/m^2)")
        frame, t_ns = emu._check(frame, t_ns, linear=True)
        return frame * np.float32(255.0 / emu.params.reference_cd_m2), t_ns, linlog_linear
    frame, t_ns = emu._check(frame, t_ns)
    return frame, t_ns, linlog


def _step_one(emu: EventEmulator, frame, t_ns: int, linear: bool) -> np.ndarray:
    if linear:
        return emu.step_luminance(frame, t_ns)
    return emu.step(frame, t_ns)


def _group_key(emu: EventEmulator, t_ns: int, log) -> tuple | None:
    """Emulators with equal keys step as one stack; None: this one steps alone (its first
    frame, a repeated or restarting time, or the linear hold's per-frame input)."""
    p = emu.params
    if emu.t_ns is None:
        return None
    dt_ns = t_ns - emu.t_ns
    if not 0 < dt_ns <= emu._max_gap_ns:
        return None
    if p.cutoff_hz > 0 and p.lowpass_hold == "linear":
        return None
    # the same model but for the seed (the fixed pattern and noise are each env's own)
    return (emu.t_ns, t_ns, replace(p, seed=0), emu.shape, log)


def emulate_batch(emulators: list[EventEmulator], frames: list[np.ndarray],
                  times: list[int], linear: list[bool],
                  stacks: "Stacks | None" = None) -> list[np.ndarray]:
    """One frame for each of N emulators -> each one's events, as N calls of its
    step() (linear False) or step_luminance() (True) give them, bit for bit.

    Emulators at the same sample times with the same model (seeds apart) step as one
    stack of (n*H, W) arrays; the rest, and a group of one, step alone.

    Parameters:
        emulators: N EventEmulators (distinct).
        frames: N frames, each as its step takes it: uint8 DN, or float cd/m^2.
        times: N int ns timestamps.
        linear: N flags, step_luminance() for True.
        stacks: the cache of stacked states (None: stacked anew).

    Returns:
        N EVENT_DTYPE arrays, sorted by time. ValueError, as step() raises it, for a bad
        frame or time (the emulators checked before it keep their state: check first).
    """
    n = len(emulators)
    out: list[np.ndarray | None] = [None] * n
    checked = [_checked(e, f, t, lin) for e, f, t, lin in zip(emulators, frames, times, linear)]
    groups: dict[tuple, list[int]] = {}
    for i, (emu, (frame, t_ns, log)) in enumerate(zip(emulators, checked)):
        key = _group_key(emu, t_ns, log)
        if key is None:
            out[i] = emu._step(frame, t_ns, log)
        else:
            groups.setdefault(key, []).append(i)
    for members in groups.values():
        rows = emulators[members[0]].shape[0]
        per_stack = max(1, (MAX_STACK_ROWS - 1) // rows)
        for start in range(0, len(members), per_stack):
            part = members[start:start + per_stack]
            if len(part) == 1:
                i = part[0]
                out[i] = emulators[i]._step(*checked[i])
                continue
            events = _step_stack([emulators[i] for i in part], [checked[i][0] for i in part],
                                 checked[part[0]][1], checked[part[0]][2], stacks)
            for i, ev in zip(part, events):
                out[i] = ev
    return out


class Stacks:
    """Stacked (n*H, W) copies of n emulators' per-pixel arrays, kept between steps: a
    state that each emulator holds as a view of the last stack is not copied again."""

    def __init__(self, keep: int = 16) -> None:
        self.keep = keep
        self._cache: dict[tuple, tuple[tuple, np.ndarray]] = {}

    def stack(self, key: tuple, parts: list[np.ndarray]) -> np.ndarray:
        """The parts stacked along their first axis (the kept stack, if they are it)."""
        hit = self._cache.get(key)
        if hit is not None and len(hit[0]) == len(parts) and \
                all(a is b for a, b in zip(hit[0], parts)):
            return hit[1]
        whole = np.concatenate(parts)
        self.remember(key, parts, whole)
        return whole

    def remember(self, key: tuple, parts, whole: np.ndarray) -> None:
        if self.keep <= 0:
            return
        if key not in self._cache and len(self._cache) >= self.keep:
            self._cache.pop(next(iter(self._cache)))
        self._cache[key] = (tuple(parts), whole)

    def split(self, key: tuple, whole: np.ndarray, n: int) -> list[np.ndarray]:
        """`whole` cut into n views along its first axis, kept as the next stack of them."""
        rows = whole.shape[0] // n
        views = [whole[i * rows:(i + 1) * rows] for i in range(n)]
        self.remember(key, views, whole)
        return views


class _StackView:
    """The attributes EventEmulator._crossings and _refractory read, for a stack."""

    def __init__(self, params, shape, theta_on, theta_off, last_t) -> None:
        self.params, self.shape = params, shape
        self.theta_on, self.theta_off, self.last_t = theta_on, theta_off, last_t


def _step_stack(emus: list[EventEmulator], frames: list[np.ndarray], t_ns: int, log,
                stacks: Stacks | None) -> list[np.ndarray]:
    """EventEmulator._step of n emulators with the same model, state times and shape, on
    their n checked frames at t_ns: the per-pixel passes over the stack, the random
    draws (shot noise) per emulator from its own stream in its own order."""
    stacks = stacks or Stacks(keep=0)
    n = len(emus)
    p = emus[0].params
    h, w = emus[0].shape
    ident = tuple(id(e) for e in emus)

    def stacked(name: str) -> np.ndarray:
        return stacks.stack((name, ident), [getattr(e, name) for e in emus])

    # per env where OpenCV works on the whole image (a blur must not cross envs, and a
    # SIMD routine's tail may round differently from its body), numpy's passes stacked
    lumas = [e.preprocess(f) for e, f in zip(emus, frames)]
    luma = np.concatenate(lumas)
    target = np.concatenate([log(x) for x in lumas])
    t0 = emus[0].t_ns
    dt_ns = t_ns - t0
    dt = dt_ns * 1e-9
    lp0 = stacked("lp")
    if p.cutoff_hz > 0:
        tau = 1.0 / (2 * math.pi * p.cutoff_hz)
        eps = emus[0]._lowpass_gain(luma, dt / tau)    # EventEmulator._step's, per pixel
        lp = np.subtract(target, lp0, out=target)
        lp *= eps
        lp += lp0
    else:
        lp = target
    base = stacked("base")
    if p.leak_rate_hz > 0:
        base = base - np.float32(dt) * stacked("leak")
    view = _StackView(p, (n * h, w), stacked("theta_on"), stacked("theta_off"),
                      stacked("last_t"))
    events, base = EventEmulator._crossings(view, lp0, lp, base, t0, dt_ns)
    if p.shot_noise_rate_hz > 0:
        noise = []
        for i, (e, x) in enumerate(zip(emus, lumas)):
            ev = e._shot_noise(x, t0, dt_ns)
            ev["y"] += i * h
            noise.append(ev)
        events = np.concatenate([events, *noise])
    if p.refractory_period_s > 0 and events.size:
        events = EventEmulator._refractory(view, events)
    # by env, then by time (ties in the order made): each env's events as its own step
    # sorts them, one sort for all
    env = (events["y"] // h).astype(np.int64)
    order = pixel_time_order(env, events["t"])
    events, env = events[order], env[order]
    cuts = np.searchsorted(env, np.arange(n + 1))
    out = []
    lp_views = stacks.split(("lp", ident), lp, n)
    base_views = stacks.split(("base", ident), base, n)
    last_views = stacks.split(("last_t", ident), view.last_t, n)
    for i, e in enumerate(emus):
        ev = events[cuts[i]:cuts[i + 1]]
        if i:
            ev["y"] -= i * h
        out.append(ev)
        e.frames += 1
        e.lp, e.base, e.last_t, e.t_ns = lp_views[i], base_views[i], last_views[i], t_ns
    return out
