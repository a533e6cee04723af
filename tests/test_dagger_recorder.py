"""The LockstepRecorder's `drive` input: the drive command goes on to the sim, the file keeps
the expert's label, the episode names its driver; `drive` without `action` is refused."""
import json

import numpy as np
import pytest

from sebvs.cli import main
from sebvs.data.check import check_dataset
from sebvs.data.episode import open_episode
from sebvs.data.index import DatasetIndex
from sebvs.runtime.supervisor import run_topology
from sebvs.runtime.topology import TopologyError, load_topology
from tests.dagger_actors import drive_command
from tests.data_actors import expected_action


def topology(tmp_path, out, *, action=True, drive=True, frames=5, episodes=2):
    label = ', action = "source/action"' if action else ""
    driven = ', drive = "driver/action"' if drive else ""
    events = 'events = "source/events"'
    path = tmp_path / "dagger.toml"
    path.write_text(f"""
[topology]
name = "dagger_test"
seed = 0
[actors.source]
run = "tests.data_actors:DataSource"
frames = {frames}
[actors.driver]
run = "tests.dagger_actors:Driver"
inputs = {{ rgb = "source/rgb" }}
[actors.recorder]
run = "actors.recorder:LockstepRecorder"
inputs = {{ rgb = "source/rgb", episode = "source/episode", {events}{label}{driven} }}
out = "{out}"
episodes = {episodes}
[actors.probe]
run = "actors.synthetic:Probe"
inputs = {{ action = "recorder/action" }}
path = "{tmp_path / 'probe'}"
""")
    return path


def test_the_drive_command_goes_on_and_the_expert_s_label_is_recorded(tmp_path):
    out = tmp_path / "ds"
    run_topology(topology(tmp_path, out), duration_s=20, runs_dir=tmp_path)
    # what the recorder passed on (the sim's side of the wire): the driver's commands
    entries = json.loads((tmp_path / "probe.json").read_text())
    assert [e["tick"] for e in entries][:10] == list(range(10))
    assert all(e["meta"]["modality"] == "event" for e in entries)
    arrays = np.load(tmp_path / "probe.npz")
    for i, e in enumerate(entries[:10]):
        np.testing.assert_array_equal(arrays[f"{i}.action.action"], drive_command(e["tick"]))
    # what the file holds: the expert's label as `action`, the driver's command as `drive`
    index = DatasetIndex(out)
    assert len(index.episodes()) == 2 and check_dataset(out).ok
    for path in index.episode_paths():
        with open_episode(path) as ep:
            ticks = ep.tick[:]
            assert len(ticks) == 5
            np.testing.assert_array_equal(ep.action[:], [expected_action(t) for t in ticks])
            np.testing.assert_array_equal(ep.drive[:], [drive_command(t) for t in ticks])
            assert ep.attrs["driver"] == "driver:event"
            assert [m.decode() for m in ep.modality[:]] == ["event"] * 5
            assert ep.attrs["event_scale"] == 0.5      # the events' attributes kept beside it


def test_without_drive_the_label_drives_and_names_its_source(tmp_path):
    out = tmp_path / "ds"
    run_topology(topology(tmp_path, out, drive=False, episodes=1), duration_s=20,
                 runs_dir=tmp_path)
    arrays = np.load(tmp_path / "probe.npz")
    np.testing.assert_array_equal(arrays["2.action.action"], expected_action(2))
    with open_episode(DatasetIndex(out).episode_paths()[0]) as ep:
        assert ep.drive is None and ep.attrs["driver"] == "source:rgb"


def test_drive_without_action_is_refused_at_load_in_one_line(tmp_path, capsys):
    path = topology(tmp_path, tmp_path / "ds", action=False)
    with pytest.raises(TopologyError) as info:
        load_topology(path)
    text = str(info.value)
    assert "\n" not in text and "[actors.recorder]" in text
    assert "'drive' is wired but 'action' is not" in text
    # as a command: one line, exit 2, nothing started or written
    code = main(["record", str(path), "--episodes", "1", "--out", str(tmp_path / "ds"),
                 "--runs-dir", str(tmp_path / "runs"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "'drive'" in err, err
    assert not (tmp_path / "ds").exists() and not (tmp_path / "runs").exists()
    # the plain Recorder, which passes nothing on, has no drive input at all
    plain = path.read_text().replace("LockstepRecorder", "Recorder")
    path.write_text(plain.replace('action = "recorder/action"', 'other = "source/rgb"'))
    with pytest.raises(TopologyError, match="has no input 'drive'"):
        load_topology(path)


def test_nav_dagger_topology_wires_the_policy_to_drive_and_the_expert_to_label():
    topo = load_topology("topologies/nav_dagger.toml")
    rec = topo.actors["recorder"].inputs
    assert (rec["drive"].producer, rec["drive"].output) == ("policy", "action")
    assert (rec["action"].producer, rec["action"].output) == ("expert", "action")
    sim = topo.actors["sim"].inputs["action"]
    assert (sim.producer, sim.output) == ("recorder", "action")
    policy = topo.actors["policy"].inputs
    assert {k: (v.producer, v.output) for k, v in policy.items()} == \
        {"rgb": ("camera", "rgb"), "events": ("accumulator", "frames")}
    # nav_record.toml's settings otherwise
    record = load_topology("topologies/nav_record.toml")
    for name in ("sim", "camera", "emulator", "accumulator", "expert"):
        assert topo.actors[name].params == record.actors[name].params, name


def test_data_check_refuses_a_drive_column_of_another_width_than_the_label(tmp_path):
    from sebvs.data.episode import EpisodeWriter
    from sebvs.data.index import make_entry
    index = DatasetIndex(tmp_path, "nav")
    path = index.path_for(index.next_episode_number())
    with EpisodeWriter(path, "nav", {"seed": 1, "scene": "synthetic"}) as w:
        for t in range(3):
            w.append(rgb=np.zeros((8, 8, 3), np.uint8), t_sim=t / 10, tick=t,
                     action=np.zeros(2, np.float32), drive=np.zeros(3, np.float32))
        w.finish("synthetic")
    index.add(make_entry(path))
    report = check_dataset(tmp_path)
    assert not report.ok
    assert any("drive is (3, 3), expected [3, 2]" in p for p in report.problems), \
        report.problems
