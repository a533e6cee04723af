"""What the closed-loop studies under tools/ share: running `sebvs`, evaluating a policy on
the test split (once: a finished evaluation is read back), and pairing episodes.

An episode is one line of `sebvs eval`'s results.json ("modality", "condition", "scenario",
"seed", "metrics"). Two policies' episodes pair when they have the same training seed,
condition, scenario and episode seed: the same scene, played by two policies.
"""
from __future__ import annotations

import json
import statistics
import subprocess
import sys
from pathlib import Path

from sebvs.metrics import paired_comparison

ROOT = Path(__file__).resolve().parents[1]
METRICS = (("success", "paper rate"), ("strict_success", "strict rate"),
           ("episode_success", "episode success"))


def sebvs(*args: str) -> None:
    """Run one `sebvs` command from the checkout's root, echoed first; raise if it fails."""
    print("+ sebvs " + " ".join(args), flush=True)
    subprocess.run([sys.executable, "-m", "sebvs.cli", *args], cwd=ROOT, check=True)


def evaluate(args, name: str, extra: list[str]) -> dict:
    """`sebvs eval --task nav --split test` into ``args.out/eval/name``, unless its
    results.json exists; returns the results. ``args`` carries out, eval_seed,
    eval_episodes, conditions, scenarios and workers."""
    out = args.out / "eval" / name
    results = out / "results.json"
    if not results.is_file():
        sebvs("eval", "--task", "nav", "--split", "test", "--seed", str(args.eval_seed),
              "--episodes", str(args.eval_episodes), "--conditions", args.conditions,
              "--scenarios", args.scenarios, "--out", str(out), "--workers",
              str(args.workers), *extra)
    res = json.loads(results.read_text())
    if res.get("seed") != args.eval_seed:
        raise SystemExit(f"{results}: evaluated on topology seed {res.get('seed')}, this "
                         f"study's is {args.eval_seed}: use another --out")
    return res


def best_losses(train_dir: Path) -> dict:
    """A train-sweep's best validation loss per point: {(modality, seed): loss or None}."""
    sweep = json.loads((train_dir / "sweep.json").read_text())
    return {(p["settings"]["modality"], p["settings"]["seed"]): p.get("best_val_loss")
            for p in sweep["points"]}


def cells(episodes: list[dict]) -> dict[tuple[str, str], list[dict]]:
    out: dict = {}
    for ep in episodes:
        out.setdefault((ep["condition"], ep["scenario"]), []).append(ep)
    return out


def baseline_rows(reference: dict) -> dict:
    """The expert's and the no-action baseline's metric means per "condition/scenario"."""
    rows: dict = {}
    for key, eps in cells(reference["episodes"]).items():
        for modality in ("expert", "no_action"):
            mine = [e for e in eps if e["modality"] == modality]
            if mine:
                rows.setdefault(modality, {})[f"{key[0]}/{key[1]}"] = {
                    m: statistics.fmean(e["metrics"][m] for e in mine) for m, _ in METRICS}
    return rows


def keyed(episodes_by_seed: dict) -> dict:
    """{training seed: episodes} -> {(seed, condition, scenario, episode seed): episode}."""
    return {(s, e["condition"], e["scenario"], e["seed"]): e
            for s, eps in episodes_by_seed.items() for e in eps}


def cell_summary(mine: dict, against: dict[str, dict] | None = None) -> dict:
    """Per "condition/scenario" of keyed episodes ``mine``: each metric's mean over every
    episode of every training seed, the episode count, and for each ``against`` (a name ->
    keyed episodes) the paired comparison on the keys both have, under "vs_<name>"."""
    out = {}
    for cond, scen in sorted({(k[1], k[2]) for k in mine}):
        keys = sorted(k for k in mine if k[1:3] == (cond, scen))
        cell = {m: statistics.fmean(mine[k]["metrics"][m] for k in keys) for m, _ in METRICS}
        cell["episodes"] = len(keys)
        for name, base in (against or {}).items():
            paired = [k for k in keys if k in base]
            cell[f"vs_{name}"] = {
                m: paired_comparison([mine[k]["metrics"][m] for k in paired],
                                     [base[k]["metrics"][m] for k in paired])
                for m, _ in METRICS}
        out[f"{cond}/{scen}"] = cell
    return out
