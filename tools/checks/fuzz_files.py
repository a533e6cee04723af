"""The files class of tools/checks/fuzz_run.py: every writing command at every hostile
output, every reader at every damaged episode, as a user would type them.

Records a small real dataset (two 2 s nav episodes with raw events), trains a checkpoint
on it, and then runs each command of `sebvs` as its own process:

  writers  record, train, eval, data export, events export, events show, v2e,
           data stats --plot, view --save, each pointed (without --force) at
           source    its own input (the episode, the dataset, the checkpoint folder, ...)
           sibling   another episode of the dataset
           index     the dataset's index.json
           readonly  an existing read-only file (mode 0444)
           existing  an existing file; for folder outputs a folder holding another's
                     file, and for train a finished checkpoint of the same variant
  readers  train, data export (dataset and episode), events export, events show,
           data stats, view, data check, each on a copy of the dataset whose first
           episode is
           truncated, zeroed (4 KiB), header-flipped (the superblock), chunk-flipped
           (4 KiB inside one compressed rgb chunk: it may still decode)

Counted (the targets are 0 everywhere):
  overwritten   writer cases where a file that existed before changed or went away
  accepted      writer cases that exited 0
  unnamed       reader cases that did not exit non-zero with the damaged file's name in
                what they printed
  tracebacks    cases whose output holds a Python traceback
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
VICTIM = "episode_0000.h5"
DAMAGES = ("truncated", "zeroed", "header-flipped", "chunk-flipped")
HOSTILE = ("source", "sibling", "index", "readonly", "existing")


def sebvs(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sebvs.cli", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout,
                          env=dict(os.environ, PYTHONWARNINGS="ignore"))


def snapshot(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` and the sha256 of its bytes."""
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            out[str(p.relative_to(folder))] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def damage(path: Path, how: str) -> None:
    """Damage an episode in place as a disk, a copy or a stray write would."""
    import h5py
    data = bytearray(path.read_bytes())
    if how == "truncated":
        del data[len(data) // 2:]
    elif how == "zeroed":
        at = len(data) // 3
        data[at:at + 4096] = bytes(4096)
    elif how == "header-flipped":
        data[:64] = bytes(b ^ 0xFF for b in data[:64])
    elif how == "chunk-flipped":
        with h5py.File(path, "r") as f:
            info = f["rgb"].id.get_chunk_info(0)
        at, n = int(info.byte_offset) + int(info.size) // 4, min(4096, int(info.size) // 2)
        data[at:at + n] = bytes(b ^ 0x5A for b in data[at:at + n])
    else:
        raise ValueError(how)
    path.write_bytes(bytes(data))


def prepare(work: Path) -> dict[str, Path]:
    """A recorded dataset, a checkpoint trained on it, a folder of images, a video."""
    import cv2
    import numpy as np
    ds = work / "ds"
    done = sebvs("record", str(ROOT / "topologies" / "nav_record.toml"), "--episodes", "2",
                 "--out", str(ds), "--set", "sim.episode_s=2.0", "--set",
                 "recorder.raw_events=true", "--set", 'recorder.inputs.raw="emulator/events"',
                 "--runs-dir", str(work / "runs"), "--quiet")
    if done.returncode:
        raise RuntimeError(f"recording failed: {done.stderr.strip()[-500:]}")
    ck = work / "ck"
    done = sebvs("train", "--task", "nav", "--modality", "rgb", "--data", str(ds), "--out",
                 str(ck), "--epochs", "1", "--size", "32", "--no-progress")
    if done.returncode:
        raise RuntimeError(f"training failed: {done.stderr.strip()[-500:]}")
    frames = work / "frames"
    frames.mkdir()
    rng = np.random.default_rng(0)
    for k in range(4):
        cv2.imwrite(str(frames / f"f{k}.png"), rng.integers(0, 255, (24, 24, 3), np.uint8))
    return {"ds": ds, "ck": ck, "frames": frames}


def hostile_paths(work: Path, made: dict[str, Path]) -> dict[str, Path]:
    ro = work / "readonly.bin"
    if ro.exists():     # made again after a case wrote over it
        ro.chmod(0o644)
    ro.write_bytes(b"read-only, not ours")
    ro.chmod(0o444)
    existing = work / "existing.bin"
    existing.write_bytes(b"not ours")
    busy = work / "busy"
    busy.mkdir(exist_ok=True)
    (busy / "notes.txt").write_text("not ours")
    ds = made["ds"]
    return {"sibling": ds / "episode_0001.h5", "index": ds / "index.json", "readonly": ro,
            "existing": existing, "busy": busy}


def writers(made: dict[str, Path], work: Path) -> dict[str, tuple[list[str], Path]]:
    """name -> (argv before --out, its own input) of every command that writes."""
    ds, ck, frames = made["ds"], made["ck"], made["frames"]
    ep = ds / VICTIM
    topo = ROOT / "topologies" / "nav_record.toml"
    return {
        "record": (["record", str(topo), "--episodes", "1", "--set", "sim.episode_s=1.0",
                    "--runs-dir", str(work / "runs"), "--quiet", "--out"], topo),
        "train": (["train", "--task", "nav", "--modality", "rgb", "--data", str(ds),
                   "--epochs", "1", "--size", "32", "--no-progress", "--out"], ds),
        "eval": (["eval", "--modalities", "rgb", "--checkpoints", str(ck), "--episodes", "1",
                  "--no-expert", "--no-baseline", "--out"], ck),
        "data export": (["data", "export", str(ep), "--quiet", "--out"], ep),
        "events export": (["events", "export", str(ep), "--quiet", "--out"], ep),
        "events show": (["events", "show", str(ep), "--out"], ep),
        "v2e": (["v2e", str(frames), "--fps", "10", "--quiet", "--out"], frames),
        "data stats --plot": (["data", "stats", str(ds), "--plot"], ds),
        "view --save": (["view", str(ep), "--save"], ep),
    }


FOLDER_OUTPUTS = ("record", "train", "eval")


def readers(ds: Path, work: Path) -> dict[str, list[str]]:
    ep = str(ds / VICTIM)
    return {
        "train": ["train", "--task", "nav", "--modality", "rgb", "--data", str(ds), "--out",
                  str(work / "r-ck"), "--epochs", "1", "--size", "32", "--no-progress"],
        "data export (dataset)": ["data", "export", str(ds), "--out", str(work / "r-mcap"),
                                  "--quiet"],
        "data export (episode)": ["data", "export", ep, "--out", str(work / "r-one.mcap"),
                                  "--quiet"],
        "events export": ["events", "export", ep, "--out", str(work / "r-ev.h5"), "--quiet"],
        "events show": ["events", "show", ep, "--out", str(work / "r-ev.png")],
        "data stats": ["data", "stats", str(ds)],
        "view": ["view", ep, "--save", str(work / "r-view.rrd")],
        "data check": ["data", "check", str(ds)],
    }


def run_files(work: Path, progress=print) -> dict:
    """Both halves in ``work`` (a scratch folder); returns the figures and every case."""
    t0 = time.monotonic()
    made = prepare(work)
    paths = hostile_paths(work, made)
    # kept aside: a case that writes over the dataset or the checkpoint must not decide
    # the next case, nor the readers' copies
    kept = work / "kept"
    for key in ("ds", "ck"):
        shutil.copytree(made[key], kept / key)
    cases = []
    for name, (argv, source) in writers(made, work).items():
        for hostile in HOSTILE:
            if hostile == "source":
                out = source
            elif hostile == "existing" and name == "train":
                out = made["ck"]    # a finished checkpoint of the same variant
            elif hostile == "existing" and name in FOLDER_OUTPUTS:
                out = paths["busy"]
            else:
                out = paths[hostile]
            before = snapshot(work)
            done = sebvs(*argv, str(out))
            after = snapshot(work)
            changed = sorted(k for k, v in before.items() if after.get(k) != v)
            text = done.stdout + done.stderr
            cases.append({"kind": "writer", "command": name, "output": hostile,
                          "exit": done.returncode, "overwritten": changed,
                          "traceback": "Traceback" in text,
                          "said": done.stderr.strip().splitlines()[-1:] or [""]})
            progress(f"  writer {name:<18} -> {hostile:<9} exit {done.returncode}"
                     f"{'  OVERWROTE ' + ', '.join(changed) if changed else ''}")
            if changed:
                for key in ("ds", "ck"):
                    shutil.rmtree(made[key], ignore_errors=True)
                    shutil.copytree(kept / key, made[key])
                paths = hostile_paths(work, made)
    pristine = kept / "ds"
    for how in DAMAGES:
        ds = work / f"ds-{how}"
        shutil.rmtree(ds, ignore_errors=True)
        shutil.copytree(pristine, ds)
        damage(ds / VICTIM, how)
        for name, argv in readers(ds, work).items():
            done = sebvs(*argv)
            text = done.stdout + done.stderr
            named = done.returncode != 0 and VICTIM in text
            cases.append({"kind": "reader", "command": name, "damage": how,
                          "exit": done.returncode, "named": named,
                          "traceback": "Traceback" in text,
                          "said": [ln for ln in text.splitlines() if VICTIM in ln][:1]})
            progress(f"  reader {name:<22} <- {how:<14} exit {done.returncode}"
                     f"{'' if named else '  NOT NAMED'}")
    w = [c for c in cases if c["kind"] == "writer"]
    r = [c for c in cases if c["kind"] == "reader"]
    return {"writer_cases": len(w), "reader_cases": len(r),
            "overwritten": sum(bool(c["overwritten"]) for c in w),
            "accepted": sum(c["exit"] == 0 for c in w),
            "unnamed": sum(not c["named"] for c in r),
            "tracebacks": sum(c["traceback"] for c in cases),
            "wall_s": round(time.monotonic() - t0, 1), "cases": cases}
