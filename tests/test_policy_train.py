"""Behaviour-cloning training on tiny synthetic datasets: learning, determinism, the split,
the lazy dataset and the `sebvs train` command."""
import csv
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from sebvs.cli import main
from sebvs.policy.checkpoint import checkpoints_in
from sebvs.policy.dataset import EpisodeFrames, load_index, split_episodes
from sebvs.policy.inputs import Normalisation
from sebvs.policy.train import train
from tests.policy_data import make_dataset

torch.set_num_threads(1)
QUIET = dict(progress=False, log=lambda s: None)


@pytest.fixture(scope="module")
def gain_data(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("gain"), episodes=6, frames=32, target="gain")


def test_training_reduces_validation_loss(gain_data, tmp_path):
    res = train(gain_data, tmp_path, "nav", ["rgb+event"], epochs=4, batch=8, lr=1e-3,
                patience=10, norm=Normalisation(size=32), **QUIET)
    with open(tmp_path / "nav-rgb+event-losses.csv") as f:
        rows = list(csv.DictReader(f))
    val = [float(r["val_loss"]) for r in rows]
    assert len(val) == 4
    assert min(val[1:]) < 0.5 * val[0], val
    cfg = json.loads((tmp_path / "nav-rgb+event.json").read_text())
    assert cfg == {"version": 1, **res["rgb+event"]}
    assert cfg["training"]["best_val_loss"] == pytest.approx(min(val))
    assert cfg["channels"] == 5 and cfg["channel_order"] == ["r", "g", "b", "on", "off"]
    assert cfg["normalisation"]["event_clip"] == 8 and len(cfg["dataset"]["hash"]) == 64
    assert (tmp_path / "nav-losses.png").stat().st_size > 5000


def test_same_seed_same_weights(gain_data, tmp_path):
    kw = dict(epochs=2, batch=8, max_frames=48, norm=Normalisation(size=32), **QUIET)
    train(gain_data, tmp_path / "a", "nav", ["event"], seed=3, **kw)
    train(gain_data, tmp_path / "b", "nav", ["event"], seed=3, **kw)
    train(gain_data, tmp_path / "c", "nav", ["event"], seed=4, **kw)
    a, b, c = (torch.load(tmp_path / d / "nav-event.pt", weights_only=True) for d in "abc")
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not all(torch.equal(a[k], c[k]) for k in a)


@pytest.mark.parametrize("modality", ["rgb+diff", "rgb+event"])
def test_frames_in_memory_and_loader_workers_train_the_same_weights(gain_data, tmp_path,
                                                                   modality):
    """The input pipeline changes where the frames come from, not what they are: read item by
    item from the files in the training process, or read whole into memory and served by
    two forked DataLoader workers, the weights are the same bit for bit."""
    kw = dict(epochs=2, batch=8, max_frames=64, seed=1, norm=Normalisation(size=32), **QUIET)
    said = []
    train(gain_data, tmp_path / "files", "nav", [modality], cache="none", num_workers=0, **kw)
    train(gain_data, tmp_path / "memory", "nav", [modality], cache="memory", num_workers=2,
          **dict(kw, log=said.append))
    a, b = (torch.load(tmp_path / d / f"nav-{modality}.pt", weights_only=True)
            for d in ("files", "memory"))
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert any(line.startswith("  frames in memory: ") for line in said), said


class StopHere(Exception):
    """Stands for a killed training: raised from the log line of an epoch."""


def stop_in_epoch(n: int):
    """A training's log that stops it at epoch n's line (as a kill in that epoch would:
    the state file then holds epoch n - 1)."""
    def log(line):
        if line.startswith(f"  epoch {n}:"):
            raise StopHere
    return log


def test_a_stopped_training_resumes_to_the_same_weights(gain_data, tmp_path):
    """Stopped in its third epoch, a training goes on after epoch 2 from its state file and
    ends bit for bit where one that never stopped ends: weights, losses and schedule."""
    kw = dict(epochs=4, batch=8, max_frames=48, seed=2, patience=10, progress=False,
              norm=Normalisation(size=32),
              plateau={"factor": 0.5, "patience": 0, "threshold": 1.0, "threshold_mode": "abs"})
    train(gain_data, tmp_path / "whole", "nav", ["rgb+event"], log=lambda s: None, **kw)
    stop_in_epoch_3 = stop_in_epoch(3)
    with pytest.raises(StopHere):
        train(gain_data, tmp_path / "cut", "nav", ["rgb+event"], log=stop_in_epoch_3, **kw)
    state = tmp_path / "cut" / "nav-rgb+event.resume.pt"
    assert state.exists() and not (tmp_path / "cut" / "nav-rgb+event.pt").exists()
    assert checkpoints_in(tmp_path / "cut") == []          # a resume state is not a model
    said = []
    train(gain_data, tmp_path / "cut", "nav", ["rgb+event"], log=said.append, **kw)
    assert "  resuming after epoch 2 (nav-rgb+event.resume.pt)" in said
    assert not any(line.startswith(("  epoch 1:", "  epoch 2:")) for line in said)
    a, b = (torch.load(tmp_path / d / "nav-rgb+event.pt", weights_only=True)
            for d in ("whole", "cut"))
    assert all(torch.equal(a[k], b[k]) for k in a)
    rows = [(tmp_path / d / "nav-rgb+event-losses.csv").read_text() for d in ("whole", "cut")]
    assert rows[0] == rows[1] and ",5e-05" in rows[0]     # the schedule halved the lr twice
    cfg = json.loads((tmp_path / "cut" / "nav-rgb+event.json").read_text())
    assert cfg["training"]["resumed_after_epochs"] == [2] and not state.exists()
    assert checkpoints_in(tmp_path / "cut") == [tmp_path / "cut" / "nav-rgb+event.pt"]

    # a state made by other settings is not continued
    with pytest.raises(StopHere):
        train(gain_data, tmp_path / "other", "nav", ["rgb+event"], log=stop_in_epoch_3, **kw)
    said = []
    train(gain_data, tmp_path / "other", "nav", ["rgb+event"], log=said.append,
          **dict(kw, lr=1e-3, epochs=1))
    assert "  nav-rgb+event.resume.pt: made by other settings or data; training from the " \
           "start" in said
    assert any(line.startswith("  epoch 1:") for line in said)
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "nav-rgb+event.resume.pt").write_bytes(b"not a torch file")
    said = []
    train(gain_data, tmp_path / "bad", "nav", ["rgb+event"], log=said.append,
          **dict(kw, epochs=1))
    assert any("nav-rgb+event.resume.pt: unreadable" in line for line in said), said


def test_preload_holds_the_files_values_and_auto_declines_what_does_not_fit(
        gain_data, tmp_path, monkeypatch):
    from sebvs.policy import train as train_module
    eps = load_index(gain_data)
    norm = Normalisation(size=32)
    lazy = EpisodeFrames(gain_data, eps, "nav", "rgb+diff", norm)
    held = EpisodeFrames(gain_data, eps, "nav", "rgb+diff", norm)
    n = held.preload()
    assert n >= held.frame_bytes() == 6 * 32 * 32 * 32 * 3     # rgb only: diff reads rgb
    assert held.open_episodes() == 0                            # the files are released
    for i in (0, 31, 32, 100, len(lazy) - 1):
        np.testing.assert_array_equal(lazy[i][0], held[i][0])
        np.testing.assert_array_equal(lazy[i][1], held[i][1])
    said = []
    # both sets' frames against half the available memory
    monkeypatch.setattr(train_module, "available_memory", lambda: 4 * held.frame_bytes())
    assert train_module._use_cache("auto", lazy, held, said.append) is True
    monkeypatch.setattr(train_module, "available_memory", lambda: 3 * held.frame_bytes())
    assert train_module._use_cache("auto", lazy, held, said.append) is False
    assert "would take more than 50% of the" in said[0] and "--cache memory" in said[0]
    with pytest.raises(ValueError, match="unknown cache 'disk'"):
        train_module._use_cache("disk", lazy, held, said.append)
    lazy.close()
    held.close()


@pytest.mark.parametrize("modality", ["rgb+diff", "rgb+event"])
def test_preload_of_a_thinned_set_reads_only_the_rows_its_items_use(gain_data, modality):
    eps = load_index(gain_data)
    norm = Normalisation(size=32)
    lazy = EpisodeFrames(gain_data, eps, "nav", modality, norm, max_frames=9)
    held = EpisodeFrames(gain_data, eps, "nav", modality, norm, max_frames=9)
    whole = EpisodeFrames(gain_data, eps, "nav", modality, norm)
    rows = sum(r.size for _, r in held._rows_read())
    # rgb+diff also reads the frame before each item's (none before an episode's first)
    assert (rows > len(held)) == (modality == "rgb+diff") and rows <= 2 * len(held)
    per_frame = 32 * 32 * 3 + (2 * 32 * 32 if modality == "rgb+event" else 0)
    assert held.frame_bytes() == rows * per_frame < whole.frame_bytes() / 4
    n = held.preload()
    assert held.frame_bytes() <= n < held.frame_bytes() + 4096     # + ticks and targets
    for i in range(len(lazy)):
        np.testing.assert_array_equal(lazy[i][0], held[i][0])
        np.testing.assert_array_equal(lazy[i][1], held[i][1])
    with pytest.raises(KeyError, match="frame .* is not held"):
        next(iter(held._cached.values())).rgb[10_000]
    for ds in (lazy, held, whole):
        ds.close()


def test_gated_stem_trains_rgb_event_and_refuses_other_modalities(gain_data, tmp_path):
    kw = dict(epochs=1, batch=8, max_frames=32, norm=Normalisation(size=32), stem="gated",
              **QUIET)
    cfg = train(gain_data, tmp_path, "nav", ["rgb+event"], **kw)["rgb+event"]
    assert cfg["stem"] == "gated" and math.isfinite(cfg["training"]["best_val_loss"])
    # refused before anything trains: --modality all would otherwise leave rgb unfinished
    with pytest.raises(ValueError, match=r"gated stem fuses rgb and event planes: it needs "
                                         r"modality rgb\+event, not rgb"):
        train(gain_data, tmp_path / "all", "nav", ["rgb", "event", "rgb+event"], **kw)
    assert not (tmp_path / "all").exists()
    assert main(["train", "--task", "nav", "--modality", "event", "--stem", "gated",
                 "--data", str(gain_data), "--out", str(tmp_path / "cli")]) == 2


def test_split_is_by_episode_and_seeded(tmp_path):
    eps = [{"file": f"e{i}.h5", "frames": 10} for i in range(10)]
    tr, va = split_episodes(eps, 0.2, seed=1)
    assert len(va) == 2 and len(tr) == 8
    assert not {e["file"] for e in tr} & {e["file"] for e in va}
    assert split_episodes(eps, 0.2, seed=1) == (tr, va)
    assert split_episodes(eps, 0.2, seed=2) != (tr, va)
    with pytest.raises(ValueError, match="at least 2 episodes"):
        split_episodes(eps[:1], 0.2, 0)


def test_dataset_reads_frames_lazily(tmp_path):
    root = make_dataset(tmp_path, episodes=3, frames=5, height=24, width=40, task="arm")
    eps = load_index(root)
    ds = EpisodeFrames(root, eps, "arm", "rgb+event", Normalisation(size=32))
    assert len(ds) == 15 and not ds._handles           # nothing opened yet
    x, y = ds[7]
    assert x.shape == (5, 32, 32) and y.shape == (6,)
    assert list(ds._handles) == [1]                     # only the episode read from
    assert EpisodeFrames(root, eps, "arm", "rgb", Normalisation(size=32), max_frames=4
                         ).episodes_of() == {e["file"] for e in eps}
    ds.close()


def open_files() -> list[str]:
    out = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            out.append(os.readlink(f"/proc/self/fd/{fd}"))
        except OSError:         # the directory listing's own descriptor, gone already
            pass
    return out


def test_dataset_keeps_a_bounded_set_of_episodes_open(tmp_path, monkeypatch):
    import sebvs.policy.dataset as dataset
    monkeypatch.setattr(dataset, "OPEN_EPISODES", 2)
    root = make_dataset(tmp_path, episodes=4, frames=3, task="arm")
    eps = load_index(root)
    ds = EpisodeFrames(root, eps, "arm", "rgb", Normalisation(size=32))
    first = [ds[i][1] for i in range(len(ds))]          # walks all 4 episodes
    assert ds.open_episodes() == 2 and list(ds._handles) == [2, 3]
    # the evicted episodes' files are really closed (released, not just forgotten)
    assert sorted(Path(f).name for f in open_files() if f.startswith(str(root))) == \
        sorted(eps[i]["file"] for i in (2, 3))
    again = [ds[i][1] for i in reversed(range(len(ds)))]  # reopens the evicted ones
    assert all(np.array_equal(a, b) for a, b in zip(first, reversed(again)))
    assert ds.open_episodes() == 2
    ds.close()


def test_episode_block_sampler_shuffles_within_blocks_of_episodes():
    from sebvs.policy.dataset import EpisodeBlockSampler
    episode_of_item = np.repeat(np.arange(10), [3, 1, 4, 2, 5, 3, 1, 2, 6, 3])
    s = EpisodeBlockSampler(episode_of_item, block=3, generator=torch.Generator().manual_seed(0))
    order = list(s)
    assert sorted(order) == list(range(len(episode_of_item))) and len(s) == len(order)
    # episodes in the order they first appear, in groups of 3: each group's items fill one
    # contiguous span of the order (a block), so at most 3 episodes are read at a time
    eps_in_order = list(dict.fromkeys(int(episode_of_item[i]) for i in order))
    where = np.empty(len(order), int)
    where[order] = np.arange(len(order))
    for k in range(0, 10, 3):
        pos = np.sort(where[np.isin(episode_of_item, eps_in_order[k:k + 3])])
        assert pos[-1] - pos[0] + 1 == len(pos)
    again = list(EpisodeBlockSampler(episode_of_item, 3, torch.Generator().manual_seed(0)))
    other = list(EpisodeBlockSampler(episode_of_item, 3, torch.Generator().manual_seed(1)))
    assert again == order and other != order
    assert order != sorted(order)
    with pytest.raises(ValueError, match="block"):
        EpisodeBlockSampler(episode_of_item, 0)


def test_large_training_sets_use_the_block_sampler(tmp_path, monkeypatch):
    import sebvs.policy.train as train_mod
    made = []

    class Spy(train_mod.EpisodeBlockSampler):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)

    monkeypatch.setattr(train_mod, "OPEN_EPISODES", 2)
    monkeypatch.setattr(train_mod, "EpisodeBlockSampler", Spy)
    data = make_dataset(tmp_path / "arm", episodes=6, frames=4, task="arm")
    res = train(data, tmp_path / "ckpt", "arm", ["rgb"], epochs=1, batch=4,
                norm=Normalisation(size=32), **QUIET)["rgb"]
    assert len(made) == 1 and made[0].block == 2 and len(made[0]) == 20   # 5 train episodes
    assert res["training"]["epochs_run"] == 1 and math.isfinite(res["training"]["best_val_loss"])


def test_cli_trains_all_modalities_and_plots(tmp_path):
    data = make_dataset(tmp_path / "data", episodes=4, frames=8, task="arm")
    out = tmp_path / "out"
    assert main(["train", "--task", "arm", "--modality", "all", "--data", str(data),
                 "--out", str(out), "--size", "32", "--epochs", "2", "--batch", "8",
                 "--no-progress"]) == 0
    for m in ("rgb", "event", "rgb+event"):
        cfg = json.loads((out / f"arm-{m}.json").read_text())
        assert cfg["task"] == "arm" and cfg["modality"] == m
        assert cfg["training"]["loss"] == "smooth_l1" and cfg["training"]["lr"] == 1e-4
        assert cfg["training"]["plateau"]["factor"] == 0.5
        assert not set(cfg["dataset"]["train_episodes"]) & set(cfg["dataset"]["val_episodes"])
    assert (out / "arm-losses.png").exists()
    # a dataset of the other task, or none at all, is an error message, not a traceback
    assert main(["train", "--task", "nav", "--modality", "rgb", "--data", str(data),
                 "--out", str(out)]) == 2
    assert main(["train", "--task", "nav", "--modality", "rgb", "--data", str(tmp_path / "no"),
                 "--out", str(out)]) == 2


def test_help_does_not_import_torch():
    code = ("import sys; from sebvs.cli import build_parser; build_parser(); "
            "import sebvs_actors.policy; print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.stdout.strip() == "False", out.stderr


def test_arm_pose_is_standardised_from_the_training_targets(tmp_path):
    """The arm head learns in a standardised pose space (stats from the training split,
    stored in the state_dict and the config) and still outputs metres and radians."""
    from sebvs.policy.checkpoint import load_checkpoint
    from sebvs.policy.model import ERP
    from sebvs.policy.train import POSE_SCALE_FLOOR, pose_stats
    data = make_dataset(tmp_path / "arm", episodes=4, frames=12, task="arm")
    res = train(data, tmp_path / "ckpt", "arm", ["rgb"], epochs=1, batch=8,
                norm=Normalisation(size=32), **QUIET)["rgb"]
    stats = res["target_stats"]
    eps = load_index(data, "arm")
    tr, _ = split_episodes(eps, 0.2, 0)
    frames = EpisodeFrames(data, tr, "arm", "rgb", Normalisation(size=32))
    want = pose_stats(frames.targets())
    frames.close()
    np.testing.assert_allclose(stats["mean"], want["mean"])
    assert all(s >= f for s, f in zip(stats["scale"], POSE_SCALE_FLOOR))
    model, cfg, _ = load_checkpoint(tmp_path / "ckpt" / "arm-rgb.pt")
    np.testing.assert_allclose(model.head.mean.numpy(), stats["mean"], rtol=1e-6)
    # forward = mean + scale * mlp for x..pitch; the prediction's loss space measures the
    # same offset from the mean in centimetres (0.05 rad for roll and pitch) and keeps the
    # mlp's yaw pair as it is (not normalised), and it agrees with encode(forward(x))
    m = ERP("arm", 3, 32).eval()
    m.head.set_target_stats([0.4, 0.1, 0.2, 3.1, 0.0, 0.0], [0.05, 0.2, 0.01, 0.05, 0.05, 0.3])
    x = torch.rand(2, 3, 32, 32)
    with torch.no_grad():
        raw = m.head.mlp(m.encoder(m.tokens(m.embed(x)))[:, 0])
        pred = m.predict_loss_space(x)
        torch.testing.assert_close(pred[:, :5], raw[:, :5] * m.head.scale[:5] /
                                   torch.tensor([0.01, 0.01, 0.01, 0.05, 0.05]))
        torch.testing.assert_close(pred[:, 5:], raw[:, 5:])
        enc = m.loss_space(m(x))
        torch.testing.assert_close(enc[:, :5], pred[:, :5], atol=1e-4, rtol=1e-5)
        torch.testing.assert_close(enc[:, 5:], raw[:, 5:] / raw[:, 5:].norm(dim=1, keepdim=True))
    nav = ERP("nav", 3, 32)
    y = torch.rand(4, 2)
    assert torch.equal(nav.loss_space(y), y)
    nav.eval()
    assert torch.equal(nav.predict_loss_space(x), nav(x))


def test_arm_yaw_is_encoded_continuously_across_the_cube_fold():
    """Yaw labels are folded into [-45, 45) degrees: two cubes a hair either side of 45
    degrees look alike and must be near in the loss space, far apart as raw angles."""
    from sebvs.policy.model import ERP
    m = ERP("arm", 3, 32)
    near = torch.tensor([[0.4, 0.1, 0.2, 3.14, 0.0, math.radians(44.9)],
                         [0.4, 0.1, 0.2, 3.14, 0.0, math.radians(-44.9)]])
    enc = m.loss_space(near)
    assert (enc[0] - enc[1]).abs().max() < 0.02
    # positions in centimetres from the mean; the yaw comes back from its pair
    m.head.set_target_stats([0.4, 0.1, 0.2, 3.14, 0.0, 0.0], [0.05, 0.2, 0.01, 0.05, 0.05, 0.3])
    poses = torch.tensor([[0.43, 0.05, 0.2, 3.14, 0.01, math.radians(a)] for a in (-44, -10, 0, 30)])
    enc = m.loss_space(poses)
    torch.testing.assert_close(enc[:, :3], torch.tensor([[3.0, -5.0, 0.0]] * 4), atol=1e-4, rtol=0)
    assert torch.allclose(enc[:, 4], torch.full((4,), 0.2))         # 0.01 rad of pitch = 0.2
    torch.testing.assert_close(torch.atan2(enc[:, 6], enc[:, 5]) / 4, poses[:, 5],
                               atol=1e-5, rtol=0)


def test_the_content_digest_sees_what_a_training_reads_and_not_the_wall_clock(tmp_path):
    """A recording made again (other latencies, ticks from another run's start, so other
    files) has the digest of the first; a changed pixel changes it for the modalities that
    read pixels only; compressed chunks are hashed as stored."""
    import h5py

    from sebvs.policy.dataset import content_digest, dataset_hash
    from tests.policy_data import recorded_again
    first = make_dataset(tmp_path / "a", episodes=3, frames=8, compression="lzf")
    again = recorded_again(first, tmp_path / "b")
    eps_a, eps_b = load_index(first), load_index(again)
    assert dataset_hash(first, eps_a) != dataset_hash(again, eps_b)
    for modality in ("rgb", "event", "rgb+event", "rgb+diff"):
        assert content_digest(first, eps_a, modality) == content_digest(again, eps_b, modality)
    before = {m: content_digest(again, eps_b, m) for m in ("rgb", "event", "rgb+diff")}
    with h5py.File(again / eps_b[1]["file"], "r+") as f:
        f["rgb"][3, 5, 5, 0] ^= 1
    after = {m: content_digest(again, eps_b, m) for m in before}
    assert after["rgb"] != before["rgb"] and after["rgb+diff"] != before["rgb+diff"]
    assert after["event"] == before["event"]
    # the episodes' order and membership are part of what is read
    assert content_digest(first, eps_a[:2], "rgb") != content_digest(first, eps_a, "rgb")
    assert content_digest(first, eps_a[::-1], "rgb") != content_digest(first, eps_a, "rgb")


def test_a_training_stopped_on_one_recording_resumes_on_the_same_one_made_again(gain_data,
                                                                                tmp_path):
    """The state a stopped session left continues on a new checkout's recording, made again
    from the same commands (other files, the same content), to the weights of a training
    that never stopped; on a recording whose content differs it starts again."""
    import h5py
    import shutil

    from tests.policy_data import recorded_again, reindex
    kw = dict(epochs=3, batch=8, max_frames=48, seed=5, patience=10, progress=False,
              norm=Normalisation(size=32))
    train(gain_data, tmp_path / "whole", "nav", ["rgb+diff"], log=lambda s: None, **kw)
    with pytest.raises(StopHere):
        train(gain_data, tmp_path / "cut", "nav", ["rgb+diff"], log=stop_in_epoch(2), **kw)
    state = tmp_path / "cut" / "nav-rgb+diff.resume.pt"
    shutil.copy(state, tmp_path / "kept.resume.pt")
    again = recorded_again(gain_data, tmp_path / "again")
    said = []
    train(again, tmp_path / "cut", "nav", ["rgb+diff"], log=said.append, **kw)
    assert "  resuming after epoch 1 (nav-rgb+diff.resume.pt)" in said
    a, b = (torch.load(tmp_path / d / "nav-rgb+diff.pt", weights_only=True)
            for d in ("whole", "cut"))
    assert all(torch.equal(a[k], b[k]) for k in a)

    other = recorded_again(gain_data, tmp_path / "other")
    first = load_index(other)[0]["file"]
    with h5py.File(other / first, "r+") as f:
        f["action"][0, 0] += 0.5
    reindex(other)              # another recording's index, not a damaged file
    (tmp_path / "cut2").mkdir()
    shutil.copy(tmp_path / "kept.resume.pt", tmp_path / "cut2" / "nav-rgb+diff.resume.pt")
    said = []
    train(other, tmp_path / "cut2", "nav", ["rgb+diff"], log=said.append, **kw)
    assert "  nav-rgb+diff.resume.pt: made by other settings or data; training from the " \
           "start" in said


def test_a_training_whose_loss_goes_nan_stops_in_one_line_and_writes_no_checkpoint(
        gain_data, tmp_path, capsys):
    """lr 1e30 makes the loss NaN within two batches: `sebvs train` says where in one line,
    exit status 2, and leaves no checkpoint (it wrote one of NaN weights before)."""
    out = tmp_path / "out"
    assert main(["train", "--task", "nav", "--modality", "event", "--data", str(gain_data),
                 "--out", str(out), "--size", "32", "--epochs", "2", "--batch", "8",
                 "--max-frames", "32", "--lr", "1e30", "--threads", "1",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert re.fullmatch(r"sebvs train: nav-event: training loss is nan at epoch 1, batch \d+; "
                        r"stopped, no checkpoint written", err), err
    assert not (out / "nav-event.pt").exists() and not (out / "nav-event.json").exists()
    assert not (out / "nav-event.resume.pt").exists()      # no epoch ended


class NaNLoss(torch.nn.MSELoss):
    """MSE, NaN once NaNLoss.on is set: for training batches, or for validation ones."""
    on = False

    def __init__(self, validation: bool = False):
        super().__init__()
        self.validation = validation

    def forward(self, pred, target):
        loss = super().forward(pred, target)
        if NaNLoss.on and torch.is_grad_enabled() != self.validation:
            return loss * math.nan
        return loss


def nan_from_epoch_2(line):
    if line.startswith("  epoch 1:"):
        NaNLoss.on = True


@pytest.mark.parametrize("validation", [False, True], ids=["training", "validation"])
def test_a_loss_gone_nan_keeps_the_earlier_checkpoint_and_a_finite_resume_state(
        gain_data, tmp_path, monkeypatch, validation):
    """Trained again into a directory with a good checkpoint, a run whose (training or
    validation) loss goes NaN in epoch 2 leaves that checkpoint, its config and its
    losses as they were, and the resume state of epoch 1, finite, to go on from."""
    from sebvs.policy.resume import first_non_finite
    from sebvs.policy.train import TrainingDiverged
    kw = dict(epochs=2, batch=8, max_frames=32, seed=1, patience=10,
              norm=Normalisation(size=32), progress=False)
    train(gain_data, tmp_path, "nav", ["event"], log=lambda s: None, **kw)
    names = ("nav-event.pt", "nav-event.json", "nav-event-losses.csv")
    before = [(tmp_path / n).read_bytes() for n in names]
    monkeypatch.setattr(torch.nn, "MSELoss", lambda: NaNLoss(validation))
    monkeypatch.setattr(NaNLoss, "on", False)
    kind = "validation" if validation else "training"
    with pytest.raises(TrainingDiverged, match=rf"^nav-event: {kind} loss is nan at epoch 2, "
                                               rf"batch 1; stopped, no checkpoint written$"):
        train(gain_data, tmp_path, "nav", ["event"], log=nan_from_epoch_2, **kw)
    assert [(tmp_path / n).read_bytes() for n in names] == before
    state = torch.load(tmp_path / "nav-event.resume.pt", weights_only=True)
    assert state["epoch"] == 1 and first_non_finite(state) is None


def test_a_weight_gone_nan_with_a_finite_loss_stops_the_training(gain_data, tmp_path,
                                                                 monkeypatch):
    """A BatchNorm statistic of the conv stem is not used by a training pass, so the loss
    never sees it go NaN: the check of the weights after each epoch does."""
    import sebvs.policy.train as train_module
    from sebvs.policy.train import TrainingDiverged

    class Poison:
        """Stands for ZeroSubnormals (called after each step): NaNs a running mean."""
        total = 0

        def __init__(self, model, optimizer):
            self.model = model

        def __call__(self):
            self.model.embed.net[1].running_mean.fill_(math.nan)

    monkeypatch.setattr(train_module, "ZeroSubnormals", Poison)
    with pytest.raises(TrainingDiverged, match=r"^nav-rgb: weight embed.net.1.running_mean is "
                                               r"not finite after epoch 1; stopped, no "
                                               r"checkpoint written$"):
        train(gain_data, tmp_path, "nav", ["rgb"], epochs=2, batch=8, max_frames=32,
              stem="conv", zero_subnormals=True, norm=Normalisation(size=32), **QUIET)
    assert list(tmp_path.glob("nav-rgb*")) == []


def test_a_non_finite_resume_state_is_neither_written_nor_continued(tmp_path):
    from sebvs.policy.resume import NonFiniteState, load_state, save_state
    path = tmp_path / "nav-event.resume.pt"
    good = {"fingerprint": "k", "epoch": 1, "model": {"w": torch.ones(2)},
            "optimizer": {"state": {0: {"exp_avg_sq": torch.ones(2)}}}}
    save_state(path, good)
    bad = {**good, "epoch": 2,
           "optimizer": {"state": {0: {"exp_avg_sq": torch.tensor([1.0, math.inf])}}}}
    with pytest.raises(NonFiniteState, match="not written, optimizer/state/0/exp_avg_sq is "
                                             "not finite"):
        save_state(path, bad)
    assert load_state(path, "k")["epoch"] == 1              # the previous epoch's is kept
    torch.save(bad, path)                                   # as code before the check did
    said = []
    assert load_state(path, "k", said.append) is None
    assert said == ["  nav-event.resume.pt: optimizer/state/0/exp_avg_sq is not finite; "
                    "training from the start"]


def with_emulator(root, out, versions: list[int | None], preset: str = "physical"):
    """A copy of the dataset at ``root`` in ``out`` whose episodes name the emulator the
    recorder resolved, episode i at ``versions[i]`` (None: a "resolved" without the key, as
    recorded before issue 67), reindexed as a recording made so."""
    import shutil

    import h5py

    from tests.policy_data import reindex
    out = Path(out)
    shutil.copytree(root, out)
    for e, version in zip(load_index(out), versions):
        resolved = {"shot_noise_rate_hz": 0.5, **({"preset_version": version}
                                                   if version is not None else {})}
        with h5py.File(out / e["file"], "r+") as f:
            f.attrs["emulator"] = json.dumps({"preset": preset, "overrides": {},
                                              "resolved": resolved})
    return reindex(out)


def test_a_checkpoint_names_the_emulator_its_events_were_recorded_with(gain_data, tmp_path):
    """The emulator's preset and preset_version go from the episodes into the config of a
    modality with events (not into the weights' record); absent, version 1; rgb alone has
    none to name."""
    from sebvs.policy.checkpoint import CONFIG_RECORD, load_checkpoint
    kw = dict(epochs=1, batch=8, max_frames=16, norm=Normalisation(size=32), **QUIET)
    v2 = with_emulator(gain_data, tmp_path / "v2", [2] * 6)
    res = train(v2, tmp_path / "a", "nav", ["event", "rgb"], **kw)
    assert res["event"]["emulator"] == {"preset": "physical", "preset_version": 2}
    assert "emulator" not in res["rgb"]
    model, cfg, _ = load_checkpoint(tmp_path / "a" / "nav-event.pt")
    assert cfg["emulator"] == {"preset": "physical", "preset_version": 2}
    record = torch.load(tmp_path / "a" / "nav-event.pt", weights_only=True)[CONFIG_RECORD]
    assert "emulator" not in json.loads(bytes(record.tolist()))
    old = with_emulator(gain_data, tmp_path / "v1", [None] * 6)
    assert train(old, tmp_path / "b", "nav", ["rgb+event"], **kw)["rgb+event"]["emulator"] \
        == {"preset": "physical", "preset_version": 1}
    # the synthetic recording names no emulator at all: version 1, preset unknown
    assert train(gain_data, tmp_path / "c", "nav", ["event"], **kw)["event"]["emulator"] \
        == {"preset": None, "preset_version": 1}


def test_a_dataset_that_mixes_emulator_versions_is_refused_in_one_line(gain_data, tmp_path):
    from sebvs.policy.dataset import emulator_of
    mixed = with_emulator(gain_data, tmp_path / "mixed", [1, 1, 2, None, 2, 1])
    with pytest.raises(ValueError, match=r"^\S+mixed: episodes recorded with emulator "
                                         r"preset_version 1 \(episode_0000.h5\) and 2 "
                                         r"\(episode_0002.h5\): one noise model per dataset$"):
        train(mixed, tmp_path / "out", "nav", ["rgb+event"], epochs=1, batch=8,
              norm=Normalisation(size=32), **QUIET)
    assert not (tmp_path / "out").exists()          # refused before anything is written
    # an rgb training reads no events, and names no emulator: the mix does not matter to it
    assert "emulator" not in train(mixed, tmp_path / "rgb", "nav", ["rgb"], epochs=1,
                                   batch=8, max_frames=16, norm=Normalisation(size=32),
                                   **QUIET)["rgb"]
    odd = with_emulator(gain_data, tmp_path / "odd", [3] * 6)
    with pytest.raises(ValueError, match=r"episode_0000.h5: emulator preset_version 3 is not "
                                         r"one of 1, 2$"):
        emulator_of(odd, load_index(odd))
    assert emulator_of(with_emulator(gain_data, tmp_path / "two", [2] * 6, "noisy"),
                       load_index(tmp_path / "two")) == {"preset": "noisy",
                                                         "preset_version": 2}
