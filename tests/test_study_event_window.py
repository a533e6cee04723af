"""tools/study_event_window.py: its summary pairs each window's episodes with the reference
window's on the same (training seed, condition, scenario, episode seed), and its report
shows the differences and the baseline rows."""
import argparse
import importlib.util
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parents[1] / "tools" / "study_event_window.py"


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("study_event_window", TOOL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def episode(modality, condition, seed, success, strict=0.0):
    return {"modality": modality, "condition": condition, "scenario": "indoor", "seed": seed,
            "metrics": {"success": success, "strict_success": strict, "episode_success": 0.0}}


def test_windows_are_paired_with_the_reference_on_the_same_episodes(tool):
    args = argparse.Namespace(windows=[0.1, 0.4], train_seeds=[0, 1], out=Path("/x"))
    losses = {0.1: {0: 0.03, 1: 0.04}, 0.4: {0: 0.02, 1: None}}
    # 0.4 s wins on three of four (training seed, episode) pairs and ties on one; episode
    # 12 exists only for the 0.4 s window and must not be paired
    base = {0: [episode("event", "nominal", 11, 0.1), episode("event", "nominal", 13, 0.3)],
            1: [episode("event", "nominal", 11, 0.2), episode("event", "nominal", 13, 0.5)]}
    long = {0: [episode("event", "nominal", 11, 0.3), episode("event", "nominal", 13, 0.3),
                episode("event", "nominal", 12, 0.9)],
            1: [episode("event", "nominal", 11, 0.4), episode("event", "nominal", 13, 0.6)]}
    reference = {"episodes": [episode("expert", "nominal", 11, 1.0, 0.5),
                              episode("no_action", "nominal", 11, 0.25)]}
    summary = tool.summarise(args, losses, {0.1: base, 0.4: long}, reference)
    cell = summary["windows"]["0.4"]["cells"]["nominal/indoor"]
    assert cell["episodes"] == 5 and cell["success"] == pytest.approx(2.5 / 5)
    vs = cell["vs_reference"]["success"]
    assert (vs["n"], vs["wins"], vs["losses"], vs["ties"]) == (4, 3, 0, 1)
    assert vs["mean_diff"] == pytest.approx(0.5 / 4)
    assert "vs_reference" not in summary["windows"]["0.1"]["cells"]["nominal/indoor"]
    assert summary["reference_rows"]["no_action"]["nominal/indoor"]["success"] == 0.25
    text = tool.report(summary)
    assert "| 0.4 | 0.02000 | - |" in text
    assert "| no_action | 25.0 |" in text
    assert "| event, window 0.4 s | 50.0 (+12.5, p 0.25) |" in text
