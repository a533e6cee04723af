"""research/ideal8/event_share.py: the target's share of a frame's events, on frames built by hand,
and the whole tool on a small dataset."""
import json

import numpy as np

from sebvs.data.episode import EpisodeWriter
from sebvs.data.index import DatasetIndex, make_entry
from research.tests.study_loader import study_module


def test_shares_count_the_box_in_the_event_frames_resolution():
    with study_module("ideal8/event_share") as tool:
        ev = np.zeros((3, 2, 40, 40), np.uint8)
        ev[0, 0, 10:20, 10:20] = 1                 # all inside the box
        ev[1, 1, 30:40, 30:40] = 1                 # all outside
        ev[2, 0, 10:20, 10:20] = 1
        ev[2, 1, 30:40, 30:40] = 3                 # a quarter inside
        # the truth's image is 80 px: the box (20, 20)-(40, 40) there is (10, 10)-(20, 20) here
        bbox = np.tile([20.0, 20.0, 40.0, 40.0], (3, 1))
        image = np.tile([80.0, 80.0], (3, 1))
        total, share, area = tool.frame_shares(ev, bbox, image, margin=0.0)
        assert total.tolist() == [100, 100, 400]
        assert share.tolist() == [1.0, 0.0, 0.25]
        assert np.allclose(area, 100 / 1600)
        _, share_m, area_m = tool.frame_shares(ev, bbox, image, margin=1.0)
        assert np.allclose(area_m, 144 / 1600) and share_m[0] == 1.0


def _dataset(root, sensor=None, camera="camera"):
    """Two 4-frame nav episodes (indoor: no target events, outdoor: 5 per target pixel),
    a 2 x 2 px target at (12, 12) with a 10 px wide contrast step behind it; recorded
    through a camera actor of that name."""
    idx = DatasetIndex(root, "nav")
    topology = {} if sensor is None else {"topology": {
        "file": "nav_record.toml", "overrides": [],
        "content": {"actors": {"sim": {"run": "actors.sim:Sim"},
                               camera: {"run": "actors.camera:Camera", "sensor": sensor}}}}}
    for variant, inside in (("indoor", 0), ("outdoor", 5)):
        path = idx.path_for(idx.next_episode_number())
        w = EpisodeWriter(path, "nav", {"scene": "nav", "conditions": {"variant": variant},
                                        "seed": 1, **topology})
        for t in range(4):
            ev = np.zeros((2, 32, 32), np.uint8)
            ev[0, 0:2, 0:2] = 1                             # background edges
            ev[1, 12:14, 12:14] = inside                    # the target's
            rgb = np.zeros((32, 32, 3), np.uint8)
            rgb[8:24, 8:24] = 200                            # a box the contrast can read
            w.append(rgb=rgb, event_frame=ev, t_sim=0.1 * t, tick=t, action=np.zeros(2),
                     truth={"bbox": np.array([10.0, 10.0, 22.0, 22.0]),
                            "image": np.array([32.0, 32.0]), "visible": 1.0})
        w.finish("time_limit")
        idx.add(make_entry(path))


def test_no_contrast_is_read_off_a_frame_the_emulator_did_not_see(tmp_path):
    """Through the physical camera the emulator read linear luminance: the frame's luma
    says nothing about its threshold, so the contrast is left unmeasured."""
    with study_module("ideal8/event_share") as tool:
        for sensor in ("ideal8", "physical"):
            _dataset(tmp_path / sensor, sensor)
        eight = tool.summarise(tool.collect(tmp_path / "ideal8", ["variant"], 0.0))
        linear = tool.summarise(tool.collect(tmp_path / "physical", ["variant"], 0.0))
    assert all(r["edge_contrast_p50"] is not None for r in eight)
    assert all(r["edge_contrast_p50"] is None for r in linear)
    assert [r["density_ratio_p50"] for r in eight] == [r["density_ratio_p50"] for r in linear]


def test_the_camera_is_found_by_what_it_runs_not_by_its_name(tmp_path):
    with study_module("ideal8/event_share") as tool:
        _dataset(tmp_path / "eye", "physical", camera="eye")
        rows = tool.summarise(tool.collect(tmp_path / "eye", ["variant"], 0.0))
    assert all(r["edge_contrast_p50"] is None for r in rows)


def test_the_tool_groups_by_scene_setting(tmp_path, capsys):
    with study_module("ideal8/event_share") as tool:
        idx = DatasetIndex(tmp_path / "ds", "nav")
        for variant, inside in (("indoor", 0), ("outdoor", 5)):
            path = idx.path_for(idx.next_episode_number())
            w = EpisodeWriter(path, "nav", {"scene": "nav", "conditions": {"variant": variant},
                                            "seed": 1})
            for t in range(4):
                ev = np.zeros((2, 32, 32), np.uint8)
                ev[0, 0:2, 0:2] = 1                             # background edges
                ev[1, 12:14, 12:14] = inside                    # the target's
                w.append(rgb=np.zeros((32, 32, 3), np.uint8), event_frame=ev, t_sim=0.1 * t,
                         tick=t, action=np.zeros(2),
                         truth={"bbox": np.array([12.0, 12.0, 14.0, 14.0]),
                                "image": np.array([32.0, 32.0]), "visible": 1.0})
            w.finish("time_limit")
            idx.add(make_entry(path))
        out = tmp_path / "share.json"
        assert tool.main([str(tmp_path / "ds"), "--by", "variant", "--margin", "0",
                          "--json", str(out)]) == 0
        rows = {r["group"]: r for r in json.loads(out.read_text())["rows"]}
        assert rows["variant=indoor"]["target_event_share_p50"] == 0.0
        assert rows["variant=indoor"]["frames_without_target_events"] == 1.0
        assert rows["variant=outdoor"]["target_event_share_p50"] == 20 / 24
        assert abs(rows["variant=outdoor"]["density_ratio_p50"] - (20 / 24) / (4 / 1024)) < 1e-6
        assert "variant=outdoor" in capsys.readouterr().out
        # a 2 px box is too narrow to measure an edge on, and there is no emulator attribute
        assert rows["variant=indoor"]["edge_contrast_p50"] is None
        assert rows["variant=indoor"]["frames_under_threshold"] is None


def test_edge_contrast_is_in_the_emulators_lin_log_units():
    with study_module("ideal8/event_share") as tool:
        rgb = np.full((40, 40, 3), 100, np.uint8)
        rgb[10:20, 10:20] = 150                                 # the target, 1.5x as bright
        image = np.array([80.0, 80.0])                          # truth at twice the frame's size
        box = np.array([20.0, 20.0, 40.0, 40.0])
        assert abs(tool.edge_contrast(rgb, box, image) - np.log(1.5)) < 1e-5
        rgb[10:20, 7:10] = 150                                  # same brightness on the left
        assert abs(tool.edge_contrast(rgb, box, image) - np.log(1.5)) < 1e-5   # the right edge
        rgb[10:20, 20:23] = 150
        assert tool.edge_contrast(rgb, box, image) < 1e-6       # no edge on either side
        # under 20 DN the sensor is linear: 10 against 5 DN is 0.15 log units, not ln 2
        dim = np.full((40, 40, 3), 5, np.uint8)
        dim[10:20, 10:20] = 10
        assert abs(tool.edge_contrast(dim, box, image) - 5 * np.log(20) / 20) < 1e-5
        # a box at the frame's edge, or too narrow, has no side bands to measure
        assert np.isnan(tool.edge_contrast(rgb, np.array([0.0, 20.0, 20.0, 40.0]), image))
        assert np.isnan(tool.edge_contrast(rgb, np.array([20.0, 20.0, 24.0, 40.0]), image))
