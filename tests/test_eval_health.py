"""Run health in `sebvs eval`: a policy that never acted (every command NaN) fails the
evaluation with its row marked, the counters (rejected commands, non-finite actions,
action timeouts, handler errors) reach results.json and report.md and survive a resume,
fan-out shards' handler errors are summed, and results or episode lines written before
the counters read as zeros."""
import asyncio
import json
from pathlib import Path

import numpy as np
import pytest
from tqdm import tqdm

from sebvs.cli import main
from sebvs.eval.report import never_acted, render_report
from sebvs.eval.run import EvalPlan, Run, evaluate, run_fanout, run_health
from sebvs.metrics import nav_episode_metrics

ZERO = {"rejected": 0, "action_timeouts": 0, "deadline_misses": 0, "nonfinite_actions": 0,
        "handler_errors": {}, "never_acted": False}


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    """A tiny untrained (finite) RGB checkpoint: the test actors make its outputs bad."""
    import torch

    from sebvs.policy.checkpoint import model_config, save_checkpoint
    from sebvs.policy.inputs import Normalisation, channels
    from sebvs.policy.model import ERP
    d = tmp_path_factory.mktemp("ckpt")
    torch.manual_seed(0)
    save_checkpoint(ERP("nav", channels("rgb"), 32), model_config("nav", "rgb",
                                                                  Normalisation(32)), d)
    return d


def by_modality(results: dict) -> dict:
    return {r["modality"]: r for r in results["runs"]}


def test_a_nan_policy_fails_the_evaluation_with_its_row_marked(tmp_path, ckpt, capsys):
    """Every action NaN: the sim rejects every command and the robot holds still, which
    scores like the baseline; the evaluation says so instead of reporting it."""
    out = tmp_path / "eval"
    args = ["eval", "--task", "nav", "--modalities", "rgb", "--no-expert",
            "--scenarios", "indoor", "--episodes", "1", "--checkpoints", str(ckpt),
            "--set", "sim.episode_s=1.0",
            "--set", 'policy.run="tests.health_actors:NaNPolicy"', "--out", str(out)]
    assert main(args) == 1
    err = [line for line in capsys.readouterr().err.splitlines()
           if line.startswith("sebvs eval:")]
    # 1 s at 10 Hz: 11 ticks, the commands for the 10 before the last drive the steps
    assert err == ["sebvs eval: rgb nominal_physical indoor: the policy never acted (10 of "
                   "10 commands rejected, 10 of 10 actions not finite); its row is marked "
                   "in report.md"]
    results = json.loads((out / "results.json").read_text())
    runs = by_modality(results)
    assert runs["rgb"] == {"condition": "nominal_physical", "scenario": "indoor",
                           "modality": "rgb", "episodes": 1, "commands": 10, "rejected": 10,
                           "action_timeouts": 0, "deadline_misses": 0, "actions": 10,
                           "nonfinite_actions": 10, "handler_errors": {},
                           "never_acted": True}
    # the baseline's zero commands are valid ones: a healthy run, counters 0
    assert runs["no_action"] == {**runs["no_action"], **ZERO}
    assert runs["no_action"]["commands"] == runs["no_action"]["actions"] == 10
    report = (out / "report.md").read_text()
    assert "| RGB-only ! | 1 |" in report and "| No action (baseline) | 1 |" in report
    assert "! RGB-only: 10 of 10 commands rejected, 10 of 10 actions not finite: it never " \
           "acted" in report
    health = report.split("## Run health")[1]
    assert "| nominal_physical / indoor / RGB-only (never acted) | 1 | 10 of 10 | " \
           "10 of 10 | 0 | 0 | 0 |" in health and "No action" not in health
    # resume: nothing runs again, the counters come from the episode lines as before
    n_runs = len(list((out / "runs").iterdir()))
    assert main(args) == 1
    assert len(list((out / "runs").iterdir())) == n_runs
    assert json.loads((out / "results.json").read_text())["runs"] == results["runs"]


def test_handler_errors_and_action_timeouts_are_counted_and_survive_a_resume(tmp_path, ckpt):
    """A policy whose handler raises on every odd tick: the errors (only in the actors'
    stats) and the lockstep timeouts they cause are the run's; the row is not marked, as
    every command that came was applied, but Run health lists the run."""
    plan = EvalPlan(task="nav", modalities=["rgb"], conditions=["nominal_physical"],
                    scenarios=["indoor"], episodes=1, out=tmp_path / "eval",
                    checkpoints=str(ckpt), expert=False, baseline=False,
                    extra=["sim.episode_s=1.0", "sim.action_timeout_s=0.5",
                           'policy.run="tests.health_actors:FlakyPolicy"'])
    results = evaluate(plan)
    run = by_modality(results)["rgb"]
    # ticks 3 and 7 raise and the sim waits for them in vain; each of the 10 ticks it waits
    # on has its command in time or times out (a slow start may time out on more)
    assert run["handler_errors"] == {"policy.rgb": 2} and run["actions"] == 8
    assert run["action_timeouts"] >= 2 and run["commands"] + run["action_timeouts"] == 10
    assert (run["rejected"], run["nonfinite_actions"], run["never_acted"]) == (0, 0, False)
    assert never_acted(results) == []
    report = (tmp_path / "eval" / "report.md").read_text()
    assert "| RGB-only | 1 |" in report
    assert (f"| nominal_physical / indoor / RGB-only | 1 | 0 of {run['commands']} | 0 of 8 | "
            f"{run['action_timeouts']} | 0 | 2 (policy.rgb 2) |") in report
    again = evaluate(plan)          # skipped: the errors come from its health file
    assert by_modality(again)["rgb"] == run


def nav_record(k: int, seed: int, **extra) -> dict:
    m = nav_episode_metrics([[80, 80]] * 10, [20] * 10, [True] * 10, (160, 160),
                            10.0).as_dict()
    return {"episode": k, "seed": 100 + k, "topology_seed": seed, "metrics": m,
            "trace_error_px": [0.0] * 10, "inference_ms": [], **extra}


def test_fanout_sums_the_shards_handler_errors_and_old_lines_read_as_zeros(tmp_path,
                                                                          monkeypatch):
    """Shards run by a stand-in for the workers: each writes its episode lines as the
    tracker would and reports one handler error; the run's file holds their sum."""
    import sebvs.scale
    plan = EvalPlan(task="nav", modalities=[], conditions=["nominal_physical"],
                    scenarios=["indoor"], episodes=4, out=tmp_path / "eval", workers=2,
                    baseline=False)
    run = Run("nominal_physical", "indoor", "expert")

    def fake_fan_out(shards, task_of, collect, **kwargs):
        for shard in shards:
            task = task_of(shard)
            # the shard's tracker.path, merged over the run's own
            path = Path(task.overrides["tracker"]["path"])
            assert json.loads(json.dumps(task.overrides)) == task.overrides   # plain JSON
            # lines written before the counters existed: no "health"
            path.write_text("".join(json.dumps(nav_record(k, plan.seed)) + "\n"
                                    for k in range(shard.first, shard.stop)))
            collect(shard, {"losses": {"camera.state": {"errors": 1, "torn": 2}}})

    monkeypatch.setattr(sebvs.scale, "fan_out", fake_fan_out)
    with tqdm(disable=True) as bar:
        run_fanout(plan, [run], bar)
    saved = json.loads(plan.health_file(run).read_text())
    assert saved == {"topology_seed": plan.seed, "handler_errors": {"camera.state": 2}}
    results = evaluate(plan)        # every run complete: nothing runs, the counters read
    assert results["runs"] == [{"condition": "nominal_physical", "scenario": "indoor",
                                "modality": "expert", "episodes": 4, "commands": 0,
                                "rejected": 0, "action_timeouts": 0, "deadline_misses": 0,
                                "actions": 0, "nonfinite_actions": 0,
                                "handler_errors": {"camera.state": 2},
                                "never_acted": False}]
    # another seed's health file is not this evaluation's
    other = EvalPlan(task="nav", modalities=[], conditions=["nominal_physical"],
                     scenarios=["indoor"], episodes=4, out=tmp_path / "eval", seed=2000)
    assert run_health(other, run, [])["handler_errors"] == {}


def test_run_health_sums_the_episode_lines():
    plan = EvalPlan(task="nav", modalities=["rgb"], conditions=["nominal"], episodes=2,
                    out=Path("/nonexistent"))
    run = Run("nominal", "indoor", "rgb")
    h = {"commands": 10, "rejected": 10, "action_timeouts": 0, "deadline_misses": 0,
         "actions": 11, "nonfinite_actions": 11}
    got = run_health(plan, run, [nav_record(0, 1000, health=h), nav_record(1, 1000, health=h)])
    assert (got["commands"], got["rejected"], got["nonfinite_actions"]) == (20, 20, 22)
    assert got["never_acted"] is True
    half = {**h, "rejected": 4, "nonfinite_actions": 4}
    assert run_health(plan, run, [nav_record(0, 1000, health=half)])["never_acted"] is False
    # no command came at all (a policy that never answered): never acted either
    none = {**h, "commands": 0, "rejected": 0, "action_timeouts": 10, "actions": 0,
            "nonfinite_actions": 0}
    assert run_health(plan, run, [nav_record(0, 1000, health=none)])["never_acted"] is True
    assert run_health(plan, run, [nav_record(0, 1000)])["never_acted"] is False


def synthetic(runs: list[dict] | None) -> dict:
    eps = [{"modality": m, "condition": "nominal", "scenario": "indoor", "seed": s,
            "metrics": nav_record(s, 1000)["metrics"]}
           for m in ("expert", "no_action", "rgb", "event") for s in (0, 1)]
    out = {"task": "nav", "clock": "lockstep", "episodes": eps}
    if runs is not None:
        out["runs"] = runs
    return out


def health(modality: str, **counts) -> dict:
    return {"condition": "nominal", "scenario": "indoor", "modality": modality,
            "episodes": 2, "commands": 20, "rejected": 0, "action_timeouts": 0,
            "deadline_misses": 0, "actions": 20, "nonfinite_actions": 0,
            "handler_errors": {}, "never_acted": False, **counts}


def test_report_marks_the_rows_with_rejected_or_non_finite_commands():
    runs = [health("expert"), health("no_action"),
            health("rgb", rejected=20, nonfinite_actions=20, never_acted=True),
            health("event", rejected=3, deadline_misses=7,
                   handler_errors={"policy.events": 2})]
    text = render_report(synthetic(runs))
    assert "| Expert (reference) | 2 |" in text and "| No action (baseline) | 2 |" in text
    assert "| RGB-only ! | 2 |" in text and "| Event-only ! | 2 |" in text
    assert "! RGB-only: 20 of 20 commands rejected, 20 of 20 actions not finite: it never " \
           "acted, these are the figures of a robot that kept its idle command." in text
    assert "! Event-only: 3 of 20 commands rejected: the robot kept its last accepted " \
           "command on those ticks." in text
    # the summary's cells are marked too, with a legend
    summary = text.split("## Condition:")[0]
    assert "100.0 / 100.0 / 2 of 2 ! |" in summary and "!: a command rejected" in summary
    section = text.split("## Run health")[1]
    assert "| nominal / indoor / RGB-only (never acted) | 2 | 20 of 20 | 20 of 20 | 0 | " \
           "0 | 0 |" in section
    assert "| nominal / indoor / Event-only | 2 | 3 of 20 | 0 of 20 | 0 | 7 | " \
           "2 (policy.events 2) |" in section
    assert "Expert" not in section and "No action" not in section
    assert "runs: " not in text          # the counters are not dumped in the header
    assert never_acted(synthetic(runs)) == [
        "rgb nominal indoor: the policy never acted (20 of 20 commands rejected, 20 of 20 "
        "actions not finite); its row is marked in report.md"]
    # a deadline miss alone lists the run, but marks no row
    text = render_report(synthetic([health("rgb", deadline_misses=2)]))
    assert "| RGB-only | 2 |" in text and "| nominal / indoor / RGB-only |" in text


def test_report_of_healthy_and_of_older_results():
    healthy = render_report(synthetic([health(m) for m in ("expert", "no_action", "rgb",
                                                           "event")]))
    assert "!" not in healthy
    assert "Every run of the 4: no command rejected" in healthy
    # results.json written before the counters: the report as it was, nothing marked
    old = render_report(synthetic(None))
    assert "!" not in old and "Run health" not in old and "| RGB-only | 2 |" in old
    assert never_acted(synthetic(None)) == []


class AnsweringNode:
    """Stands in for the runtime: records the episode meta and answers each control tick
    of the sim's state as a policy would, NaN on NAN_TICKS, nothing on SILENT_TICKS."""
    NAN_TICKS, SILENT_TICKS = (1, 2), (4,)

    def __init__(self):
        self.ends, self.sim = [], None

    def emit(self, output, arrays, *, meta=None, t_sim=None, tick=None, parent=None):
        from sebvs.runtime.wire import Message
        if output == "episode" and meta["event"] == "end":
            self.ends.append(meta)
        if output != "state" or not meta.get("control") or tick in self.SILENT_TICKS:
            return
        cmd = [float("nan")] * 2 if tick in self.NAN_TICKS else [0.1, 0.0]
        msg = Message(topic="t", source="policy", output="action", seq=tick, t_sim=t_sim,
                      tick=tick, stamps=[], meta={}, arrays={"action": np.asarray(cmd)})
        asyncio.get_running_loop().create_task(self.sim.on_action(msg))   # after the publish

    def event(self, kind, fields):
        pass

    def finish(self, reason):
        pass


@pytest.mark.parametrize("clock", ["lockstep", "realtime"])
def test_the_sims_episode_end_carries_its_counters_by_tick(clock):
    """0.5 s at 20 Hz: 11 ticks; the commands for the 10 before the last are counted (the
    last one's, which drives no step, is not, though it comes before the end here)."""
    from sebvs_actors.sim import Sim
    node = AnsweringNode()
    sim = Sim("sim", Sim.Params(episode_s=0.5, render_hz=100.0, episodes=2, linger_s=0.0,
                                action_timeout_s=0.05),
              seed=7, clock=clock, consumed=frozenset({"state", "episode"}),
              connected=frozenset({"action"}), node=node)
    node.sim = sim
    asyncio.run(sim.setup())
    asyncio.run(sim.run())
    first, second = [end["health"] for end in node.ends]
    # episode 0 has ticks 0-10: 2 NaN, tick 4 unanswered; episode 1 (ticks 11-21) answers all
    assert first["rejected"] == 2 and second["rejected"] == 0
    if clock == "lockstep":
        assert (first["commands"], second["commands"]) == (9, 10)
        assert (first["action_timeouts"], first["deadline_misses"]) == (1, 0)
        assert second["action_timeouts"] == 0
    else:   # tick 4's action never came: at least that deadline was missed (a host that
        # falls behind the pace may hold an answer past the end: at most as many)
        assert first["commands"] <= 9 and second["commands"] <= 10
        assert first["action_timeouts"] == 0 and first["deadline_misses"] >= 1
    assert sim.counts["rejected"] == 2
