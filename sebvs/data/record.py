"""``sebvs record TOPOLOGY --episodes N --out DIR``: run a recording topology to N episodes.

Runs the topology with the runtime's Supervisor, overriding the recorder's ``out``,
``episodes`` and ``topology`` params, and shows a progress bar (episodes, frames, speed in
simulated seconds per wall second) from the recorder's ``stats`` on its control socket.
The recorder ends the run after N finished episodes; numbering resumes in an existing
dataset. A topology seed in the test split's range (sebvs/data/splits.py) is refused
before anything starts: held-out episodes stay held out only if no recording ever makes
them.
"""
from __future__ import annotations

import json
import signal
import sys
import time
from pathlib import Path

RECORDER_CLASS = "actors.recorder:Recorder"


def find_recorder(topo) -> str:
    # actors.recorder:Recorder or :LockstepRecorder (or a user's subclass named *Recorder)
    names = [n for n, a in topo.actors.items() if a.run.split(":")[-1].endswith("Recorder")]
    if len(names) != 1:
        raise LookupError(f"{topo.path if hasattr(topo, 'path') else 'topology'}: expected "
                          f"one recorder actor ({RECORDER_CLASS}), found {names or 'none'}")
    return names[0]


class Progress:
    """Polls the recorder's stats every `every_s` while the supervisor waits."""

    def __init__(self, sup, recorder: str, episodes: int, every_s: float = 0.5,
                 enabled: bool = True):
        from tqdm import tqdm
        self.sup, self.recorder, self.every_s = sup, recorder, every_s
        self.t0 = time.monotonic()
        self.next_poll = 0.0
        self.last: dict = {}
        self.bar = tqdm(total=episodes, unit="ep", desc="recording", disable=not enabled,
                        dynamic_ncols=True)

    def __call__(self, poll_s: float) -> None:
        time.sleep(poll_s)
        now = time.monotonic()
        if now < self.next_poll:
            return
        self.next_poll = now + self.every_s
        self.refresh()

    def refresh(self) -> None:
        if self.recorder not in self.sup.specs:
            return
        reply = self.sup.request(self.recorder, {"cmd": "stats"}, 0.5)
        if not reply or not reply.get("ok"):
            return
        st = reply["result"].get("actor_stats", {})
        if not st:
            return
        self.last = st
        wall = time.monotonic() - self.t0
        self.bar.n = min(st["episodes"], self.bar.total or st["episodes"])
        self.bar.set_postfix(frames=st["frames"] + st["frames_in_progress"],
                             speed=f"{st['sim_s'] / max(wall, 1e-9):.1f}x",
                             lost_ticks=st["incomplete_ticks"], refresh=False)
        self.bar.refresh()

    def close(self) -> None:
        self.bar.close()


def cmd_record(args) -> int:
    from sebvs.runtime.supervisor import RunFailed, Supervisor
    from sebvs.runtime.topology import load_topology
    from .index import DatasetIndex
    from .splits import check_recording_seed

    name = find_recorder(load_topology(args.topology, args.set))
    out = Path(args.out)
    overrides = [*args.set, f"{name}.out={json.dumps(str(out))}",
                 f"{name}.episodes={args.episodes}",
                 f"{name}.topology={json.dumps(str(Path(args.topology).resolve()))}"]
    topo = load_topology(args.topology, overrides)
    # refused outright, with no flag to allow it: a test split that one flag can record from
    # is held out only by convention, and nothing a recording needs lies in that range
    try:
        warning = check_recording_seed(topo.seed)
    except ValueError as exc:
        print(f"sebvs record: {exc}", file=sys.stderr)
        return 2
    if warning:
        print(f"sebvs record: warning: {warning}", file=sys.stderr)
    first = DatasetIndex(out).next_episode_number() if out.exists() else 0
    echo = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr))
    sup = Supervisor(topo, runs_dir=args.runs_dir, echo=echo)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda s, f: sup.interrupt(signal.Signals(s).name))
    progress = None
    t0 = time.monotonic()
    try:
        sup.start()
        print(f"sebvs record: {topo.name} -> {out} (first episode {first:04d}), run dir "
              f"{sup.rundir}", file=sys.stderr)
        progress = Progress(sup, name, args.episodes, enabled=not args.quiet)
        code = sup.wait(args.timeout, progress)
    except RunFailed as exc:
        print(f"sebvs record: {exc}", file=sys.stderr)
        sup.stop()
        return 1
    except BaseException:
        sup.stop()
        raise
    finally:
        if progress is not None and sup.status != "ended":
            progress.close()
    wall = time.monotonic() - t0
    if sup.failure:
        print(f"sebvs record: run stopped: {sup.failure.splitlines()[0]}", file=sys.stderr)
    index = DatasetIndex(out) if (out / "index.json").exists() else None
    new = [e for e in (index.episodes() if index else [])
           if int(e["file"].split("_")[1].split(".")[0]) >= first]
    frames = sum(e["frames"] for e in new)
    if progress is not None:
        progress.bar.n = min(len(new), args.episodes)   # the last episode ends the run
        progress.bar.set_postfix(frames=frames, refresh=False)
        progress.close()
    print(f"sebvs record: {len(new)} of {args.episodes} episode(s) recorded, {frames} frames, "
          f"{wall:.1f} s wall; dataset {out} now holds "
          f"{len(index.episodes()) if index else 0} episode(s)")
    return 0 if code == 0 and len(new) >= args.episodes else 1
