"""What the 8-bit benchmark's closed-loop studies here (study_event_input.py, study_fusion.py)
share: running `sebvs`, evaluating a policy on the test split (once: a finished evaluation
is read back), and pairing episodes. Once tools/studyio.py; the metrics' names it reads
are sebvs/eval/results.py's METRICS, which the helpers there use too.

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

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.metrics import paired_comparison, points  # noqa: E402
from sebvs.eval.results import METRICS  # noqa: E402


def sebvs(*args: str) -> None:
    """Run one `sebvs` command from the checkout's root, echoed first; raise if it fails."""
    print("+ sebvs " + " ".join(args), flush=True)
    subprocess.run([sys.executable, "-m", "sebvs.cli", *args], cwd=ROOT, check=True)


def test_seed(text: str) -> int:
    """An --eval-seed: an integer in the test split (sebvs/data/splits.py), else refused."""
    import argparse
    seed = int(text)
    if seed < 100000:
        raise argparse.ArgumentTypeError(f"{seed} is not a test seed: test seeds are 100000 "
                                         f"and above (sebvs/data/splits.py)")
    return seed


def study_parser(doc: str, name: str, seed: int, conditions: str):
    """A study's command line with what every study takes: --out (default out/NAME) and
    the closed-loop options: the test seed (default ``seed``), episodes per cell,
    conditions (default ``conditions``), scenarios and workers. ``doc`` is its --help."""
    import argparse
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "out" / name)
    ap.add_argument("--eval-seed", type=test_seed, default=seed,
                    help=f"test-split topology seed (100000+), one no earlier study used "
                         f"(100004: window study; 100005: bins study; 100006 and 100007: "
                         f"fusion study and its replication; 100008: the shipped nav "
                         f"checkpoints; 100009: bins and sensor together; default {seed})")
    ap.add_argument("--eval-episodes", type=int, default=10, help="episodes per cell")
    ap.add_argument("--conditions", default=conditions, help=f"default {conditions}")
    ap.add_argument("--scenarios", default="indoor,outdoor")
    ap.add_argument("--workers", type=int, default=2)
    return ap


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


def evaluate_policy(args, name: str, modality: str, checkpoints: Path,
                    extra: tuple[str, ...] = ()) -> list[dict]:
    """One checkpoint directory's ``modality`` policy alone (no expert, no baseline: the
    "reference" evaluation has those), on the study's episodes; returns its episodes."""
    return evaluate(args, name, ["--modalities", modality, "--no-expert", "--no-baseline",
                                 "--checkpoints", str(checkpoints), *extra])["episodes"]


def write_study(out: Path, summary: dict, text: str, plot) -> None:
    """OUT/study.json, OUT/study.md (``text``) and OUT/study.png (``plot(summary, path)``),
    and the report printed."""
    (out / "study.json").write_text(json.dumps(summary, indent=1))
    (out / "study.md").write_text(text)
    plot(summary, out / "study.png")
    print(text)
    print(f"wrote {out}/study.json, study.md, study.png")


def best_losses(train_dir: Path) -> dict:
    """A train-sweep's best validation loss per point: {(modality, seed): loss or None}."""
    sweep = json.loads((train_dir / "sweep.json").read_text())
    return {(p["settings"]["modality"], p["settings"]["seed"]): p.get("best_val_loss")
            for p in sweep["points"]}


def paired_text(vs: dict | None) -> str:
    """A paired comparison as a table cell: "+2.5, p 0.04" (points), "p < 0.01" below
    that, "-" when no episode pairs."""
    if not vs or not vs["n"]:
        return "-"
    p = vs["p_sign"]
    return f"{points(vs['mean_diff'])}, " + ("p < 0.01" if p < 0.01 else f"p {p:.2f}")


def loss_table(rows: dict, first_column: str) -> list[str]:
    """Markdown lines: one row per entry of ``rows`` (each with "description" and
    "best_val_mse", {seed: loss or None}), one column per training seed."""
    seeds = sorted({s for r in rows.values() for s in r["best_val_mse"]})
    lines = [f"| {first_column} | " + " | ".join(f"seed {s}" for s in seeds) + " |",
             "|---|" + "---|" * len(seeds)]
    for r in rows.values():
        vals = r["best_val_mse"]
        lines.append(f"| {r['description']} | " + " | ".join(
            "-" if vals.get(s) is None else f"{vals[s]:.5f}" for s in seeds) + " |")
    return lines


def baseline_table_head(cell_names: list[str], reference_rows: dict, metric: str) -> list[str]:
    """Markdown lines opening a metric's table: the header (a column per cell) and the
    expert's and no-action rows (baseline_rows) in %."""
    lines = ["| row | " + " | ".join(cell_names) + " |", "|---|" + "---|" * len(cell_names)]
    for name, rows in reference_rows.items():
        lines.append(f"| {name} | " + " | ".join(
            f"{100 * rows[c][metric]:.1f}" if c in rows else "-" for c in cell_names) + " |")
    return lines


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
