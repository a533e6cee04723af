"""research/sensors/sensor_study.py builds the plan's steps (research/sensors/plan.md) and
resumes where a stop left them."""
import json
import shutil

import pytest

from research.tests.study_loader import study_module
from tests.eval_readers import reader


@pytest.fixture(autouse=True)
def no_real_datasets(tmp_path, monkeypatch):
    """Every test's study datasets under its own tmp_path: a step's `done` file of a
    recording is the dataset's index.json, and a test that removes its steps' done files
    once removed datasets/study_nav30/index.json from under a running study."""
    monkeypatch.setenv("SEBVS_STUDY_DATASETS", str(tmp_path / "study-datasets"))


def test_the_datasets_of_a_test_are_never_the_real_ones(tmp_path):
    with study_module("sensors/sensor_study") as study:
        records = [s for s in study.plan_steps(tmp_path, 2, None) if s.kind == "record"]
    assert len(records) == 4
    assert all(s.done.is_relative_to(tmp_path) for s in records)


def test_the_steps_are_the_plans():
    with study_module("sensors/sensor_study") as study:
        steps = study.plan_steps(study.ROOT / "out" / "x", 2, None)
        kinds = [s.kind for s in steps]
        assert [kinds.count(k) for k in ("record", "train", "eval", "read")] == [4, 36, 18, 4]
        record = " ".join(steps[0].argv)
        for part in ("topologies/nav_record.toml", "--episodes 120", "topology.seed=20",
                     'camera.sensor="physical"', 'emulator.preset="physical"',
                     "sim.episode_s=20.0"):
            assert part in record, part
        evals = [" ".join(s.argv) for s in steps if s.kind == "eval"]
        assert all("--split test" in e and "--episodes 20" in e for e in evals)
        assert sum("--seed 100100" in e for e in evals) == 12      # nav: 2 rates x 3 x 2
        assert all("--control-hz 30" in e for e in evals if "nav30" in e or "arm30" in e)
        # the expert and no-action rows once per task and rate: with training seed 0
        assert sum("--no-expert" not in e for e in evals) == 6
        reads = [" ".join(s.argv) for s in steps if s.kind == "read"]
        assert all("--a rgb+event --b rgb+diff --min-diff 10 --min-ahead 3" in r
                   for r in reads)
        assert "--metric strict_success" in reads[0]


def test_a_recording_resumes_with_the_episodes_missing(tmp_path, monkeypatch):
    with study_module("sensors/sensor_study") as study:
        monkeypatch.setattr(study, "dataset_dir", lambda task, rate: tmp_path / f"{task}{rate}")
        step = study.plan_steps(tmp_path, 2, {"nav10"})[0]
        assert not study.is_done(step)
        (tmp_path / "nav10").mkdir()
        index = tmp_path / "nav10" / "index.json"

        def holding(numbers):
            index.write_text(json.dumps(
                {"episodes": [{"file": f"episode_{k:04d}.h5"} for k in numbers]}))
        holding(range(30))                       # 0..29: extended by the 90 missing
        argv = study.command_of(step)
        assert argv[argv.index("--episodes") + 1] == "90"
        holding([*range(10), *range(60, 75)])    # an interrupted fan-out's holes: filled
        argv = study.command_of(step)
        assert argv[-1] == "--fill" and argv[argv.index("--episodes") + 1] == "120"
        holding(range(120))
        assert study.is_done(step)


def _episode(modality, condition, scenario, k, value):
    return {"modality": modality, "condition": condition, "scenario": scenario, "seed": k,
            "metrics": {"strict_success": value}}


def test_the_report_reads_the_rule_against_the_plans_predictions(tmp_path, capsys):
    """Three seeds where events lead by 30 points in hdr indoors, tie in nominal light, and
    have no scored episode under flicker: helps (predicted: held), no clear difference
    (held), no reading; the 30 Hz column and the arm are not yet run."""
    with study_module("sensors/sensor_study") as study, \
            reader("table") as seeds, \
            study_module("sensors/sensor_report") as rep:
        runs = {}
        for seed in (0, 1, 2):
            main, flicker = [], []
            for k in range(10):
                main += [_episode("rgb+event", "hdr", "indoor", k, 0.8),
                         _episode("rgb+diff", "hdr", "indoor", k, 0.5),
                         _episode("rgb+event", "nominal_physical", "indoor", k, 0.6),
                         _episode("rgb+diff", "nominal_physical", "indoor", k, 0.6)]
                flicker += [_episode("rgb+event", "flicker_100", "indoor", k, None),
                            _episode("rgb+diff", "flicker_100", "indoor", k, 0.4)]
                if seed == 0:
                    main += [_episode("expert", "hdr", "indoor", k, 1.0),
                             _episode("expert", "nominal_physical", "indoor", k, 1.0),
                             _episode("no_action", "hdr", "indoor", k, 0.1 * (k % 2)),
                             _episode("no_action", "nominal_physical", "indoor", k,
                                      0.1 * (k % 2) if k else 0.2)]
            for group, episodes in (("main", main), ("flicker", flicker)):
                d = study.eval_dir(tmp_path, "nav", 10, seed, group)
                d.mkdir(parents=True)
                (d / "results.json").write_text(json.dumps(
                    {"task": "nav", "seed": 100100, "episodes": episodes}))
            runs[f"seed{seed}"] = seeds.merge_runs(
                [(g, json.loads((study.eval_dir(tmp_path, "nav", 10, seed, g)
                                 / "results.json").read_text())) for g in ("main", "flicker")])
        table = seeds.seed_table(runs, "rgb+event", "rgb+diff", "strict_success", 10.0, 3)
        (tmp_path / "read").mkdir()
        (tmp_path / "read" / "nav10.json").write_text(json.dumps(table))

        text, data, done = rep.report(tmp_path)
        assert not done
        lines = {}                         # the headline table's rows: the first of each cell
        for line in text.splitlines():
            if line.startswith("| "):
                lines.setdefault(line.split(" | ")[0].lstrip("| "), line)
        hdr = lines["hdr/indoor"]
        assert "+30.0 [+30.0, +30.0], 3/0, **helps**" in hdr and "| held / - |" in hdr
        assert "not yet run" in hdr                       # the 30 Hz column
        assert "**no clear difference**" in lines["nominal_physical/indoor"]
        assert "no reading" in lines["flicker_100/indoor"]
        assert "not yet run" in lines["dusk/outdoor"]
        # the expert plays the same episodes in both cells, no action differs in one
        assert data["tasks"]["nav"]["alike"][10] == {
            "expert": [["nominal_physical/indoor", "hdr/indoor"]]}
        assert "expert in nominal_physical/indoor = hdr/indoor." in text
        assert "no_action in" not in text and data["tasks"]["nav"]["alike"][30] is None
        means = data["tasks"]["nav"]["rows"][10]
        assert means["rgb+event"]["hdr/indoor"] == pytest.approx(0.8)
        assert means["no_action"]["hdr/indoor"] == pytest.approx(0.05)
        assert "rgb+event" not in means or "flicker_100/indoor" not in means["rgb+event"]
        assert data["tasks"]["nav"]["seeds_found"][10] == {
            "rgb+event": 3, "rgb+diff": 3, "expert": 1, "no_action": 1}
        assert "| rgb+diff (3 seeds) | rgb+event (3 seeds) |" in text
        # a rate not read yet shows how far its evaluations are, not their figures
        assert "nav at 30 Hz: not read yet (0 of its 6 planned evaluations done)" in text
        assert "nav at 30 Hz, every row" not in text and data["tasks"]["nav"]["rows"][30] is None
        assert rep.main(["--out", str(tmp_path), "--markdown", str(tmp_path / "r.md"),
                         "--plot", str(tmp_path / "r.png")]) == 3
        assert (tmp_path / "r.md").read_text() == text
        assert (tmp_path / "r.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        labels = rep.plot(data, tmp_path / "r2.png")
        assert labels[:2] == ["10 Hz", "30 Hz"] and labels[-2:] == ["not yet run", "no reading"]
        # --update: the page's prose stays, the tables between the markers are remade
        page = tmp_path / "results.md"
        page.write_text(f"# Results\nprose\n{rep.BEGIN}\nold tables\n{rep.END}\nmore prose\n")
        assert rep.main(["--out", str(tmp_path), "--update", str(page)]) == 3
        assert page.read_text() == \
            f"# Results\nprose\n{rep.BEGIN}\n{text.rstrip()}\n{rep.END}\nmore prose\n"
        page.write_text("# Results\nno markers\n")
        assert rep.main(["--out", str(tmp_path), "--update", str(page)]) == 2
        # --reading: one reading in full, each seed's own difference and the sign test
        capsys.readouterr()
        assert rep.main(["--out", str(tmp_path), "--reading", "nav10"]) == 0
        detail = {line.split(" | ")[0].lstrip("| "): line
                  for line in capsys.readouterr().out.splitlines() if line.startswith("| ")}
        assert detail["hdr/indoor"] == ("| hdr/indoor | +30.0 [+30.0, +30.0] | 3/0 | +30.0, "
                                        "+30.0, +30.0 | 10/0/0 (p 0.00195) | helps | helps "
                                        "| held |")
        assert "no reading" in detail["flicker_100/indoor"]
        assert "| 0/0/10 (p 1) | no clear difference |" in detail["nominal_physical/indoor"]
        assert rep.main(["--out", str(tmp_path), "--reading", "nav30"]) == 2
        assert "nav30.json" in capsys.readouterr().err
        assert rep.main(["--out", str(tmp_path), "--reading", "nav"]) == 2
        # while a seed's evaluation is missing, the header says how many the figures hold
        shutil.rmtree(study.eval_dir(tmp_path, "nav", 10, 2, "main").parent)
        (tmp_path / "read" / "nav10.json").unlink()
        partial, _, _ = rep.report(tmp_path)
        assert "nav at 10 Hz: not read yet (4 of its 6 planned evaluations done)" in partial
        assert "2 of 3 seeds" not in partial
        partial, _, _ = rep.report(tmp_path, unread_rows=True)
        assert "| rgb+diff (2 of 3 seeds) | rgb+event (2 of 3 seeds) |" in partial
        assert page.read_text() == "# Results\nno markers\n"       # left alone


def test_the_finished_studys_figure_has_no_legend_for_cells_it_lacks(tmp_path):
    """The committed study has every reading (exit 0): its figure's legend names the rates
    and verdicts, not the markers of unread or left-out cells, which it does not draw."""
    with study_module("sensors/sensor_study") as study, \
            study_module("sensors/sensor_report") as rep:
        _, data, done = rep.report(study.STUDY_DIR)
        assert done
        labels = rep.plot(data, tmp_path / "r.png")
        assert "not yet run" not in labels and "no reading" not in labels
        assert {"10 Hz", "30 Hz", "helps", "hurts"} <= set(labels)


def test_a_difference_that_sums_to_zero_reads_plus_zero():
    """Seeds at -5, +5 and 0 points average to -1e-17 in floating point: the tables say
    +0.0 there (arm 10 Hz, nominal_physical/multi, first printed -0.0)."""
    with study_module("sensors/sensor_report") as rep:
        assert rep.points((-0.05 + 0.05 + 0.0) / 3 - 1e-17) == "+0.0"
        assert rep.points(-0.15) == "-15.0" and rep.points(0.07017) == "+7.0"
        r = {"mean_diff": -1e-17, "episodes": {"ci95": [-0.05, 0.05]}}
        assert rep.effect_text(r) == "+0.0 [-5.0, +5.0]"


def fake_datasets(study, root, monkeypatch, frames: dict[str, int]) -> None:
    """Study datasets of these frame counts under root (their index only), in place of
    datasets/, which a checkout does not hold: each holds its plan's episodes (a shorter
    one is still being recorded), the frames on the first."""
    monkeypatch.setattr(study, "dataset_dir", lambda task, rate: root / f"study_{task}{rate}")
    for name, n in frames.items():
        task, rate = name.removeprefix("study_")[:3], int(name.removeprefix("study_")[3:])
        episodes = study.SENSORS.recordings[(task, rate)].episodes
        (root / name).mkdir()
        (root / name / "index.json").write_text(json.dumps(
            {"version": 1, "task": task, "episodes": [
                {"file": f"episode_{i:04d}.h5", "frames": 0 if i else n}
                for i in range(episodes)]}))


def test_status_shows_each_steps_time_and_estimates_the_rest(tmp_path, monkeypatch):
    with study_module("sensors/sensor_study") as study:
        fake_datasets(study, tmp_path, monkeypatch, {"study_nav10": 100})
        steps = [s for s in study.plan_steps(tmp_path, 2, {"nav10"}) if s.kind == "train"]
        ledger = tmp_path / "steps.jsonl"
        for step, seconds, code in [(steps[0], 600.4, 0), (steps[1], 100.0, -15),
                                    (steps[2], 900.0, 0), (steps[1], 200.0, 0)]:
            study.append_ledger(ledger, step, 0.0, seconds, code)
        with ledger.open("a") as f:                  # a torn or foreign line is skipped
            f.write('{"label": "train nav 10 Hz rgb seed 0", "seconds": "soon"}\n{"lab\n')
        took = study.step_seconds(ledger)
        # a step resumed over runs: the sum of its runs, the stopped one's time included
        assert took == {steps[0].label: 600.4, steps[1].label: 300.0, steps[2].label: 900.0}
        for s in steps[:3]:
            s.done.parent.mkdir(parents=True, exist_ok=True)
            s.done.write_bytes(b"")
        text = study.status_text(steps, ["train"], took)
        assert "train: 3/10 done" in text
        assert f"done: {steps[2].label} (15 min)" in text
        assert f"left: {steps[3].label} (~10 min, from 3 done like it)" in text
        assert "estimated wall time left: 0.6 h (trainings 2 at once)" in text   # 7 x 10 / 2


def test_status_counts_only_the_epochs_a_resume_state_leaves(tmp_path, monkeypatch):
    import torch
    with study_module("sensors/sensor_study") as study:
        fake_datasets(study, tmp_path, monkeypatch, {"study_nav10": 100})
        steps = [s for s in study.plan_steps(tmp_path, 2, {"nav10"}) if s.kind == "train"]
        took = {}
        for s in steps[:3]:                        # 10 planned epochs in 10 min each
            s.done.parent.mkdir(parents=True, exist_ok=True)
            s.done.write_bytes(b"")
            took[s.label] = 600.0
        stopped, torn = steps[3], steps[4]

        state = study.resume_state_of(stopped)
        state.parent.mkdir(parents=True, exist_ok=True)
        torch.save({"fingerprint": "x", "epoch": 5}, state)
        torn_state = study.resume_state_of(torn)
        torn_state.parent.mkdir(parents=True, exist_ok=True)
        torn_state.write_bytes(b"PK\x03\x04 half a file")
        assert study.epochs_kept(stopped) == 5 and study.epochs_kept(torn) == 0
        text = study.status_text(steps, ["train"], took)
        assert (f"left: {stopped.label} (~5 min, from 3 done like it; 5 epochs kept in its "
                f"resume state)") in text
        assert f"left: {torn.label} (~10 min, from 3 done like it)\n" in text
        assert "estimated wall time left: 0.5 h" in text       # (6 x 10 + 5) / 2 min


def test_status_scales_estimates_by_the_work_of_each_step(tmp_path, monkeypatch):
    with study_module("sensors/sensor_study") as study:
        fake_datasets(study, tmp_path, monkeypatch, {"study_nav10": 100, "study_nav30": 300})
        steps = study.plan_steps(tmp_path, 2, {"nav10", "nav30"})
        train = [s for s in steps if s.kind == "train"]
        first = train[0]
        first.done.parent.mkdir(parents=True, exist_ok=True)
        first.done.write_bytes(b"")
        took = {first.label: 600.0}
        assert study.step_work(first) == 100 * 10                 # frames x epochs
        text = study.status_text(train, ["train"], took)
        nav30 = next(s for s in train if " 30 Hz " in s.label)
        # three times the frames: three times the time, from the one nav 10 Hz training
        assert f"left: {nav30.label} (~30 min, scaled by frames from 1 done trainings)" in text
        evals = [s for s in steps if s.kind == "eval"]
        main0, flicker0 = evals[0], evals[1]
        # seed 0: four modalities, the expert and no action; 8 cells of 20 x 10 s episodes
        assert study.step_work(main0) == 6 * 8 * 20 * 10.0
        assert study.step_work(flicker0) == 6 * 2 * 20 * 10.0
        seed1 = next(s for s in evals if "seed 1 main" in s.label)
        assert study.step_work(seed1) == 3 * 8 * 20 * 10.0      # three modalities, no refs
        arm0 = next(s for s in study.plan_steps(tmp_path, 2, {"arm10"}) if s.kind == "eval")
        # no --set of its length: arm_policy.toml's 2 s episodes, which sebvs eval plays
        assert study.step_work(arm0) == 6 * 8 * 20 * 2.0
        main0.done.parent.mkdir(parents=True, exist_ok=True)
        main0.done.write_bytes(b"")
        text = study.status_text(evals, ["eval"], {main0.label: 1200.0})
        assert f"left: {seed1.label} (~10 min, from 1 done like it)" in text   # half the rows
        assert f"left: {flicker0.label}\n" in text + "\n"          # no flicker run done yet
        assert "steps have no estimate yet" in text
        # at 30 Hz none has run: scaled from the slower rate's, by simulated seconds, and
        # marked as the lower bound it is (a tick costs more at a faster rate)
        main30 = next(s for s in evals if s.label == "eval nav 30 Hz seed 0 main")
        text = study.status_text(evals, ["eval"], {main0.label: 1200.0})
        assert f"left: {main30.label} (>= 20 min, scaled by simulated seconds from 1 done " \
               f"at a slower rate)" in text
        assert "estimated wall time left: at least " in text
        assert "evaluation estimates are lower bounds" in text


def test_status_times_a_training_by_its_own_record_and_the_epochs_it_ran(tmp_path, monkeypatch):
    with study_module("sensors/sensor_study") as study:
        fake_datasets(study, tmp_path, monkeypatch, {"study_nav10": 100, "study_arm10": 200})
        train = [s for s in study.plan_steps(tmp_path, 2, {"nav10", "arm10"})
                 if s.kind == "train"]
        nav = [s for s in train if s.label.startswith("train nav")]
        arm = [s for s in train if s.label.startswith("train arm")]
        ran = {0: (6, 1200.0), 1: (8, 800.0), 2: (5, 500.0)}     # of 10 planned, stopped early
        for i, (epochs, seconds) in ran.items():
            nav[i].done.parent.mkdir(parents=True, exist_ok=True)
            nav[i].done.write_bytes(b"")
            nav[i].done.with_suffix(".json").write_text(json.dumps(
                {"training": {"epochs": 10, "epochs_run": epochs, "seconds": seconds,
                              "resumed_after_epochs": [3]}}))
        # the log saw only the last part of seed 0's resumed training; its record has all
        took = {nav[0].label: 300.0, nav[1].label: 800.0}
        text = study.status_text(train, ["train"], took)
        assert f"done: {nav[0].label} (20 min)" in text
        assert f"done: {nav[2].label} (8 min)" in text             # in no log at all
        assert study.step_work(nav[0]) == 100 * 6                 # the epochs it ran
        # per frame-epoch: 2.0, 1.0, 1.0 s (median 1 s); nav runs 6 of 10 planned (median)
        assert f"left: {nav[3].label} (~10 min, from 3 done like it)" in text      # 100 x 6
        # no arm training done: the planned 16 epochs, scaled from the nav ones by frames
        assert f"left: {arm[0].label} (~53 min, scaled by frames from 3 done trainings)" in text
        # a sidecar without a usable record: the log's time, the planned epochs
        nav[3].done.write_bytes(b"")
        nav[3].done.with_suffix(".json").write_text('{"training": {"seconds": "soon"}}')
        assert study.training_record(nav[3]) is None
        assert study.step_work(nav[3]) == 100 * 10


def test_a_stopped_driver_logs_the_time_its_steps_ran(tmp_path, monkeypatch):
    import signal
    import sys
    import threading
    with study_module("sensors/sensor_study") as study:
        step = study.Step("train", "train nav 10 Hz rgb seed 0", ("x",), tmp_path / "x.pt")
        monkeypatch.setattr(study, "command_of", lambda s: [
            sys.executable, "-c", "import time; print('start' + 'ed', flush=True); time.sleep(60)"])
        log = tmp_path / "log.txt"
        result = []
        runner = threading.Thread(target=lambda: result.append(
            study.run_step(step, log, threading.Event())))
        runner.start()
        for _ in range(200):                          # until the step's process is up
            output = study.step_log(log, step)
            if "started" in output.read_text() if output.exists() else False:
                break
            threading.Event().wait(0.05)
        study.stop_running(signal.SIGTERM, None)
        runner.join(10)
        assert not runner.is_alive()
        assert result[0][1] == -signal.SIGTERM
        assert f"=== exit -15 after " in log.read_text()
        assert "started" not in log.read_text()        # the step's output is in its own file
        assert output.name == "train_nav_10_Hz_rgb_seed_0.txt" and "=== exit -15" in \
            output.read_text()
        assert step.label in study.step_seconds(tmp_path / study.LEDGER)
        start, end = map(json.loads, (tmp_path / study.LEDGER).read_text().splitlines())
        assert end["exit"] == -signal.SIGTERM and end["machine"] == study.machine()
        assert "seconds" not in start and start["machine"] == study.machine()
        assert start.get("gl") == end.get("gl") == study.gl_stack()   # None: no GL here
        # a stopped driver starts nothing more
        assert study.run_step(step, log, threading.Event())[1] is None


def test_run_finishes_each_cell_before_the_next_and_stops_at_a_failure(tmp_path, monkeypatch):
    with study_module("sensors/sensor_study") as study:
        ran = []

        def fake_step(step, log, stop):
            if stop.is_set():
                return step, None, 0.0
            ran.append(step)
            if step.label != fail_at:
                step.done.parent.mkdir(parents=True, exist_ok=True)
                step.done.write_bytes(b"")
            return step, 0 if step.label != fail_at else 1, 0.0

        monkeypatch.setattr(study, "run_step", fake_step)
        fail_at = None
        argv = ["run", "--steps", "train,eval,read", "--out", str(tmp_path), "--parallel", "1"]
        assert study.main(argv) == 0
        cells = [study.step_cell(s) for s in ran]
        assert cells == sorted(cells, key=["nav10", "nav30", "arm10", "arm30"].index)
        for cell in ("nav10", "arm30"):
            kinds = [s.kind for s in ran if study.step_cell(s) == cell]
            assert kinds == sorted(kinds, key=["train", "eval", "read"].index)
            assert kinds.count("read") == 1 and kinds.count("eval") >= 3
        assert len(ran) == 36 + 18 + 4
        # all done: nothing runs again
        ran.clear()
        assert study.main(argv) == 0 and ran == []
        # a failed training stops the run before any later cell or kind starts
        first = next(s for s in study.plan_steps(tmp_path, 2, {"nav30"}) if s.kind == "train")
        first.done.unlink()
        later = next(s for s in study.plan_steps(tmp_path, 2, {"arm10"}) if s.kind == "eval")
        later.done.unlink()
        fail_at = first.label
        assert study.main(argv) == 1
        assert [s.label for s in ran] == [first.label]
        # --only: the cells in the order given
        ran.clear()
        fail_at = None
        later.done.unlink(missing_ok=True)
        first.done.unlink(missing_ok=True)
        assert study.main(argv + ["--only", "arm10,nav30"]) == 0
        assert [study.step_cell(s) for s in ran] == ["arm10", "nav30"]


def test_ray_sends_the_recordings_and_evaluations_there_and_changes_nothing_else(tmp_path):
    with study_module("sensors/sensor_study") as study:
        here = study.plan_steps(tmp_path, 2, {"nav10"})
        ray = study.plan_steps(tmp_path, 8, {"nav10"}, ray="ray://head:10001")
        local = study.plan_steps(tmp_path, 2, {"nav10"}, ray="")
    assert [s.label for s in here] == [s.label for s in ray]
    for a, b, c in zip(here, ray, local):
        assert "--ray" not in a.argv
        if a.kind in ("record", "eval"):
            i = b.argv.index("--ray")
            assert b.argv[i + 1] == "ray://head:10001"
            assert b.argv[b.argv.index("--workers") + 1] == "8"
            assert list(c.argv) == [*a.argv[:a.argv.index("--workers") + 2], "--ray",
                                    *a.argv[a.argv.index("--workers") + 2:]]
        else:
            assert a.argv == b.argv == c.argv and a.done == b.done


def study_repo(tmp_path, monkeypatch, study):
    """A git repository in tmp_path with one commit, the driver's ROOT pointed at it and
    its study directory (OUT, with the real .gitignore); (repo, git(*args) -> stdout, OUT)."""
    import subprocess
    repo = tmp_path / "repo"
    repo.mkdir()

    def git(*args):
        return subprocess.run(["git", *args], cwd=repo, check=True, capture_output=True,
                              text=True).stdout
    git("init", "-q")
    git("config", "user.email", "t@example.org")
    git("config", "user.name", "t")
    (repo / "README.md").write_text("x\n")
    git("add", "README.md")
    git("commit", "-qm", "start")
    monkeypatch.setattr(study, "ROOT", repo)
    out = repo / "research" / "sensors" / "outputs"
    out.mkdir(parents=True)
    (out / ".gitignore").write_text((study.STUDY_DIR / ".gitignore").read_text())
    return repo, git, out


def test_commit_keeps_a_finished_steps_outputs_and_nothing_else(tmp_path, monkeypatch):
    with study_module("sensors/sensor_study") as study:
        repo, git, out = study_repo(tmp_path, monkeypatch, study)
        train = next(s for s in study.plan_steps(out, 2, {"nav10"}) if s.kind == "train")
        seed_dir = train.done.parent
        seed_dir.mkdir(parents=True)
        for name in (train.done.name, "nav-rgb+event.json", "nav-rgb+event-losses.csv",
                     "nav-rgb.resume.pt", "nav-losses.png"):
            (seed_dir / name).write_bytes(b"w")
        study.append_ledger(out / study.LEDGER, train, 0.0, 60.0, 0)
        (repo / "README.md").write_text("an edit of someone else's, staged\n")
        git("add", "README.md")
        assert study.commit_outputs(train, out) is None
        kept = git("show", "--name-only", "--format=%s", "HEAD").split("\n")
        assert kept[0].startswith(f"study: {train.label} done")
        assert sorted(filter(None, kept[1:])) == sorted(
            f"research/sensors/outputs/{p}" for p in (
                "steps.jsonl", "checkpoints/nav10/seed0/nav-rgb+event.pt",
                "checkpoints/nav10/seed0/nav-rgb+event.json",
                "checkpoints/nav10/seed0/nav-rgb+event-losses.csv"))
        # the other change stays staged, uncommitted
        assert git("diff", "--cached", "--name-only").split() == ["README.md"]
        # nothing new: no commit, no complaint
        head = git("rev-parse", "HEAD")
        assert study.commit_outputs(train, out) is None and git("rev-parse", "HEAD") == head
        # git refusing is said, not swallowed
        (repo / ".git" / "index.lock").write_text("")
        said = study.commit_outputs(train, out, attempts=1)
        assert said and "index.lock" in said


def test_a_stop_commits_the_ledger_and_the_trainings_resume_states(tmp_path, monkeypatch):
    """A new checkout lacks what is not committed: at a stop, the ledger and the resume
    states of the trainings in flight are committed (ignored files, by force), and a state
    whose training finished since is removed with the training's own commit."""
    with study_module("sensors/sensor_study") as study:
        repo, git, out = study_repo(tmp_path, monkeypatch, study)
        trainings = [s for s in study.plan_steps(out, 2, {"arm30"}) if s.kind == "train"]
        a, b = trainings[0], trainings[3]            # seed 0's and another seed's
        states = [study.resume_state_of(s) for s in (a, b)]
        for state in states:
            state.parent.mkdir(parents=True, exist_ok=True)
            state.write_bytes(b"epoch 3")
        for step in (a, b):
            study.append_ledger(out / study.LEDGER, step, 0.0, 600.0, -15)
        assert study.commit_at_stop(out) is None
        kept = git("show", "--name-only", "--format=%s", "HEAD").split("\n")
        assert kept[0].startswith("study: stopped; the ledger and the resume states")
        assert sorted(filter(None, kept[1:])) == sorted(
            str(p.relative_to(repo)) for p in (out / study.LEDGER, *states))
        # nothing new since: no commit
        head = git("rev-parse", "HEAD")
        assert study.commit_at_stop(out) is None and git("rev-parse", "HEAD") == head
        # a later epoch is kept at the next stop
        states[1].write_bytes(b"epoch 4")
        assert study.commit_at_stop(out) is None
        assert git("show", f"HEAD:{states[1].relative_to(repo)}") == "epoch 4"
        # a finished training: its checkpoint in, its state out, with its own commit
        states[0].unlink()
        a.done.write_bytes(b"w")
        study.append_ledger(out / study.LEDGER, a, 0.0, 900.0, 0)
        assert study.commit_outputs(a, out) is None
        tracked = git("ls-files", "research").split()
        assert str(a.done.relative_to(repo)) in tracked
        assert str(states[0].relative_to(repo)) not in tracked
        assert str(states[1].relative_to(repo)) in tracked
        # a state committed and gone without its training's commit is removed at a stop
        states[1].unlink()
        assert study.commit_at_stop(out) is None
        assert str(states[1].relative_to(repo)) not in git("ls-files", "research").split()


def test_run_commit_keeps_each_step_that_finishes_and_says_when_it_cannot(tmp_path, monkeypatch,
                                                                            capsys):
    with study_module("sensors/sensor_study") as study:
        def fake_step(step, log, stop):
            if stop.is_set():
                return step, None, 0.0
            if step.label.endswith("seed 1"):
                return step, 1, 0.0                  # failed: nothing of it is committed
            step.done.parent.mkdir(parents=True, exist_ok=True)
            step.done.write_bytes(b"")
            return step, 0, 0.0

        committed = []
        monkeypatch.setattr(study, "run_step", fake_step)
        monkeypatch.setattr(study, "commit_outputs", lambda step, out: committed.append(
            (step.label, out)) or ("fatal: no space left" if "seed 2" in step.label else None))
        argv = ["run", "--steps", "train", "--only", "nav30", "--out", str(tmp_path),
                "--parallel", "1", "--commit"]
        assert study.main(argv) == 1
        labels = [label for label, out in committed]
        # (a step the pool started before the failure was seen may finish, and is kept)
        assert labels[0] == "train nav 30 Hz rgb+event seed 0" and committed[0][1] == tmp_path
        assert not any(label.endswith("seed 1") for label in labels)
        for s in study.plan_steps(tmp_path, 2, {"nav30"}):
            if s.kind == "train" and s.label.endswith("seed 1"):
                s.done.parent.mkdir(parents=True, exist_ok=True)
                s.done.write_bytes(b"")
        committed.clear()
        assert study.main(argv) == 0
        assert "train nav 30 Hz rgb+event seed 2: its outputs are not committed " \
               "(fatal: no space left)" in capsys.readouterr().err
        # without --commit, nothing is
        committed.clear()
        for s in study.plan_steps(tmp_path, 2, {"nav30"}):
            if s.kind == "train":
                s.done.unlink(missing_ok=True)
        assert study.main(argv[:-1]) == 1 and committed == []


def test_a_cell_whose_trainings_are_done_is_not_recorded_again(tmp_path, monkeypatch, capsys):
    with study_module("sensors/sensor_study") as study:
        monkeypatch.setattr(study, "dataset_dir", lambda task, rate: tmp_path / "none")
        ran = []

        def fake_step(step, log, stop):
            ran.append(step.label)
            return step, 1, 0.0                      # stop at the first step run

        monkeypatch.setattr(study, "run_step", fake_step)
        out = tmp_path / "out"
        argv = ["run", "--steps", "record,train", "--only", "nav10,arm10", "--out", str(out)]
        trainings = [s for s in study.plan_steps(out, 2, {"nav10"}) if s.kind == "train"]
        for s in trainings[:-1]:
            s.done.parent.mkdir(parents=True, exist_ok=True)
            s.done.write_bytes(b"")
        # one nav training left: its dataset is recorded first
        assert study.main(argv) == 1 and ran == ["record nav 10 Hz"]
        trainings[-1].done.write_bytes(b"")
        ran.clear()
        # all done: nav's recording is skipped, and said so; the arm's is needed
        assert study.main(argv) == 1 and ran == ["record arm 10 Hz"]
        assert "record nav 10 Hz: not needed, every training of its cell is done" in \
            capsys.readouterr().err
        assert study.main(["status", "--only", "nav10", "--out", str(out)]) == 0
        text = capsys.readouterr().out
        assert "record nav 10 Hz: not needed" in text and "train: 10/10 done" in text
        # the plan still lists the command
        assert study.main(["plan", "--only", "nav10", "--out", str(out)]) == 0
        assert "# record nav 10 Hz" in capsys.readouterr().out


def test_the_ledger_names_the_cpu_each_run_had():
    with study_module("sensors/sensor_study") as study:
        cpuinfo = ("processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 25\nmodel\t\t: 17\n"
                   "model name\t: AMD EPYC\nflags\t\t: fpu sse2 avx avx2 avx512f avx512bw\n\n"
                   "processor\t: 1\nmodel name\t: AMD EPYC\n")
        assert study.machine(cpuinfo).startswith("AMD EPYC (family 25, model 17), avx512f, ")
        older = cpuinfo.replace(" avx512f avx512bw", "")
        assert study.machine(older).startswith("AMD EPYC (family 25, model 17), avx2, ")
        assert study.machine(cpuinfo) != study.machine(older)
        assert study.machine("").endswith(" CPUs")          # no /proc/cpuinfo: still a line


def test_an_evaluation_stopped_on_another_machine_starts_again_here(tmp_path, monkeypatch):
    with study_module("sensors/sensor_study") as study:
        ledger = tmp_path / study.LEDGER
        mesa = "llvmpipe (LLVM 15.0.6, 256 bits), 4.5 (Compatibility Profile) Mesa 22.3.6"
        monkeypatch.setattr(study, "gl_stack", lambda: mesa)
        # this machine, whatever the one running the test is
        monkeypatch.setattr(study, "machine", lambda: "AMD EPYC (family 25, model 17), "
                                                      "avx512f, 2 CPUs")
        evals = [s for s in study.plan_steps(tmp_path, 2, {"arm10"}) if s.kind == "eval"]
        step, other_step = evals[0], evals[1]
        finished = step.done.parent / "episodes" / "rgb__nominal_physical.jsonl"

        def stopped_before(cpu=None, gl=mesa):
            finished.parent.mkdir(parents=True, exist_ok=True)
            finished.write_text("{}\n")
            with monkeypatch.context() as m:
                m.setattr(study, "gl_stack", lambda: gl)
                if cpu:
                    m.setattr(study, "machine", lambda: cpu)
                study.append_ledger(ledger, step, 0.0)
                study.append_ledger(ledger, other_step, 0.0)

        # stopped here before (a start line is enough: a killed run writes no end), or
        # before the ledger named GL stacks: sebvs eval resumes its finished runs
        stopped_before()
        stopped_before(gl=None)
        assert '"gl"' not in ledger.read_text().splitlines()[-1]
        assert study.start_on_this_machine(step, ledger) is None and finished.exists()
        # stopped with another GL stack
        stopped_before(gl="NVIDIA H100/PCIe/SSE2, 4.6.0 NVIDIA 550.54")
        said = study.start_on_this_machine(step, ledger)
        assert said and "another GL stack (NVIDIA H100" in said and not finished.parent.exists()
        assert "CPU" not in said.split(":")[0]
        # stopped on another CPU
        ledger.unlink()
        stopped_before(cpu="AMD EPYC (family 25, model 1), avx2, 2 CPUs")
        said = study.start_on_this_machine(step, ledger)
        assert said and "another CPU (AMD EPYC (family 25, model 1), avx2" in said
        assert not finished.parent.exists()
        # a training resumes on any machine: another draw of the recipe
        train = next(s for s in study.plan_steps(tmp_path, 2, {"arm10"}) if s.kind == "train")
        assert study.start_on_this_machine(train, ledger) is None


def test_the_ledger_names_the_gl_stack_or_says_why_not(monkeypatch, capsys):
    with study_module("sensors/sensor_study") as study:
        study.gl_stack.cache_clear()
        monkeypatch.setattr(study, "GL_PROBE", "print('llvmpipe (LLVM 15.0.6, 256 bits), 4.5 Mesa')")
        assert study.gl_stack() == "llvmpipe (LLVM 15.0.6, 256 bits), 4.5 Mesa"
        study.gl_stack.cache_clear()
        monkeypatch.setattr(study, "GL_PROBE", "raise SystemExit('no EGL display')")
        assert study.gl_stack() is None
        assert "cannot name the GL stack: no EGL display" in capsys.readouterr().err
        study.gl_stack.cache_clear()


def test_the_report_names_the_cpu_and_gl_of_every_evaluation(tmp_path):
    with study_module("sensors/sensor_study") as study, \
            study_module("sensors/sensor_report") as rep:
        evals = [s for s in study.plan_steps(tmp_path, 2, {"arm30"}) if s.kind == "eval"]
        for s in evals:
            s.done.parent.mkdir(parents=True)
            s.done.write_text(json.dumps({"task": "arm", "seed": 100200, "episodes": []}))
        a, b = "AMD EPYC (family 25, model 17), avx512f, 2 CPUs", "Xeon (family 6), avx2, 2 CPUs"
        mesa = "llvmpipe (LLVM 15.0.6, 256 bits), 4.5 Mesa 22.3.6"
        lines = [{"label": evals[0].label, "machine": a, "gl": mesa},
                 {"label": evals[1].label, "machine": a},
                 {"label": evals[1].label, "machine": b, "gl": mesa},
                 {"label": "train x", "machine": b, "gl": "other"}]
        (tmp_path / study.LEDGER).write_text("".join(json.dumps(r) + "\n" for r in lines))
        found = rep.eval_machines(tmp_path, "arm", 30)
        assert found == {evals[0].label: {"cpus": [a], "gl": [mesa]},
                         evals[1].label: {"cpus": [a, b], "gl": [mesa]},
                         evals[2].label: {"cpus": [], "gl": []}}
        line = rep.machines_line(found)
        assert line.startswith(f"Evaluated on: {a}; {b}; more than one CPU within {evals[1].label}")
        assert f"no CPU recorded for {evals[2].label}" in line
        assert f"Rendered with: {mesa}; no GL stack recorded for {evals[2].label} (3 evaluations)." in line
        text, data, _ = rep.report(tmp_path)
        assert line in text and data["tasks"]["arm"]["machines"][30] == found
        assert rep.machines_line({evals[0].label: {"cpus": [], "gl": []}}) == \
            "Evaluated on: no CPU recorded. Rendered with: no GL stack recorded (1 evaluation)."


def test_the_report_names_the_recordings_a_readings_trainings_read(tmp_path):
    with study_module("sensors/sensor_study") as study, \
            study_module("sensors/sensor_report") as rep:
        train = [s for s in study.plan_steps(tmp_path, 2, {"arm30"}) if s.kind == "train"]
        first, again = "a" * 64, "b" * 64
        for s in train:
            s.done.parent.mkdir(parents=True, exist_ok=True)
            s.done.write_bytes(b"")
            early = "rgb+event seed 0" in s.label or "rgb+event seed 1" in s.label
            s.done.with_suffix(".json").write_text(json.dumps(
                {"dataset": {"hash": first if early else again}}))
        found = rep.trained_from(tmp_path, "arm", 30)
        assert found[first] == {"rgb+event": [0, 1]}
        assert found[again] == {"rgb": [0], "event": [0], "rgb+diff": [0, 1, 2],
                                "rgb+event": [2]}
        assert rep.recordings_line("arm", 30, found) == (
            "Trained on: 2 recordings of datasets/study_arm30 (their files differ; 8 "
            "trainings): sha256 aaaaaaaaaaaa: rgb+event seeds 0, 1; sha256 bbbbbbbbbbbb: "
            "event seed 0, rgb seed 0, rgb+diff seeds 0, 1, 2, rgb+event seed 2.")
        train[0].done.with_suffix(".json").write_text("{not json")      # names none
        train[1].done.unlink()                                          # not finished
        found = rep.trained_from(tmp_path, "arm", 30)
        assert sum(len(v) for by in found.values() for v in by.values()) == 7
        assert "unknown" in found and "unknown: " in rep.recordings_line("arm", 30, found)
        one = {again: {"rgb": [0]}}
        assert rep.recordings_line("nav", 10, one) == (
            "Trained on: one recording of datasets/study_nav10 (files sha256 bbbbbbbbbbbb; "
            "1 training).")
        text, data, _ = rep.report(tmp_path, unread_rows=True)
        assert rep.recordings_line("arm", 30, found) in text
        assert data["tasks"]["arm"]["recordings"][30] == found
        text, data, _ = rep.report(tmp_path)          # not read: nor is its provenance shown
        assert "Trained on" not in text and data["tasks"]["arm"]["recordings"][30] is None


def test_a_training_is_sized_by_the_plans_frames_before_its_dataset_exists(tmp_path, monkeypatch):
    with study_module("sensors/sensor_study") as study:
        # the frames the study's four recordings held (research/sensors/log.md)
        assert [study.planned_frames(t, r) for t, r in
                (("nav", 10), ("nav", 30), ("arm", 10), ("arm", 30))] == \
            [24_120, 72_120, 31_500, 91_500]
        monkeypatch.setattr(study, "dataset_dir", lambda task, rate: tmp_path / "none")
        train = next(s for s in study.plan_steps(tmp_path, 2, {"arm30"}) if s.kind == "train")
        assert study.step_work(train) == 91_500 * 16
        # while the recording runs, its index holds part of the plan: still the plan's
        # frames (the arm 30 Hz estimate once read 636 of 1,500 episodes as the whole)
        part = tmp_path / "part"
        part.mkdir()
        monkeypatch.setattr(study, "dataset_dir", lambda task, rate: part)
        train = next(s for s in study.plan_steps(tmp_path, 2, {"arm30"}) if s.kind == "train")
        (part / "index.json").write_text(json.dumps({"version": 1, "task": "arm", "episodes": [
            {"file": f"episode_{i:04d}.h5", "frames": 61} for i in range(636)]}))
        assert study.step_work(train) == 91_500 * 16
        (part / "index.json").write_text(json.dumps({"version": 1, "task": "arm", "episodes": [
            {"file": f"episode_{i:04d}.h5", "frames": 60} for i in range(1500)]}))
        assert study.step_work(train) == 90_000 * 16          # recorded: as indexed
