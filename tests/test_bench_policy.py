"""tools/bench/bench_policy.py's shipped-checkpoint part: every graph timed, warm and cold."""
from sebvs.policy.checkpoint import model_config, save_checkpoint
from sebvs.policy.inputs import Normalisation, channels
from sebvs.policy.model import ERP
from tests.tools_loader import tool_module


def test_shipped_checkpoints_are_timed_through_each_graph(tmp_path):
    save_checkpoint(ERP("arm", channels("rgb+event"), 32, stem="conv").eval(),
                    model_config("arm", "rgb+event", Normalisation(32), "conv"), tmp_path)
    with tool_module("bench/bench_policy") as bench:
        rows = bench.bench_shipped(tmp_path / "arm-rgb+event.pt", ["eager", "frozen"], 3, 0.0)
    assert [(r["graph"], r["fallback"]) for r in rows] == [("eager", None), ("frozen", None)]
    for r in rows:
        assert r["checkpoint"] == "arm-rgb+event.pt" and r["stem"] == "conv"
        assert r["size"] == 32 and r["calls"] == 3
        assert 0 < r["warm_p50_ms"] <= r["warm_p99_ms"]
        assert 0 < r["cold_p50_ms"] <= r["cold_p99_ms"]
