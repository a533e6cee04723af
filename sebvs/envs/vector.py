"""N ERPNav or ERPArm scenes stepped in one process, as one Gymnasium 1.x vector env.

    import gymnasium as gym
    import sebvs.envs
    envs = gym.make_vec("SEBVS/ERPNav-v1", num_envs=8, vectorization_mode="vector_entry_point")
    obs, infos = envs.reset(seed=3)          # env i plays `sebvs eval --seed 3+i`'s episodes
    obs, rewards, terminations, truncations, infos = envs.step(envs.action_space.sample())

Each env is an ERPEnv (sebvs/envs/erp.py) built with the same options: its own scene,
camera core, frame camera and event sensor, stepped by its own step(). What the envs
share is the event chain's work: every luma sample's emulator step is recorded during
the envs' steps and then run for a thread's envs together, one stack of sensors per
sample time (sebvs/envs/vector_events.py). Each sensor keeps its own fixed pattern and
random stream, so the observations, rewards and infos are those of N separate envs with
the same seeds, bit for bit (tests/test_vector_env.py checks them against SyncVectorEnv).
The envs step on `threads` threads (one per core by default), env i always on thread
i % threads with its GL context (sebvs/envs/vector_workers.py); resets, which compile
scenes and make contexts, take turns.

The renders stay one env at a time, through each env's own camera. sebvs/sim/tiles.py
draws K scenes in one GL context with one readback, but on llvmpipe that saves 3-15 % of
a render's CPU (docs/sim.md, "Tiled renders"), and the camera core owns its renderer
and its sensor rig; docs/envs.md ("Vector envs in one process") says what it would take
where a GPU renders.

Autoreset: Gymnasium's modes, as SyncVectorEnv runs them (AutoresetMode.NEXT_STEP by
default, SAME_STEP with final_obs / final_info, DISABLED with options["reset_mask"]).
"""
from __future__ import annotations

import os
import threading
from typing import Any

import gymnasium
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space, concatenate, create_empty_array

from .erp import ERPArmEnv, ERPEnv, ERPNavEnv
from .vector_events import DeferredChain, Stacks, run_chains
from .vector_workers import PinnedWorkers

# scenes compile and GL contexts are made in resets and constructions: one at a time
# across the worker threads (the steps between them run side by side)
_BUILD_LOCK = threading.RLock()


def check_num_envs(num_envs) -> int:
    """num_envs as an int >= 1; ValueError in one line otherwise."""
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) \
            or num_envs < 1:
        raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
    return int(num_envs)


def auto_threads(num_envs: int) -> int:
    """One thread per core this process may run on, at most one per env."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:          # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(num_envs, cores))


class ERPVectorEnv(VectorEnv):
    """N envs of one task in this process (module docstring).

    Parameters:
        num_envs: how many envs, >= 1.
        autoreset_mode: a gymnasium AutoresetMode or its value ("NextStep", "SameStep",
            "Disabled").
        batch_events: run the event sensors of a thread's envs as one stack per sample
            time (False: one by one, as each env alone does; the results are the same).
        threads: how many threads step the envs (env i on thread i % threads, its GL
            context with it); None: one per core, at most num_envs; 1: the caller's
            thread only. The results do not depend on it.
        seed: env i's topology seed for a first reset() given none is seed + i (so the
            envs play different episodes, as reset(seed=s) gives env i seed s + i).
        **env_kwargs: the ERPEnv options (docs/envs.md, "Options"), the same for all.
    """

    env_class: type[ERPEnv] = ERPEnv

    def __init__(self, num_envs: int = 1, *,
                 autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
                 batch_events: bool = True, threads: int | None = None, seed: int = 0,
                 **env_kwargs: Any) -> None:
        self.num_envs = check_num_envs(num_envs)
        try:
            self.autoreset_mode = AutoresetMode(autoreset_mode)
        except ValueError:
            raise ValueError(f"autoreset_mode must be one of "
                             f"{', '.join(m.value for m in AutoresetMode)}, got "
                             f"{autoreset_mode!r}") from None
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise ValueError(f"seed must be an integer, got {seed!r}")
        threads = auto_threads(self.num_envs) if threads is None else threads
        if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) \
                or not 1 <= threads <= self.num_envs:
            raise ValueError(f"threads must be an integer from 1 to num_envs "
                             f"({self.num_envs}), got {threads!r}")
        self.threads = int(threads)
        self.batch_events = bool(batch_events)
        self.closed = False
        self.workers = PinnedWorkers(self.threads)
        self.envs: list[ERPEnv | None] = [None] * self.num_envs
        try:
            self._on_owners(lambda i: self._build(i, int(seed) + i, env_kwargs))
        except BaseException:
            self.close_extras()
            raise
        first = self.envs[0]
        self.metadata = {**first.metadata, "autoreset_mode": self.autoreset_mode}
        self.render_mode = first.render_mode
        self.single_observation_space = first.observation_space
        self.single_action_space = first.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.chains = [DeferredChain(env) for env in self.envs]
        # one cache per thread: a thread stacks its own envs' sensors
        self._stacks = [Stacks(keep=16) for _ in range(self.threads)]
        self._rewards = np.zeros(self.num_envs, np.float64)
        self._terminations = np.zeros(self.num_envs, np.bool_)
        self._truncations = np.zeros(self.num_envs, np.bool_)
        self._autoreset = np.zeros(self.num_envs, np.bool_)
        self._last_obs: list = [None] * self.num_envs

    # ------------------------------------------------------------------ gymnasium
    def reset(self, *, seed: int | list | None = None, options: dict | None = None):
        """Reset the envs (SyncVectorEnv's conventions): seed None (each env its next
        episode, or its first of seed + i), an int s (env i gets s + i), or a list of N
        ints or None; options go to every env, options["reset_mask"] (N bools) resets
        only those envs.

        Returns:
            (observations batched as observation_space, infos as VectorEnv batches them).
        """
        self._check_open("reset()")
        if seed is None:
            seeds = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"reset(seed=...): {len(seeds)} seeds for "
                                 f"{self.num_envs} envs")
        super().reset(seed=seeds[0])
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if mask is None:
            mask = np.ones(self.num_envs, np.bool_)
        else:
            mask = self._check_mask(mask)
        self._terminations[mask] = self._truncations[mask] = False
        self._autoreset[mask] = False
        results = self._on_owners(
            lambda i: self._reset_one(i, seeds[i], options) if mask[i] else None,
            chains=True)
        infos: dict = {}
        for i, result in enumerate(results):
            if result is not None:
                self._last_obs[i], info = result
                infos = self._add_info(infos, info, i)
        return self._batch(self._last_obs), infos

    def step(self, actions):
        """Step every env one control tick (an env that ended the step before resets
        instead, under NEXT_STEP).

        Parameters:
            actions: (num_envs, *single_action_space.shape), one action per env.

        Returns:
            (observations, rewards (N,) float64, terminations (N,) bool, truncations (N,)
            bool, infos), as SyncVectorEnv returns them.
        """
        self._check_open("step()")
        actions = np.asarray(actions)
        if actions.shape[:1] != (self.num_envs,):
            raise ValueError(f"step(): actions of shape {actions.shape}, want "
                             f"({self.num_envs}, *{self.single_action_space.shape})")
        if self.autoreset_mode == AutoresetMode.DISABLED and self._autoreset.any():
            raise RuntimeError(f"step(): envs {np.flatnonzero(self._autoreset).tolist()} "
                               f"ended and autoreset is disabled: reset them "
                               f"(options={{'reset_mask': ...}})")
        results = self._on_owners(lambda i: self._step_one(i, actions[i]), chains=True)
        infos: dict = {}
        for i, (obs, reward, terminated, truncated, info, final) in enumerate(results):
            self._last_obs[i] = obs
            self._rewards[i], self._terminations[i], self._truncations[i] = \
                reward, terminated, truncated
            if final is not None:
                infos = self._add_info(infos, final, i)
            infos = self._add_info(infos, info, i)
        self._autoreset = self._terminations | self._truncations
        return (self._batch(self._last_obs), self._rewards.copy(),
                self._terminations.copy(), self._truncations.copy(), infos)

    def render(self) -> tuple:
        """Each env's render() (the tick's RGB frame under render_mode "rgb_array")."""
        return tuple(env.render() for env in self.envs)

    def call(self, name: str, *args, **kwargs) -> tuple:
        """Each env's attribute `name`, called (on the env's thread) with the arguments if
        it is callable."""
        def one(i):
            value = getattr(self.envs[i], name)
            return value(*args, **kwargs) if callable(value) else value
        return tuple(self._on_owners(one))

    def get_attr(self, name: str) -> tuple:
        """Each env's attribute `name`."""
        return tuple(getattr(env, name) for env in self.envs)

    def close_extras(self, **kwargs) -> None:
        def close_one(i):
            env = self.envs[i]
            if env is None:
                return
            with _BUILD_LOCK:
                env.close()
        for chain in getattr(self, "chains", ()):
            chain.restore()
        try:
            self._on_owners(close_one)
        finally:
            self.workers.close()

    # ------------------------------------------------------------------ helpers
    def _on_owners(self, fn, chains: bool = False) -> list:
        """fn(i) for every env i on the thread that owns it (in i order on each), and then,
        with `chains`, that thread's envs' event chains; the N results in env order."""
        owned = [list(range(w, self.num_envs, self.threads)) for w in range(self.threads)]

        def job(w):
            out = [(i, fn(i)) for i in owned[w]]
            if chains:
                run_chains([self.chains[i] for i in owned[w]], self.batch_events,
                           self._stacks[w])
            return out
        results: list = [None] * self.num_envs
        for part in self.workers.run([lambda w=w: job(w) for w in range(self.threads)]):
            for i, value in part:
                results[i] = value
        return results

    def _build(self, i: int, seed: int, env_kwargs: dict) -> None:
        with _BUILD_LOCK:
            self.envs[i] = self.env_class(seed=seed, **env_kwargs)

    def _reset_one(self, i: int, seed, options):
        with _BUILD_LOCK:
            obs, info = self.envs[i].reset(seed=seed, options=options)
        self.chains[i].install()       # a seeded reset built the env a new event chain
        return obs, info

    def _step_one(self, i: int, action):
        """Env i's part of a vector step: (obs, reward, terminated, truncated, info, the
        {"final_obs", "final_info"} of a SAME_STEP autoreset or None)."""
        mode = self.autoreset_mode
        if mode == AutoresetMode.NEXT_STEP and self._autoreset[i]:
            obs, info = self._reset_one(i, None, None)
            return obs, 0.0, False, False, info, None
        obs, reward, terminated, truncated, info = self.envs[i].step(action)
        final = None
        if mode == AutoresetMode.SAME_STEP and (terminated or truncated):
            final = {"final_obs": obs, "final_info": info}
            obs, info = self._reset_one(i, None, None)
        return obs, reward, terminated, truncated, info, final

    def _batch(self, obs: list) -> dict:
        out = create_empty_array(self.single_observation_space, self.num_envs, np.empty)
        return concatenate(self.single_observation_space, obs, out)

    def _check_mask(self, mask) -> np.ndarray:
        if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_ \
                or mask.shape != (self.num_envs,) or not mask.any():
            raise ValueError(f"options['reset_mask'] must be a bool array of shape "
                             f"({self.num_envs},) with a True, got {mask!r}")
        return mask

    def _check_open(self, call: str) -> None:
        if self.closed:
            raise gymnasium.error.ClosedEnvironmentError(f"{call} on a closed vector env: "
                                                         f"make a new one")


class ERPNavVectorEnv(ERPVectorEnv):
    """SEBVS/ERPNav-v1's vector entry point: N ERPNavEnv in one process."""

    env_class = ERPNavEnv


class ERPArmVectorEnv(ERPVectorEnv):
    """SEBVS/ERPArm-v1's vector entry point: N ERPArmEnv in one process."""

    env_class = ERPArmEnv
