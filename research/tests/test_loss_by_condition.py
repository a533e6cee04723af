"""research/sensors/loss_by_condition.py: a checkpoint's validation loss per scene setting,
beside what a constant prediction scores on the same frames."""
import json

import pytest

from sebvs.policy.inputs import Normalisation
from sebvs.policy.train import train
from tests.policy_data import copy_without, make_dataset
from research.tests.study_loader import study_module
from tests.tools_loader import tool_module


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A nav dataset whose episodes alternate two lightings, and a checkpoint trained on it
    for a few epochs on a target it can see (the square's brightness)."""
    root = tmp_path_factory.mktemp("loss_by_condition")
    data = make_dataset(root / "data", episodes=10, frames=16, target="gain")
    index = json.loads((data / "index.json").read_text())
    for k, e in enumerate(index["episodes"]):
        e["conditions"] = {"lighting": ("nominal", "hdr")[k % 2], "variant": "indoor"}
    (data / "index.json").write_text(json.dumps(index))
    train(data, root / "ckpt", "nav", ["rgb"], epochs=4, batch=8, val_fraction=0.4,
          norm=Normalisation(size=32), progress=False, log=lambda s: None)
    return data, root / "ckpt" / "nav-rgb.pt"


def test_each_group_has_its_loss_the_constants_and_the_skill(trained, tmp_path):
    import torch
    data, pt = trained
    record = json.loads(pt.with_suffix(".json").read_text())
    val = set(record["dataset"]["val_episodes"])
    index = json.loads((data / "index.json").read_text())["episodes"]
    expect = {}
    for e in index:
        if e["file"] in val:
            expect.setdefault(f"{e['conditions']['lighting']}/indoor", []).append(e["file"])
    with study_module("sensors/loss_by_condition") as tool, \
            tool_module("eval/val_loss") as val_loss:
        out = tmp_path / "r.json"
        assert tool.main([str(data), str(pt), "--json", str(out),
                          "--plot", str(tmp_path / "r.png")]) == 0
        result = json.loads(out.read_text())["results"][0]
        groups = result["groups"]
        assert set(groups) == set(expect)
        for group, files in expect.items():
            g = groups[group]
            assert g["episodes"] == len(files) and g["frames"] == 16 * len(files)
            assert g["skill"] == pytest.approx(1 - g["loss"] / g["constant_loss"])
        # the groups' losses, weighted by their frames, are the checkpoint's whole
        # validation loss (the loss training recorded for its best epoch, here the last)
        total = sum(g["loss"] * g["frames"] for g in groups.values()) / \
            sum(g["frames"] for g in groups.values())
        assert total == pytest.approx(val_loss.recompute(pt, data)["val_loss_now"], rel=1e-6)
        # the constant is the training targets' mean: its loss is their spread about it
        model, cfg, norm, _ = val_loss.validation_of(pt, data)
        constant = tool.constant_of(model, cfg, norm, data)
        train_files = [e for e in index if e["file"] in set(record["dataset"]["train_episodes"])]
        frames = val_loss.frames_of(data, train_files, cfg, norm)
        assert torch.allclose(constant, torch.from_numpy(frames.targets()).mean(dim=0))
        frames.close()
    assert (tmp_path / "r.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_constant_model_has_no_skill(trained, monkeypatch):
    """A model that always answers the training targets' mean scores skill 0 in every
    group: the baseline is what it claims to be."""
    import torch
    data, pt = trained
    with study_module("sensors/loss_by_condition") as tool:
        model, cfg, norm, episodes = tool.validation_of(pt, data)
        constant = tool.constant_of(model, cfg, norm, data)

        class Constant(torch.nn.Module):
            def predict_loss_space(self, x):
                return constant.expand(len(x), -1)

            def loss_space(self, y):
                return y

        monkeypatch.setattr(tool, "validation_of",
                            lambda p, d: (Constant(), cfg, norm, episodes))
        result = tool.measure(data, pt, ["lighting"])
    assert len(result["groups"]) == 2
    for g in result["groups"].values():
        assert g["skill"] == pytest.approx(0.0, abs=1e-6) and g["constant_loss"] > 0


def test_a_dataset_without_the_training_episodes_is_refused(trained, tmp_path, capsys):
    data, pt = trained
    trained_on = json.loads(pt.with_suffix(".json").read_text())["dataset"]["train_episodes"]
    short = copy_without(data, tmp_path / "short", trained_on[0])
    with study_module("sensors/loss_by_condition") as tool:
        assert tool.main([str(short), str(pt)]) == 2
    assert f"lacks 1 of the checkpoint's training episodes ({trained_on[0]})" in \
        capsys.readouterr().err


def test_a_held_out_recording_is_measured_whole_and_must_be_held_out(trained, tmp_path,
                                                                       capsys):
    data, pt = trained
    other = make_dataset(tmp_path / "other", episodes=3, frames=16, target="gain", seed=7)
    with study_module("sensors/loss_by_condition") as tool:
        out = tmp_path / "r.json"
        assert tool.main([str(other), str(pt), "--held-out-from", str(data), "--by", "scene",
                          "--json", str(out)]) == 0
        result = json.loads(out.read_text())["results"][0]
        assert result["on"] == "held-out"
        assert list(result["groups"]) == ["-"]          # no conditions in these episodes
        assert result["groups"]["-"]["episodes"] == 3 and result["groups"]["-"]["frames"] == 48
        # the training recording itself is not held out from itself
        assert tool.main([str(data), str(pt), "--held-out-from", str(data)]) == 2
    assert "episodes have the seed of one in" in capsys.readouterr().err


def test_ablating_the_part_a_policy_reads_costs_its_skill(tmp_path):
    """A two-stream nav policy whose target shows in the frame's brightness: mean-ablating
    the frame takes its skill away, ablating the event planes (which a "gain" target does
    not need) costs little; a one-stream policy has nothing to ablate beside another."""
    data = make_dataset(tmp_path / "data", episodes=10, frames=16, target="gain")
    train(data, tmp_path / "ckpt", "nav", ["rgb+event", "rgb"], epochs=6, batch=8,
          val_fraction=0.4, norm=Normalisation(size=32), progress=False, log=lambda s: None)
    pt = tmp_path / "ckpt" / "nav-rgb+event.pt"
    with study_module("sensors/loss_by_condition") as tool:
        whole, no_rgb, no_events = (tool.measure(data, pt, ["scene"], ablate=a)["groups"]["-"]
                                    for a in (None, "rgb", "second"))
        assert whole["skill"] > 0.3
        assert no_rgb["skill"] < whole["skill"] - 0.3
        assert no_events["skill"] > whole["skill"] - 0.1
        assert no_rgb["constant_loss"] == whole["constant_loss"]
        _, cfg, _, _ = tool.validation_of(pt, data)
        assert tool.ablated_channels(cfg, "rgb") == [0, 1, 2]
        assert tool.ablated_channels(cfg, "second") == [3, 4]
        assert tool.main([str(data), str(tmp_path / "ckpt" / "nav-rgb.pt"),
                          "--ablate", "second"]) == 2


def test_a_recurrent_checkpoint_is_ablated_on_its_windows(tmp_path):
    """A recipe checkpoint (GRU, windows of ticks with a burn-in) is measured as it was
    validated, on windows; the ablated frames feed those windows, burn-in included."""
    data = make_dataset(tmp_path / "data", episodes=8, frames=12, target="gain")
    train(data, tmp_path / "ckpt", "nav", ["rgb+event"], epochs=4, batch=8,
          val_fraction=0.4, norm=Normalisation(size=32), progress=False, log=lambda s: None,
          memory="gru", seq_len=2, lanes=4, burn_in=2)
    pt = tmp_path / "ckpt" / "nav-rgb+event.pt"
    with study_module("sensors/loss_by_condition") as tool, \
            tool_module("eval/val_loss") as val_loss:
        _, cfg, _, _ = tool.validation_of(pt, data)
        assert cfg["training"]["recipe"]["memory"] == "gru"
        whole, no_rgb = (tool.measure(data, pt, ["scene"], ablate=a)["groups"]["-"]
                         for a in (None, "rgb"))
        assert whole["loss"] == pytest.approx(val_loss.recompute(pt, data)["val_loss_now"],
                                              rel=1e-6)
        assert no_rgb["frames"] == whole["frames"] and no_rgb["loss"] > whole["loss"]


def test_ablation_levels_are_the_channels_mean_and_parse_as_the_actors_parameter(tmp_path,
                                                                                 capsys):
    """research/sensors/ablation_levels.py: the event channels' mean over the validation
    frames, as the offline ablation holds them, and a --set the policy actor takes."""
    import numpy as np

    from sebvs.runtime.topology import parse_override
    data = make_dataset(tmp_path / "data", episodes=6, frames=8, target="gain")
    train(data, tmp_path / "ckpt", "nav", ["rgb+event", "rgb"], epochs=1, batch=8,
          val_fraction=0.4, norm=Normalisation(size=32), progress=False, log=lambda s: None)
    pt = tmp_path / "ckpt" / "nav-rgb+event.pt"
    with study_module("sensors/ablation_levels") as tool, \
            tool_module("eval/val_loss") as val:
        levels = tool.levels_of(data, pt)
        assert levels["channels"] == [3, 4] and levels["modality"] == "rgb+event"
        _, cfg, norm, episodes = val.validation_of(pt, data)
        frames = val.frames_of(data, episodes, cfg, norm)
        mean = np.mean([frames[i][0][[3, 4]].mean(axis=(1, 2)) for i in range(len(frames))],
                       axis=0)
        frames.close()
        np.testing.assert_allclose(levels["levels"], mean, rtol=1e-5)
        parts, value = parse_override(tool.override(levels))
        assert parts == ["policy", "ablate"]
        assert value == {"rgb+event": {"channels": [3, 4], "levels": levels["levels"]}}
        assert tool.main([str(data), str(pt), "--json", str(tmp_path / "l.json")]) == 0
        assert "--set 'policy.ablate=" in capsys.readouterr().out
        assert json.loads((tmp_path / "l.json").read_text()) == levels
        assert tool.main([str(data), str(tmp_path / "ckpt" / "nav-rgb.pt")]) == 2
        assert "no 'second' part" in capsys.readouterr().err
