"""An actor whose supervisor dies ends itself: the kernel's parent-death SIGTERM (or any
stop) ends it at once whatever step of its start it is in (its setup, waiting for its
consumers' subscriptions), not once that step is done."""
import asyncio
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# A supervisor that spawns its actors, waits until the sink's setup has begun (its signal
# handlers are in place by then), and dies without a word, as a killed process does.
DYING_SUPERVISOR = textwrap.dedent("""
    import json, os, sys, time
    from pathlib import Path
    from sebvs.runtime import supervisor
    from sebvs.runtime.topology import load_topology
    topo, runs, marker, pids = sys.argv[1:5]

    def die_once_setup_has_begun(self):
        Path(pids).write_text(json.dumps([p.popen.pid for p in self.procs.values()]))
        deadline = time.monotonic() + 60
        while not Path(marker).exists() and time.monotonic() < deadline:
            time.sleep(0.02)
        os._exit(0)

    supervisor.Supervisor._await_ready = die_once_setup_has_begun
    supervisor.Supervisor(load_topology(Path(topo)), runs_dir=Path(runs),
                          echo=lambda s: None).start()
""")


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


def test_actors_end_when_their_supervisor_dies_during_their_start(tmp_path):
    from tests.test_runtime_hardening import source_sink_topology

    marker, pids_file = tmp_path / "setup-begun", tmp_path / "pids.json"
    topo = source_sink_topology(
        tmp_path, "orphans", sink_run="tests.runtime_actors:SlowSetupSink",
        source="width = 16\nheight = 16\nrate_hz = 50.0")
    topo.write_text(topo.read_text() + f'marker = "{marker}"\nsetup_s = 60.0\n')
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    child = subprocess.run([sys.executable, "-c", DYING_SUPERVISOR, str(topo), str(tmp_path),
                            str(marker), str(pids_file)], cwd=ROOT, env=env, timeout=90)
    assert child.returncode == 0 and marker.exists()
    pids = json.loads(pids_file.read_text())
    assert len(pids) == 2
    try:
        deadline = time.monotonic() + 10      # far below the sink's 60 s setup
        while any(_alive(p) for p in pids) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not [p for p in pids if _alive(p)], "actors outlived their supervisor"
    finally:
        for p in pids:
            if _alive(p):
                os.kill(p, signal.SIGKILL)


# ----------------------------------------------------------------- one Node, in process
def _probe_node(tmp_path, setup_s, outputs=None):
    """A Node around an actor whose setup takes ``setup_s`` (None: for ever) and which
    notes whether its teardown ran; ``outputs``: the spec's, as the supervisor plans them."""
    from sebvs.runtime import Actor
    from sebvs.runtime.node import Node

    class Probe(Actor):
        torn_down = False

        async def setup(self):
            await (asyncio.Event().wait() if setup_s is None else asyncio.sleep(setup_s))

        async def teardown(self):
            self.torn_down = True

    spec = {"name": "probe", "run_id": f"orphan{os.getpid()}", "outputs": outputs or {},
            "inputs": {}, "control": f"ipc://{tmp_path}/probe.ctl",
            "telemetry": f"ipc://{tmp_path}/probe.tel"}
    return Node(spec, lambda node: Probe("probe", None, node=node))


def _stopped_after(node, tmp_path, delay_s: float):
    async def go():
        asyncio.get_running_loop().call_later(delay_s, node.finish, "signal SIGTERM")
        t0 = time.monotonic()
        code = await asyncio.wait_for(node.run(f"ipc://{tmp_path}/nobody"), 30)
        return code, time.monotonic() - t0
    return asyncio.run(go())


def test_a_stop_during_setup_ends_the_start_and_skips_teardown(tmp_path):
    node = _probe_node(tmp_path, setup_s=None)
    code, took = _stopped_after(node, tmp_path, 0.2)
    assert code == 0 and node.finished_reason == "signal SIGTERM" and took < 5
    assert not node.actor.torn_down and not node.ready


def test_a_stop_while_waiting_for_consumers_ends_the_start(tmp_path):
    """One consumer expected, none ever comes: the wait would last its 60 s timeout."""
    out = {"frames": {"endpoint": f"ipc://{tmp_path}/frames", "hwm": 8, "slots": 4,
                      "subscribers": 1, "ring": f"sebvs-orphan{os.getpid()}-probe-frames"}}
    node = _probe_node(tmp_path, setup_s=0, outputs=out)
    code, took = _stopped_after(node, tmp_path, 0.5)
    assert code == 0 and took < 5 and not node.ready
    assert node.actor.torn_down            # its setup had finished: it is torn down
