"""Episode videos of a closed-loop run: what the policy saw, the events, and the truth.

`compose_frame` turns one control tick into one picture: the RGB frame, upscaled
(nearest neighbour: the policy's pixels stay visible as pixels), the event frame of the
same tick overlaid in the colours of `sebvs.dvs.render.event_image` (ON blue, OFF red),
the target's privileged bbox and centroid, and a caption strip below. `EpisodeVideo`
writes such pictures to a file. Neither knows about processes or sockets
(`actors/video.py` wires them to a run).
"""
from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from sebvs.dvs.render import event_image

from ..metrics import centre_error_px

CAPTION_PX = 22              # height of the caption strip below the image
EVENT_ALPHA = 0.8            # events over the RGB: opaque enough to read, the scene still shows
BBOX_BGR = (0, 255, 0)
CENTROID_BGR = (0, 255, 255)
CENTRE_BGR = (200, 200, 200)
TEXT_BGR = (255, 255, 255)

log = logging.getLogger(__name__)


def caption(label: str, tick: int | None, truth: dict | None) -> str:
    """The caption line of one frame: label (modality), tick, and the nav target's centre
    error or the arm task's mode (grasp / home_none / home_workspace)."""
    parts = [label] if label else []
    parts.append(f"tick {tick}" if tick is not None else "tick ?")
    if truth and "mode" in truth:
        parts.append(truth["mode"])
    else:
        err = centre_error_px(truth) if truth else None
        parts.append(f"err {err:.1f} px" if err is not None else "target out of view")
    return "  ".join(parts)


def _arm_target(truth: dict) -> tuple[float, float] | None:
    """The arm truth's target cube in the image (uv px), or None when there is none."""
    t = truth.get("target", -1)
    return tuple(truth["cubes"][t]["uv"]) if t is not None and t >= 0 else None


def compose_frame(rgb: np.ndarray, events: np.ndarray | None, truth: dict | None,
                  text: str = "", scale: int = 3) -> np.ndarray:
    """One video frame of a control tick.

    rgb     [H, W, 3] uint8, RGB order (as the camera publishes it)
    events  [2, H, W] event counts (ON, OFF) at the RGB frame's size, or None: no overlay
    truth   the sim's privileged truth (camera meta `truth`): nav centroid [u, v] px, bbox
            [u0, v0, u1, v1] px (continuous pixel coordinates, clipped to the image),
            visible; or the arm's cubes [{uv}] and target index (the target is marked);
            optional image [width, height] when the truth's pixel grid differs from the
            frame's. None, not visible or no target: nothing marked.
    text    one caption line (ASCII; OpenCV's Hershey fonts have no other glyphs)
    Returns [H * scale + CAPTION_PX, W * scale, 3] uint8, BGR order (OpenCV's, for
    cv2.VideoWriter). Frame pixel (u, v) covers rows v*scale .. v*scale + scale - 1 and
    the same columns: the caption is below the image so that image coordinates stay
    plain multiples of `scale`.
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"rgb: expected [H, W, 3] uint8, got shape {list(rgb.shape)} "
                         f"dtype {rgb.dtype}")
    h, w = rgb.shape[:2]
    if not isinstance(scale, (int, np.integer)) or scale < 1:
        raise ValueError(f"scale: expected an integer >= 1, got {scale!r}")
    img = rgb.astype(np.float32)
    if events is not None:
        events = np.asarray(events)
        if events.shape != (2, h, w):
            raise ValueError(f"events: expected [2, {h}, {w}] (ON, OFF counts at the rgb "
                             f"frame's size), got shape {list(events.shape)}")
        if not np.issubdtype(events.dtype, np.number):
            raise ValueError(f"events: expected numeric counts, got dtype {events.dtype}")
        # only pixels with an event are tinted: event_image's white background would
        # otherwise wash the whole scene out
        hit = (events > 0).any(axis=0)
        colours = event_image(events).astype(np.float32)
        img[hit] = EVENT_ALPHA * colours[hit] + (1 - EVENT_ALPHA) * img[hit]
    img = np.ascontiguousarray(np.round(img).astype(np.uint8)[..., ::-1])
    big = cv2.resize(img, (w * scale, h * scale), interpolation=cv2.INTER_NEAREST)
    out = np.zeros((h * scale + CAPTION_PX, w * scale, 3), np.uint8)
    out[:h * scale] = big
    view = out[:h * scale]      # drawing stays inside the image, off the caption strip
    c = (w * scale // 2, h * scale // 2)
    cv2.drawMarker(view, c, CENTRE_BGR, cv2.MARKER_CROSS, 2 * scale + 4, 1)
    if truth and "cubes" in truth:        # the arm: mark the task's target cube
        iw, ih = truth.get("image", (w, h))
        uv = _arm_target(truth)
        if uv is not None:
            cv2.drawMarker(view, (round(uv[0] * scale * w / iw), round(uv[1] * scale * h / ih)),
                           CENTROID_BGR, cv2.MARKER_TILTED_CROSS, 4 * scale, 1)
    elif truth and truth.get("visible"):
        iw, ih = truth.get("image", (w, h))
        sx, sy = scale * w / iw, scale * h / ih
        u0, v0, u1, v1 = truth["bbox"]
        p0 = (_clamp(round(u0 * sx), w * scale), _clamp(round(v0 * sy), h * scale))
        # bbox edges are continuous coordinates: the last covered pixel is one before u1
        p1 = (_clamp(round(u1 * sx) - 1, w * scale), _clamp(round(v1 * sy) - 1, h * scale))
        cv2.rectangle(view, p0, p1, BBOX_BGR, 1)
        u, v = truth["centroid"]
        cv2.drawMarker(view, (round(u * sx), round(v * sy)), CENTROID_BGR,
                       cv2.MARKER_TILTED_CROSS, 3 * scale, 1)
    if text:
        safe = text.encode("ascii", "replace").decode()
        cv2.putText(out, safe, (4, h * scale + CAPTION_PX - 7), cv2.FONT_HERSHEY_SIMPLEX,
                    0.45, TEXT_BGR, 1, cv2.LINE_AA)
    return out


def _clamp(x: int, n: int) -> int:
    return min(max(x, 0), n - 1)


class EpisodeVideo:
    """One episode's video file, opened at the first frame (its size sets the video's).

    MP4 with the `mp4v` codec; where this OpenCV cannot write that, Motion-JPEG in an
    .avi next to it (`path` then names the file actually written). Frames of another
    size than the first are refused: a video cannot change size.
    """

    def __init__(self, path: str | Path, fps: float) -> None:
        self.path = Path(path)
        self.fps = float(fps)
        self.frames = 0
        self._writer: cv2.VideoWriter | None = None
        self._size: tuple[int, int] | None = None

    def _open(self, size: tuple[int, int]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), self.fps,
                                 size)
        if not writer.isOpened():
            avi = self.path.with_suffix(".avi")
            log.warning("%s: this OpenCV cannot write mp4v; writing MJPG to %s",
                        self.path, avi)
            self.path = avi
            writer = cv2.VideoWriter(str(avi), cv2.VideoWriter_fourcc(*"MJPG"), self.fps, size)
            if not writer.isOpened():
                raise RuntimeError(f"{self.path}: OpenCV can write neither mp4v nor MJPG")
        self._writer, self._size = writer, size

    def write(self, frame: np.ndarray) -> None:
        """frame: [H, W, 3] uint8 BGR (as compose_frame returns)."""
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            raise ValueError(f"frame: expected [H, W, 3] uint8 BGR, got shape "
                             f"{list(frame.shape)} dtype {frame.dtype}")
        size = (frame.shape[1], frame.shape[0])
        if self._writer is None:
            if self.frames:
                raise ValueError(f"{self.path}: already closed")
            self._open(size)
        elif size != self._size:
            raise ValueError(f"{self.path}: frame size {size} differs from the video's "
                             f"{self._size}")
        self._writer.write(frame)
        self.frames += 1

    def close(self) -> int:
        """Finish the file (an MP4 is unreadable until then); returns the frame count."""
        if self._writer is not None:
            self._writer.release()
            self._writer = None
        return self.frames


def count_frames(path: str | Path) -> int:
    """Frames that OpenCV decodes from a video file (0 if it cannot open it)."""
    cap = cv2.VideoCapture(str(path))
    n = 0
    try:
        while cap.isOpened():
            ok, _ = cap.read()
            if not ok:
                break
            n += 1
    finally:
        cap.release()
    return n
