"""A short closed-loop evaluation end to end: expert, the no-action baseline and a tiny
policy, 2 episodes, real runs, with episode videos; the held-out split over both nav
scene variants; how a plan picks its seeds."""
import json
import re
from pathlib import Path

import numpy as np
import pytest

from sebvs.cli import main
from sebvs.data.splits import SPLITS
from sebvs.eval.run import EvalPlan, evaluate
from sebvs.eval.video import count_frames
from tests.policy_data import make_dataset


def test_short_evaluation_runs_end_to_end_and_resumes(tmp_path):
    from sebvs.policy.inputs import Normalisation
    from sebvs.policy.train import train

    data = make_dataset(tmp_path / "data", episodes=4, frames=12, height=32, width=32)
    train(data, tmp_path / "ckpt", "nav", ["rgb+event"], progress=False, log=lambda *a: None,
          epochs=1, batch=8, norm=Normalisation(size=32))
    plan = EvalPlan(task="nav", modalities=["rgb+event"], conditions=["nominal"], episodes=2,
                    scenarios=["indoor"], out=tmp_path / "eval",
                    checkpoints=str(tmp_path / "ckpt"),
                    extra=["sim.episode_s=1.5"], video=True, video_episodes=2)
    results = evaluate(plan)
    eps = results["episodes"]
    assert {(e["modality"], e["condition"]) for e in eps} == {("expert", "nominal"),
                                                              ("no_action", "nominal"),
                                                              ("rgb+event", "nominal")}
    by_mod = {}
    for e in eps:
        by_mod.setdefault(e["modality"], []).append(e["seed"])
    assert len(by_mod["expert"]) == 2
    assert by_mod["expert"] == by_mod["rgb+event"] == by_mod["no_action"]   # same episodes
    policy_eps = [e for e in eps if e["modality"] == "rgb+event"]
    assert all(len(e["inference_ms"]) > 5 for e in policy_eps)
    report = (tmp_path / "eval" / "report.md").read_text()
    assert "## Condition: nominal, indoor" in report and "| RGB+Event | 2 |" in report
    assert "| Expert (reference) | 2 |" in report
    assert "| No action (baseline) | 2 |" in report
    # the baseline ran without a policy, emulator or accumulator: they were pruned
    baseline_run = next(p for p in (tmp_path / "eval" / "runs").glob("nav_policy-*")
                        if (p / "logs" / "baseline.log").exists())
    assert not (baseline_run / "logs" / "policy.log").exists()
    assert not (baseline_run / "logs" / "emulator.log").exists()
    for png in ("success.png", "centroid_error.png", "latency.png"):
        assert (tmp_path / "eval" / png).stat().st_size > 5000
    saved = json.loads((tmp_path / "eval" / "results.json").read_text())
    assert len(saved["episodes"]) == 6
    # every row healthy: each command of the 15 ticks before each episode's last applied
    for run in saved["runs"]:
        assert (run["commands"], run["actions"], run["episodes"]) == (30, 30, 2), run
        assert not (run["rejected"] or run["nonfinite_actions"] or run["action_timeouts"]
                    or run["deadline_misses"] or run["handler_errors"] or run["never_acted"])
    assert "Every run of the 3: no command rejected" in report and " ! |" not in report
    # one video per episode, one frame per control tick the tracker counted
    videos = [f"videos/nominal__indoor__{m}__ep{k}.mp4"
              for m in ("expert", "no_action", "rgb_event") for k in (0, 1)]
    assert saved["videos"] == videos
    ticks = [len(e["trace_error_px"]) for e in eps]
    assert ticks[0] == 16                               # 1.5 s at 10 Hz, both ends
    assert [count_frames(tmp_path / "eval" / v) for v in videos] == ticks
    # the policy run's writer had the event frames: all but (under load) the run's very
    # last tick, whose action the sim does not wait for, carry the overlay
    log = next(p for p in (tmp_path / "eval" / "runs").glob("nav_policy-*/logs/video.log")
               if (p.parent / "policy.log").exists()).read_text()
    assert "events overlaid" in log
    assert int(re.search(r"'without_overlay': (\d+)", log).group(1)) <= 1
    # resume: everything is finished, so nothing runs again and the results are the same
    runs_before = len(list((tmp_path / "eval" / "runs").iterdir()))
    again = evaluate(plan)
    assert len(list((tmp_path / "eval" / "runs").iterdir())) == runs_before
    assert [e["seed"] for e in again["episodes"]] == [e["seed"] for e in eps]
    assert again["runs"] == saved["runs"]


def test_short_arm_evaluation_grasps_and_reports(tmp_path):
    """The arm through `sebvs eval`: expert and a tiny policy, one episode each, multi-object;
    every tick scored against the task's pose, the last pose grasped by the sim."""
    from sebvs.policy.inputs import Normalisation
    from sebvs.policy.train import train

    data = make_dataset(tmp_path / "data", episodes=3, frames=8, height=32, width=32,
                        task="arm")
    train(data, tmp_path / "ckpt", "arm", ["rgb"], progress=False, log=lambda *a: None,
          epochs=1, batch=8, norm=Normalisation(size=32))
    plan = EvalPlan(task="arm", modalities=["rgb"], conditions=["moving"],
                    scenarios=["multi"], episodes=1, out=tmp_path / "eval",
                    checkpoints=str(tmp_path / "ckpt"), extra=["sim.episode_s=0.5"])
    results = evaluate(plan)
    eps = {e["modality"]: e for e in results["episodes"]}
    assert set(eps) == {"expert", "no_action", "rgb"}
    assert eps["expert"]["seed"] == eps["rgb"]["seed"] == eps["no_action"]["seed"]
    # the baseline stays home every tick, so it grasps nothing
    from sebvs.sim.arm import HOME_POSE
    baseline = eps["no_action"]["metrics"]
    assert np.allclose(baseline["pred"], [HOME_POSE] * len(baseline["pred"]), atol=1e-5)
    assert baseline["grasp_success"] in (False, None)
    assert all(e["scenario"] == "multi" for e in eps.values())
    expert = eps["expert"]["metrics"]
    assert len(expert["pred"]) == 6 and expert["scenario"] == "multi"    # ticks 0..5
    assert expert["position_error_mm"] < 10 and expert["accuracy"] == 1.0
    # scored against the task's pose led as the recording's expert leads (arm_policy.toml)
    assert expert["reference_lead_s"] == eps["rgb"]["metrics"]["reference_lead_s"] == 0.1
    assert expert["outcome"] == "lifted_and_held" and expert["grasp_success"] is True
    policy = eps["rgb"]["metrics"]
    assert policy["outcome"] and policy["grasp_success"] in (True, False)
    assert len(eps["rgb"]["inference_ms"]) == 6
    report = (tmp_path / "eval" / "report.md").read_text()
    assert "## Condition: moving, multi-object" in report
    assert "| Expert (reference) | 1 | 6 |" in report and "| RGB-only | 1 | 6 |" in report
    assert (tmp_path / "eval" / "pose_error.png").stat().st_size > 5000
    assert (tmp_path / "eval" / "episodes" / "moving__multi__expert.jsonl").exists()
    # the baseline's HOME and the expert's poses are all applied: 5 ticks before the last
    for run in results["runs"]:
        if run["modality"] in ("expert", "no_action"):
            assert (run["commands"], run["rejected"], run["nonfinite_actions"],
                    run["never_acted"]) == (5, 0, 0, False), run


def test_test_split_runs_reserved_seeds_over_both_nav_variants(tmp_path):
    """`--split test`: the topology seed is the reserved range's first, every row plays the
    same episodes in the indoor and the outdoor scene, and holding still scores below the
    expert on them."""
    from sebvs_actors.sim import episode_seed
    from sebvs.runtime.topology import load_topology

    plan = EvalPlan(task="nav", modalities=[], conditions=["nominal"], episodes=2,
                    split="test", out=tmp_path / "eval", extra=["sim.episode_s=3.0"])
    results = evaluate(plan)
    test = SPLITS["test"]
    assert results["split"] == "test" and results["seed"] == test.first
    assert results["seed_range"] == [test.first, test.last]
    assert results["scenarios"] == ["indoor", "outdoor"]
    assert results["overrides"] == ["sim.episode_s=3.0"]       # said in results.json
    # the episode seeds are those the sim derives from the reserved topology seed
    sim_seed = load_topology(plan.expert_topology, [f"topology.seed={test.first}"]) \
        .actor_seed("sim")
    expected = [episode_seed(sim_seed, k) for k in range(2)]
    eps = results["episodes"]
    for scen in ("indoor", "outdoor"):
        for mod in ("expert", "no_action"):
            assert [e["seed"] for e in eps
                    if e["scenario"] == scen and e["modality"] == mod] == expected
    # each scenario's runs really had that scene variant
    sim_logs = [p.read_text() for p in (tmp_path / "eval" / "runs").glob("*/logs/sim.log")]
    assert len(sim_logs) == 4
    assert sum("'variant': 'indoor'" in t for t in sim_logs) == 2
    assert sum("'variant': 'outdoor'" in t for t in sim_logs) == 2
    for scen in ("indoor", "outdoor"):
        m = {mod: [e["metrics"] for e in eps if e["scenario"] == scen
                   and e["modality"] == mod] for mod in ("expert", "no_action")}
        assert all(x["strict_success"] <= x["success"] for ms in m.values() for x in ms)
        # the target walks away from a robot that holds still; the expert follows it
        assert all(b["success"] < a["success"] for a, b in zip(m["expert"], m["no_action"]))
        assert [x["episode_success"] for x in m["no_action"]] == [0.0, 0.0]
        assert [x["episode_success"] for x in m["expert"]] == [1.0, 1.0]
    report = (tmp_path / "eval" / "report.md").read_text()
    assert "## Condition: nominal, indoor" in report
    assert "## Condition: nominal, outdoor" in report
    assert "split: test" in report


def test_plan_seeds_come_from_the_split_or_are_custom(tmp_path):
    dev = EvalPlan(task="nav", modalities=[], conditions=["nominal"], episodes=1, out=tmp_path)
    assert (dev.split, dev.seed) == ("dev", SPLITS["dev"].first) and dev.seed == 1000
    assert dev.scenarios == ["indoor", "outdoor"]
    test = EvalPlan(task="arm", modalities=[], conditions=["nominal"], episodes=1,
                    out=tmp_path, split="test")
    assert test.seed == SPLITS["test"].first and test.seed_range == SPLITS["test"]
    custom = EvalPlan(task="nav", modalities=[], conditions=["nominal"], episodes=1,
                      out=tmp_path, seed=2000)
    assert custom.split == "custom"
    assert (custom.seed_range.first, custom.seed_range.last) == (2000, 2000)
    for kwargs in ({"split": "test", "seed": 5}, {"split": "dev", "seed": SPLITS["test"].first},
                   {"split": "train"}, {"extra": ["topology.seed=5"]},
                   {"extra": ['sim.config.variant="outdoor"']}):
        plan = EvalPlan(task="nav", modalities=[], conditions=["nominal"], episodes=1,
                        out=tmp_path, **kwargs)
        with pytest.raises(ValueError):
            plan.validate()
    # a seed of the test range may be named explicitly with its split (a second draw)
    EvalPlan(task="nav", modalities=[], conditions=["nominal"], episodes=1, out=tmp_path,
             split="test", seed=SPLITS["test"].first + 7).validate()


def test_resume_never_reuses_another_seed_s_episodes(tmp_path):
    """An output directory reused with another split: the dev episodes on disk are not
    passed off as test episodes, so the run plays again."""
    from sebvs.eval.run import Run, _read_episodes
    plan = EvalPlan(task="nav", modalities=[], conditions=["nominal"], episodes=1,
                    out=tmp_path, split="test")
    path = plan.episode_file(Run("nominal", "indoor", "expert"))
    path.parent.mkdir(parents=True)
    line = {"episode": 0, "seed": 7, "metrics": {}}
    path.write_text("\n".join(json.dumps({**line, **extra}) for extra in
                              ({"topology_seed": 1000}, {})) + "\n")
    assert _read_episodes(path, plan.seed) == [] and len(_read_episodes(path)) == 2
    path.write_text(json.dumps({**line, "topology_seed": plan.seed}) + "\n")
    assert len(_read_episodes(path, plan.seed)) == 1


def test_eval_command_refuses_a_seed_outside_its_split(tmp_path, capsys):
    code = main(["eval", "--task", "nav", "--modalities", "", "--split", "test", "--seed", "5",
                 "--out", str(tmp_path / "eval")])
    err = capsys.readouterr().err
    assert code == 2 and "outside the test split" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "eval").exists()


def test_conditions_all_names_every_condition_of_the_sensor_pair():
    from sebvs.conditions import TASKS
    from sebvs.eval.cli import conditions_of
    NAV_CONDITIONS, NAV_PHYSICAL_CONDITIONS = (TASKS["nav"].names(p) for p in ("ideal8",
                                                                               "physical"))
    ARM_CONDITIONS, ARM_PHYSICAL_CONDITIONS = (TASKS["arm"].names(p) for p in ("ideal8",
                                                                               "physical"))
    assert conditions_of("all", "arm", "ideal8") == list(ARM_CONDITIONS)
    assert conditions_of("all", "nav", "ideal8") == list(NAV_CONDITIONS)
    assert conditions_of("all", "nav") == list(NAV_PHYSICAL_CONDITIONS)     # the default pair
    assert conditions_of("all", "arm", "physical") == list(ARM_PHYSICAL_CONDITIONS)
    assert "moving" in conditions_of("all", "arm", "ideal8") and "moving" not in NAV_CONDITIONS
    assert conditions_of("fast, blur,", "nav", "ideal8") == ["fast", "blur"]
    assert conditions_of(None, "nav") == ["nominal_physical"]
    assert conditions_of(None, "arm", "ideal8") == ["nominal"]
    with pytest.raises(ValueError, match=r"condition 'nominal' is the ideal8 sensor pair's.*"
                                         r"give --sensor ideal8"):
        conditions_of("hdr,nominal", "nav")
    with pytest.raises(ValueError, match=r"condition 'hdr' is the physical sensor pair's"):
        conditions_of("hdr", "arm", "ideal8")


def test_each_condition_runs_its_own_sensor_pair_whatever_the_topology_says(tmp_path):
    """A condition sets the camera's sensor (and, for an event row, the emulator's preset),
    so the 8-bit benchmark's conditions still run the ideal 8-bit pair on topologies that
    default to the physical one, and the physical conditions the physical pair."""
    from sebvs.eval.run import EvalPlan, Run
    from sebvs.runtime.topology import load_topology
    plan = EvalPlan(task="nav", modalities=["rgb+event", "rgb"], conditions=["nominal", "hdr"],
                    episodes=1, out=tmp_path)
    plan.validate()
    for cond, camera, emulator in (("nominal", "ideal8", "paper"),
                                   ("hdr", "physical", "physical")):
        for extra in ([], ['camera.sensor="physical"'], [{"camera": {"sensor": "ideal8"}}]):
            topo = load_topology(plan.policy_topology, extra)
            topo_path, sets = plan.overrides(Run(cond, "indoor", "rgb+event"))
            topo = load_topology(topo_path, [*extra, sets])
            assert topo.actors["camera"].params["sensor"] == camera, (cond, extra)
            assert topo.actors["emulator"].params["preset"] == emulator, (cond, extra)
        topo = load_topology(*plan.overrides(Run(cond, "indoor", "rgb")))
        assert topo.actors["camera"].params["sensor"] == camera
        assert topo.actors["emulator"].pruned            # an RGB row runs no event sensor


def test_the_shipped_topologies_and_checkpoints_are_the_physical_pair():
    from sebvs.policy.checkpoint import read_config
    from sebvs.runtime.topology import load_topology
    from sebvs.sensor_pairs import checkpoint_dir, sensor_overrides, topology_overrides
    root = Path(__file__).resolve().parents[1]
    for name in ("nav_policy", "arm_policy", "nav_record", "arm_record"):
        topo = load_topology(root / "topologies" / f"{name}.toml")
        assert topo.actors["camera"].params["sensor"] == "physical", name
        assert topo.actors["emulator"].params["preset"] == "physical", name
        old = load_topology(root / "topologies" / f"{name}.toml", sensor_overrides("ideal8"))
        assert old.actors["camera"].params["sensor"] == "ideal8"
        assert old.actors["emulator"].params["preset"] == "paper"
    policy = load_topology(root / "topologies" / "nav_policy.toml", topology_overrides("ideal8"))
    assert policy.actors["policy"].params["directory"] == "checkpoints/ideal8"
    # the plan's four policies of the physical pair; the 8-bit benchmark's three beside them
    for task in ("nav", "arm"):
        shipped = {pair: {pt.name for pt in (root / checkpoint_dir(pair)).glob(f"{task}-*.pt")}
                   for pair in ("physical", "ideal8")}
        paper = {f"{task}-rgb.pt", f"{task}-event.pt", f"{task}-rgb+event.pt"}
        assert shipped == {"physical": paper | {f"{task}-rgb+diff.pt"}, "ideal8": paper}, task
        for pt in (root / checkpoint_dir("physical")).glob(f"{task}-*.pt"):
            config = read_config(pt)
            assert config["dataset"]["path"].endswith(f"study_{task}10"), pt
            assert config["training"]["seed"] == 0, pt


def test_a_demo_swap_to_the_frame_difference_loads_its_checkpoint():
    from sebvs.demo import load_for_swap
    from sebvs.runtime.topology import load_topology
    root = Path(__file__).resolve().parents[1]
    sets = load_for_swap("rgb+diff", [])
    topo = load_topology(root / "topologies" / "nav_policy.toml", sets)
    assert topo.actors["policy"].params["modalities"] == ["rgb", "event", "rgb+event",
                                                          "rgb+diff"]
    assert load_for_swap("event", []) == load_for_swap(None, []) == {}
    # the user's own list stands, a --set line's or a mapping's
    assert load_for_swap("rgb+diff", ['policy.modalities=["rgb", "rgb+diff"]']) == {}
    assert load_for_swap("rgb+diff", {"policy": {"modalities": ["rgb+diff"]}}) == {}


def test_control_rate_sets_ticks_window_and_a_whole_multiple_render_rate(tmp_path):
    from sebvs.eval.run import EvalPlan, Run
    from sebvs.runtime.overrides import lookup
    from sebvs.runtime.topology import load_topology
    # checkpoints that name no event window (none at all here): the window is one tick
    plan = EvalPlan(task="nav", modalities=["rgb+event"], conditions=["nominal", "flicker_100"],
                    episodes=1, out=tmp_path, control_hz=30.0,
                    checkpoints=str(tmp_path / "no-checkpoints"))
    for cond, render, physics in (("nominal", 120.0, 1080.0), ("flicker_100", 1020.0, 1020.0)):
        for modality in ("rgb+event", "expert"):
            path, sets = plan.overrides(Run(cond, "indoor", modality))
            assert lookup(sets, "sim", "control_hz") == 30.0
            assert lookup(sets, "sim", "render_hz") == render
            assert lookup(sets, "camera", "dvs_hz") == render
            assert lookup(sets, "sim", "physics_hz") == physics
            if modality != "expert":
                assert lookup(sets, "accumulator", "window_s") == pytest.approx(1 / 30)
            topo = load_topology(path, sets)          # the sim accepts the rates
            assert topo.actors["sim"].params["control_hz"] == 30.0
    with pytest.raises(ValueError, match="control-hz"):
        EvalPlan(task="nav", modalities=["rgb"], conditions=["nominal"], episodes=1,
                 out=tmp_path, control_hz=-1.0).validate()


def test_a_video_run_lingers_past_the_writers_finalize_wait(tmp_path):
    """The run stops when the sim's linger ends; a video's trailing frames still queued on
    the writer's inputs would be lost, so --video lengthens it (a user's --set still wins)."""
    from sebvs.eval.run import Run
    from sebvs.runtime.topology import load_topology
    for extra, linger in (([], None), (["sim.linger_s=7.0"], 7.0)):
        plan = EvalPlan(task="nav", modalities=["rgb+event"], conditions=["nominal"],
                        episodes=1, out=tmp_path, video=True, extra=extra)
        for modality in ("rgb+event", "expert", "no_action"):
            topo = load_topology(*plan.overrides(Run("nominal", "indoor", modality)))
            got = topo.actors["sim"].params["linger_s"]
            wait = topo.actors["video"].params["finalize_after_s"]
            assert got == (linger or got) and got > wait, (modality, got, wait)
    plan = EvalPlan(task="nav", modalities=["rgb"], conditions=["nominal"], episodes=1,
                    out=tmp_path)
    topo = load_topology(*plan.overrides(Run("nominal", "indoor", "rgb")))
    assert "linger_s" not in topo.actors["sim"].params     # no video: the sim's default
