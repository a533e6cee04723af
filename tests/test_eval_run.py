"""A short closed-loop evaluation end to end: expert and a tiny policy, 2 episodes, real runs."""
import json

from sebvs.eval.run import EvalPlan, evaluate
from tests.policy_data import make_dataset


def test_short_evaluation_runs_end_to_end_and_resumes(tmp_path):
    from sebvs.policy.inputs import Normalisation
    from sebvs.policy.train import train

    data = make_dataset(tmp_path / "data", episodes=4, frames=12, height=32, width=32)
    train(data, tmp_path / "ckpt", "nav", ["rgb+event"], progress=False, log=lambda *a: None,
          epochs=1, batch=8, norm=Normalisation(size=32))
    plan = EvalPlan(task="nav", modalities=["rgb+event"], conditions=["nominal"], episodes=2,
                    out=tmp_path / "eval", checkpoints=str(tmp_path / "ckpt"),
                    extra=["sim.episode_s=1.5"])
    results = evaluate(plan)
    eps = results["episodes"]
    assert {(e["modality"], e["condition"]) for e in eps} == {("expert", "nominal"),
                                                              ("rgb+event", "nominal")}
    by_mod = {}
    for e in eps:
        by_mod.setdefault(e["modality"], []).append(e["seed"])
    assert len(by_mod["expert"]) == 2
    assert by_mod["expert"] == by_mod["rgb+event"]         # the same seeded episodes
    policy_eps = [e for e in eps if e["modality"] == "rgb+event"]
    assert all(len(e["inference_ms"]) > 5 for e in policy_eps)
    report = (tmp_path / "eval" / "report.md").read_text()
    assert "## Condition: nominal" in report and "| RGB+Event | 2 |" in report
    assert "| Expert (reference) | 2 |" in report
    for png in ("success.png", "centroid_error.png", "latency.png"):
        assert (tmp_path / "eval" / png).stat().st_size > 5000
    saved = json.loads((tmp_path / "eval" / "results.json").read_text())
    assert len(saved["episodes"]) == 4
    # resume: everything is finished, so nothing runs again and the results are the same
    runs_before = len(list((tmp_path / "eval" / "runs").iterdir()))
    again = evaluate(plan)
    assert len(list((tmp_path / "eval" / "runs").iterdir())) == runs_before
    assert [e["seed"] for e in again["episodes"]] == [e["seed"] for e in eps]
