"""An evaluation read back: its results.json, its episodes by cell, the metrics read from them.

    from sebvs.eval.results import episodes_by_key, read_results
    results = read_results(Path("out/eval"))          # the directory or its results.json
    event = episodes_by_key(results, "event")          # {(condition, scenario, seed): episode}

What `sebvs eval compare` (compare.py), `sebvs eval table` (table.py) and the helpers in
tools/eval/ read of an evaluation that `sebvs eval` wrote (report.py describes the file).
"""
from __future__ import annotations

import json
from pathlib import Path

# the nav metrics every table reads, with their names in a table's header
METRICS = (("success", "paper rate"), ("strict_success", "strict rate"),
           ("episode_success", "episode success"))

# the arm's grasp_success is None where the task says HOME: those episodes have no grasp
TASK_METRICS = {"nav": METRICS, "arm": (("grasp_success", "grasp success"),)}


def results_path(path: Path) -> Path:
    """The results.json an `sebvs eval --out` directory (or the file itself) names."""
    path = Path(path)
    return path / "results.json" if path.is_dir() else path


def read_results(path: Path) -> dict:
    """An evaluation's results.json, from the file or the directory holding it.

    Parameters:
        path: an `sebvs eval --out` directory, or the results.json in one.

    Returns:
        The file's dict (it holds an "episodes" list).

    Raises:
        ValueError: naming the path, where there is no such file, it is not JSON, or it
            holds no "episodes" list (not an `sebvs eval` results.json).
    """
    path = results_path(path)
    try:
        results = json.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: no such file (an `sebvs eval --out` directory or its "
                         f"results.json)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not a readable results.json ({exc})") from None
    if not isinstance(results, dict) or not isinstance(results.get("episodes"), list):
        raise ValueError(f"{path}: no 'episodes' list: not an `sebvs eval` results.json")
    return results


def episodes_by_key(results: dict, modality: str) -> dict[tuple, dict]:
    """One modality's episodes, by what pairs them with another row's or evaluation's.

    Parameters:
        results: an evaluation's results.json dict (read_results).
        modality: the row ("rgb+event", "expert", "event@fr" once tagged, ...).

    Returns:
        {(condition, scenario, episode seed): episode}: an episode of another modality or
        evaluation with the same key played the same scene.
    """
    return {(e["condition"], e["scenario"], e["seed"]): e
            for e in results["episodes"] if e["modality"] == modality}


def task_metrics(results: dict) -> tuple[tuple[str, str], ...]:
    """The metrics the helpers read of an evaluation's task.

    Parameters:
        results: an evaluation's results.json dict.

    Returns:
        (metric, label) pairs: nav's three rates, the arm's grasp success; nav's for a
        task this does not know.
    """
    return TASK_METRICS.get(results.get("task"), METRICS)
