#!/usr/bin/env python3
"""Does the expert score the same through the Gymnasium environment as in `sebvs eval`?

For each task, condition, scenario and topology seed S: `sebvs eval`'s lockstep run of the
expert (the reference row alone: EvalPlan with no modality and no baseline) plays episodes
0..K-1 of seed S; the environment (sebvs.envs, privileged=True) is reset with seed S and
played K episodes on with sebvs.envs.ExpertPolicy. Per episode the episode seeds are
compared and the metrics: nav, every figure of the tracker's record (the paper's success
rate, the "paper rate", among them); arm, the grasp outcome (and the pose error beside
it: the env scores the poses its steps gave, the eval also the final tick's, which the
sim never executes).

Targets (issue 36): nav paper rate within 0.5 points, arm the same grasp outcomes.

    tools/checks/env_parity.py [--tasks nav,arm] [--seeds 0,1,2] [--episodes K]
        [--conditions nominal] [--scenarios indoor,outdoor|single,multi]
        [--episode-s S] [--json OUT]
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))


def eval_episodes(task: str, condition: str, scenario: str, seed: int, episodes: int,
                  episode_s: float | None, out: Path) -> list[dict]:
    """The expert row of `sebvs eval` for one condition and scenario: its episodes."""
    from sebvs.eval.run import EvalPlan, evaluate
    extra = [f"sim.episode_s={float(episode_s)}"] if episode_s else []
    plan = EvalPlan(task=task, modalities=[], conditions=[condition], episodes=episodes,
                    scenarios=[scenario], out=out, seed=seed, baseline=False, extra=extra)
    return evaluate(plan)["episodes"]


def env_episodes(task: str, condition: str, scenario: str, seed: int, episodes: int,
                 episode_s: float | None) -> list[dict]:
    """The same episodes through the environment, the expert acting: per episode its
    seed, metrics (the tracker's record), outcome and return."""
    import gymnasium as gym
    import sebvs.envs
    from sebvs.envs import ExpertPolicy
    kw = {"episode_s": episode_s} if episode_s else {}
    env = gym.make(sebvs.envs.ENV_IDS[task], condition=condition, scenario=scenario,
                   privileged=True, **kw)
    expert = ExpertPolicy(env)
    out = []
    for k in range(episodes):
        obs, info = env.reset(seed=seed) if k == 0 else env.reset()
        total, done = 0.0, False
        while not done:
            obs, reward, terminated, truncated, info = env.step(expert(obs, info))
            total += reward
            done = terminated or truncated
        metrics = info["episode_metrics"]
        out.append({"seed": info["seed"], "return": total,
                    "metrics": metrics if task == "nav" else metrics["metrics"]})
    env.close()
    return out


def _same(a, b) -> bool:
    """Equal, NaN equal to NaN."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def compare(task: str, condition: str, scenario: str, *, seed: int, episodes: int,
            episode_s: float | None, out: Path) -> dict:
    """One condition, scenario and seed: the eval's expert episodes against the env's."""
    t0 = time.perf_counter()
    ref = eval_episodes(task, condition, scenario, seed, episodes, episode_s, Path(out))
    t_eval = time.perf_counter() - t0
    t0 = time.perf_counter()
    got = env_episodes(task, condition, scenario, seed, episodes, episode_s)
    t_env = time.perf_counter() - t0
    row = {"task": task, "condition": condition, "scenario": scenario, "seed": seed,
           "episodes": len(got), "seeds_match": [e["seed"] for e in ref] ==
           [g["seed"] for g in got], "eval_wall_s": round(t_eval, 1),
           "env_wall_s": round(t_env, 1)}
    if task == "nav":
        a = [e["metrics"]["success"] * 100 for e in ref]
        b = [g["metrics"]["success"] * 100 for g in got]
        row.update(eval_paper_rate=statistics.fmean(a), env_paper_rate=statistics.fmean(b),
                   paper_rate_diff_points=statistics.fmean(b) - statistics.fmean(a),
                   max_episode_diff_points=max(abs(x - y) for x, y in zip(a, b)),
                   identical_metrics=sum(all(_same(e["metrics"][k], g["metrics"].get(k))
                                             for k in e["metrics"])
                                         for e, g in zip(ref, got)))
    else:
        a = [e["metrics"]["outcome"] for e in ref]
        b = [g["metrics"]["outcome"] for g in got]
        pa = [e["metrics"]["position_error_mm"] for e in ref]
        pb = [g["metrics"]["position_error_mm"] for g in got]
        row.update(eval_outcomes=a, env_outcomes=b,
                   same_outcomes=sum(x == y for x, y in zip(a, b)),
                   eval_grasp_success=[e["metrics"]["grasp_success"] for e in ref],
                   env_grasp_success=[g["metrics"]["grasp_success"] for g in got],
                   eval_position_error_mm=statistics.fmean(pa),
                   env_position_error_mm=statistics.fmean(pb))
    return row


def summarise(rows: list[dict]) -> dict:
    out = {}
    nav = [r for r in rows if r["task"] == "nav"]
    if nav:
        n = sum(r["episodes"] for r in nav)
        ea = sum(r["eval_paper_rate"] * r["episodes"] for r in nav) / n
        eb = sum(r["env_paper_rate"] * r["episodes"] for r in nav) / n
        out["nav"] = {"episodes": n, "eval_paper_rate": round(ea, 3),
                      "env_paper_rate": round(eb, 3), "diff_points": round(eb - ea, 3),
                      "identical_episode_metrics": sum(r["identical_metrics"] for r in nav),
                      "seeds_match": all(r["seeds_match"] for r in nav),
                      "target_within_0_5_points": abs(eb - ea) <= 0.5}
    arm = [r for r in rows if r["task"] == "arm"]
    if arm:
        n = sum(r["episodes"] for r in arm)
        same = sum(r["same_outcomes"] for r in arm)
        out["arm"] = {"episodes": n, "same_outcomes": same,
                      "seeds_match": all(r["seeds_match"] for r in arm),
                      "eval_lifted": sum(o == "lifted_and_held" for r in arm
                                         for o in r["eval_outcomes"]),
                      "env_lifted": sum(o == "lifted_and_held" for r in arm
                                        for o in r["env_outcomes"]),
                      "target_same_outcomes": same == n}
    return out


def main(argv=None) -> int:
    from benchio import print_report
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", default="nav,arm")
    ap.add_argument("--seeds", default="0,1,2", help="topology seeds, comma-separated")
    ap.add_argument("--episodes", type=int, default=3, help="episodes per seed")
    ap.add_argument("--conditions", default="nominal")
    ap.add_argument("--scenarios", default=None,
                    help="default: every scenario of the task (nav indoor,outdoor; arm "
                         "single,multi)")
    ap.add_argument("--episode-s", type=float, default=None,
                    help="episode length (default: the topologies', nav 30 s, arm 2 s)")
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args(argv)
    from sebvs.conditions import TASKS
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for task in args.tasks.split(","):
            scenarios = args.scenarios.split(",") if args.scenarios else list(TASKS[task].scenarios)
            for condition in args.conditions.split(","):
                for scenario in scenarios:
                    for seed in (int(s) for s in args.seeds.split(",")):
                        out = Path(tmp) / f"{task}-{condition}-{scenario}-{seed}"
                        rows.append(compare(task, condition, scenario, seed=seed,
                                            episodes=args.episodes, episode_s=args.episode_s,
                                            out=out))
                        print(json.dumps(rows[-1]), file=sys.stderr)
    print_report({"study": "env_parity", "summary": summarise(rows), "rows": rows}, args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
