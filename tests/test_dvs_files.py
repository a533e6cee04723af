import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from sebvs.dvs.eventfile import read_events

ROOT = Path(__file__).resolve().parents[1]


def sebvs(*args):
    return subprocess.run([sys.executable, "-m", "sebvs.cli", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


def test_v2e_on_an_image_folder_and_show(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(20):
        img = np.full((48, 64, 3), 30, np.uint8)
        cv2.rectangle(img, (4 + 2 * i, 10), (16 + 2 * i, 30), (255, 255, 255), -1)
        cv2.imwrite(str(frames / f"{i:03d}.png"), img)
    out = tmp_path / "ev.h5"
    r = sebvs("v2e", str(frames), "--out", str(out), "--fps", "100", "--quiet")
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert info["frames"] == 20 and info["events"] > 100
    ev, attrs = read_events(out)
    assert ev.size == info["events"] and (attrs["width"], attrs["height"]) == (32, 24)
    assert np.all(np.diff(ev["t"]) >= 0) and set(np.unique(ev["p"])) <= {-1, 1}
    assert ev["t"].max() <= 190 * 10 ** 6        # 19 frame periods of 10 ms
    part, _ = read_events(out, 50, 100)      # milliseconds from the file's first event
    rel = part["t"] - attrs["t_offset_us"] * 1000
    assert part.size and rel.min() >= 50 * 10 ** 6 and rel.max() < 100 * 10 ** 6
    png = tmp_path / "show.png"
    r = sebvs("events", "show", str(out), "--out", str(png))
    assert r.returncode == 0, r.stderr
    assert png.stat().st_size > 5000


def test_v2e_errors_are_clear(tmp_path):
    r = sebvs("v2e", str(tmp_path / "missing.mp4"), "--out", str(tmp_path / "x.h5"))
    assert r.returncode == 2 and "no such file" in r.stderr
    (tmp_path / "empty").mkdir()
    r = sebvs("v2e", str(tmp_path / "empty"), "--out", str(tmp_path / "x.h5"), "--fps", "30")
    assert r.returncode == 2 and "no images" in r.stderr
