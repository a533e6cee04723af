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
class _Starting:
    """An actor whose setup takes `setup_s` (None: for ever); it notes its teardown."""

    def __init__(self, setup_s):
        from sebvs.runtime import Actor

        outer = self

        class Probe(Actor):
            async def setup(self):
                if setup_s is None:
                    await asyncio.Event().wait()
                await asyncio.sleep(setup_s)

            async def teardown(self):
                outer.torn_down = True

        self.cls, self.torn_down = Probe, False

    def __call__(self, node):
        return self.cls("probe", None, node=node)


def _node(tmp_path, actor):
    from sebvs.runtime.node import Node
    spec = {"name": "probe", "run_id": f"orphan{os.getpid()}", "outputs": {}, "inputs": {},
            "control": f"ipc://{tmp_path}/probe.ctl", "telemetry": f"ipc://{tmp_path}/probe.tel"}
    return Node(spec, actor)


def test_a_stop_during_setup_ends_the_start_and_skips_teardown(tmp_path):
    actor = _Starting(setup_s=None)

    async def go():
        node = _node(tmp_path, actor)
        asyncio.get_running_loop().call_later(0.2, node.finish, "signal SIGTERM")
        t0 = time.monotonic()
        code = await asyncio.wait_for(node.run(f"ipc://{tmp_path}/nobody"), 10)
        return node, code, time.monotonic() - t0

    node, code, took = asyncio.run(go())
    assert code == 0 and node.finished_reason == "signal SIGTERM" and took < 5
    assert not actor.torn_down and not node.ready
