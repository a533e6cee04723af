"""tools/eval/video_strip.py: evenly spaced frames of each video, one row per video."""
from pathlib import Path

import cv2
import numpy as np

from tests.tools_loader import tool_module


def _video(path: Path, frames: int, size=(64, 48)) -> Path:
    """Frame k is a flat grey of level 10 k (MJPG keeps flat levels to within a few DN)."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, size)
    assert writer.isOpened()
    for k in range(frames):
        writer.write(np.full((size[1], size[0], 3), 10 * k, np.uint8))
    writer.release()
    return path


def test_frames_are_spread_from_skip_to_the_last(tmp_path):
    with tool_module("eval/video_strip") as tool:
        frames = tool.read_frames(_video(tmp_path / "a.avi", 21), count=3, skip=2)
        # frames 2, 11 and 20 of 0..20
        assert [round(float(f.mean()) / 10) for f in frames] == [2, 11, 20]


def test_strip_has_a_row_per_video_and_scaled_frames(tmp_path):
    with tool_module("eval/video_strip") as tool:
        a, b = _video(tmp_path / "a.avi", 12), _video(tmp_path / "b.avi", 8)
        out = tmp_path / "strip.png"
        assert tool.main([str(a), str(b), "--frames", "4", "--skip", "0", "--width", "32",
                          "--out", str(out)]) == 0
        image = cv2.imread(str(out))
        assert image.shape == (2 * 24, 4 * 32, 3)      # 64 x 48 frames scaled to 32 x 24
        # the second row's last frame is b's last (level 70), the first row's a's (110)
        assert abs(float(image[24:, 96:].mean()) - 70) < 4
        assert abs(float(image[:24, 96:].mean()) - 110) < 4


def test_bad_input_is_named(tmp_path, capsys):
    with tool_module("eval/video_strip") as tool:
        junk = tmp_path / "junk.mp4"
        junk.write_bytes(b"not a video")
        assert tool.main([str(junk), "--out", str(tmp_path / "x.png")]) == 2
        assert "junk.mp4: not a readable video" in capsys.readouterr().err
        short = _video(tmp_path / "short.avi", 5)
        assert tool.main([str(short), "--skip", "9", "--out", str(tmp_path / "x.png")]) == 2
        assert "past its 5 frames" in capsys.readouterr().err
        assert not (tmp_path / "x.png").exists()
