"""tools/checks/machine_parity.py: a snapshot compared with itself is identical; a render
that differs by 1 DN in one pixel, or a missing piece, is named with its size."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.tools_loader import tool_module

ROOT = Path(__file__).resolve().parents[1]
TOOL = ROOT / "tools" / "checks" / "machine_parity.py"


def test_difference_measures_each_kind_in_its_unit():
    with tool_module("checks/machine_parity") as tool:
        img = np.zeros((2, 4, 4, 3), np.uint8)
        other = img.copy()
        other[1, 2, 3, 0] = 3
        row = tool.difference(img, other)
        assert row == {"equal": False, "share_differing": round(1 / img.size, 4),
                       "max_dn": 3, "mean_dn": round(3 / img.size, 3)}
        lum = np.full((4, 4), 2.0, np.float32)
        brighter = lum.copy()
        brighter[0, 0] = 2.5
        assert tool.difference(lum, brighter)["max_relative"] == pytest.approx(0.25)
        assert tool.difference(lum, lum) == {"equal": True, "share_differing": 0.0}
        assert tool.difference(lum, lum[:2])["shapes"] == [[4, 4], [2, 4]]


def test_compare_names_what_differs_and_what_one_side_lacks():
    with tool_module("checks/machine_parity") as tool:
        a = {"nav_indoor/qpos": np.arange(3.0), "rng/normal": np.ones(5)}
        b = {"nav_indoor/qpos": np.arange(3.0) + [0, 0, 1e-12]}
        report = tool.compare(a, b)
        assert not report["identical"]
        assert report["items"]["nav_indoor/qpos"]["equal"] is False
        assert report["items"]["rng/normal"] == {"equal": False, "only_in": "a"}
        assert tool.compare(a, a)["identical"]


def test_snapshot_of_this_machine_matches_itself(tmp_path):
    """Two snapshots in two processes: the same renders, physics and draws (exit 0)."""
    paths = [tmp_path / "one.npz", tmp_path / "two.npz"]
    for p in paths:
        subprocess.run([sys.executable, str(TOOL), "snapshot", str(p)], check=True,
                       cwd=ROOT, capture_output=True)
    done = subprocess.run([sys.executable, str(TOOL), "compare", *map(str, paths),
                           "--json", str(tmp_path / "r.json")], cwd=ROOT,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    with np.load(paths[0]) as f:
        assert set(f.files) >= {"nav_indoor/rgb", "nav_outdoor/luminance", "arm/qpos",
                                "rng/poisson", "stack"}
        assert f["nav_indoor/rgb"].shape == (4, 160, 160, 3)
        assert f["nav_indoor/rgb"].std() > 0            # a scene, not a blank image


def test_compare_rejects_a_file_that_is_not_a_snapshot(tmp_path):
    text, truncated, single = (tmp_path / n for n in ("bad.npz", "cut.npz", "one.npy"))
    text.write_text("not a zip")
    np.savez(truncated, a=np.zeros(1000))
    truncated.write_bytes(truncated.read_bytes()[:100])        # a zip's start, cut short
    np.save(single, np.zeros(3))
    for bad in (text, truncated, single):
        done = subprocess.run([sys.executable, str(TOOL), "compare", str(bad), str(bad)],
                              cwd=ROOT, capture_output=True, text=True)
        assert done.returncode == 2 and "not a snapshot" in done.stderr, done.stderr[-800:]
