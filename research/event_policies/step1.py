#!/usr/bin/env python3
"""Step 1 of docs/plan_event_policies.md: the recipe, chosen on the dev split.

    research/event_policies/step1.py plan        # every command, nothing run
    research/event_policies/step1.py run         # what is not done yet, in order
    research/event_policies/step1.py select      # the selection table, once every row is in

The commands are the plan's (CANDIDATES, DEV below say what the plan says; nothing here
chooses anything). Each step resumes by itself (`sebvs record --hard-share` records what
a dataset lacks, `sebvs train` and `sebvs train-dagger` go on from their last finished
epoch or round, `sebvs eval` keeps its finished runs) and is skipped once its output is
there, so a session that ends mid-step loses only that step's work in flight. Trainings
run two at a time, one thread each. Every step's start, seconds and exit code go to
OUTPUT/steps.jsonl; each step's output to OUTPUT/logs/<step>.txt (not tracked).

Datasets go to datasets/ (not tracked); checkpoints, evaluations, the ledger and the
selection table to research/event_policies/outputs/step1/ (tracked).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "research" / "event_policies" / "outputs" / "step1"
SEBVS = str(ROOT / ".venv" / "bin" / "sebvs")
MODALITIES = ("event", "rgb+event")

# the plan's dev data: nav topology seed 30, 60 episodes of 20 s, half under hard conditions,
# the emulator's current noise (preset_version 2)
RECORD = ["record", "topologies/nav_record.toml", "--episodes", "60", "--hard-share", "0.5",
          "--workers", "2", "--quiet", "--set", "sim.episode_s=20.0",
          "--set", "topology.seed=30",
          "--set", "emulator.overrides={downsample=1.0, preset_version=2}"]
DATASETS = {"counts": ("datasets/ev_dev_counts", []),
            "time_surface": ("datasets/ev_dev_ts",
                             ["--set", 'accumulator.representation="time_surface"',
                              "--set", "accumulator.window_s=0.3"])}
# the shipped recipe (checkpoints/README.md): conv stem, Adam 5e-4, 10 epochs, patience 3
BASE = ["--stem", "conv", "--lr", "5e-4", "--patience", "3", "--threads", "1", "--seed", "0",
        "--no-progress"]
# 32 windows of 2 ticks a batch, a burn-in of 6: the plan's second amendment of
# 2026-12-02 (the lanes it named, and 4 windows of 8, did not train)
MEMORY = ["--memory", "gru", "--seq-len", "2", "--lanes", "32", "--burn-in", "6"]
TARGET = ["--aux-weight", "0.5"]
FUSED_DROPOUT = ["--modality-dropout", "0.25"]
# id -> (dataset, options, DAgger rounds)
CANDIDATES = {"R0": ("counts", [], 0),
              "R1": ("counts", MEMORY, 0),
              "R2": ("counts", MEMORY + TARGET, 0),
              "R3": ("time_surface", MEMORY + TARGET, 0),
              "R4": ("counts", MEMORY + TARGET, 1)}
# the DAgger round's 40 episodes of 20 s on train seed 31 (the plan fixes the round's size
# and driver; this seed, next to the dev data's, is the driver's choice, in the log)
DAGGER = ["--rounds", "1", "--episodes", "40", "--episode-s", "20", "--first-seed", "31",
          "--workers", "2",
          # the round's recording on the same noise model as the dev data (a training
          # refuses datasets of two emulator preset versions)
          "--set", "emulator.overrides={downsample=1.0, preset_version=2}"]
# a DAgger candidate -> the candidate that is its round 0 (same data, options and seed)
DAGGER_INIT = {"R4": "R2"}
DEV_EVAL = ["--split", "dev", "--seed", "2000", "--episodes", "10",
            "--conditions", "nominal_physical,hdr", "--set", "sim.episode_s=10",
            "--workers", "2"]


def steps() -> list[dict]:
    """Every step of step 1, in order: {name, argv, done (a path that exists once it is),
    parallel (trainings: two at a time)}."""
    out = []
    for kind, (path, extra) in DATASETS.items():
        out.append({"name": f"record_{kind}", "argv": [*RECORD, "--out", path, *extra],
                    "done": None, "dataset": path})
    for rid, (kind, options, rounds) in CANDIDATES.items():
        data = DATASETS[kind][0]
        for m in MODALITIES:
            opts = options + (FUSED_DROPOUT if m == "rgb+event" and options else [])
            ck = OUT / rid / "checkpoints"
            if rounds:
                run = OUT / rid / f"dagger-{m}"
                # round 0 is the same recipe without DAgger on the same data and seed:
                # that candidate's checkpoint drives round 1 instead of a second training
                init = OUT / DAGGER_INIT[rid] / "checkpoints"
                argv = ["train-dagger", "--task", "nav", "--modality", m, "--data", data,
                        "--out", str(run), "--init", str(init), *DAGGER, *BASE, *opts]
                # two at a time like the others: each round's recording and training are
                # one modality's, independent of the other's
                out.append({"name": f"train_{rid}_{m}", "argv": argv, "parallel": True,
                            "done": run / f"round-{rounds}" / "checkpoints" / f"nav-{m}.pt",
                            "copy_to": ck})
            else:
                argv = ["train", "--task", "nav", "--modality", m, "--data", data,
                        "--out", str(ck), *BASE, *opts]
                out.append({"name": f"train_{rid}_{m}", "argv": argv, "parallel": True,
                            "done": ck / f"nav-{m}.pt"})
    out.append({"name": "eval_reference", "argv": [
        # the expert and no-action rows alone (no modality): the reference beside the rows
        "eval", "--task", "nav", "--modalities", "", "--out", str(OUT / "eval" / "reference"),
        *DEV_EVAL], "done": OUT / "eval" / "reference" / "results.json"})
    for rid in CANDIDATES:
        ev = OUT / "eval" / rid
        out.append({"name": f"eval_{rid}", "argv": [
            "eval", "--task", "nav", "--modalities", ",".join(MODALITIES),
            "--checkpoints", str(OUT / rid / "checkpoints"), "--no-expert", "--no-baseline",
            "--out", str(ev), *DEV_EVAL], "done": ev / "results.json"})
    # the cheapest complete readings first: the candidates on the counts data without
    # DAgger (recording, trainings, evaluations), then the time surface's, then DAgger's
    return sorted(out, key=_phase)


def _phase(step: dict) -> int:
    """0: the counts data and its candidates without DAgger, with the reference row;
    1: the time-surface data and its candidates; 2: candidates with DAgger rounds."""
    name = step["name"]
    if name.startswith("record_"):
        return 0 if name == "record_counts" else 1
    rid = name.split("_")[1]
    if rid not in CANDIDATES:
        return 0
    kind, _, rounds = CANDIDATES[rid]
    return 2 if rounds else (1 if kind != "counts" else 0)


def is_done(step: dict) -> bool:
    if step["done"] is not None:
        return Path(step["done"]).exists()
    index = ROOT / step["dataset"] / "index.json"
    if not index.exists():
        return False
    return len(json.loads(index.read_text()).get("episodes", [])) >= 60


def run_step(step: dict) -> subprocess.Popen:
    (OUT / "logs").mkdir(parents=True, exist_ok=True)
    log = open(OUT / "logs" / f"{step['name']}.txt", "a")
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    proc = subprocess.Popen([SEBVS, *step["argv"]], cwd=ROOT, stdout=log,
                            stderr=subprocess.STDOUT, env=env)
    proc.step, proc.t0, proc.log = step, time.time(), log
    print(f"start {step['name']}", flush=True)
    return proc


def finish(proc: subprocess.Popen) -> int:
    rc = proc.wait()
    proc.log.close()
    step = proc.step
    if rc == 0 and step.get("copy_to"):     # a DAgger run's last round is the candidate's
        import shutil
        Path(step["copy_to"]).mkdir(parents=True, exist_ok=True)
        for suffix in (".pt", ".json"):
            src = Path(step["done"]).with_suffix(suffix)
            shutil.copy2(src, Path(step["copy_to"]) / src.name)
    line = {"step": step["name"], "start": time.strftime("%Y-%m-%dT%H:%M:%S",
                                                        time.gmtime(proc.t0)),
            "seconds": round(time.time() - proc.t0, 1), "rc": rc}
    with open(OUT / "steps.jsonl", "a") as f:
        f.write(json.dumps(line) + "\n")
    print(f"end {step['name']}: rc {rc}, {line['seconds']:.0f} s", flush=True)
    return rc


def run(parallel: int = 2, only: set[str] = frozenset()) -> int:
    """Every step not done yet (of ``only``'s names, where given), in order."""
    todo = [s for s in steps() if not is_done(s) and (not only or s["name"] in only)]
    running: list[subprocess.Popen] = []
    for step in todo:
        if not step.get("parallel"):
            for p in running:
                if finish(p):
                    return 1
            running = []
            if finish(run_step(step)):
                return 1
            continue
        if len(running) >= parallel:
            if finish(running.pop(0)):
                return 1
        running.append(run_step(step))
    return 1 if any(finish(p) for p in running) else 0


def select() -> int:
    """The plan's selection table: the mean paper rate over the four cells and two
    modalities per candidate; the rule picks the best, a lower id within 2 points first."""
    sys.path.insert(0, str(ROOT))
    from sebvs.eval.results import read_results
    rows = {}
    for rid in CANDIDATES:
        path = OUT / "eval" / rid / "results.json"
        if not path.exists():
            print(f"{rid}: not evaluated yet")
            continue
        cells: dict = {}
        for ep in read_results(path)["episodes"]:
            key = (ep["modality"], ep["condition"], ep["scenario"])
            cells.setdefault(key, []).append(ep["metrics"]["success"])
        rows[rid] = {f"{m}/{c}/{s}": 100 * sum(v) / len(v) for (m, c, s), v in cells.items()}
    if not rows:
        return 1
    means = {rid: sum(r.values()) / len(r) for rid, r in rows.items()}
    chosen = None
    for rid in CANDIDATES:      # a lower id within 2 points of the best wins
        if rid in means and means[rid] >= max(means.values()) - 2.0:
            chosen = rid
            break
    table = {"rows": rows, "means": means, "chosen": chosen,
             "complete": len(rows) == len(CANDIDATES)}
    (OUT / "selection.json").write_text(json.dumps(table, indent=2) + "\n")
    keys = sorted({k for r in rows.values() for k in r})
    print("| candidate | " + " | ".join(keys) + " | mean |")
    print("|---" * (len(keys) + 2) + "|")
    for rid, r in rows.items():
        print(f"| {rid} | " + " | ".join(f"{r.get(k, float('nan')):.1f}" for k in keys)
              + f" | {means[rid]:.1f} |")
    print(f"chosen: {chosen}" + ("" if table["complete"] else " (not every candidate in yet)"))
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=["plan", "run", "select"])
    ap.add_argument("--parallel", type=int, default=2, help="trainings at once (default 2)")
    ap.add_argument("--only", default="", metavar="STEP,...",
                    help="run only these steps (names as `plan` prints them)")
    args = ap.parse_args(argv)
    if args.what == "plan":
        for s in steps():
            print(("done  " if is_done(s) else "todo  ") + s["name"] + ": sebvs "
                  + " ".join(s["argv"]))
        return 0
    if args.what == "run":
        return run(args.parallel, {n for n in args.only.split(",") if n})
    return select()


if __name__ == "__main__":
    sys.exit(main())
