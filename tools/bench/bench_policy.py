"""Benchmark the ERP on this CPU: batch-1 inference latency and training throughput.

    python tools/bench/bench_policy.py [--quick] [--json FILE] [--shipped-only]

JSON: {"inference": [{"modality", "size", "threads", "memory", "p50_ms", "p99_ms", ...}],
       "shipped":   [{"checkpoint", "graph", "warm_p50_ms", "cold_p50_ms", ...}],
       "training":  [{"size", "samples_per_s", "batch", "threads", ...}], "env": {...}}

Inference is what the policy actor does per tick: model.eval(), torch.inference_mode(),
batch 1, the nav head (the arm head adds two small linear layers). Input preparation
(inputs.py: resize + scale from a 640x640 frame) is timed separately as `prep_ms`.
The token embeddings named by --stems are timed: the paper's patch projection, ConvStem,
GatedFusionStem and DualStem (the last two rgb+event only: they have no other modality),
each without memory and with the GRU state (--memories: a recurrent model's tick is its
step, the state carried from call to call as the policy actor carries it).
Training is one Adam step (forward, MSE, backward, update) on random batches.

`shipped` times every checkpoint in --checkpoints (default checkpoints/) as the policy
actor runs it, one thread, through each inference graph (sebvs/policy/graph.py: eager,
frozen): `warm` back to back, `cold` after --idle-s of sleep, as a policy in a loop runs
once per control tick. Graphs alternate call by call, so a slow phase hits both.
"""
from __future__ import annotations

import argparse
import itertools
import json
import platform
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from sebvs.policy.checkpoint import checkpoints_in  # noqa: E402
from sebvs.policy.inputs import MODALITIES, Normalisation, channels, model_input  # noqa: E402
from sebvs.policy.model import ERP, count_parameters  # noqa: E402
from sebvs.policy.train import check_stem  # noqa: E402


def _timed(fn, budget_s: float, min_iter: int, max_iter: int, warm: int = 2) -> np.ndarray:
    """Call fn repeatedly for about budget_s (bounded iterations); returns ms per call."""
    for _ in range(warm):   # first calls allocate
        fn()
    out = []
    end = time.perf_counter() + budget_s
    while len(out) < max_iter and (len(out) < min_iter or time.perf_counter() < end):
        t0 = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t0) * 1e3)
    return np.asarray(out)


def stem_fits(stem: str, modality: str) -> bool:
    try:
        check_stem(stem, modality)
    except ValueError:
        return False
    return True


def bench_inference(modality: str, size: int, threads: int, budget_s: float,
                    min_iter: int = 10, stem: str = "patch", memory: str = "none") -> dict:
    torch.set_num_threads(threads)
    cv2.setNumThreads(threads)     # as the policy actor does
    torch.manual_seed(0)
    model = ERP("nav", channels(modality), size, stem=stem, memory=memory).eval()
    x = torch.rand(1, channels(modality), size, size)
    state = [model.initial_state()]

    def step():
        with torch.inference_mode():
            if model.state_size:        # as PolicySet.act: the state stepped on each tick
                _, state[0] = model.step(x, state[0])
            else:
                model(x)

    ms = _timed(step, budget_s, min_iter=min_iter, max_iter=5000)
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (640, 640, 3), dtype=np.uint8)
    ev = rng.integers(0, 4, (2, 640, 640), dtype=np.uint8)
    norm = Normalisation(size=size)
    prep = _timed(lambda: model_input(modality, norm, rgb=rgb, events=ev), budget_s / 4, 5, 500)
    return {"modality": modality, "size": size, "threads": threads, "stem": stem,
            "memory": memory, "tokens": (size // 16) ** 2,
            "parameters": count_parameters(model), "p50_ms": round(float(np.median(ms)), 4),
            "p90_ms": round(float(np.percentile(ms, 90)), 4),
            "p99_ms": round(float(np.percentile(ms, 99)), 4), "n": int(ms.size),
            "prep_ms_from_640": round(float(np.median(prep)), 4)}


def bench_shipped(path: Path, graphs: list[str], calls: int, idle_s: float) -> list[dict]:
    """One checkpoint through each graph: model time only, warm and after ``idle_s`` idle."""
    from sebvs.policy.checkpoint import load_checkpoint
    from sebvs.policy.graph import inference_graph, step_module
    torch.set_num_threads(1)
    model, cfg, _ = load_checkpoint(path)
    x = torch.rand(1, model.in_channels, model.size, model.size)
    # a model with memory runs its step, (x, state) -> (y, state), as PolicySet does
    args = (x, model.initial_state()) if model.state_size else (x,)
    runnable = step_module(model) if model.state_size else model
    runs = {g: inference_graph(runnable, args if model.state_size else x, g) for g in graphs}
    times = {g: {"warm": [], "cold": []} for g in graphs}
    with torch.inference_mode():
        for g in graphs:
            for _ in range(3):      # first calls allocate
                runs[g][0](*args)
        for _ in range(calls):
            for g in graphs:
                run = runs[g][0]
                time.sleep(idle_s)
                t0 = time.perf_counter()
                run(*args)
                t1 = time.perf_counter()
                run(*args)
                t2 = time.perf_counter()
                times[g]["cold"].append((t1 - t0) * 1e3)
                times[g]["warm"].append((t2 - t1) * 1e3)
    out = []
    for g in graphs:
        warm, cold = np.asarray(times[g]["warm"]), np.asarray(times[g]["cold"])
        out.append({"checkpoint": path.name, "stem": cfg.get("stem", "patch"),
                    "memory": cfg.get("memory", "none"),
                    "size": model.size, "threads": 1, "graph": runs[g][1],
                    "fallback": runs[g][2], "calls": calls, "idle_s": idle_s,
                    "warm_p50_ms": round(float(np.median(warm)), 4),
                    "warm_p99_ms": round(float(np.percentile(warm, 99)), 4),
                    "cold_p50_ms": round(float(np.median(cold)), 4),
                    "cold_p99_ms": round(float(np.percentile(cold, 99)), 4)})
    return out


def bench_training(size: int, batch: int, threads: int, steps: int) -> dict:
    torch.set_num_threads(threads)
    torch.manual_seed(0)
    model = ERP("nav", 5, size).train()
    opt = torch.optim.Adam(model.parameters(), lr=2e-4, weight_decay=1e-4)
    x, y = torch.rand(batch, 5, size, size), torch.rand(batch, 2) * 2 - 1

    def step():
        loss = torch.nn.functional.mse_loss(model(x), y)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    ms = _timed(step, 0.0, min_iter=steps, max_iter=steps, warm=1)
    per_batch = float(np.median(ms))
    return {"size": size, "batch": batch, "threads": threads, "modality": "rgb+event",
            "ms_per_batch": round(per_batch, 2), "samples_per_s": round(batch * 1e3 / per_batch, 1),
            "steps": steps}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short timings (under 40 s)")
    ap.add_argument("--json", metavar="FILE", help="write the results here")
    ap.add_argument("--sizes", default="160,320,640")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--stems", default="patch,conv,gated",
                    help="token embeddings to time: patch (the paper's), conv (ConvStem), "
                         "gated (GatedFusionStem), dual (DualStem); the last two rgb+event "
                         "only")
    ap.add_argument("--memories", default="none,gru",
                    help="comma list of the models' memory to time (sebvs/policy/model.py: "
                         "none, the paper's per-tick model; gru, a state across ticks)")
    ap.add_argument("--checkpoints", default=str(Path(__file__).resolve().parents[2] /
                                                  "checkpoints"),
                    help="directory of shipped .pt checkpoints to time (default checkpoints/)")
    ap.add_argument("--graphs", default="eager,frozen",
                    help="inference graphs for the shipped checkpoints (sebvs/policy/graph.py)")
    ap.add_argument("--idle-s", type=float, default=0.1,
                    help="idle time before a cold call: one control period at 10 Hz")
    ap.add_argument("--shipped-only", action="store_true",
                    help="only the shipped checkpoints, no synthetic models or training")
    args = ap.parse_args(argv)
    stems = args.stems.split(",")
    memories = args.memories.split(",")
    sizes = [int(s) for s in args.sizes.split(",")]
    threads = [int(t) for t in args.threads.split(",")]
    budget = 0.35 if args.quick else 2.0
    t_start = time.monotonic()

    shipped = []
    for pt in checkpoints_in(args.checkpoints):
        rows = bench_shipped(pt, args.graphs.split(","), 15 if args.quick else 60, args.idle_s)
        shipped += rows
        print(f"shipped {pt.name:>20}: " + "  ".join(
            f"{r['graph']} warm {r['warm_p50_ms']:.3f} cold {r['cold_p50_ms']:.3f} ms"
            for r in rows), flush=True)
    if args.shipped_only:
        sizes = []

    inference = []
    for size in sizes:
        for t in threads:
            for stem, m, mem in itertools.product(stems, MODALITIES, memories):
                if not stem_fits(stem, m):
                    continue
                r = bench_inference(m, size, t, budget * (1 if size <= 320 else 1.5),
                                    min_iter=5 if args.quick and size > 320 else 10, stem=stem,
                                    memory=mem)
                inference.append(r)
                print(f"inference {stem:>5} {mem:>4} {m:>9} {size:>4}px {t} thr: "
                      f"p50 {r['p50_ms']:.3f} ms  "
                      f"p99 {r['p99_ms']:.3f} ms  (prep {r['prep_ms_from_640']:.3f} ms)",
                      flush=True)
    training = []
    for size in sizes:
        # batch 32 as the paper; at 640 px one batch of 32 takes tens of seconds on 2 cores,
        # so the quick run measures a smaller batch there (samples/s is per sample anyway)
        batch = 32 if size <= 320 or not args.quick else 4
        steps = (2 if args.quick else 5) if size <= 320 else (1 if args.quick else 2)
        r = bench_training(size, batch, max(threads), steps)
        training.append(r)
        print(f"training {size:>4}px batch {batch}: {r['ms_per_batch']:.1f} ms/batch, "
              f"{r['samples_per_s']:.1f} samples/s", flush=True)

    result = {"inference": inference, "shipped": shipped, "training": training,
              "env": {"torch": torch.__version__, "python": platform.python_version(),
                      "machine": platform.machine(), "processor": platform.processor(),
                      "quick": args.quick, "seconds": round(time.monotonic() - t_start, 1)}}
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    print(f"done in {result['env']['seconds']} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
