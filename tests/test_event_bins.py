"""Time-binned event input (issue 15, item 3): a histogram of K time bins per polarity
travels from the recording through training into the checkpoint, and an evaluation sets
its accumulator to give the frames the checkpoint was trained on."""
import json

import numpy as np
import pytest
import torch

from sebvs.data.episode import EpisodeWriter
from sebvs.dvs.accumulator import EventAccumulator, EventGeometry
from sebvs.dvs.emulator import EVENT_DTYPE
from sebvs.eval.run import EvalPlan, Run
from sebvs.policy.checkpoint import load_checkpoint
from sebvs.policy.dataset import EpisodeFrames, event_frames_of, load_index
from sebvs.policy.infer import PolicySet
from sebvs.policy.inputs import Normalisation, channel_names, channels, event_input
from sebvs.policy.train import train
from tests.policy_data import make_dataset

torch.set_num_threads(1)
QUIET = dict(progress=False, log=lambda s: None)


def test_channels_and_names_follow_the_bins():
    assert channels("event", 4) == 8 and channels("rgb+event", 4) == 11
    assert channels("rgb", 4) == 3 and channels("event") == 2
    assert channel_names("event") == ["on", "off"]
    assert channel_names("rgb+event", 2) == ["r", "g", "b", "on_t0", "on_t1", "off_t0",
                                             "off_t1"]
    with pytest.raises(ValueError, match="event_bins"):
        Normalisation(event_bins=0)


def test_histogram_frames_become_per_bin_input_planes():
    """The accumulator's histogram (ON bins oldest first, then OFF bins) is what
    event_input takes: each plane clipped and scaled on its own."""
    acc = EventAccumulator(EventGeometry((8, 8), (8, 8)), "histogram", window_s=0.1, bins=2)
    ev = np.zeros(3, EVENT_DTYPE)
    ev["x"], ev["y"] = [1, 1, 5], [2, 2, 6]
    ev["t"] = [10_000_000, 20_000_000, 90_000_000]     # ns: first bin, first bin, second
    ev["p"] = [1, 1, -1]
    acc.add(ev)
    frame = acc.frame(100_000_000)
    assert frame.shape == (4, 8, 8) and frame.dtype == np.uint8
    x = event_input(frame, Normalisation(size=8, event_clip=4, event_bins=2))
    assert x.shape == (4, 8, 8)
    assert x[0, 2, 1] == 0.5 and x[3, 6, 5] == 0.25        # ON bin 0: 2 of 4, OFF bin 1
    assert x.sum() == pytest.approx(0.75)
    with pytest.raises(ValueError, match=r"\[4, H, W\] \(2 time bins per polarity\)"):
        event_input(frame[:2], Normalisation(size=8, event_bins=2))


def test_training_takes_the_bins_from_the_recording(tmp_path):
    data = make_dataset(tmp_path / "data", episodes=4, frames=8, event_bins=3)
    assert event_frames_of(data, load_index(data)) == {
        "representation": "histogram", "bins": 3, "window_s": 0.1, "sensor": [16, 16],
        "output": [32, 32]}
    res = train(data, tmp_path / "ck", "nav", ["event"], epochs=1, batch=4,
                norm=Normalisation(size=32), **QUIET)["event"]
    assert res["channels"] == 6 and res["normalisation"]["event_bins"] == 3
    assert res["channel_order"][:3] == ["on_t0", "on_t1", "on_t2"]
    assert res["event_frames"]["bins"] == 3 and res["event_frames"]["window_s"] == 0.1
    model, cfg, norm = load_checkpoint(tmp_path / "ck" / "nav-event.pt")
    assert norm.event_bins == 3
    policies = PolicySet({"event": tmp_path / "ck" / "nav-event.pt"})
    policies.warm_up()                                   # zeros of the trained shape
    y, _, _ = policies.act("event", events=np.ones((6, 32, 32), np.uint8))
    assert y.shape == (2,) and np.isfinite(y).all()
    # a counts frame is refused with the shapes named, not silently mis-read
    with pytest.raises(ValueError, match=r"\[6, H, W\]"):
        policies.act("event", events=np.ones((2, 32, 32), np.uint8))


def test_a_dataset_mixing_representations_is_refused_by_file(tmp_path):
    data = make_dataset(tmp_path / "a", episodes=2, frames=4, event_bins=2)
    frames = EpisodeFrames(data, load_index(data), "nav", "event", Normalisation(size=32))
    with pytest.raises(ValueError, match=r"ep.*4 planes, the model takes 2"):
        frames[0]


def test_voxel_frames_are_refused_at_recording_and_training(tmp_path):
    with EpisodeWriter(tmp_path / "e.h5", "nav", {"seed": 0}, compression="none") as w:
        with pytest.raises(ValueError, match="must hold counts"):
            w.append(rgb=np.zeros((8, 8, 3), np.uint8), t_sim=0.0, tick=0,
                     action=np.zeros(2, np.float32),
                     event_frame=np.full((5, 8, 8), -0.5, np.float32))
    data = make_dataset(tmp_path / "v", episodes=2, frames=2)
    first = data / load_index(data)[0]["file"]
    import h5py
    with h5py.File(first, "a") as f:
        f.attrs["event_representation"] = "voxel"
    from tests.policy_data import reindex
    reindex(data)
    with pytest.raises(ValueError, match="voxel grids"):
        event_frames_of(data, load_index(data))


def test_eval_sets_the_accumulator_from_the_checkpoint(tmp_path):
    ck = tmp_path / "ck"
    ck.mkdir()
    cfg = {"task": "nav", "modality": "event",
           "event_frames": {"representation": "histogram", "bins": 4, "window_s": 0.4,
                            "sensor": [160, 160], "output": [160, 160]}}
    (ck / "nav-event.json").write_text(json.dumps(cfg))
    plan = EvalPlan(task="nav", modalities=["event"], conditions=["nominal"], episodes=1,
                    out=tmp_path / "out", checkpoints=str(ck),
                    extra=["accumulator.window_s=0.2"])
    _, sets = plan.overrides(Run("nominal", "indoor", "event"))
    # the checkpoint's frames (a full-size sensor), the user's --set after them
    assert sets["accumulator"] == {"representation": "histogram", "bins": 4, "window_s": 0.2}
    assert sets["camera"]["luma_scale"] == 1.0
    assert sets["emulator"]["preset"] == "paper"    # the condition's: the 8-bit benchmark's
    # without the user's --set the checkpoint's window stands
    plan.extra = []
    _, sets = plan.overrides(Run("nominal", "indoor", "event"))
    assert sets["accumulator"]["window_s"] == 0.4
    plan.extra = ["accumulator.window_s=0.2"]
    assert plan.event_frame_notes() == []
    # an older checkpoint (no event_frames) leaves the topology's accumulator as written
    (ck / "nav-event.json").write_text(json.dumps({"task": "nav", "modality": "event"}))
    _, sets = plan.overrides(Run("nominal", "indoor", "event"))
    assert sets["accumulator"] == {"window_s": 0.2}
    # ... and the evaluation says so, naming the file and the setting that would match it
    notes = plan.event_frame_notes()
    assert len(notes) == 1 and str(ck / "nav-event.json") in notes[0]
    assert "camera.luma_scale=0.5" in notes[0]


def test_a_control_rate_keeps_the_window_the_checkpoint_learned_from(tmp_path):
    """--control-hz sets one tick's window only where the checkpoint names none: a policy
    trained on 0.1 s frames (widen_event_window.py's, or a 10 Hz recording) evaluated at
    30 Hz still gets 0.1 s frames, not silently a third of its events."""
    from sebvs.runtime.topology import load_topology
    ck = tmp_path / "ck"
    ck.mkdir()
    plan = EvalPlan(task="nav", modalities=["event"], conditions=["nominal"], episodes=1,
                    out=tmp_path / "out", checkpoints=str(ck), control_hz=30.0)
    for frames, window in (({"representation": "counts", "bins": 1, "window_s": 0.1,
                             "sensor": [160, 160], "output": [160, 160]}, 0.1),
                           (None, 1 / 30)):
        cfg = {"task": "nav", "modality": "event"}
        if frames:
            cfg["event_frames"] = frames
        (ck / "nav-event.json").write_text(json.dumps(cfg))
        topo = load_topology(*plan.overrides(Run("nominal", "indoor", "event")))
        assert topo.actors["accumulator"].params["window_s"] == pytest.approx(window)
        assert topo.actors["sim"].params["control_hz"] == 30.0
