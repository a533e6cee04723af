"""The recipe options of issue 65, item 2: a recurrent state across ticks, the target head,
modality dropout; trained on lanes of ticks (sebvs/policy/sequence.py) and run with their
state by the policy actor (PolicySet.reset on an episode's start and a swap)."""
import asyncio
import json

import numpy as np
import pytest
import torch

from sebvs.policy.checkpoint import CheckpointError, load_checkpoint, model_config, save_checkpoint
from sebvs.policy.dataset import EpisodeFrames, load_index
from sebvs.policy.graph import inference_graph, step_module
from sebvs.policy.infer import PolicySet
from sebvs.policy.inputs import Modality, Normalisation, channels
from sebvs.policy.model import ERP
from sebvs.policy.sequence import WindowBatches, ModalityDropout, target_truth
from sebvs.policy.train import TrainSettings, check_recipe, train
from sebvs_actors.policy import Policy
from tests.policy_data import make_dataset
from tests.test_policy_actor import _msg, _Node

torch.set_num_threads(1)
QUIET = dict(progress=False, log=lambda s: None)


def test_a_sequence_is_its_steps_and_its_state_carries_on():
    torch.manual_seed(0)
    model = ERP("nav", 2, 32, memory="gru", aux=True).eval()
    x = torch.rand(3, 5, 2, 32, 32)
    with torch.no_grad():
        pred, aux, last = model.sequence(x, model.initial_state(3))
        state, steps = model.initial_state(3), []
        for t in range(5):
            y, state = model.step(x[:, t], state)
            steps.append(y)
        assert pred.shape == (3, 5, 2) and aux.shape == (3, 5, 3) and last.shape == (3, 64)
        torch.testing.assert_close(torch.stack(steps, 1), pred, atol=1e-5, rtol=0)
        torch.testing.assert_close(state, last, atol=1e-5, rtol=0)
        # the state a sequence ends with carries on: ticks 0-1, then 2-4 from their state,
        # are the five ticks at once (what a window's burn-in relies on)
        _, _, after_two = model.sequence(x[:, :2], model.initial_state(3))
        rest, _, _ = model.sequence(x[:, 2:], after_two)
        torch.testing.assert_close(rest, pred[:, 2:], atol=1e-5, rtol=0)
        fresh, _, _ = model.sequence(x[:, 2:], model.initial_state(3))
        assert not torch.allclose(pred[:, 2:], fresh, atol=1e-4)     # the state mattered
        assert ((aux[..., :2] >= 0) & (aux[..., :2] <= 1)).all()
        # one tick from the initial state: the first tick of the sequence, whichever way in
        torch.testing.assert_close(model.predict_loss_space(x[:, 0]), pred[:, 0],
                                   atol=1e-5, rtol=0)
        torch.testing.assert_close(model(x[:, 0]), steps[0], atol=1e-5, rtol=0)
    plain = ERP("nav", 2, 32)
    assert plain.state_size == 0 and plain.initial_state(2).shape == (2, 0)


def test_the_recurrent_step_freezes_to_the_same_ticks():
    torch.manual_seed(1)
    model = ERP("nav", 5, 32, memory="gru").eval()
    x0, h0 = torch.zeros(1, 5, 32, 32), model.initial_state()
    run, used, why = inference_graph(step_module(model), (x0, h0), "frozen")
    assert (used, why) == ("frozen", None)
    gen = torch.Generator().manual_seed(2)
    eager_h = frozen_h = h0
    with torch.inference_mode():
        for _ in range(4):
            x = torch.rand(1, 5, 32, 32, generator=gen)
            ye, eager_h = model.step(x, eager_h)
            yf, frozen_h = run(x, frozen_h)
            torch.testing.assert_close(yf, ye, atol=1e-5, rtol=0)
        torch.testing.assert_close(frozen_h, eager_h, atol=1e-5, rtol=0)


@pytest.fixture(scope="module")
def remember_data(tmp_path_factory):
    """The square shows in an episode's first 2 of 12 frames; the action is where it was."""
    return make_dataset(tmp_path_factory.mktemp("remember"), episodes=64, frames=12,
                        target="remember", truth=True, height=16, width=16)


def test_memory_learns_what_a_memoryless_policy_cannot(remember_data, tmp_path):
    """Both on the same lanes of ticks (the target head on, so the memoryless model trains
    on sequences too); only the state differs. A 16 px input is one patch, whose linear
    projection can locate the square: what is left to learn is to remember it."""
    losses = {}
    for memory in ("none", "gru"):
        cfg = train(remember_data, tmp_path / memory, "nav", ["event"], epochs=30, lr=3e-3,
                    patience=100, norm=Normalisation(size=16), memory=memory,
                    aux_weight=0.1, seq_len=12, lanes=8, **QUIET)["event"]
        losses[memory] = cfg["training"]["best_val_loss"]
        assert cfg["memory"] == memory and cfg["aux"] is True
        assert cfg["training"]["recipe"] == {"memory": memory, "aux_weight": 0.1,
                                             "modality_dropout": 0.0, "seq_len": 12,
                                             "lanes": 8, "burn_in": 6}
    assert losses["gru"] < 0.2 * losses["none"], losses


def test_a_recurrent_checkpoint_loads_with_its_state_and_an_edited_config_is_refused(
        tmp_path):
    torch.manual_seed(0)
    model = ERP("nav", 2, 32, memory="gru", aux=True)
    pt = save_checkpoint(model, model_config("nav", "event", Normalisation(32), memory="gru",
                                             aux=True), tmp_path)
    loaded, cfg, _ = load_checkpoint(pt)
    assert loaded.memory == "gru" and loaded.aux and cfg["memory"] == "gru"
    x = torch.rand(1, 2, 32, 32)
    with torch.no_grad():
        torch.testing.assert_close(loaded.step(x, loaded.initial_state())[0],
                                   model.eval().step(x, model.initial_state())[0])
    js = pt.with_suffix(".json")
    edited = json.loads(js.read_text())
    edited["memory"] = "none"
    js.write_text(json.dumps(edited))
    with pytest.raises(CheckpointError, match="memory is 'none' in nav-event.json, but the "
                                              "weights were saved with memory 'gru'"):
        load_checkpoint(pt)
    edited["memory"] = "lstm"
    js.write_text(json.dumps(edited))
    with pytest.raises(CheckpointError, match="memory"):
        load_checkpoint(pt)


def test_a_config_without_the_new_fields_is_the_papers_model(tmp_path):
    pt = save_checkpoint(ERP("nav", 2, 32), model_config("nav", "event", Normalisation(32)),
                         tmp_path)
    js = pt.with_suffix(".json")
    cfg = json.loads(js.read_text())
    del cfg["memory"], cfg["aux"]
    js.write_text(json.dumps(cfg))
    model, _, _ = load_checkpoint(pt)
    assert model.memory == "none" and not model.aux and model.state_size == 0


def test_windows_hold_every_tick_once_each_with_the_ticks_before_it_as_burn_in(tmp_path):
    data = make_dataset(tmp_path, episodes=5, frames=7, height=16, width=16)
    frames = EpisodeFrames(data, load_index(data, "nav"), "nav", "event",
                           Normalisation(size=16))
    plain = WindowBatches(frames, lanes=2, length=3, burn_in=2)
    batches = list(plain)
    assert len(batches) == len(plain) == 8            # 5 episodes x 3 windows, 2 a batch
    burn, burn_valid, x, y, truth, mask = batches[0]
    assert burn.shape == (2, 2, 2, 16, 16) and x.shape == (2, 3, 2, 16, 16)
    assert y.shape == (2, 3, 2) and truth.shape == (2, 3, 3)
    # in index order: episode 0's windows at ticks 0 and 3; the second's burn-in is 1, 2
    assert not burn_valid[0].any() and burn_valid[1].all()
    for t in range(3):
        np.testing.assert_array_equal(x[0, t].numpy(), frames[t][0])
        np.testing.assert_array_equal(x[1, t].numpy(), frames[3 + t][0])
    for t in range(2):
        np.testing.assert_array_equal(burn[1, t].numpy(), frames[1 + t][0])
    # the episode's last window: one tick and padding; its burn-in the two before it
    last = batches[1]
    assert last[5][0].tolist() == [True, False, False] and last[1][0].all()
    assert sum(int(b[5].sum()) for b in batches) == 35    # every tick once
    # shuffled, seeded: every tick still once, and the same seed the same batches
    gen = torch.Generator().manual_seed(0)
    shuffled = list(WindowBatches(frames, lanes=2, length=3, generator=gen, burn_in=2))
    assert sum(int(b[5].sum()) for b in shuffled) == 35
    again = next(iter(WindowBatches(frames, lanes=2, length=3, burn_in=2,
                                  generator=torch.Generator().manual_seed(0))))
    torch.testing.assert_close(again[2], shuffled[0][2])
    assert not all(torch.equal(a[2], b[2]) for a, b in zip(shuffled, batches))


def test_padding_leaves_the_state_as_it_was():
    torch.manual_seed(0)
    model = ERP("nav", 2, 32, memory="gru").eval()
    x = torch.rand(2, 4, 2, 32, 32)
    valid = torch.tensor([[False, False, True, True], [True, True, True, True]])
    with torch.no_grad():
        _, _, padded = model.sequence(x, model.initial_state(2), valid=valid)
        _, _, tail = model.sequence(x[:1, 2:], model.initial_state(1))
    torch.testing.assert_close(padded[:1], tail, atol=1e-6, rtol=0)


def test_modality_dropout_takes_one_stream_of_a_lane():
    x = torch.ones(400, 2, 5, 4, 4)
    ModalityDropout(1.0).apply(x, torch.Generator().manual_seed(0))
    rgb_gone = (x[:, :, :3] == 0).all(dim=(1, 2, 3, 4))
    events_gone = (x[:, :, 3:] == 0).all(dim=(1, 2, 3, 4))
    assert bool((rgb_gone ^ events_gone).all())          # one, never both, never neither
    assert 150 < int(rgb_gone.sum()) < 250
    y = torch.ones(10, 2, 5, 4, 4)
    ModalityDropout(0.0).apply(y, torch.Generator().manual_seed(0))
    assert bool((y == 1).all())
    with pytest.raises(ValueError, match="modality_dropout must be in"):
        ModalityDropout(1.5)


@pytest.mark.parametrize("changes, match", [
    ({"memory": "lstm"}, "unknown memory 'lstm'"),
    ({"aux_weight": float("nan")}, "aux_weight must be a finite number"),
    ({"modality_dropout": 0.3}, "modality dropout needs two streams"),
    ({"seq_len": 0}, "seq_len and lanes must be >= 1"),
    ({"burn_in": -1}, "burn_in >= 0")])
def test_recipe_options_out_of_place_are_refused(changes, match):
    s = TrainSettings("nav", lr=1e-3, weight_decay=0.0, loss="mse", **changes)
    with pytest.raises(ValueError, match=match):
        check_recipe(s, Modality.EVENT)


def test_target_truth_is_the_centroid_as_a_fraction_and_visibility(remember_data, tmp_path):
    entry = load_index(remember_data, "nav")[0]
    truth = target_truth(remember_data / entry["file"])
    assert truth.shape == (12, 3) and truth.dtype == np.float32
    assert truth[:2, 2].tolist() == [1.0, 1.0] and truth[2:, 2].sum() == 0
    assert ((truth[:2, :2] > 0) & (truth[:2, :2] < 1)).all() and (truth[2:, :2] == 0).all()
    bare = make_dataset(tmp_path, episodes=2, frames=3, height=16, width=16)
    file = load_index(bare, "nav")[0]["file"]
    with pytest.raises(ValueError, match="no truth/centroid or truth/visible: the target head"):
        target_truth(bare / file)


def test_the_target_head_learns_where_the_target_is(tmp_path):
    data = make_dataset(tmp_path / "d", episodes=16, frames=12, truth=True, height=16,
                        width=16)
    said = []
    train(data, tmp_path / "ck", "nav", ["rgb"], epochs=12, lr=3e-3, patience=100,
          norm=Normalisation(size=16), aux_weight=1.0, seq_len=6, lanes=4,
          progress=False, log=said.append)
    heads = [float(line.split("target head train ")[1].split()[0]) for line in said
             if "target head train" in line]
    assert len(heads) == 12 and heads[-1] < 0.5 * heads[0], heads


def _recurrent_checkpoints(tmp_path):
    torch.manual_seed(0)
    for m in ("rgb", "event"):
        save_checkpoint(ERP("nav", channels(m), 32, memory="gru"),
                        model_config("nav", m, Normalisation(32), memory="gru"), tmp_path)
    return tmp_path


def test_policy_set_steps_its_state_and_reset_forgets_it(tmp_path):
    policies = PolicySet({"event": _recurrent_checkpoints(tmp_path) / "nav-event.pt"})
    assert policies.recurrent == ["event"]
    ev = np.random.default_rng(0).integers(0, 5, (2, 32, 32), dtype=np.uint8)
    first = policies.act("event", events=ev)[0]
    second = policies.act("event", events=ev)[0]
    assert not np.allclose(first, second)     # the same frame, another state
    policies.reset()
    np.testing.assert_array_equal(policies.act("event", events=ev)[0], first)


def test_the_actor_starts_the_state_afresh_per_episode_and_at_a_swap(tmp_path):
    ckpts = _recurrent_checkpoints(tmp_path)
    node = _Node()
    actor = Policy("policy", Policy.Params(directory=str(ckpts), modalities=["rgb", "event"],
                                           modality="event"),
                   connected=frozenset({"rgb", "events"}), node=node)
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, (32, 32, 3), dtype=np.uint8)
    ev = rng.integers(0, 5, (2, 32, 32), dtype=np.uint8)

    def tick(t, episode):
        for stream, array in (("rgb", rgb), ("events", ev)):
            msg = _msg(stream, t, array)
            msg.meta["episode"] = episode
            yield stream, msg

    async def scenario():
        await actor.setup()
        for t, episode in enumerate((0, 0, 0, 1, 1, 1)):
            for stream, msg in tick(t, episode):
                await (actor.on_rgb if stream == "rgb" else actor.on_events)(msg)
        await actor.control("modality", "rgb")
        await actor.control("modality", "event")
        for stream, msg in tick(6, 1):
            await (actor.on_rgb if stream == "rgb" else actor.on_events)(msg)

    asyncio.run(scenario())
    actions = np.stack([a["action"] for _, _, a in node.sent])
    assert len(actions) == 7
    np.testing.assert_array_equal(actions[3:6], actions[0:3])    # episode 1 as episode 0
    assert not np.allclose(actions[0], actions[1])
    np.testing.assert_array_equal(actions[6], actions[0])         # the swap back reset it
    stats = actor.stats()
    assert stats["state_resets"] == {"episode": 2, "swap": 2}
    assert stats["memory"] == {"rgb": "gru", "event": "gru"}
    swaps = [f for k, f in node.events if k == "modality_swap"]
    assert all(s["state_reset"] for s in swaps)


def test_a_voxel_grid_is_refused_at_the_policy_input_not_read_as_counts():
    from sebvs.policy.inputs import event_input
    voxel = np.full((2, 16, 16), -1.0, np.float32)
    with pytest.raises(ValueError, match="a voxel grid cannot feed an ERP policy"):
        event_input(voxel, Normalisation(size=16))


def test_a_time_surface_dataset_trains_with_its_values_unclipped(tmp_path):
    import h5py

    from tests.policy_data import reindex
    data = make_dataset(tmp_path / "d", episodes=3, frames=4, height=16, width=16)
    for entry in load_index(data, "nav", verify=False):
        with h5py.File(data / entry["file"], "r+") as f:
            f.attrs["event_representation"] = "time_surface"
    reindex(data)
    cfg = train(data, tmp_path / "ck", "nav", ["event"], epochs=1,
                norm=Normalisation(size=16), **QUIET)["event"]
    assert cfg["normalisation"]["event_clip"] == 255
    assert cfg["event_frames"]["representation"] == "time_surface"


def test_a_sweep_takes_the_recipe_options_as_settings():
    from sebvs.policy.sweep import resolved_settings, train_overrides
    from sebvs.policy.sweep_grid import SETTINGS
    assert SETTINGS["memory"]("gru") == "gru"
    with pytest.raises(ValueError, match="expected one of none, gru"):
        SETTINGS["memory"]("lstm")
    with pytest.raises(ValueError, match="between 0 and 1"):
        SETTINGS["modality_dropout"](1.5)
    point = {"modality": "event", "memory": "gru", "aux_weight": 0.5, "seq_len": 4}
    assert train_overrides(point, 1, "cpu")["memory"] == "gru"
    resolved = resolved_settings("nav", point)
    assert (resolved["memory"], resolved["aux_weight"], resolved["seq_len"],
            resolved["lanes"], resolved["burn_in"]) == ("gru", 0.5, 4, 32, 6)


def test_the_burn_in_carries_what_a_window_cannot_see(remember_data, tmp_path):
    """Windows of 4 ticks: after the first, none shows the square; the 8 ticks of burn-in
    before a window hold it, and the state they leave is all the window can go on."""
    losses = {}
    for burn_in in (0, 8):
        cfg = train(remember_data, tmp_path / str(burn_in), "nav", ["event"], epochs=30,
                    lr=3e-3, patience=100, norm=Normalisation(size=16), memory="gru",
                    aux_weight=0.1, seq_len=4, lanes=8, burn_in=burn_in, **QUIET)["event"]
        losses[burn_in] = cfg["training"]["best_val_loss"]
    assert losses[8] < 0.2 * losses[0], losses
