"""tools/checks/fuzz_run.py on a live run, small: every hostile message counted under its kind,
the input alive after each (oversized ones included), both actors ended as asked."""
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_fuzz_run_counts_every_hostile_message_and_no_input_is_cut_off(tmp_path):
    out = tmp_path / "fuzz.json"
    done = subprocess.run([sys.executable, str(ROOT / "tools" / "checks" / "fuzz_run.py"),
                           "--messages", "700", "--oversize-every", "20", "--json", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    r = json.loads(out.read_text())
    assert r["messages_sent"] >= 700 and r["uncounted_total"] == 0
    assert r["counters"]["oversize"]["counted"] == r["counters"]["oversize"]["sent"] >= 2
    assert all(v["sent"] > 0 and v["counted"] == v["sent"] for v in r["counters"].values())
    assert r["probes_handled"] == r["probes_sent"] and r["inputs_cut_off"] == 0
    assert r["actors_alive"] and r["memory_growth_mb"] < 50
