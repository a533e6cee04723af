#!/usr/bin/env python3
"""The sensor study's report (issue 38): the tables docs/results.md opens with, built from
what research/sensors/sensor_study.py wrote, in the shape research/sensors/plan.md fixes.

    research/sensors/sensor_report.py [--out research/sensors/outputs] [--markdown FILE]
                                      [--json FILE] [--plot FILE] [--update docs/results.md]
                                      [--unread-rows]
    research/sensors/sensor_report.py --reading nav30

Per task, one table: per cell, the plan's reading of RGB+Event against RGB+Diff at each
control rate (the mean difference over the three training seeds, the episodes' paired 95 %
interval, how many seeds are ahead / behind, the rule's verdict), and beside it what the
plan's physics predicted and whether that held. Below it, per rate, the descriptive rows:
each modality's mean (over its training seeds), the expert and no action, per cell, the
cells in which the expert or no action played the same episodes (alike_cells: their
figures repeat there, and the line says why), the recording (or recordings) its trainings
read, and the CPUs and GL stacks the evaluations ran on (the driver's ledger,
OUT/steps.jsonl). A rate the plan has not read yet shows how many of its evaluations are
in, not their figures (--unread-rows shows those too).

Nothing here reads a rule or a prediction of its own: the readings come from `sebvs eval table`'s
JSON (OUT/read/<task><rate>.json), the predictions are the plan's section "What the physics
predicts", copied into PREDICTIONS below. A cell the plan lists that has no reading yet is
shown as "not yet run"; one that `sebvs eval table` left out (a row scored no episode of it)
as "no reading". The exit code is 0 when every planned cell has a reading, else 3.

--reading TASKRATE prints one reading in full (each training seed's difference, the
episodes' sign test), the figures a reading's log entry quotes.

--plot draws the headline tables as one figure: per task and cell, the effect and its
interval at each rate, coloured by the rule's verdict, the rule's threshold as a band, and
the plan's prediction beside each cell.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from sebvs.metrics import points  # noqa: E402
from sebvs.eval.results import TASK_METRICS, read_results  # noqa: E402
from research.sensors.sensor_study import (EVAL_GROUPS, LEDGER, PLAN_FILE,  # noqa: E402
                                        PLAN_SEEDS, READ_METRIC, READ_RULE, READINGS,
                                        eval_dir, ledger_machines, plan_steps,
                                        reading_path)

RATES = (10, 30)
# the plan's cells, in its order: (condition, scenarios)
PLAN_CELLS = {
    "nav": [(c, s) for c in ("nominal_physical", "hdr", "dusk", "dusk_fast")
            for s in ("indoor", "outdoor")]
           + [("flicker_100", "indoor"), ("flicker_120", "indoor")],
    "arm": [(c, s) for c in ("nominal_physical", "fast_physical", "hdr", "dusk_moving")
            for s in ("single", "multi")],
}
# The plan's "What the physics predicts", per task and condition: rate -> (the reading
# predicted, the other readings its words allow), or None where it made no firm one.
HELPS, HURTS, NONE = "helps", "hurts", "no clear difference"
PREDICTIONS = {
    ("nav", "hdr"): {10: (HELPS, ()), 30: (HELPS, ())},
    ("arm", "hdr"): {10: (HELPS, (NONE,)), 30: (HELPS, (NONE,))},
    ("nav", "dusk"): {10: (NONE, ()), 30: None},
    ("nav", "dusk_fast"): {10: (NONE, ()), 30: None},
    ("arm", "dusk_moving"): {10: (NONE, ()), 30: None},
    ("nav", "flicker_100"): {10: (HURTS, (NONE,)), 30: (HURTS, (NONE,))},
    ("nav", "flicker_120"): {10: (HURTS, (NONE,)), 30: (HURTS, (NONE,))},
    ("nav", "nominal_physical"): {10: (NONE, ()), 30: (NONE, ())},
    ("arm", "nominal_physical"): {10: (NONE, ()), 30: (NONE, ())},
    ("arm", "fast_physical"): {10: (NONE, ()), 30: (NONE, ())},
}
ROWS = ("expert", "no_action", "rgb", "event", "rgb+diff", "rgb+event")


def verdict(reading: str) -> str:
    """seed_table's reading ("rgb+event helps", ...) as helps / hurts / no clear difference."""
    for word in (HELPS, HURTS):
        if reading.endswith(" " + word):
            return word
    return NONE


def held(prediction, found: str | None) -> str:
    if found is None:
        return "-"
    if prediction is None:
        return "no firm prediction"
    expected, allowed = prediction
    if found == expected:
        return "held"
    return "allowed" if found in allowed else "did not hold"


def predicted(prediction) -> str:
    if prediction is None:
        return "no firm prediction"
    expected, allowed = prediction
    return expected + "".join(f" (or {a})" for a in allowed)


def reading_cell(table: dict | None, cell: str) -> tuple[str, str | None]:
    """(the text of one rate's column, the verdict or None) for condition/scenario."""
    if table is None:
        return "not yet run", None
    if cell in table.get("left_out", []):
        return "no reading (a row scored no episode)", None
    r = table["cells"].get(cell)
    if r is None:
        return "not yet run", None
    found = verdict(r["reading"])
    return f"{effect_text(r)}, {r['ahead']}/{r['behind']}, **{found}**", found


def effect_text(r: dict) -> str:
    """A read cell's effect in points and its episodes' paired 95 % interval."""
    lo, hi = (points(v) for v in r["episodes"]["ci95"])
    return f"{points(r['mean_diff'])} [{lo}, {hi}]"


def task_table(task: str, tables: dict[int, dict | None]) -> tuple[list[str], int]:
    """The markdown rows of one task's headline table; the number of cells read at
    every rate."""
    metric = tables_metric(task, tables)
    lines = [f"**{task}** ({metric}; RGB+Event - RGB+Diff in points, mean over training "
             f"seeds [episodes' paired 95 % interval], seeds ahead/behind, the plan's reading)",
             "", "| cell | " + " | ".join(f"{r} Hz" for r in RATES)
             + " | predicted (10 / 30 Hz) | held (10 / 30 Hz) |",
             "|---|" + "---|" * (len(RATES) + 2)]
    complete = 0
    for condition, scenario in PLAN_CELLS[task]:
        cell = f"{condition}/{scenario}"
        texts, found = zip(*(reading_cell(tables.get(rate), cell) for rate in RATES))
        complete += all(f is not None for f in found)
        pred = PREDICTIONS[(task, condition)]
        lines.append(f"| {cell} | " + " | ".join(texts) + " | "
                     + " / ".join(predicted(pred[r]) for r in RATES) + " | "
                     + " / ".join(held(pred[r], f) for r, f in zip(RATES, found)) + " |")
    return lines, complete


def reading_detail(task: str, rate: int, table: dict) -> list[str]:
    """One reading in full, for the study's log and a session's note: per cell the effect
    and its interval, each training seed's own difference, the episodes' sign test, the
    rule's verdict and the plan's prediction; every figure from `sebvs eval table`'s JSON, so
    that none is typed by hand."""
    runs = table["runs"]
    lines = [f"{task} at {rate} Hz, {table['metric']}: {table['a']} - {table['b']} in points; "
             f"mean over training seeds [episodes' paired 95 % interval]; each seed's own "
             f"difference ({', '.join(runs)}); episodes ahead/behind/tied with the sign "
             f"test's p; the rule's verdict (at least {table['rule']['min_diff_points']:g} "
             f"points and {table['rule']['min_ahead']} seeds the same way)", "",
             "| cell | effect | seeds ahead/behind | per seed | episodes (sign p) "
             "| verdict | predicted | held |", "|---|" + "---|" * 7]
    for condition, scenario in PLAN_CELLS[task]:
        cell = f"{condition}/{scenario}"
        text, found = reading_cell(table, cell)
        pred = PREDICTIONS[(task, condition)][rate]
        if found is None:
            lines.append(f"| {cell} | {text} | | | | | {predicted(pred)} | - |")
            continue
        r = table["cells"][cell]
        per_seed = ", ".join(points(r['per_run'][k]['diff']) for k in runs
                             if k in r["per_run"])
        ep = r["episodes"]
        lines.append(f"| {cell} | {effect_text(r)} | {r['ahead']}/{r['behind']} | {per_seed} "
                     f"| {ep['wins']}/{ep['losses']}/{ep['ties']} (p {ep['p_sign']:.3g}) "
                     f"| {found} | {predicted(pred)} | {held(pred, found)} |")
    if table.get("left_out"):
        lines += ["", f"Left out (a row scored no episode there): {', '.join(table['left_out'])}."]
    return lines


def tables_metric(task: str, tables: dict[int, dict | None]) -> str:
    for t in tables.values():
        if t:
            return t["metric"]
    return READ_METRIC[task] or TASK_METRICS[task][0][0]


def evaluations(out: Path, task: str, rate: int):
    """Each planned evaluation of the task and rate that has results: its episodes (one
    list per training seed and evaluation group, in the plan's order)."""
    for seed in sorted({s for ss in PLAN_SEEDS[rate].values() for s in ss}):
        for group, _, _ in EVAL_GROUPS[task]:
            path = eval_dir(out, task, rate, seed, group) / "results.json"
            if path.exists():
                yield read_results(path)["episodes"]


def row_means(out: Path, task: str, rate: int, metric: str
              ) -> tuple[dict[str, dict[str, float]], dict[str, int]]:
    """{row: {condition/scenario: mean metric}} over every evaluation found for the task
    and rate; a modality trained with several seeds is averaged over them (each seed's
    cell mean first); and {row: the training seeds found for it}, which is fewer than the
    plan's while its evaluations are under way."""
    per_seed: dict[str, dict[str, list[float]]] = {}
    for episodes in evaluations(out, task, rate):
        cells: dict[tuple[str, str], list[float]] = {}
        for e in episodes:
            v = e["metrics"].get(metric)
            if v is not None:
                cells.setdefault((e["modality"], f"{e['condition']}/{e['scenario']}"),
                                 []).append(float(v))
        for (row, cell), xs in cells.items():
            per_seed.setdefault(row, {}).setdefault(cell, []).append(statistics.fmean(xs))
    means = {row: {cell: statistics.fmean(ms) for cell, ms in cells.items()}
             for row, cells in per_seed.items()}
    return means, {row: max(len(ms) for ms in cells.values())
                   for row, cells in per_seed.items()}


REFERENCE_ROWS = ("expert", "no_action")


def alike_cells(out: Path, task: str, rate: int) -> dict[str, list[list[str]]]:
    """{reference row: the groups of two or more cells in which it scored alike, episode by
    episode (the same test seeds, every metric of every episode equal)}, over every
    evaluation found for the task and rate.

    The expert drives on the ideal render through a colour detector that reads hue and
    chroma, which neither the light nor the scene variant changes, and no action holds
    still: both play the same episodes wherever the target moves the same way. The report
    says where, so that a figure repeated across cells reads as what it is."""
    episodes: dict[tuple[str, str], list[tuple[int, str]]] = {}
    for e in (e for found in evaluations(out, task, rate) for e in found):
        if e["modality"] in REFERENCE_ROWS:
            episodes.setdefault((e["modality"], f"{e['condition']}/{e['scenario']}"),
                                []).append((e["seed"], json.dumps(e["metrics"], sort_keys=True)))
    groups: dict[str, dict[tuple, list[str]]] = {}
    for (row, cell), played in episodes.items():
        groups.setdefault(row, {}).setdefault(tuple(sorted(played)), []).append(cell)
    order = {f"{c}/{s}": i for i, (c, s) in enumerate(PLAN_CELLS[task])}
    alike = {}
    for row in REFERENCE_ROWS:
        same = [sorted(cells, key=lambda c: order.get(c, len(order)))
                for cells in groups.get(row, {}).values() if len(cells) > 1]
        if same:
            alike[row] = same
    return alike


def alike_line(alike: dict[str, list[list[str]]]) -> str:
    """The reference rows that repeat across cells, and why, in one paragraph."""
    said = "; ".join(f"{row} in {' = '.join(cells)}" for row, groups in alike.items()
                     for cells in groups)
    return (f"Alike, episode by episode (same test seeds, every metric equal): {said}. The "
            f"expert reads the ideal render through a colour detector that finds the target "
            f"by hue and chroma (sebvs/experts/detector.py), which neither the light nor the "
            f"scene variant changes, and no action holds still, so both repeat wherever the "
            f"target moves the same way.")


def eval_steps(out: Path, task: str, rate: int) -> list:
    """The plan's evaluation steps of the task and rate, done or not."""
    return [s for s in plan_steps(out, 1, {f"{task}{rate}"}) if s.kind == "eval"]


def eval_machines(out: Path, task: str, rate: int) -> dict[str, dict[str, list[str]]]:
    """{evaluation step label: {"cpus": the CPUs its runs ran on, "gl": the GL stacks they
    rendered with}}, from the driver's ledger, for the plan's evaluations of the task and
    rate that have results (an empty list: run before the ledger named them)."""
    return {step.label: {"cpus": sorted(ledger_machines(out / LEDGER, step.label)),
                         "gl": sorted(ledger_machines(out / LEDGER, step.label, "gl"))}
            for step in eval_steps(out, task, rate) if step.done.exists()}


def machines_line(found: dict[str, dict[str, list[str]]]) -> str:
    """Where the evaluations ran, in one sentence: the report names the CPU and GL stack of
    every reading, as no reading may pair rows made on different ones (docs/scale.md)."""
    parts = []
    for key, what in (("cpus", "CPU"), ("gl", "GL stack")):
        seen = sorted({m for ms in found.values() for m in ms[key]})
        mixed = [label for label, ms in found.items() if len(ms[key]) > 1]
        unknown = [label for label, ms in found.items() if not ms[key]]
        part = "; ".join(seen) if seen else f"no {what} recorded"
        if mixed:
            part += f"; more than one {what} within {', '.join(mixed)}"
        if unknown and seen:
            part += f"; no {what} recorded for {', '.join(unknown)}"
        parts.append(part)
    return (f"Evaluated on: {parts[0]}. Rendered with: {parts[1]} ({len(found)} "
            f"evaluation{'s' * (len(found) != 1)}).")


def trained_from(out: Path, task: str, rate: int) -> dict[str, dict[str, list[int]]]:
    """{the files' sha256 of the recording a training read: {modality: its training
    seeds}}, from the JSON beside each of the plan's finished checkpoints of the task and
    rate ("unknown" where that JSON names none). A dataset recorded again (a new checkout
    must: the recordings are not kept) has other files, so a reading whose trainings read
    more than one recording shows it here (research/sensors/log.md says whether their
    content differed)."""
    found: dict[str, dict[str, list[int]]] = {}
    for step in plan_steps(out, 1, {f"{task}{rate}"}):
        if step.kind != "train" or not step.done.exists():
            continue
        try:
            digest = json.loads(step.done.with_suffix(".json").read_text())["dataset"]["hash"]
        except (OSError, ValueError, KeyError, TypeError):
            digest = None
        digest = digest if isinstance(digest, str) and digest else "unknown"
        modality = step.argv[step.argv.index("--modality") + 1]
        seed = int(step.argv[step.argv.index("--seed") + 1])
        found.setdefault(digest, {}).setdefault(modality, []).append(seed)
    return found


def recordings_line(task: str, rate: int, found: dict[str, dict[str, list[int]]]) -> str:
    """Which recording the reading's trainings read, in one sentence: one, or each of
    several with the trainings that read it."""
    def trainings(by_modality: dict[str, list[int]]) -> str:
        return ", ".join(f"{m} seed{'s' * (len(seeds) > 1)} {', '.join(map(str, sorted(seeds)))}"
                         for m, seeds in sorted(by_modality.items()))

    def short(digest: str) -> str:
        return digest if digest == "unknown" else f"sha256 {digest[:12]}"
    n = sum(len(seeds) for by in found.values() for seeds in by.values())
    where = f"datasets/study_{task}{rate}"
    if len(found) == 1:
        (digest, _), = found.items()
        return (f"Trained on: one recording of {where} (files {short(digest)}; "
                f"{n} training{'s' * (n != 1)}).")
    parts = "; ".join(f"{short(d)}: {trainings(by)}" for d, by in sorted(found.items()))
    return (f"Trained on: {len(found)} recordings of {where} (their files differ; "
            f"{n} trainings): {parts}.")


def rows_table(task: str, rate: int, means: dict[str, dict[str, float]],
               found: dict[str, int] | None = None) -> list[str]:
    """The descriptive table; a learned row's header says its seeds, and how many of the
    plan's its figures hold while some are still to be evaluated (``found``)."""
    planned = {m: len(s) for m, s in PLAN_SEEDS[rate].items()}
    found = found or {}

    def header(row: str) -> str:
        if row not in planned:
            return row
        n = planned[row]
        have = found.get(row, n) if row in means else n
        seeds = f"{n} seed{'s' * (n > 1)}"
        return f"{row} ({seeds})" if have >= n else f"{row} ({have} of {seeds})"
    head = [header(r) for r in ROWS]
    lines = ["| cell | " + " | ".join(head) + " |", "|---|" + "---|" * len(ROWS)]
    for condition, scenario in PLAN_CELLS[task]:
        cell = f"{condition}/{scenario}"
        vals = [means.get(r, {}).get(cell) for r in ROWS]
        lines.append(f"| {cell} | " + " | ".join("-" if v is None else f"{100 * v:.1f}"
                                                  for v in vals) + " |")
    return lines


def planned_evaluations(out: Path, task: str, rate: int) -> tuple[int, int]:
    """(how many of the plan's evaluations of the task and rate are done, how many it has)."""
    steps = eval_steps(out, task, rate)
    return sum(s.done.exists() for s in steps), len(steps)


def report(out: Path, unread_rows: bool = False) -> tuple[str, dict, bool]:
    """(markdown, the data behind it, whether every planned cell has a reading).

    A task and rate without a reading shows no figures, only how many of its evaluations
    are in: the plan reads them when all three seeds' are, and a page (or a session)
    that showed partial means before then would invite reading them early.
    ``unread_rows`` shows them anyway, each learned row's header saying how many of its
    seeds they hold."""
    lines = [f"The sensor study's readings, by the rule of {PLAN_FILE} (fixed before any "
             f"recording): RGB+Event against the RGB+Diff control, three training seeds "
             f"each, test seeds never used before.", ""]
    data: dict = {"plan": PLAN_FILE, "tasks": {}}
    done = True
    for task in ("nav", "arm"):
        tables = {}
        for rate in RATES:
            path = reading_path(out, task, rate)
            tables[rate] = json.loads(path.read_text()) if path.exists() else None
        rows, complete = task_table(task, tables)
        done &= complete == len(PLAN_CELLS[task])
        lines += rows + [""]
        metric = tables_metric(task, tables)
        data["tasks"][task] = {"readings": tables, "rows": {}, "machines": {}}
        for rate in RATES:
            if tables[rate] is None and not unread_rows:
                have, planned = planned_evaluations(out, task, rate)
                for key in ("rows", "seeds_found", "alike", "recordings"):
                    data["tasks"][task].setdefault(key, {})[rate] = None
                lines += [f"{task} at {rate} Hz: not read yet ({have} of its {planned} "
                          f"planned evaluations done); its rows appear with its reading.", ""]
            else:
                means, found = row_means(out, task, rate, metric)
                data["tasks"][task]["rows"][rate] = means
                data["tasks"][task].setdefault("seeds_found", {})[rate] = found
                lines += [f"{task} at {rate} Hz, every row ({metric}, %, mean over the "
                          f"seeds each modality was trained with; test seed episodes):",
                          "", *rows_table(task, rate, means, found), ""]
                alike = alike_cells(out, task, rate)
                data["tasks"][task].setdefault("alike", {})[rate] = alike
                if alike:
                    lines += [alike_line(alike), ""]
                recordings = trained_from(out, task, rate)
                data["tasks"][task].setdefault("recordings", {})[rate] = recordings
                if recordings:
                    lines += [recordings_line(task, rate, recordings), ""]
            found = eval_machines(out, task, rate)
            data["tasks"][task]["machines"][rate] = found
            if found:
                lines += [machines_line(found), ""]
    return "\n".join(lines), data, done


VERDICT_COLOUR = {HELPS: "tab:green", HURTS: "tab:red", NONE: "0.45"}
RATE_MARKER = {10: "o", 30: "s"}
SHORT = {HELPS: "helps", HURTS: "hurts", NONE: "none"}


def plot(data: dict, path: Path) -> list[str]:
    """The headline tables as a forest plot, one panel per task: per cell (top to bottom
    in the plan's order) RGB+Event - RGB+Diff in points at each rate, a marker at the
    mean over training seeds and a line for the episodes' paired 95 % interval, coloured
    by the rule's verdict (hollow where the cell has no reading yet); the grey band is the
    rule's least difference; the plan's prediction is written at the right. Returns the
    legend's labels: the markers for unread and left-out cells appear only where used."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    min_diff = float(READ_RULE[READ_RULE.index("--min-diff") + 1])
    tasks = list(data["tasks"])
    fig, axes = plt.subplots(1, len(tasks), figsize=(6.2 * len(tasks), 5.2), squeeze=False)
    missing = set()                 # which of "not yet run", "no reading" was drawn
    for ax, task in zip(axes[0], tasks):
        readings = data["tasks"][task]["readings"]
        cells = PLAN_CELLS[task]
        ax.axvspan(-min_diff, min_diff, color="0.92", zorder=0)
        ax.axvline(0, color="black", lw=0.8)
        for i, (condition, scenario) in enumerate(cells):
            y = len(cells) - 1 - i
            for k, rate in enumerate(RATES):
                yk = y + (0.15 if k == 0 else -0.15)
                table = readings.get(rate) or readings.get(str(rate))
                cell = f"{condition}/{scenario}"
                r = (table or {}).get("cells", {}).get(cell)
                if r is None:
                    left_out = cell in (table or {}).get("left_out", [])
                    ax.plot(0, yk, "x" if left_out else RATE_MARKER[rate],
                            mfc="none", mec="0.6", color="0.6", ms=5)
                    missing.add("no reading" if left_out else "not yet run")
                    continue
                colour = VERDICT_COLOUR[verdict(r["reading"])]
                lo, hi = (100 * v for v in r["episodes"]["ci95"])
                ax.hlines(yk, lo, hi, color=colour, lw=1.5)
                ax.plot(100 * r["mean_diff"], yk, RATE_MARKER[rate], color=colour, ms=6)
            pred = PREDICTIONS[(task, condition)]
            ax.annotate(" / ".join(SHORT[pred[r][0]] if pred[r] else "?" for r in RATES),
                        (1.01, y), xycoords=("axes fraction", "data"), fontsize=7,
                        va="center", color="0.3")
        ax.set_yticks(range(len(cells)),
                      [f"{c}/{s}" for c, s in reversed(cells)], fontsize=8)
        ax.set_ylim(-0.7, len(cells) - 0.3)
        metric = tables_metric(task, readings)
        ax.set_xlabel(f"RGB+Event - RGB+Diff, {metric} (points)")
        ax.set_title(f"{task}; at right the plan's prediction at 10 / 30 Hz", fontsize=9)
        span = max([min_diff + 5] + [abs(x) + 2 for x in ax.get_xlim()])
        ax.set_xlim(-span, span)
    handles = [Line2D([], [], marker=RATE_MARKER[r], ls="", color="0.3", label=f"{r} Hz")
               for r in RATES]
    handles += [Line2D([], [], color=c, lw=2, label=v) for v, c in VERDICT_COLOUR.items()]
    if "not yet run" in missing:
        handles.append(Line2D([], [], marker="o", ls="", mfc="none", mec="0.6",
                              label="not yet run"))
    if "no reading" in missing:
        handles.append(Line2D([], [], marker="x", ls="", color="0.6", label="no reading"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8,
               frameon=False)
    fig.suptitle(f"The sensor study ({PLAN_FILE}): per cell, the mean over training seeds "
                 f"and the episodes' 95 % interval\ngrey band: the rule's "
                 f"{min_diff:g}-point least difference; predictions: helps, hurts, "
                 f"none (no clear difference), ? (no firm one)", fontsize=9)
    fig.tight_layout(rect=(0, 0.05, 1, 0.95), w_pad=6)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [h.get_label() for h in handles]


BEGIN = "<!-- sensor_report.py: begin -->"
END = "<!-- sensor_report.py: end -->"


def replace_block(doc: str, tables: str) -> str:
    """`doc` with what stands between its BEGIN and END lines replaced by `tables`:
    the page's own prose stays, the tables are regenerated. ValueError unless each
    marker stands once, BEGIN first."""
    lines = doc.splitlines(keepends=True)
    at = {m: [i for i, line in enumerate(lines) if line.strip() == m] for m in (BEGIN, END)}
    if len(at[BEGIN]) != 1 or len(at[END]) != 1 or at[BEGIN][0] > at[END][0]:
        raise ValueError(f"needs one line {BEGIN!r} and, after it, one line {END!r} "
                         f"(found {len(at[BEGIN])} and {len(at[END])})")
    b, e = at[BEGIN][0], at[END][0]
    return "".join(lines[:b + 1]) + tables.rstrip("\n") + "\n" + "".join(lines[e:])


def print_reading(out: Path, name: str) -> int:
    """--reading: 0 and the reading's detail, or 2 and what was wrong."""
    if name not in READINGS:
        print(f"sensor_report: --reading {name!r}: expected one of {', '.join(READINGS)}",
              file=sys.stderr)
        return 2
    task, rate = READINGS[name]
    path = reading_path(out, task, rate)
    try:
        table = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        print(f"sensor_report: --reading {name}: {path}: {exc} (not read yet?)",
              file=sys.stderr)
        return 2
    print("\n".join(reading_detail(task, rate, table)))
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "research" / "sensors" / "outputs",
                    help="the study driver's --out (default research/sensors/outputs)")
    ap.add_argument("--markdown", type=Path, help="write the tables here (default: print)")
    ap.add_argument("--json", type=Path, help="also write the data behind them here")
    ap.add_argument("--plot", type=Path, help="also draw them as one figure here (PNG)")
    ap.add_argument("--update", type=Path, metavar="DOC",
                    help=f"put the tables into DOC (docs/results.md) between its lines "
                         f"{BEGIN!r} and {END!r}, the rest of it left as it is")
    ap.add_argument("--unread-rows", action="store_true",
                    help="also show the rows of a task and rate the plan has not read yet "
                         "(means over the seeds evaluated so far; off by default, so that "
                         "nothing is read before its time)")
    ap.add_argument("--reading", metavar="TASKRATE",
                    help="print one reading in full instead (e.g. nav30: each seed's "
                         "difference, the episodes' sign test, the prediction), from "
                         "OUT/read/TASKRATE.json")
    args = ap.parse_args(argv)
    if args.reading:
        return print_reading(args.out, args.reading)
    text, data, done = report(args.out, args.unread_rows)
    if args.update:
        try:
            args.update.write_text(replace_block(args.update.read_text(), text))
        except (OSError, ValueError) as exc:
            print(f"sensor_report: --update {args.update}: {exc}", file=sys.stderr)
            return 2
    if args.markdown:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(text)
    else:
        print(text)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(data, indent=1) + "\n")
    if args.plot:
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        plot(data, args.plot)
    if not done:
        print("sensor_report: some planned cells have no reading yet (see the tables)",
              file=sys.stderr)
    return 0 if done else 3


if __name__ == "__main__":
    sys.exit(main())
