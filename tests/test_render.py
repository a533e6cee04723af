"""sebvs/sim/render.py: FrameRenderer draws what mujoco.Renderer draws, pixel for pixel, and
switches models in its GL context (what a randomised recording's camera does per episode)."""
import asyncio

from sebvs.sim.render import FrameRenderer  # first: it selects MUJOCO_GL before mujoco loads

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from sebvs.sim import make_scene  # noqa: E402


def posed(scene_name: str, **config):
    scene = make_scene(scene_name, **config)
    model = scene.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return scene, model, data


@pytest.mark.parametrize("scene_name, config", [
    ("nav", {"variant": "outdoor"}), ("nav", {"variant": "indoor", "height": 120}), ("arm", {})])
def test_frames_match_mujocos_own_renderer(scene_name, config):
    scene, model, data = posed(scene_name, **config)
    h, w = scene.image_shape()
    for camera in scene.cameras:
        ref = mujoco.Renderer(model, h, w)
        try:
            ref.update_scene(data, camera=camera)
            rgb = ref.render().copy()
            ref.enable_depth_rendering()
            depth = ref.render().copy()
            ref.disable_depth_rendering()
            ref.enable_segmentation_rendering()
            seg = ref.render().copy()
        finally:
            ref.close()
        with FrameRenderer(model, h, w) as r:
            r.update(data, camera)
            np.testing.assert_array_equal(r.rgb(), rgb, err_msg=camera)
            np.testing.assert_array_equal(r.depth(), depth, err_msg=camera)
            np.testing.assert_array_equal(r.segmentation(), seg, err_msg=camera)
            np.testing.assert_array_equal(r.rgb(), rgb, err_msg=f"{camera}, rgb after seg")
        assert (seg[..., 0] >= 0).any() and depth.min() > 0


def test_a_new_model_renders_as_in_a_fresh_renderer():
    (_, outdoor, d_out), (_, indoor, d_in) = posed("nav", variant="outdoor"), \
        posed("nav", variant="indoor", lighting="low")
    with FrameRenderer(indoor, 160, 160) as fresh:
        fresh.update(d_in, "front")
        expected_indoor = fresh.rgb()
    with FrameRenderer(outdoor, 160, 160) as r:
        r.update(d_out, "front")
        first = r.rgb()
        r.set_model(indoor)
        r.update(d_in, "front")
        np.testing.assert_array_equal(r.rgb(), expected_indoor)
        r.set_model(outdoor)
        r.update(d_out, "front")
        np.testing.assert_array_equal(r.rgb(), first)
    assert not np.array_equal(first, expected_indoor)


def test_bad_cameras_and_small_offscreen_buffers_are_named():
    _, model, data = posed("nav")
    with FrameRenderer(model, 64, 64) as r:
        with pytest.raises(ValueError, match="no camera named 'rear'"):
            r.update(data, "rear")
        with pytest.raises(ValueError, match="camera id 99"):
            r.update(data, 99)
        model.vis.global_.offwidth = 32
        with pytest.raises(ValueError, match="offscreen buffer is 32x"):
            r.set_model(model)


def test_the_camera_keeps_its_renderers_when_the_scene_changes():
    from sebvs_actors.camera import Camera
    from tests.test_sim_actors import FakeNode
    cam = Camera("camera", Camera.Params(luma_scale=0.5), seed=0, clock="lockstep",
                 consumed=frozenset({"rgb", "luma"}), node=FakeNode())
    asyncio.run(cam.setup())
    core = cam.core                  # the rendering (sebvs.sensors.camera)
    core.build("nav", {"variant": "indoor"})
    rgb_r, luma_r = core.renderer, core.luma_renderer
    core.build("nav", {"variant": "outdoor", "lighting": "low"})
    assert core.renderer is rgb_r and core.luma_renderer is luma_r
    assert rgb_r.model is core.model and luma_r.model is core.model
    core.build("nav", {"variant": "outdoor", "width": 96, "height": 96})   # another size
    assert core.renderer is not rgb_r and (core.renderer.height, core.luma_renderer.width) == (96, 48)
    asyncio.run(cam.teardown())


def test_a_view_draws_as_a_renderer_of_its_size_and_follows_the_model():
    (_, outdoor, _), (_, indoor, d_in) = posed("nav", variant="outdoor"), \
        posed("nav", variant="indoor")
    with FrameRenderer(indoor, 80, 80) as alone:
        alone.update(d_in, "front")
        expected = alone.luma(), alone.depth()
    with FrameRenderer(outdoor, 160, 160) as r:
        small = r.view(80, 80)
        r.set_model(indoor)                   # switches the view's model too
        r.update(d_in, "front")               # and poses its scene
        big = r.rgb()
        np.testing.assert_array_equal(small.luma(), expected[0])
        np.testing.assert_array_equal(small.depth(), expected[1])
        np.testing.assert_array_equal(r.rgb(), big)
        assert small.model is indoor and big.shape == (160, 160, 3)
        with pytest.raises(ValueError, match="smaller than the 800x800 render"):
            r.view(800, 800)


def test_rendering_after_close_is_a_clear_error():
    _, model, data = posed("nav")
    r = FrameRenderer(model, 64, 64)
    small = r.view(32, 32)
    r.update(data, "front")
    r.close()
    r.close()                                   # twice: nothing more to free
    for renderer in (r, small):
        with pytest.raises(RuntimeError, match="render after close"):
            renderer.rgb()
