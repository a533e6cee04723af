"""tools/eval/val_loss.py: a checkpoint tells whether a dataset holds the validation
frames it was trained on."""
import json

import h5py
import pytest

from sebvs.policy.inputs import Normalisation
from sebvs.policy.train import train
from tests.policy_data import copy_without, make_dataset, reindex
from tests.tools_loader import tool_module


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("val_loss")
    data = make_dataset(root / "data", episodes=5, frames=16, target="gain")
    train(data, root / "ckpt", "nav", ["rgb+event"], epochs=2, batch=8,
          norm=Normalisation(size=32), progress=False, log=lambda s: None)
    return data, root / "ckpt" / "nav-rgb+event.pt"


def test_the_same_frames_give_the_recorded_loss(trained, tmp_path):
    data, pt = trained
    with tool_module("eval/val_loss") as tool:
        out = tmp_path / "r.json"
        assert tool.main([str(pt), str(data), "--json", str(out)]) == 0
        result = json.loads(out.read_text())
    assert result["same"] and result["val_loss_now"] == result["val_loss_recorded"]
    assert result["val_frames"] == 16                     # one of five episodes held out


def test_one_changed_validation_frame_is_seen(trained, tmp_path):
    import shutil
    data, pt = trained
    changed = tmp_path / "changed"
    shutil.copytree(data, changed)
    val = json.loads(pt.with_suffix(".json").read_text())["dataset"]["val_episodes"]
    with h5py.File(changed / val[0], "r+") as f:
        f["events/frame"][3] = f["events/frame"][3] + 1   # one frame's event counts
    reindex(changed)            # a recording that differs, not a damaged one
    with tool_module("eval/val_loss") as tool:
        out = tmp_path / "r.json"
        assert tool.main([str(pt), str(changed), "--json", str(out)]) == 1
        assert json.loads(out.read_text())["relative_difference"] > 1e-6


def test_a_dataset_without_the_validation_episodes_is_refused(trained, tmp_path, capsys):
    data, pt = trained
    val = json.loads(pt.with_suffix(".json").read_text())["dataset"]["val_episodes"]
    short = copy_without(data, tmp_path / "short", val[0])
    with tool_module("eval/val_loss") as tool:
        assert tool.main([str(pt), str(short)]) == 2
        assert f"lacks 1 of the checkpoint's validation episodes ({val[0]})" in \
            capsys.readouterr().err
        assert tool.main([str(tmp_path / "none.pt"), str(data)]) == 2
        assert "none" in capsys.readouterr().err


def test_a_recipe_checkpoint_recomputes_its_loss_on_its_lanes(tmp_path):
    """A checkpoint trained on lanes of ticks (a GRU's state carried) validates on them
    again: the recorded loss, exactly, not a per-frame loss from the empty state."""
    data = make_dataset(tmp_path / "data", episodes=5, frames=16, target="gain")
    train(data, tmp_path / "ckpt", "nav", ["event"], epochs=2, memory="gru", seq_len=4,
          lanes=2, norm=Normalisation(size=32), progress=False, log=lambda s: None)
    with tool_module("eval/val_loss") as tool:
        out = tmp_path / "r.json"
        assert tool.main([str(tmp_path / "ckpt" / "nav-event.pt"), str(data),
                          "--json", str(out)]) == 0
        result = json.loads(out.read_text())
    assert result["same"] and result["val_loss_now"] == result["val_loss_recorded"]


def test_a_checkpoint_of_two_datasets_takes_both_in_its_order(tmp_path, capsys):
    """A DAgger round's checkpoint is trained on the expert's recording and the round's:
    its validation episodes come from both, the second's named by their absolute path."""
    first = make_dataset(tmp_path / "expert", episodes=5, frames=16, target="gain")
    second = make_dataset(tmp_path / "round-1", episodes=5, frames=16, target="gain", seed=7)
    train([first, second], tmp_path / "ckpt", "nav", ["event"], epochs=1, batch=8,
          norm=Normalisation(size=32), progress=False, log=lambda s: None)
    pt = tmp_path / "ckpt" / "nav-event.pt"
    val = json.loads(pt.with_suffix(".json").read_text())["dataset"]["val_episodes"]
    assert any(name.startswith("/") for name in val)      # this split draws from both
    with tool_module("eval/val_loss") as tool:
        out = tmp_path / "r.json"
        assert tool.main([str(pt), str(first), str(second), "--json", str(out)]) == 0
        result = json.loads(out.read_text())
        assert result["same"] and result["val_loss_now"] == result["val_loss_recorded"]
        assert tool.main([str(pt), str(first)]) == 2
        assert "lacks" in capsys.readouterr().err
