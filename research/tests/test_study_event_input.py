"""research/ideal8/study_event_input.py: its summary pairs each variant's episodes with the
reference variant's on the same (training seed, condition, scenario, episode seed), its
report shows the differences and the baseline rows, and its variants parse and name their
outputs."""
import argparse
from pathlib import Path

import pytest

from research.tests.study_loader import study_module


@pytest.fixture(scope="module")
def tool():
    with study_module("ideal8/study_event_input") as module:
        yield module


def episode(modality, condition, seed, success, strict=0.0):
    return {"modality": modality, "condition": condition, "scenario": "indoor", "seed": seed,
            "metrics": {"success": success, "strict_success": strict, "episode_success": 0.0}}


def test_variants_parse_and_keep_the_window_study_s_names(tool):
    counts, bins = tool.Variant.parse("0.1"), tool.Variant.parse("0.4x4")
    assert (counts.window, counts.bins, counts.tag, counts.label) == (0.1, 1, "w0.1", "0.1")
    assert (bins.window, bins.bins, bins.tag, bins.label) == (0.4, 4, "w0.4_h4", "0.4x4")
    # the sensor is always set: the nav topologies' own changed (80 px, then 160 px)
    assert counts.accumulator_sets() == ["--set", "accumulator.window_s=0.1",
                                         "--set", "camera.luma_scale=0.5"]
    assert bins.accumulator_sets()[2:] == ["--set", 'accumulator.representation="histogram"',
                                           "--set", "accumulator.bins=4",
                                           "--set", "camera.luma_scale=0.5"]
    full = tool.Variant.parse("0.4x4@1")
    assert (full.sensor, full.tag, full.label) == (1.0, "w0.4_h4_s1", "0.4x4@1")
    assert full.accumulator_sets()[-2:] == ["--set", "camera.luma_scale=1.0"]
    assert full.description == "4 bins, 0.4 s, sensor x1"
    for bad in ("x4", "0.1x", "0.1x0", "-1", "fast", "0.1@", "0.1@2"):
        with pytest.raises(ValueError, match="variant"):
            tool.Variant.parse(bad)


def test_variants_are_paired_with_the_reference_on_the_same_episodes(tool):
    ref, binned = tool.Variant(0.1), tool.Variant(0.1, 4)
    args = argparse.Namespace(variants=[ref, binned], reference=ref, train_seeds=[0, 1],
                              out=Path("/x"))
    losses = {ref: {0: 0.03, 1: 0.04}, binned: {0: 0.02, 1: None}}
    # the binned input wins on three of four (training seed, episode) pairs and ties on
    # one; episode 12 exists only for it and must not be paired
    base = {0: [episode("event", "nominal", 11, 0.1), episode("event", "nominal", 13, 0.3)],
            1: [episode("event", "nominal", 11, 0.2), episode("event", "nominal", 13, 0.5)]}
    other = {0: [episode("event", "nominal", 11, 0.3), episode("event", "nominal", 13, 0.3),
                 episode("event", "nominal", 12, 0.9)],
             1: [episode("event", "nominal", 11, 0.4), episode("event", "nominal", 13, 0.6)]}
    reference = {"episodes": [episode("expert", "nominal", 11, 1.0, 0.5),
                              episode("no_action", "nominal", 11, 0.25)]}
    summary = tool.summarise(args, losses, {ref: base, binned: other}, reference)
    assert summary["config"]["variants"] == ["0.1", "0.1x4"]
    cell = summary["variants"]["0.1x4"]["cells"]["nominal/indoor"]
    assert cell["episodes"] == 5 and cell["success"] == pytest.approx(2.5 / 5)
    vs = cell["vs_reference"]["success"]
    assert (vs["n"], vs["wins"], vs["losses"], vs["ties"]) == (4, 3, 0, 1)
    assert vs["mean_diff"] == pytest.approx(0.5 / 4)
    assert "vs_reference" not in summary["variants"]["0.1"]["cells"]["nominal/indoor"]
    assert summary["reference_rows"]["no_action"]["nominal/indoor"]["success"] == 0.25
    text = tool.report(summary)
    assert "| 4 bins, 0.1 s | 0.02000 | - |" in text
    assert "| no_action | 25.0 |" in text
    assert "| event, 4 bins, 0.1 s | 50.0 (+12.5, p 0.25) |" in text
    assert "difference to counts, 0.1 s" in text
