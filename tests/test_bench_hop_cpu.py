"""tools/bench_hop_cpu.py drives a Node's reader callback directly: check it still runs
against the runtime, reports every condition, and leaves no ring behind."""
import asyncio
import importlib.util
import os
from pathlib import Path

TOOL = Path(__file__).resolve().parents[1] / "tools" / "bench_hop_cpu.py"


def _load_tool():
    spec = importlib.util.spec_from_file_location("bench_hop_cpu", TOOL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_measures_every_condition_and_unlinks_its_ring():
    tool = _load_tool()
    result = asyncio.run(tool.measure(65536, 40))
    assert set(result) == {"warm", "paced", "after_fill"}
    for cond, figures in result.items():
        assert figures["emit_us"] > 0 and figures["receive_us"] > 0, cond
    assert result["paced"]["emit_p90_us"] >= result["paced"]["emit_us"]
    assert not [p for p in os.listdir("/dev/shm") if p.startswith(f"sebvs-benchcpu{os.getpid()}-")]
