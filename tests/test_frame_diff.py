"""The rgb+diff control: an RGB frame and its change since the previous control tick's,
made the same way in training (dataset) and in closed loop (the policy actor)."""
import asyncio
import json
import math

import numpy as np
import pytest
import torch

from sebvs_actors.policy import Policy
from sebvs.eval.run import EvalPlan, Run
from sebvs.policy.checkpoint import model_config, save_checkpoint
from sebvs.policy.dataset import EpisodeFrames, load_index, previous_rgb
from sebvs.policy.infer import PreviousFrame
from sebvs.policy.inputs import (MODALITIES, Normalisation, channel_names, channels,
                                 diff_input, model_input)
from sebvs.policy.model import ERP
from sebvs.runtime.wire import Message
from tests.policy_data import make_dataset


def grey(level: int, shape=(32, 32)) -> np.ndarray:
    return np.full((*shape, 3), level, np.uint8)


def test_change_is_counted_in_thresholds_and_split_by_sign():
    norm = Normalisation(32)            # event_clip 8, the paper's thresholds 0.3
    before = grey(100)
    after = before.copy()
    after[4:12, 4:12] = 182             # ln(182 / 100) = 0.599: two thresholds up
    after[20:28, 20:28] = 55            # ln(55 / 100) = -0.598: two down
    x = diff_input(after, before, norm)
    assert x.shape == (2, 32, 32) and x.dtype == np.float32
    assert x[0, 8, 8] == pytest.approx(math.log(182 / 100) / 0.3 / 8, rel=1e-3)
    assert x[1, 24, 24] == pytest.approx(-math.log(55 / 100) / 0.3 / 8, rel=1e-3)
    assert x[1, 8, 8] == 0 and x[0, 24, 24] == 0 and x[:, 0, 0].tolist() == [0, 0]
    # a change of more than event_clip thresholds saturates at 1, as event counts do
    assert diff_input(grey(255), grey(21), norm)[0].max() == 1.0
    assert not diff_input(before, before, norm).any()


def test_rgb_diff_is_five_channels_and_not_one_of_the_papers_three():
    assert "rgb+diff" not in MODALITIES         # never in "all" or the default eval rows
    assert channels("rgb+diff") == 5
    assert channel_names("rgb+diff") == ["r", "g", "b", "up", "down"]
    rgb = np.random.default_rng(0).integers(0, 256, (48, 48, 3), dtype=np.uint8)
    x = model_input("rgb+diff", Normalisation(32), rgb=rgb, rgb_prev=rgb[::-1].copy())
    assert x.shape == (5, 32, 32)
    np.testing.assert_array_equal(x[:3], model_input("rgb", Normalisation(32), rgb=rgb))
    with pytest.raises(ValueError, match="previous tick"):
        model_input("rgb+diff", Normalisation(32), rgb=rgb)
    with pytest.raises(ValueError, match="rgb_prev must be uint8"):
        model_input("rgb+diff", Normalisation(32), rgb=rgb, rgb_prev=rgb[:32])


class _Rows:
    """An episode's tick and rgb columns, as an open Episode exposes them."""

    def __init__(self, ticks):
        self.tick = np.asarray(ticks, np.int64)
        self.rgb = np.stack([grey(10 * (i + 1)) for i in range(len(ticks))])


def test_previous_row_only_when_it_is_the_previous_tick():
    ep = _Rows([40, 41, 43, 44])        # the row of tick 42 was lost
    np.testing.assert_array_equal(previous_rgb(ep, 0), ep.rgb[0])   # the first row
    np.testing.assert_array_equal(previous_rgb(ep, 1), ep.rgb[0])
    np.testing.assert_array_equal(previous_rgb(ep, 2), ep.rgb[2])   # no change, not 41's
    np.testing.assert_array_equal(previous_rgb(ep, 3), ep.rgb[2])


def test_training_items_pair_each_frame_with_the_previous_one(tmp_path):
    root = make_dataset(tmp_path / "d", episodes=2, frames=5, task="arm")
    episodes = load_index(root, "arm")
    norm = Normalisation(32)
    items = EpisodeFrames(root, episodes, "arm", "rgb+diff", norm)
    rgb = EpisodeFrames(root, episodes, "arm", "rgb", norm)
    ep = items._episode(0)
    frames = ep.rgb[:]
    x0, _ = items[0]
    assert x0.shape == (5, 32, 32) and not x0[3:].any()      # first row: no change
    x3, y3 = items[3]
    np.testing.assert_array_equal(x3[3:], diff_input(frames[3], frames[2], norm))
    np.testing.assert_array_equal(x3[:3], rgb[3][0])
    np.testing.assert_array_equal(y3, rgb[3][1])
    assert x3[3:].any()                  # the square moved
    x5, _ = items[5]                     # the second episode's first row
    assert not x5[3:].any()


def test_previous_frame_follows_ticks_within_an_episode():
    held = PreviousFrame()
    a, b, c, d = (grey(v) for v in (10, 20, 30, 40))
    assert held.swap(0, 7, a) is not a and (held.swap(0, 8, b) == a).all()
    assert (held.swap(1, 9, c) == c).all()          # a new episode: no change
    assert (held.swap(1, 11, d) == d).all()         # tick 10 skipped: no change
    a[:] = 99                                       # the caller's buffer is reused
    assert (held.swap(1, 12, a) == d).all()
    assert (held.swap(1, 13, grey(5, (16, 16))) == 5).all()   # a new size: no change


class _Node:
    def __init__(self):
        self.sent = []

    def emit(self, output, arrays, *, meta=None, t_sim=None, tick=None, parent=None):
        self.sent.append((tick, meta["modality"]))

    def event(self, kind, fields):
        pass


def _rgb(tick, frame, episode, control=True):
    return Message(topic="camera/rgb", source="camera", output="rgb", seq=tick,
                   t_sim=tick / 10, tick=tick, meta={"episode": episode, "control": control},
                   arrays={"rgb": frame}, stamps=[])


def test_actor_gives_the_control_the_previous_tick_of_the_same_episode(tmp_path):
    torch.manual_seed(0)
    for m in ("rgb", "rgb+diff"):
        save_checkpoint(ERP("arm", channels(m), 32), model_config("arm", m, Normalisation(32)),
                        tmp_path)
    node = _Node()
    actor = Policy("policy", Policy.Params(directory=str(tmp_path), task="arm",
                                           modalities=["rgb", "rgb+diff"],
                                           modality="rgb+diff"),
                   connected=frozenset({"rgb"}), node=node)
    frames = [grey(v) for v in (10, 20, 30, 40, 50, 60)]
    seen = []

    async def scenario():
        await actor.setup()
        act = actor.policies.act

        def spy(modality, **streams):
            seen.append((modality, streams.get("rgb_prev")))
            return act(modality, **streams)
        actor.policies.act = spy
        await actor.on_rgb(_rgb(0, frames[0], episode=0))
        await actor.on_rgb(_rgb(0, frames[5], episode=0, control=False))  # between ticks
        await actor.on_rgb(_rgb(1, frames[1], episode=0))
        await actor.control("modality", "rgb")       # still tracked while rgb is active
        await actor.on_rgb(_rgb(2, frames[2], episode=0))
        await actor.control("modality", "rgb+diff")
        await actor.on_rgb(_rgb(3, frames[3], episode=0))
        await actor.on_rgb(_rgb(4, frames[4], episode=1))

    asyncio.run(scenario())
    assert [t for t, _ in node.sent] == [0, 1, 2, 3, 4]
    diffs = [(m, None if p is None else int(p[0, 0, 0])) for m, p in seen]
    assert diffs == [("rgb+diff", 10), ("rgb+diff", 10), ("rgb", None), ("rgb+diff", 30),
                     ("rgb+diff", 50)]


def test_actor_without_the_control_keeps_no_previous_frame(tmp_path):
    save_checkpoint(ERP("arm", 3, 32), model_config("arm", "rgb", Normalisation(32)), tmp_path)
    actor = Policy("policy", Policy.Params(directory=str(tmp_path), task="arm",
                                           modalities=["rgb"], modality="rgb"),
                   connected=frozenset({"rgb"}), node=_Node())
    asyncio.run(actor.setup())
    assert actor.previous is None and set(actor.sync.frames) == {"rgb"}


def test_eval_runs_the_control_without_the_event_chain(tmp_path):
    plan = EvalPlan(task="arm", modalities=["rgb+diff"], conditions=["nominal"], episodes=1,
                    out=tmp_path)
    plan.validate()
    from sebvs.runtime.overrides import replace
    _, sets = plan.overrides(Run("nominal", "single", "rgb+diff"))
    assert sets["policy"]["inputs"] == replace({"rgb": "camera/rgb"})   # no events input
    assert Run("nominal", "single", "rgb+diff").key == "nominal__rgb_diff"


def test_eval_notes_an_unknown_event_sensor_only_for_modalities_with_events(tmp_path):
    """A checkpoint config without "event_frames" gets a note when its policy reads events
    (its sensor is then the topology's), never for the control, which reads none."""
    for m in ("rgb+diff", "rgb+event"):
        (tmp_path / f"nav-{m}.json").write_text(json.dumps({"task": "nav", "modality": m}))
    plan = EvalPlan(task="nav", modalities=["rgb+diff", "rgb+event"], conditions=["nominal"],
                    episodes=1, out=tmp_path / "eval", checkpoints=tmp_path)
    notes = plan.event_frame_notes()
    assert len(notes) == 1 and "nav-rgb+event.json does not say which event frames" in notes[0]
