"""tools/bench/bench_hop_cpu.py drives a Node's reader callback directly: check it still runs
against the runtime, reports every condition, and leaves no ring behind."""
import asyncio
import os

from tests.tools_loader import tool_module


def test_measures_every_condition_and_unlinks_its_ring():
    with tool_module("bench/bench_hop_cpu") as tool:
        result = asyncio.run(tool.measure(65536, 40))
        assert set(result) == {"warm", "paced", "after_fill"}
        for cond, figures in result.items():
            assert figures["emit_us"] > 0 and figures["receive_us"] > 0, cond
        assert result["paced"]["emit_p90_us"] >= result["paced"]["emit_us"]
        prefix = f"sebvs-benchcpu{os.getpid()}-"
        assert not [p for p in os.listdir("/dev/shm") if p.startswith(prefix)]
