"""`sebvs eval compare` (sebvs/eval/compare.py): two evaluations pair on (modality, condition, scenario, episode
seed); evaluations of other episodes, and files that are not results.json, are refused by
name; a cell only one side holds is named, not paired."""
import json
from pathlib import Path

import pytest

from tests.eval_readers import reader


@pytest.fixture(scope="module")
def tool():
    with reader("compare") as module:
        yield module


def results(rates: dict, seed: int = 100008, modality: str = "event") -> dict:
    """rates: {(condition, scenario): [paper rate per episode]}, episode seeds 10, 11, ..."""
    episodes = [{"modality": modality, "condition": c, "scenario": s, "seed": 10 + i,
                 "metrics": {"success": r, "strict_success": r / 4,
                             "episode_success": float(r >= 0.9)}}
                for (c, s), rs in rates.items() for i, r in enumerate(rs)]
    return {"task": "nav", "seed": seed, "episodes": episodes}


def write(tmp_path: Path, name: str, data: dict) -> Path:
    d = tmp_path / name
    d.mkdir()
    (d / "results.json").write_text(json.dumps(data))
    return d


def test_pairs_by_episode_seed_and_counts_wins(tool, tmp_path):
    new = results({("nominal", "outdoor"): [0.9, 0.8, 0.5, 0.3]})
    old = results({("nominal", "outdoor"): [0.2, 0.3, 0.5, 0.4],
                   ("fast", "indoor"): [0.1]})         # new has no fast/indoor cell
    out = tool.compare(new, old)
    r = out["event"]["nominal/outdoor"]["success"]
    assert r["a"] == pytest.approx(0.625) and r["b"] == pytest.approx(0.35)
    assert r["mean_diff"] == pytest.approx(0.275)
    assert (r["wins"], r["losses"], r["ties"], r["n"]) == (2, 1, 1, 4)
    assert r["p_sign"] == pytest.approx(1.0)             # 2 of 3 differing pairs
    assert out["unpaired"] == ["event fast/indoor"]
    text = tool.markdown(out, ("160 px", "80 px"))
    assert "| nominal/outdoor | 62.5 | 35.0 | +27.5 |" in text
    assert "Not in both evaluations: event fast/indoor" in text


def test_other_episodes_or_modalities_are_refused_by_name(tool):
    a = results({("nominal", "indoor"): [0.5]})
    with pytest.raises(ValueError, match=r"differ in seed \(100008 vs 100002\)"):
        tool.compare(a, results({("nominal", "indoor"): [0.5]}, seed=100002))
    with pytest.raises(ValueError, match="'rgb' is not in both.*both hold: event"):
        tool.compare(a, results({("nominal", "indoor"): [0.5]}), ["rgb"])


def test_command_line_reads_directories_and_names_bad_files(tool, tmp_path, capsys):
    a = write(tmp_path, "a", results({("nominal", "indoor"): [1.0, 1.0]}))
    b = write(tmp_path, "b", results({("nominal", "indoor"): [0.0, 0.5]}))
    assert tool.main([str(a), str(b), "--json", str(tmp_path / "c.json")]) == 0
    assert "+75.0" in capsys.readouterr().out
    saved = json.loads((tmp_path / "c.json").read_text())
    assert saved["event"]["nominal/indoor"]["success"]["wins"] == 2
    (tmp_path / "bad.json").write_text("{not json")
    assert tool.main([str(a), str(tmp_path / "bad.json")]) == 2
    assert "bad.json: not a readable results.json" in capsys.readouterr().err
    assert tool.main([str(a), str(tmp_path / "none")]) == 2
    assert "none: no such file" in capsys.readouterr().err


def test_arm_evaluations_pair_grasp_success_over_graspable_episodes(tool):
    """An arm episode where the task says HOME has no grasp (grasp_success None): it is
    left out of the pairs, not counted as a failure."""
    def arm(successes):
        return {"task": "arm", "seed": 100014, "episodes": [
            {"modality": "rgb+event", "condition": "fast", "scenario": "single", "seed": i,
             "metrics": {"grasp_success": g}} for i, g in enumerate(successes)]}
    out = tool.compare(arm([True, True, None, False]), arm([False, True, None, False]))
    r = out["rgb+event"]["fast/single"]["grasp_success"]
    assert (r["a"], r["b"], r["n"]) == (pytest.approx(2 / 3), pytest.approx(1 / 3), 3)
    assert (r["wins"], r["losses"], r["ties"]) == (1, 0, 2)
    assert "### rgb+event: grasp success, lead - shipped" in tool.markdown(out, ("lead", "shipped"))
