"""Aggregate per-episode results into the paper's tables (Markdown) and every plot.

    from sebvs.eval.report import write_outputs
    write_outputs(json.loads(Path("out/eval/results.json").read_text()), Path("out/eval"))

``results`` is what `sebvs eval` writes to results.json::

    {"task": "nav" | "arm", "clock": ..., "split": "dev" | "test" | "custom",
     "seed_range": [first, last], "seed": topology seed,
     "overrides": [the --set given, where any (or the mapping a script gave)],
     "event_sensor": [{"preset", "preset_version", "conditions"}: the emulator the event
                      rows ran, one entry per distinct sensor; absent without event rows],
     "episodes": [
        {"modality": "rgb" | "event" | "rgb+event" | "expert" | "no_action",
         "condition": "nominal", "scenario": "indoor", "seed": 3, "metrics": {...}}, ...],
     "runs": [{"condition", "scenario", "modality", "episodes", "commands", "rejected",
               "action_timeouts", "deadline_misses", "actions", "nonfinite_actions",
               "handler_errors": {"actor.input": n}, "never_acted": bool}, ...]}

"runs" (sebvs/eval/run.py run_health; absent from results written before it) says whether
a row's figures are a policy's at all: a row with a command rejected or an action not
finite is marked "!" in its tables, and every run with a counter above 0 is listed under
"Run health".

An episode's scenario is the nav scene's variant (indoor, outdoor) or the arm's object
count (single, multi); results written before nav had variants say "single" or nothing,
and their tables keep the old headings.

Navigation episode metrics are `NavEpisodeMetrics.as_dict()`; arm episode metrics hold
`scenario` ("single" | "multi"), `pred` and `expert` poses ([T, 6] lists: every tick's
prediction and the task's pose), `grasp_success` (bool, or None when the episode was not a
grasp trial) and `end_decision_correct`; an episode's `inference_ms` (a list) gives the
latency.
"""
from __future__ import annotations

import json
import math
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..data.splits import SPLITS, split_of
from ..metrics import arm_metrics, paired_comparison, points, wilson_interval

MODALITY_ORDER = ("expert", "no_action", "rgb", "event", "rgb+event", "rgb+diff")
NAME = {"expert": "Expert (reference)", "no_action": "No action (baseline)",
        "rgb": "RGB-only", "event": "Event-only", "rgb+event": "RGB+Event",
        "rgb+diff": "RGB+Diff (control)"}




@dataclass(frozen=True)
class Trace:
    """The per-tick error trace a task's tracker records: its episode key, the plot's
    file and the plot's label."""
    key: str
    png: str
    label: str


TRACES = {"nav": Trace("trace_error_px", "centroid_error.png",
                       "centroid error (px); gaps: target out of view"),
          "arm": Trace("trace_error_mm", "pose_error.png",
                       "position error against the task's pose (mm)")}


def output_files(task: str) -> str:
    """The files write_outputs() writes for a task, for `sebvs eval`'s last line."""
    return f"report.md, results.json, success.png, {TRACES[task].png}, latency.png"


# the counters that put a run into the "Run health" section
HEALTH_SHOWN = ("rejected", "nonfinite_actions", "action_timeouts", "deadline_misses")
MARK = " !"


def _ordered(keys) -> list:
    return sorted(keys, key=lambda m: (MODALITY_ORDER.index(m) if m in MODALITY_ORDER else 99, m))


def _group(episodes: list[dict], *keys) -> dict:
    groups = defaultdict(list)
    for ep in episodes:
        groups[tuple(ep[k] if k in ep else ep["metrics"].get(k) for k in keys)].append(ep)
    return groups


def _nav_scenario(ep: dict) -> str:
    return ep.get("scenario") or "single"


def _seed_note(results: dict) -> list[str]:
    """A custom topology seed inside the recording range evaluates on episodes a policy
    may have been trained on: say so where the figures are read."""
    seed = results.get("seed")
    if results.get("split") != "custom" or not isinstance(seed, int) \
            or split_of(seed) != "train":
        return []
    return [f"Note: topology seed {seed} lies in the train range ({SPLITS['train']}): "
            f"recordings may hold these very episodes.", ""]


def aggregate_nav(episodes: list[dict]) -> dict:
    """Pool per-episode navigation metrics exactly (frame-weighted means and variances)."""
    ms = [e["metrics"] for e in episodes]
    frames = np.array([m["frames"] for m in ms], dtype=np.float64)
    vis = np.array([m["visible"] for m in ms]) * frames          # visible frames per episode
    ok = vis > 0
    mu = np.array([m["centroid_error_px"] for m in ms])
    sd = np.array([m["centroid_error_std_px"] for m in ms])
    width = np.array([m["bbox_width_px"] for m in ms])
    succ = np.array([m["success"] for m in ms]) * frames
    # results written before the strict and episode rates existed lack them: nan, shown "-"
    strict = np.array([m.get("strict_success", math.nan) for m in ms]) * frames
    episode_ok = np.array([m.get("episode_success", math.nan) for m in ms])
    n_vis = vis[ok].sum()
    mean = float((vis[ok] * mu[ok]).sum() / n_vis) if n_vis else math.nan
    var = float((vis[ok] * (sd[ok] ** 2 + mu[ok] ** 2)).sum() / n_vis - mean ** 2) if n_vis \
        else math.nan
    lo, hi = wilson_interval(float(succ.sum()), int(frames.sum()))
    return {"episodes": len(ms), "frames": int(frames.sum()),
            "centroid_error_px": mean, "centroid_error_std_px": math.sqrt(max(var, 0.0)),
            "bbox_width_px": float((vis[ok] * width[ok]).sum() / n_vis) if n_vis else math.nan,
            "success": float(succ.sum() / frames.sum()), "success_ci95": [lo, hi],
            "strict_success": float(strict.sum() / frames.sum()),
            "episode_success": float(episode_ok.mean()),
            "episode_success_ci95": list(wilson_interval(float(episode_ok.sum()), len(ms)))
            if not np.isnan(episode_ok).any() else [math.nan, math.nan],
            "duration_s": float(np.mean([m["duration_s"] for m in ms]))}


def aggregate_arm(episodes: list[dict]) -> dict:
    """Pool arm episodes: every tick's prediction, every grasp trial, every latency."""
    ms = [e["metrics"] for e in episodes]
    poses = lambda key: np.concatenate([np.reshape(m[key], (-1, 6)) for m in ms]) \
        if ms else np.zeros((0, 6))                                          # noqa: E731
    acc = arm_metrics(poses("pred"), poses("expert"))
    lat = np.concatenate([np.asarray(e.get("inference_ms") or e["metrics"].get("latency_ms")
                                     or [], np.float64) for e in episodes]) \
        if episodes else np.array([])
    grasps = [m.get("grasp_success") for m in ms if m.get("grasp_success") is not None]
    ends = [m.get("end_decision_correct") for m in ms
            if m.get("end_decision_correct") is not None]
    lo, hi = wilson_interval(sum(grasps), len(grasps))
    return {**acc, "episodes": len(ms),
            "latency_p50_ms": float(np.percentile(lat, 50)) if lat.size else math.nan,
            "latency_p99_ms": float(np.percentile(lat, 99)) if lat.size else math.nan,
            "grasps": len(grasps),
            "grasp_success": float(np.mean(grasps)) if grasps else math.nan,
            "grasp_success_ci95": [lo, hi],
            "end_decision": float(np.mean(ends)) if ends else math.nan}


def _pct(x: float) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:.1f}"


def _num(x: float, fmt: str = ".1f") -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, fmt)


def _paired_section(episodes: list[dict], value, label: str) -> list[str]:
    """rgb+event against each other modality, and event-only against holding still (is the
    event input worth anything on its own?), on the seeds both ran."""
    by_mod = defaultdict(dict)
    for e in episodes:
        by_mod[e["modality"]][e["seed"]] = value(e)
    pairs = [("rgb+event", m) for m in _ordered(by_mod) if m != "rgb+event"]
    pairs.append(("event", "no_action"))
    lines = []
    for mine, other in pairs:
        if mine not in by_mod or other not in by_mod:
            continue
        seeds = sorted(set(by_mod[mine]) & set(by_mod[other]))
        if not seeds:
            continue
        r = paired_comparison([by_mod[mine][s] for s in seeds],
                              [by_mod[other][s] for s in seeds])
        if r["n"] == 0:     # no seed with the value on both sides (results of older runs)
            continue
        lines.append(f"| {NAME.get(mine, mine)} vs {NAME.get(other, other)} | {r['n']} | "
                     f"{points(r['mean_diff'])} | [{points(r['ci95'][0])}, "
                     f"{points(r['ci95'][1])}] | {r['wins']}/{r['losses']}/{r['ties']} | "
                     f"{r['p_sign']:.3f} |")
    if not lines:
        return []
    return ["", f"Paired on the same seeds ({label}, percentage points; bootstrap 95% "
                f"interval; exact sign test):", "",
            "| comparison | seeds | mean diff | 95% CI | wins/losses/ties | p |",
            "|---|---|---|---|---|---|", *lines]


def _nav_summary(groups: dict, health: dict) -> list[str]:
    """One table per scenario, a row per condition and a column per model, each cell
    `paper rate / strict rate / episodes succeeded`: the whole evaluation at a glance,
    above the per-condition tables that carry the intervals and paired tests."""
    lines = []
    for scen in sorted({s for _, s in groups}):
        conds = sorted(c for c, s in groups if s == scen)
        mods = _ordered({e["modality"] for c in conds for e in groups[(c, scen)]})
        title = "Summary" if scen == "single" else f"Summary: {scen}"
        lines += [f"## {title}", "",
                  "Per cell: paper rate (% of frames within 200 px) / strict rate (within "
                  "50 px) / episodes with >= 90 % of frames within 200 px.", "",
                  "| condition | " + " | ".join(NAME.get(m, m) for m in mods) + " |",
                  "|---|" + "---|" * len(mods)]
        for cond in conds:
            by_mod = _group(groups[(cond, scen)], "modality")
            cells = []
            for m in mods:
                if (m,) not in by_mod:
                    cells.append("-")
                    continue
                a = aggregate_nav(by_mod[(m,)])
                won = ("-" if math.isnan(a["episode_success"]) else
                       f"{round(a['episode_success'] * a['episodes'])} of {a['episodes']}")
                mark = MARK if flagged(health.get((cond, scen, m))) else ""
                cells.append(f"{_pct(a['success'])} / {_pct(a['strict_success'])} / "
                             f"{won}{mark}")
            lines.append(f"| {cond} | " + " | ".join(cells) + " |")
        if any(flagged(health.get((c, scen, m))) for c in conds for m in mods):
            lines += ["", f"{MARK.strip()}: a command rejected or an action not finite in "
                          f"that run (below its condition's table, and Run health)."]
        lines.append("")
    return lines


def _health_index(results: dict) -> dict:
    """(condition, scenario, modality) -> the run's counters; {} for older results."""
    runs = results.get("runs")
    return {(r.get("condition"), r.get("scenario") or "single", r.get("modality")): r
            for r in (runs if isinstance(runs, list) else []) if isinstance(r, dict)}


def _count(run: dict, key: str) -> int:
    v = run.get(key)
    return int(v) if isinstance(v, (int, float)) and math.isfinite(v) else 0


def _errors(run: dict) -> int:
    errors = run.get("handler_errors")
    return sum(_count(errors, k) for k in errors) if isinstance(errors, dict) else 0


def flagged(run: dict | None) -> bool:
    """A run whose row is marked: a command rejected or an action not finite."""
    return run is not None and bool(_count(run, "rejected")
                                    or _count(run, "nonfinite_actions"))


def _who(modality: str) -> str:
    return {"expert": "expert", "no_action": "no-action baseline"}.get(modality, "policy")


def _what_failed(run: dict) -> str:
    """The counts behind a mark: "10 of 10 commands rejected, 10 of 10 actions not
    finite"."""
    parts = []
    if _count(run, "commands") or _count(run, "rejected"):
        parts.append(f"{_count(run, 'rejected')} of {_count(run, 'commands')} commands "
                     f"rejected")
    else:
        parts.append(f"no command reached the sim ({_count(run, 'action_timeouts')} action "
                     f"timeouts)")
    if _count(run, "nonfinite_actions"):
        parts.append(f"{_count(run, 'nonfinite_actions')} of {_count(run, 'actions')} "
                     f"actions not finite")
    return ", ".join(parts)


def never_acted(results: dict) -> list[str]:
    """One line per run that never acted (the sim applied none of its commands), naming
    the run and the counts; [] when every run acted or the results predate the counters."""
    return [f"{r.get('modality')} {r.get('condition')} {r.get('scenario')}: the "
            f"{_who(str(r.get('modality')))} never acted ({_what_failed(r)}); its row is "
            f"marked in report.md"
            for r in _health_index(results).values() if r.get("never_acted")]


def _mark_notes(health: dict, cond: str, scen: str, mods) -> list[str]:
    """The footnotes of a table's marked rows."""
    notes = []
    for m in mods:
        run = health.get((cond, scen, m))
        if flagged(run):
            end = (": it never acted, these are the figures of a robot that kept its idle "
                   "command" if run.get("never_acted") else
                   ": the robot kept its last accepted command on those ticks")
            notes.append(f"{MARK.strip()} {NAME.get(m, m)}: {_what_failed(run)}{end}.")
    return ["", *notes] if notes else []


def _health_section(health: dict) -> list[str]:
    """Every run with a counter above 0; one line when there is none."""
    if not health:
        return []
    bad = [(k, r) for k, r in sorted(health.items(), key=lambda kv: tuple(map(str, kv[0])))
           if any(_count(r, c) for c in HEALTH_SHOWN) or _errors(r)]
    lines = ["## Run health", ""]
    if not bad:
        return lines + [f"Every run of the {len(health)}: no command rejected, no action "
                        f"that was not finite, no action timeout, no deadline miss, no "
                        f"handler error.", ""]
    lines += ["Runs with a command rejected by the sim, an action not finite (NaN, inf), a "
              "lockstep action timeout, a realtime deadline miss or an actor's input "
              "handler that raised; the others had none.", "",
              "| run | episodes | commands rejected | actions not finite | action timeouts | "
              "deadline misses | handler errors |",
              "|---|---|---|---|---|---|---|"]
    for (cond, scen, mod), r in bad:
        errors = r.get("handler_errors") if isinstance(r.get("handler_errors"), dict) else {}
        where = ", ".join(f"{k} {_count(errors, k)}" for k in sorted(errors)
                          if _count(errors, k))
        lines.append(f"| {cond} / {scen} / {NAME.get(mod, mod)}"
                     f"{' (never acted)' if r.get('never_acted') else ''} | "
                     f"{_count(r, 'episodes')} | "
                     f"{_count(r, 'rejected')} of {_count(r, 'commands')} | "
                     f"{_count(r, 'nonfinite_actions')} of {_count(r, 'actions')} | "
                     f"{_count(r, 'action_timeouts')} | {_count(r, 'deadline_misses')} | "
                     f"{_errors(r)}{f' ({where})' if where else ''} |")
    return lines + [""]


def _event_sensor_line(results: dict) -> list[str]:
    """The header's line naming the emulator the event rows ran (results written before
    it was recorded say nothing)."""
    sensors = results.get("event_sensor") or []
    if not sensors:
        return []
    named = [f"preset {s.get('preset')}, version {s.get('preset_version')}"
             + (f" ({', '.join(s.get('conditions') or [])})" if len(sensors) > 1 else "")
             for s in sensors]
    return [f"event sensor: emulator {'; '.join(named)}", ""]


def render_report(results: dict) -> str:
    task = results["task"]
    eps = results["episodes"]
    health = _health_index(results)
    lines = [f"# Closed-loop evaluation: {task}", ""]
    meta = {k: v for k, v in results.items()
            if k not in ("episodes", "task", "runs", "event_sensor")}
    if meta:
        lines += [", ".join(f"{k}: {v}" for k, v in meta.items()), ""]
    lines += _event_sensor_line(results)
    lines += _seed_note(results)
    if task == "nav":
        lines += ["Success: share of frames with the target within 200 px of the image centre "
                  "at 640 px (radius scaled with resolution); the Wilson interval counts "
                  "frames, which are correlated within an episode, so it is optimistic; the "
                  "paired comparison treats episodes as the unit. Strict: the same within "
                  "50 px. Episode success: episodes with >= 90 % of their frames within "
                  "200 px (Wilson interval over episodes). No action: the robot holds still "
                  "on the same seeds, what each rate gives for free.", ""]
        groups = defaultdict(list)
        for e in eps:
            groups[(e["condition"], _nav_scenario(e))].append(e)
        lines += _nav_summary(groups, health)
        for (cond, scen), group in sorted(groups.items()):
            title = cond if scen == "single" else f"{cond}, {scen}"
            lines += [f"## Condition: {title}", "",
                      "| Model | Episodes | Centroid error (px) | BBox width (px) | "
                      "Success rate (% within threshold) [95% CI] | Strict (% within 50 px) | "
                      "Episode success (%) [95% CI] | Trial duration (s) |",
                      "|---|---|---|---|---|---|---|---|"]
            by_mod = _group(group, "modality")
            mods = _ordered(m for (m,) in by_mod)
            for mod in mods:
                a = aggregate_nav(by_mod[(mod,)])
                lo, hi = a["success_ci95"]
                elo, ehi = a["episode_success_ci95"]
                mark = MARK if flagged(health.get((cond, scen, mod))) else ""
                lines.append(f"| {NAME.get(mod, mod)}{mark} | {a['episodes']} | "
                             f"{_num(a['centroid_error_px'])} ± "
                             f"{_num(a['centroid_error_std_px'])} | "
                             f"{_num(a['bbox_width_px'])} | {_pct(a['success'])} "
                             f"[{_pct(lo)}, {_pct(hi)}] | {_pct(a['strict_success'])} | "
                             f"{_pct(a['episode_success'])} [{_pct(elo)}, {_pct(ehi)}] | "
                             f"{_num(a['duration_s'])} |")
            lines += _mark_notes(health, cond, scen, mods)
            lines += _paired_section(group, lambda e: e["metrics"]["success"], "success")
            # the paper's 200 px rate saturates at 100 % for a policy that follows at all,
            # and then ties every pair; the 50 px rate still tells followers apart
            lines += _paired_section(group, lambda e: e["metrics"].get("strict_success",
                                                                       math.nan),
                                     "strict rate")
            lines.append("")
    elif task == "arm":
        lines += ["Position error and accuracy over every control tick: the predicted pose "
                  "against the pose the task asks for (the expert's rule applied to the true "
                  "cube poses: 10 cm above the leftmost visible cube, or HOME beyond y = "
                  "0.449 m); accuracy = share within 50 mm and 15 degrees of yaw (yaw modulo "
                  "90 degrees). Grasp success: the sim grasps the last pose of each episode "
                  "(lifted 5 cm and held 1 s), over the episodes where a cube was graspable; "
                  "end decision: HOME chosen exactly when the task said HOME.", ""]
        for (cond, scen), group in sorted(_group(eps, "condition", "scenario").items()):
            lines += [f"## Condition: {cond}, {scen}-object", "",
                      "| Model | Episodes | Predictions | Position error (mm) | Accuracy (%) | "
                      "Inference latency p50 / p99 (ms) | Grasp success (%) [95% CI] | "
                      "End decision (%) |",
                      "|---|---|---|---|---|---|---|---|"]
            by_mod = _group(group, "modality")
            mods = _ordered(m for (m,) in by_mod)
            for mod in mods:
                a = aggregate_arm(by_mod[(mod,)])
                lo, hi = a["grasp_success_ci95"]
                mark = MARK if flagged(health.get((cond, scen, mod))) else ""
                lines.append(f"| {NAME.get(mod, mod)}{mark} | {a['episodes']} | {a['n']} | "
                             f"{_num(a['position_error_mm'])} ± "
                             f"{_num(a['position_error_std_mm'])} | {_pct(a['accuracy'])} | "
                             f"{_num(a['latency_p50_ms'], '.2f')} / "
                             f"{_num(a['latency_p99_ms'], '.2f')} | "
                             f"{_pct(a['grasp_success'])} [{_pct(lo)}, {_pct(hi)}] | "
                             f"{_pct(a['end_decision'])} |")
            lines += _mark_notes(health, cond, scen, mods)
            lines += _paired_section(
                [e for e in group if e["metrics"].get("grasp_success") is not None],
                lambda e: float(e["metrics"]["grasp_success"]), "grasp success")
            lines.append("")
    else:
        raise ValueError(f"unknown task {task!r} in results")
    lines += _health_section(health)
    return "\n".join(lines)


def plot_success(results: dict, path) -> None:
    """Success by condition and modality, with 95% Wilson intervals."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    eps = results["episodes"]
    nav = results["task"] == "nav"
    # one bar group per table: condition and scenario (nav's scene variant, the arm's one
    # or three cubes); nav results from before the variants have one scenario, unnamed
    groups = defaultdict(list)
    for e in eps:
        groups[(e["condition"], _nav_scenario(e) if nav else e.get("scenario"))].append(e)
    conds = sorted(groups)
    labels = ["\n".join(str(k) for k in c if k is not None and not (nav and k == "single"))
              for c in conds]
    mods = _ordered({e["modality"] for e in eps})
    fig, ax = plt.subplots(figsize=(3.4 + 1.6 * len(conds), 3.6))
    width = 0.8 / max(1, len(mods))
    for j, mod in enumerate(mods):
        vals, errs = [], [[], []]
        for cond in conds:
            group = [e for e in groups[cond] if e["modality"] == mod]
            if not group:
                vals.append(np.nan)
                errs[0].append(0)
                errs[1].append(0)
                continue
            a = aggregate_nav(group) if nav else aggregate_arm(group)
            v = a["success"] if nav else a["grasp_success"]
            lo, hi = a["success_ci95"] if nav else a["grasp_success_ci95"]
            vals.append(100 * v)
            # max(0, ...): at 0 % or 100 % the Wilson bound can miss v by a rounding error
            errs[0].append(max(0.0, 100 * (v - lo)) if not math.isnan(lo) else 0)
            errs[1].append(max(0.0, 100 * (hi - v)) if not math.isnan(hi) else 0)
        x = np.arange(len(conds)) + (j - (len(mods) - 1) / 2) * width
        ax.bar(x, vals, width, yerr=errs, capsize=3, label=NAME.get(mod, mod))
    ax.set_xticks(np.arange(len(conds)), labels)
    ax.set_ylim(0, 105)
    ax.set_ylabel("success rate (%)" if nav else "grasp success (%)")
    # outside the axes: inside, some cell's bars are always behind it
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    ax.set_title(f"{results['task']}: success by condition and modality (95% Wilson)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_outputs(results: dict, out: Path) -> None:
    """results.json, report.md and the three plots of an evaluation into `out`."""
    (out / "results.json").write_text(json.dumps(results, indent=1))
    (out / "report.md").write_text(render_report(results) + "\n")
    plot_success(results, out / "success.png")
    trace = TRACES[results["task"]]
    plot_traces(results, out / trace.png, trace.key, trace.label)
    plot_latency(results, out / "latency.png")


def plot_traces(results: dict, path: Path, key: str, what: str) -> None:
    """A per-tick error trace against time (`key` of each episode: nav centroid error px,
    arm position error mm), one panel per condition and scenario, the first episode of
    each modality."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = sorted({(e["condition"], e.get("scenario", "single"))
                     for e in results["episodes"]})
    fig, axes = plt.subplots(len(groups) or 1, 1, figsize=(7, 2.4 * max(1, len(groups))),
                             squeeze=False)
    for ax, (cond, scen) in zip(axes[:, 0], groups):
        seen = set()
        for e in results["episodes"]:
            if (e["condition"], e.get("scenario", "single")) != (cond, scen) \
                    or e["modality"] in seen:
                continue
            seen.add(e["modality"])
            tr = np.array([np.nan if v is None else v for v in e.get(key, [])], float)
            ax.plot(np.arange(tr.size), tr, lw=1, label=f"{e['modality']} (seed {e['seed']})")
        title = cond if scen == "single" and results["task"] == "nav" else f"{cond}, {scen}"
        ax.set_title(f"{title}: {what}", fontsize=9)
        ax.set_xlabel("control tick")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_latency(results: dict, path: Path) -> None:
    """Histogram of per-call inference latency per modality."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.2))
    by_mod: dict[str, list] = {}
    for e in results["episodes"]:
        by_mod.setdefault(e["modality"], []).extend(e.get("inference_ms") or [])
    for mod, vals in by_mod.items():
        if vals:
            v = np.asarray(vals)
            ax.hist(v, bins=40, alpha=0.6,
                    label=f"{mod}: p50 {np.median(v):.2f} ms, p99 {np.percentile(v, 99):.2f}")
    ax.set_xlabel("inference latency per call (ms)")
    if by_mod and any(by_mod.values()):     # the expert and baseline rows infer nothing
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
