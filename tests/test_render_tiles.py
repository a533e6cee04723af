"""sebvs/sim/tiles.py: views drawn into the layers of one framebuffer and read back once are
the bytes of the same views rendered one by one (colour, luma, radiance), for K sample
times of one scene and for K scenes' models; MuJoCo's own buffer is untouched between."""
import sys

from sebvs.sim.render import FrameRenderer  # first: it selects MUJOCO_GL before mujoco loads

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from sebvs.sim import make_scene  # noqa: E402
from sebvs.sim.radiance import RadianceRenderer  # noqa: E402
from sebvs.sim.tiles import ModelTiles, RadianceTiles, TileRenderer  # noqa: E402
from tests.tools_loader import tool_module  # noqa: E402

SIZE = 48


def trajectory(scene_name: str, n: int, **config):
    """A scene, its model and data, and n states a few physics steps apart (the nav robot
    turns, so every state's view differs)."""
    scene = make_scene(scene_name, width=SIZE, height=SIZE, **config)
    model = scene.compile()
    data = mujoco.MjData(model)
    scene.reset(model, data, np.random.default_rng(3))
    states = []
    for _ in range(n):
        for _ in range(8):
            if scene_name == "nav":
                scene.apply_command(model, data, np.array([0.4, 1.5]))
            scene.scripted(model, data)
            mujoco.mj_step(model, data)
        states.append(scene.state(data))
    return scene, model, data, states


def pose(scene, model, data, state):
    scene.set_state(model, data, state)
    scene.kinematics(model, data)


def test_tiles_of_sample_times_are_the_single_renders_bytes():
    scene, model, data, states = trajectory("nav", 6, variant="indoor")
    with FrameRenderer(model, SIZE, SIZE) as r, TileRenderer(r, capacity=4) as tiles:
        singles, lumas = [], []
        for s in states:
            pose(scene, model, data, s)
            r.update(data, "front")
            singles.append(r.rgb())
            lumas.append(r.luma())
        assert len({a.tobytes() for a in singles}) == len(states)    # the views differ
        for s in states[:4]:
            pose(scene, model, data, s)
            r.update(data, "front")
            tiles.draw()
        first = tiles.rgb()
        for s in states[4:]:                   # a part-filled tile after a full one
            pose(scene, model, data, s)
            r.update(data, "front")
            tiles.draw()
        second = tiles.luma()
    assert first.shape == (4, SIZE, SIZE, 3) and second.shape == (2, SIZE, SIZE)
    for k in range(4):
        np.testing.assert_array_equal(first[k], singles[k], err_msg=f"view {k}")
    for k in range(2):
        np.testing.assert_array_equal(second[k], lumas[4 + k], err_msg=f"luma {k}")


def test_a_render_between_tiles_draws_where_it_always_did():
    scene, model, data, states = trajectory("nav", 2, variant="outdoor")
    with FrameRenderer(model, SIZE, SIZE) as r, TileRenderer(r, capacity=2) as tiles:
        expected = []
        for s in states:
            pose(scene, model, data, s)
            r.update(data, "front")
            expected.append(r.rgb())
        pose(scene, model, data, states[0])
        r.update(data, "front")
        tiles.draw()
        pose(scene, model, data, states[1])
        r.update(data, "front")
        between = r.rgb()                # into MuJoCo's own buffer, not into layer 0
        tiles.draw()
        drawn = tiles.rgb()
        with pytest.raises(RuntimeError, match="nothing drawn"):
            tiles.rgb()
    assert not np.array_equal(expected[0], expected[1])
    np.testing.assert_array_equal(between, expected[1])
    np.testing.assert_array_equal(drawn[0], expected[0])
    np.testing.assert_array_equal(drawn[1], expected[1])


def test_radiance_tiles_are_the_radiance_renders_bytes_with_their_flicker():
    scene, model, data, states = trajectory("nav", 3, variant="indoor", lighting="hdr")
    ph = scene.photometry()
    scales = (1.0, 0.35, 0.8)
    with RadianceRenderer(model, ph, SIZE, SIZE) as rr:
        singles, clipped = [], []
        for s, ls in zip(states, scales):
            pose(scene, model, data, s)
            rr.update(data, "front", ls)
            singles.append(rr.luminance().copy())
            clipped.append(rr.clipped)
        tiles = RadianceTiles(rr, capacity=3)
        for s, ls in zip(states, scales):
            pose(scene, model, data, s)
            tiles.draw(data, "front", ls)
        lum = tiles.luminance()
        tiles.close()
    assert lum.dtype == np.float32 and lum.shape == (3, SIZE, SIZE)
    for k in range(3):
        assert lum[k].tobytes() == singles[k].tobytes(), f"sample {k}"
    assert tiles.clipped == clipped
    # the flicker reached the tile (the median: the HDR window is its own light)
    assert np.median(singles[1]) < 0.5 * np.median(singles[0])


def test_tiles_of_several_models_are_each_models_own_render():
    worlds = [trajectory("nav", 1, variant="outdoor"), trajectory("nav", 1, variant="indoor"),
              trajectory("arm", 1)]
    expected = []
    for scene, model, data, states in worlds:
        pose(scene, model, data, states[0])
        with FrameRenderer(model, SIZE, SIZE) as r:
            r.update(data, scene.cameras[0])
            expected.append(r.rgb())
    with ModelTiles([w[1] for w in worlds], SIZE, SIZE) as tiles:
        for i, (scene, model, data, _) in reversed(list(enumerate(worlds))):
            tiles.update(i, data, scene.cameras[0])         # any order: layer i is model i
        rgb = tiles.rgb()
        with pytest.raises(RuntimeError, match=r"models \[0, 1, 2\] not updated"):
            tiles.rgb()
    for i in range(3):
        np.testing.assert_array_equal(rgb[i], expected[i], err_msg=f"model {i}")


def test_a_full_tile_and_a_bad_capacity_are_refused():
    scene, model, data, states = trajectory("nav", 1)
    with FrameRenderer(model, SIZE, SIZE) as r:
        with pytest.raises(ValueError, match="capacity must be an integer >= 1"):
            TileRenderer(r, 0)
        with TileRenderer(r, 1) as tiles:
            r.update(data, "front")
            tiles.draw()
            with pytest.raises(RuntimeError, match="read them before drawing more"):
                tiles.draw()


def test_the_benchmark_times_every_tile_count_and_checks_its_bytes():
    with tool_module("bench/bench_render_tiles") as bench:
        report = bench.run(32, "indoor", samples=4, repeats=1, tiles=(1, 2, 4),
                           kinds=("radiance", "rgb"))
    assert report["gl"]["renderer"] and report["gl"]["vendor"]
    for kind in ("radiance", "rgb"):
        rows = report["results"][kind]
        assert set(rows) == {"single", "tiles_1", "tiles_2", "tiles_4"}
        assert all(r["cpu_ms_per_sample"] > 0 for r in rows.values())
        assert all(rows[f"tiles_{k}"]["bit_identical"] for k in (1, 2, 4))
    grid = report["results"]["rgb_viewports"]["tiles_4"]
    assert grid["px_in_first_tile"] == 4 * 32 * 32
    assert grid["px_differing_from_single_in_first_tile"] >= 0


def test_the_benchmark_refuses_samples_that_do_not_fill_its_tiles(capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["bench_render_tiles.py", "--samples", "6",
                                      "--tiles", "4"])
    with tool_module("bench/bench_render_tiles") as bench:
        assert bench.main() == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["bench_render_tiles: --samples 6: give a multiple of every --tiles "
                   "count [4]"]
