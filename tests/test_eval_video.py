"""Episode videos: frame composition against hand-built inputs, the file writer, and the
video actor's tick join in process (the real run is in tests/test_eval_run.py)."""
import asyncio

import numpy as np
import pytest

from sebvs_actors.video import MAX_PENDING, VideoWriter
from sebvs.eval.video import (CAPTION_PX, EpisodeVideo, caption, centre_error_px,
                              compose_frame, count_frames)
from sebvs.runtime import Message

H = W = 160
GREEN = (0, 255, 0)      # BGR: compose_frame's bbox colour


def truth(bbox=(40.0, 50.0, 100.0, 90.0), centroid=(70.0, 70.0), visible=True):
    return {"centroid": list(centroid), "bbox": list(bbox), "visible": visible,
            "image": [W, H]}


def is_colour(img, bgr):
    return (img == np.array(bgr, np.uint8)).all(axis=-1)


def test_frame_shape_dtype_and_upscaling():
    rgb = np.random.default_rng(0).integers(0, 256, (H, W, 3), dtype=np.uint8)
    out = compose_frame(rgb, None, None, "", scale=3)
    assert out.shape == (3 * H + CAPTION_PX, 3 * W, 3) and out.dtype == np.uint8
    # nearest neighbour, RGB -> BGR: each source pixel is a 3x3 block of its colour
    assert (out[3 * 7:3 * 7 + 3, 3 * 11:3 * 11 + 3] == rgb[7, 11, ::-1]).all()
    assert compose_frame(rgb, None, None, "", scale=2).shape == (2 * H + CAPTION_PX, 2 * W, 3)


def test_bbox_and_centroid_are_marked_where_the_truth_says():
    out = compose_frame(np.zeros((H, W, 3), np.uint8), None, truth(), "", scale=3)
    rows, cols = np.nonzero(is_colour(out, GREEN))
    # bbox [40, 50, 100, 90] px -> columns 120..299, rows 150..269 at scale 3
    assert (rows.min(), rows.max(), cols.min(), cols.max()) == (150, 269, 120, 299)
    assert is_colour(out[150, 120:300], GREEN).all() and is_colour(out[269, 120:300], GREEN).all()
    assert is_colour(out[150:270, 120], GREEN).all() and is_colour(out[150:270, 299], GREEN).all()
    assert not is_colour(out[200, 200], GREEN)                      # an outline, not filled
    assert tuple(out[210, 210]) == (0, 255, 255)                    # the centroid's marker
    # a truth on another pixel grid is scaled to the frame's
    half = truth(bbox=(20.0, 25.0, 50.0, 45.0), centroid=(35.0, 35.0))
    half["image"] = [W // 2, H // 2]
    other = compose_frame(np.zeros((H, W, 3), np.uint8), None, half, "", scale=3)
    assert (is_colour(other, GREEN) == is_colour(out, GREEN)).all()


def test_target_out_of_view_is_not_marked():
    out = compose_frame(np.zeros((H, W, 3), np.uint8), None, truth(visible=False), "")
    assert not is_colour(out, GREEN).any()
    assert caption("rgb", 7, truth(visible=False)) == "rgb  tick 7  target out of view"


def test_events_overlay_on_blue_off_red_and_none_means_no_overlay():
    rgb = np.full((H, W, 3), 100, np.uint8)
    ev = np.zeros((2, H, W), np.uint8)
    ev[0, 10, 10] = 4                     # ON
    ev[1, 20, 30] = 4                     # OFF
    ev[0, 40, 40] = 1                     # a single ON event: paler, still blue
    out = compose_frame(rgb, ev, None, "", scale=3)
    b, g, r = (int(x) for x in out[31, 31])          # pixel (u=10, v=10)
    assert b > 200 and r < 60 and g < 60
    b, g, r = (int(x) for x in out[61, 91])          # pixel (u=30, v=20)
    assert r > 200 and b < 60 and g < 60
    b, g, r = (int(x) for x in out[121, 121])
    assert b > r + 20
    assert tuple(out[3 * 100, 3 * 20]) == (100, 100, 100)      # no event: the scene as it was
    plain = compose_frame(rgb, None, None, "", scale=3)
    assert (compose_frame(rgb, np.zeros((2, H, W), np.uint8), None, "") == plain).all()
    assert tuple(plain[31, 31]) == (100, 100, 100)


def test_caption_is_drawn_below_the_image():
    rgb = np.zeros((H, W, 3), np.uint8)
    t = truth(centroid=(86.0, 92.0))
    text = caption("rgb+event", 42, t)
    assert text == "rgb+event  tick 42  err 13.4 px"
    assert centre_error_px(t) == pytest.approx(np.hypot(6, 12))
    out = compose_frame(rgb, None, t, text)
    assert out[3 * H:].any() and not compose_frame(rgb, None, t, "")[3 * H:].any()


@pytest.mark.parametrize("rgb, events, scale, match", [
    (np.zeros((H, W), np.uint8), None, 3,
     r"rgb: expected \[H, W, 3\] uint8, got shape \[160, 160\]"),
    (np.zeros((H, W, 4), np.uint8), None, 3, r"rgb: .*got shape \[160, 160, 4\]"),
    (np.zeros((H, W, 3), np.float32), None, 3, r"rgb: .*dtype float32"),
    (np.zeros((H, W, 3), np.uint8), np.zeros((H, W, 2), np.uint8), 3,
     r"events: expected \[2, 160, 160\] .*got shape \[160, 160, 2\]"),
    (np.zeros((H, W, 3), np.uint8), np.zeros((2, 80, 80), np.uint8), 3,
     r"events: expected \[2, 160, 160\] .*got shape \[2, 80, 80\]"),
    (np.zeros((H, W, 3), np.uint8), None, 0, r"scale: expected an integer >= 1"),
])
def test_bad_inputs_raise_naming_the_problem(rgb, events, scale, match):
    with pytest.raises(ValueError, match=match):
        compose_frame(rgb, events, None, "", scale=scale)


def test_episode_video_is_readable_back(tmp_path):
    video = EpisodeVideo(tmp_path / "v" / "a.mp4", fps=10)
    rgb = np.zeros((H, W, 3), np.uint8)
    for k in range(5):
        rgb[:, :, 1] = 40 * k
        video.write(compose_frame(rgb, None, truth(), caption("rgb", k, truth())))
    with pytest.raises(ValueError, match="frame size"):
        video.write(np.zeros((10, 10, 3), np.uint8))
    assert video.close() == 5
    assert video.path == tmp_path / "v" / "a.mp4"      # mp4v works with this OpenCV
    assert count_frames(video.path) == 5


# ---------------------------------------------------------------- the actor, in process
class FakeNode:
    def __init__(self):
        self.events = []

    def event(self, kind, fields):
        self.events.append((kind, fields))


def msg(output, tick, arrays, meta):
    return Message(topic="t", source="x", output=output, seq=tick, t_sim=tick * 0.1, tick=tick,
                   stamps=[], meta=meta, arrays=arrays)


def rgb_msg(tick, episode=0):
    img = np.full((H, W, 3), 10 * tick % 256, np.uint8)
    return msg("rgb", tick, {"rgb": img}, {"episode": episode, "control": True,
                                          "truth": truth()})


def ev_msg(tick):
    frame = np.zeros((2, H, W), np.uint8)
    frame[0, 5, 5] = 3
    return msg("frames", tick, {"frame": frame}, {"episode": 0, "control": True,
                                                  "representation": "counts"})


def end_msg(tick, episode=0):
    return msg("episode", tick, {}, {"event": "end", "episode": episode})


def make_writer(tmp_path, connected, **params):
    node = FakeNode()
    actor = VideoWriter("video", VideoWriter.Params(directory=str(tmp_path), prefix="c__m",
                                                    **params),
                        connected=frozenset(connected), node=node)
    return actor, node


def test_actor_joins_by_tick_in_any_order_and_closes_at_the_episode_end(tmp_path):
    async def go():
        actor, node = make_writer(tmp_path, {"rgb", "events", "episode"})
        await actor.setup()
        await actor.on_events(ev_msg(0))           # events first
        await actor.on_rgb(rgb_msg(0))
        await actor.on_rgb(rgb_msg(1))             # rgb first: waits for its events
        assert actor.counts["frames"] == 1
        await actor.on_events(ev_msg(1))
        await actor.on_rgb(rgb_msg(2))             # tick 2's event frame is lost...
        await actor.on_rgb(rgb_msg(3))
        await actor.on_events(ev_msg(3))           # ... as tick 3's shows
        await actor.on_events(ev_msg(2))           # too late: dropped
        await actor.on_episode(end_msg(3))         # everything up to tick 3 written: closes
        await actor.on_rgb(rgb_msg(4, episode=1))  # beyond `episodes`: ignored
        assert not actor.videos and not actor.rgb
        await actor.teardown()
        return actor, node

    actor, node = asyncio.run(go())
    s = actor.stats()
    assert (s["frames"], s["without_overlay"], s["late"]) == (4, 1, 1)
    assert s["files"] == [{"episode": 0, "path": str(tmp_path / "c__m__ep0.mp4"), "frames": 4}]
    assert count_frames(tmp_path / "c__m__ep0.mp4") == 4
    assert [k for k, _ in node.events] == ["video"]
    assert not (tmp_path / "c__m__ep1.mp4").exists()


def test_actor_without_events_writes_at_once_and_holds_no_backlog(tmp_path):
    async def go(connected, n):
        actor, _ = make_writer(tmp_path / "-".join(sorted(connected)), connected, episodes=2)
        await actor.setup()
        for tick in range(n):
            await actor.on_rgb(rgb_msg(tick))
            assert len(actor.rgb) <= MAX_PENDING
        await actor.on_rgb(rgb_msg(n, episode=1))   # a new episode closes the last one
        await actor.teardown()                       # and teardown the open one
        return actor

    rgb_only = asyncio.run(go({"rgb", "episode"}, 5))
    assert rgb_only.counts == {"frames": 6, "without_overlay": 0, "late": 0, "ignored_events": 0}
    assert [f["frames"] for f in rgb_only.stats()["files"]] == [5, 1]
    # events wired but none ever arrive: frames go out without overlay, the backlog bounded
    starved = asyncio.run(go({"rgb", "events", "episode"}, MAX_PENDING + 10))
    assert starved.counts["frames"] == MAX_PENDING + 11
    assert starved.counts["without_overlay"] == MAX_PENDING + 11


def test_a_batch_of_rgb_ahead_of_its_event_frames_is_not_taken_for_loss(tmp_path):
    # a writer that fell behind reads up to DRAIN_BATCH (64) messages of one input before
    # the other's: 64 RGB frames, then their 64 event frames, all still to be overlaid
    from sebvs.runtime.inputs import DRAIN_BATCH

    async def go():
        actor, _ = make_writer(tmp_path, {"rgb", "events", "episode"})
        await actor.setup()
        for tick in range(DRAIN_BATCH):
            await actor.on_rgb(rgb_msg(tick))
        for tick in range(DRAIN_BATCH):
            await actor.on_events(ev_msg(tick))
        await actor.teardown()
        return actor

    actor = asyncio.run(go())
    assert actor.counts["frames"] == DRAIN_BATCH and actor.counts["without_overlay"] == 0


def test_actor_with_empty_directory_writes_nothing(tmp_path):
    async def go():
        actor = VideoWriter("video", VideoWriter.Params(), connected=frozenset({"rgb"}),
                            node=FakeNode())
        await actor.setup()
        await actor.on_rgb(rgb_msg(0))
        await actor.teardown()
        return actor

    assert asyncio.run(go()).counts["frames"] == 0


def test_actor_overlays_every_representation_and_counts_what_it_cannot(tmp_path):
    """A time surface and a histogram overlay as the viewer draws them; a frame whose
    planes are no ON/OFF pair is counted, once warned, never raised."""
    def frame_msg(tick, frame, representation):
        return msg("frames", tick, {"frame": frame}, {"episode": 0, "control": True,
                                                      "representation": representation})

    async def go():
        actor, _ = make_writer(tmp_path, {"rgb", "events", "episode"})
        await actor.setup()
        surface = np.zeros((2, H, W), np.uint8)
        surface[0, 5, 5] = 255
        hist = np.zeros((4, H, W), np.uint8)
        hist[1, 5, 5] = 2
        await actor.on_events(frame_msg(0, surface, "time_surface"))
        await actor.on_events(frame_msg(1, hist, "histogram"))
        await actor.on_events(frame_msg(2, np.zeros((3, H, W), np.uint8), "histogram"))
        held = {t: f.copy() for t, f in actor.events.items()}
        for tick in range(3):
            await actor.on_rgb(rgb_msg(tick))
        await actor.on_episode(end_msg(2))
        await actor.teardown()
        return actor, held

    actor, held = asyncio.run(go())
    assert sorted(held) == [0, 1]
    assert held[0].shape == held[1].shape == (2, H, W)
    assert held[0][0, 5, 5] == 4 and held[1][0, 5, 5] == 2      # full colour; two counts
    s = actor.stats()
    assert (s["frames"], s["without_overlay"], s["ignored_events"]) == (3, 1, 1)
