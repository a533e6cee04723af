"""research/ideal8/copycat.py: the scores tell a policy that copies the previous command from one
that predicts the next; the command line scores a checkpoint on its own validation
episodes and refuses another dataset's by name."""
import json

import numpy as np
import pytest
import torch

from sebvs.policy.inputs import Normalisation
from sebvs.policy.train import train
from tests.policy_data import make_dataset
from research.tests.study_loader import study_module

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def tool():
    with study_module("ideal8/copycat") as module:
        yield module


def smooth_labels(rng, episodes=4, ticks=200):
    """Random walks in [v, w]: each tick's label is the last one plus a small step."""
    return [np.cumsum(rng.normal(0, 0.03, (ticks, 2)), axis=0) for _ in range(episodes)]


def test_a_copycat_matches_the_previous_label_and_not_its_change(tool):
    rng = np.random.default_rng(0)
    labels = smooth_labels(rng)
    copycat = [np.vstack([x[:1], x[:-1]]) + rng.normal(0, 1e-3, x.shape) for x in labels]
    s = tool.copy_scores(labels, copycat)
    assert s["ticks"] == 4 * 199
    assert all(r > 0.99 for r in s["r2_prev"])
    assert all(abs(c) < 0.15 for c in s["innovation"])
    assert all(a < b for a, b in zip(s["r2_label"], s["r2_prev"]))
    assert s["copy_mse"] == pytest.approx(s["mse"], rel=0.05)


def test_an_oracle_predicts_the_change(tool):
    rng = np.random.default_rng(1)
    labels = smooth_labels(rng)
    oracle = [x + rng.normal(0, 0.005, x.shape) for x in labels]
    s = tool.copy_scores(labels, oracle)
    assert all(r > 0.99 for r in s["r2_label"])
    assert all(c > 0.9 for c in s["innovation"])
    assert s["mse"] < 0.1 * s["copy_mse"]
    with pytest.raises(ValueError, match="two or more"):
        tool.copy_scores([labels[0][:1]], [oracle[0][:1]])


def test_command_line_scores_validation_episodes_and_refuses_another_dataset(tool, tmp_path,
                                                                            capsys):
    data = make_dataset(tmp_path / "d", episodes=5, frames=12)
    train(data, tmp_path / "ck", "nav", ["event"], epochs=1, batch=8, lr=1e-3, patience=1,
          norm=Normalisation(size=32), progress=False, log=lambda s: None)
    pt = tmp_path / "ck" / "nav-event.pt"
    val = json.loads((tmp_path / "ck" / "nav-event.json").read_text())["dataset"]["val_episodes"]
    out = tmp_path / "copy.json"
    assert tool.main([str(data), str(pt), "--by", "", "--threads", "1", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [(r["modality"], r["group"], r["episodes"], r["ticks"]) for r in rows] == \
        [("event", "all", len(val), 11 * len(val))]
    assert "nav-event.pt" in capsys.readouterr().out
    other = make_dataset(tmp_path / "other", episodes=2, frames=12, seed=3)
    with pytest.raises(SystemExit, match="not .*other.*--episodes all"):
        tool.main([str(other), str(pt), "--threads", "1"])
    assert tool.main([str(other), str(pt), "--episodes", "all", "--threads", "1"]) == 0


def test_a_recurrent_checkpoint_is_run_with_its_state(tool, tmp_path):
    """The outputs are the actor's: each tick stepped from the state the ticks before it
    left, not a tick with nothing remembered."""
    from sebvs.data.episode import open_episode
    from sebvs.policy.checkpoint import load_checkpoint
    from sebvs.policy.inputs import model_input
    data = make_dataset(tmp_path / "d", episodes=4, frames=12)
    train(data, tmp_path / "ck", "nav", ["event"], epochs=1, batch=8, lr=1e-3, patience=1,
          norm=Normalisation(size=32), progress=False, log=lambda s: None,
          memory="gru", seq_len=2, lanes=4, burn_in=2)
    model, cfg, norm = load_checkpoint(tmp_path / "ck" / "nav-event.pt")
    path = sorted(data.glob("episode_*.h5"))[0]
    with open_episode(path) as ep:
        out = tool.run_policy(model, "event", norm, ep)
        x = torch.from_numpy(np.stack([model_input("event", norm, events=e)
                                       for e in ep.event_frame[:]]))
    with torch.no_grad():
        stepped, _, _ = model.sequence(x[None], model.initial_state(1))
        alone = model(x).numpy()
    np.testing.assert_allclose(out, stepped[0].numpy(), atol=1e-5)
    assert not np.allclose(out[1:], alone[1:], atol=1e-5)      # the state mattered
