"""research/ideal8/study_fusion.py: each RGB+Event arm pairs with RGB-only, and gated with early
fusion, on the same (training seed, condition, scenario, episode seed); the report shows
the paired differences beside the baseline rows; the arms name their sweep points."""
import argparse
from pathlib import Path

import pytest

from research.tests.study_loader import RESEARCH, study_module


@pytest.fixture(scope="module")
def tool():
    with study_module("ideal8/study_fusion") as module:
        yield module


def episode(modality, seed, success, condition="fast"):
    return {"modality": modality, "condition": condition, "scenario": "outdoor", "seed": seed,
            "metrics": {"success": success, "strict_success": success / 2,
                        "episode_success": 0.0}}


def test_arms_pair_on_the_same_episodes(tool, tmp_path):
    args = argparse.Namespace(out=Path("/x"), eval_seed=100006)
    losses = {("rgb", 0): 0.02, ("rgb", 1): 0.03, ("early", 0): 0.021, ("early", 1): None,
              ("gated", 0): 0.019, ("gated", 1): 0.028}
    arm_eps = {
        "rgb": {0: [episode("rgb", 5, 0.5), episode("rgb", 6, 0.5)],
                1: [episode("rgb", 5, 0.4), episode("rgb", 6, 0.6)]},
        "early": {0: [episode("rgb+event", 5, 0.7), episode("rgb+event", 6, 0.5)],
                  1: [episode("rgb+event", 5, 0.6), episode("rgb+event", 6, 0.7)]},
        # episode 7 has no partner in the other arms: counted in the mean, never paired
        "gated": {0: [episode("rgb+event", 5, 0.9), episode("rgb+event", 6, 0.4),
                      episode("rgb+event", 7, 1.0)],
                  1: [episode("rgb+event", 5, 0.6), episode("rgb+event", 6, 0.9)]}}
    reference = {"episodes": [episode("expert", 5, 1.0), episode("no_action", 5, 0.2),
                              episode("no_action", 6, 0.3)]}
    summary = tool.summarise(args, losses, arm_eps, reference)
    early = summary["arms"]["early"]["cells"]["fast/outdoor"]
    assert early["success"] == pytest.approx(2.5 / 4) and early["episodes"] == 4
    vs = early["vs_rgb"]["success"]           # +0.2, 0, +0.2, +0.1
    assert (vs["n"], vs["wins"], vs["losses"], vs["ties"]) == (4, 3, 0, 1)
    assert vs["mean_diff"] == pytest.approx(0.5 / 4)
    gated = summary["arms"]["gated"]["cells"]["fast/outdoor"]
    assert gated["episodes"] == 5 and set(gated) >= {"vs_rgb", "vs_early"}
    vs = gated["vs_early"]["success"]         # +0.2, -0.1, 0, +0.2
    assert (vs["n"], vs["wins"], vs["losses"], vs["ties"]) == (4, 2, 1, 1)
    assert "vs_early" not in early and not any(k.startswith("vs_") for k in
                                                summary["arms"]["rgb"]["cells"]["fast/outdoor"])
    assert summary["arms"]["early"]["best_val_mse"] == {"0": 0.021, "1": None}
    assert summary["reference_rows"]["no_action"]["fast/outdoor"]["success"] == \
        pytest.approx(0.25)
    text = tool.report(summary)
    assert "| RGB+Event, early fusion | 0.02100 | - |" in text
    assert "| no_action | 25.0 |" in text
    assert "| early - rgb | +12.5, p 0.25 |" in text
    assert "| gated - early | +7.5, p 1.00 |" in text
    assert "| RGB+Event, gated fusion | 76.0 |" in text
    tool.plot(summary, tmp_path / "study.png")
    assert (tmp_path / "study.png").read_bytes()[:4] == b"\x89PNG"


def test_arms_find_their_sweep_points(tool):
    args = argparse.Namespace(out=Path("/s"))
    assert tool.checkpoint_dir(args, "rgb", 1) == Path("/s/train/conv/modality=rgb__seed=1")
    assert tool.checkpoint_dir(args, "gated", 0) == \
        Path("/s/train/gated/modality=rgb+event__seed=0")
    for arm, (modality, stem, grid) in tool.ARMS.items():
        text = (RESEARCH / "ideal8" / "grids" / f"{grid}.toml").read_text()
        assert f'stem = "{stem}"' in text and f'"{modality}"' in text


def test_other_training_seeds_rewrite_only_the_seed_axis(tool, tmp_path):
    grid = RESEARCH / "ideal8" / "grids" / "nav_fusion_gated.toml"
    assert tool.grid_with_seeds(grid, None, tmp_path) == grid
    copy = tool.grid_with_seeds(grid, [2, 3, 4], tmp_path)
    assert copy.parent == tmp_path / "grids"
    old, new = grid.read_text().splitlines(), copy.read_text().splitlines()[1:]
    assert [(a, b) for a, b in zip(old, new) if a != b] == [("seed = [0, 1]", "seed = [2, 3, 4]")]
    assert len(old) == len(new)


def test_paired_cells_say_below_one_percent_and_nothing_paired():
    from research.ideal8.studyio import paired_text
    assert paired_text({"n": 20, "mean_diff": 0.166, "p_sign": 0.0004}) == "+16.6, p < 0.01"
    assert paired_text({"n": 20, "mean_diff": -0.021, "p_sign": 0.5}) == "-2.1, p 0.50"
    assert paired_text({"n": 0, "mean_diff": 0.0, "p_sign": 1.0}) == paired_text(None) == "-"


def test_a_study_refuses_an_eval_seed_outside_the_test_split():
    import argparse

    from research.ideal8.studyio import test_seed
    assert test_seed("100006") == 100006
    with pytest.raises(argparse.ArgumentTypeError, match="5 is not a test seed"):
        test_seed("5")
