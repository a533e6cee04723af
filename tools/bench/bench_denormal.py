#!/usr/bin/env python3
"""Subnormal weights and the speed of a training step (found in issue 38's study).

A nav RGB+Event training of the sensor study ran its eighth epoch three times slower than
its seventh. The cause: weights that get no gradient from the data (dead units) decay
under Adam's weight decay into float32's subnormal range (non-zero, below 1.18e-38), where
the CPU computes with them through slow microcode. This measures it on a saved training:

  - how many floats of the model, and of Adam's state, are subnormal, and in which tensors;
  - the time of one training step (forward, backward, Adam step on a batch of random
    inputs) and of one inference (batch 1), three ways side by side in every repeat (the
    order turning), medians over repeats: as trained (the CPU's flush-to-zero off, how the
    project trains and runs by default), `flush` (`torch.set_flush_denormal(True)`), and
    `zeroed` (`sebvs train --zero-subnormals`: the subnormals of the weights and of Adam's
    state set to zero before the step and after it, that work timed with the step);
  - the same steps on a freshly initialised model of the same architecture: the speed
    without subnormals;
  - whether flushing changes the inference outputs (bitwise, on the same inputs).

STATE is a `<task>-<modality>.resume.pt` (sebvs/policy/resume.py: model and Adam state,
the settings in its fingerprint) or a checkpoint `.pt` beside its `.json` (the model
only; the training step then starts from a fresh Adam state).

    tools/bench/bench_denormal.py STATE [--repeats 5] [--batch 32] [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from benchio import print_report  # noqa: E402
from sebvs.policy.subnormal import (count_subnormals, state_tensors,  # noqa: E402
                                    zero_subnormals_)

MODES = (("saved", "as_trained"), ("saved", "flush"), ("saved", "zeroed"),
         ("fresh", "as_trained"))


def load(path: Path):
    """(model, Adam optimizer state dict or None, a description) from a resume file or a
    checkpoint."""
    import torch

    from sebvs.policy.checkpoint import load_checkpoint
    from sebvs.policy.inputs import Normalisation, channels
    from sebvs.policy.model import ERP
    if path.name.endswith(".resume.pt"):
        state = torch.load(path, weights_only=True)
        key = json.loads(state["fingerprint"])
        s, modality = key["settings"], key["modality"]
        norm = Normalisation.from_dict(s["norm"])
        model = ERP(s["task"], channels(modality, norm.event_bins), norm.size, stem=s["stem"])
        model.load_state_dict(state["model"])
        return model, state["optimizer"], {
            "kind": "resume", "task": s["task"], "modality": modality, "epoch": state["epoch"],
            "lr": s["lr"], "weight_decay": s["weight_decay"]}
    model, cfg, _ = load_checkpoint(path)
    return model, None, {"kind": "checkpoint", "task": cfg["task"], "modality": cfg["modality"]}


def fresh_like(model):
    from sebvs.policy.model import ERP
    return ERP(model.task, model.in_channels, model.size, stem=model.stem)


def census(model, optimizer_state) -> dict:
    """Subnormal counts: the model's, Adam's, and the tensors that hold the most."""
    per_tensor = {k: (count_subnormals(v), v.numel()) for k, v in model.state_dict().items()
                  if v.is_floating_point()}
    adam = 0
    if optimizer_state is not None:
        adam = sum(count_subnormals(v) for v in state_tensors(optimizer_state["state"].values()))
    top = sorted(((k, n, size) for k, (n, size) in per_tensor.items() if n),
                 key=lambda r: -r[1])[:8]
    return {"model": sum(n for n, _ in per_tensor.values()),
            "model_floats": sum(size for _, size in per_tensor.values()),
            "adam_state": adam,
            "tensors": {k: f"{n} of {size}" for k, n, size in top}}


def step_ms(model, optimizer_state, lr, weight_decay, x, y, zero: bool = False) -> float:
    """One training step's time (forward, backward, Adam step; with ``zero``, the
    subnormals zeroed after it as training does, and once before the untimed first step),
    after one untimed step; the model and optimizer are copies, so every call starts from
    the same weights."""
    import copy

    import torch
    m = copy.deepcopy(model).train()
    opt = torch.optim.Adam(m.parameters(), lr=lr, weight_decay=weight_decay)
    if optimizer_state is not None:
        opt.load_state_dict(copy.deepcopy(optimizer_state))
    if zero:
        zero_subnormals_(m, opt)
    times = []
    for _ in range(2):
        t = time.perf_counter()
        opt.zero_grad()
        torch.nn.functional.mse_loss(m(x), y).backward()
        opt.step()
        if zero:
            zero_subnormals_(m, opt)
        times.append(time.perf_counter() - t)
    return times[-1] * 1e3


def infer_ms(model, x) -> tuple[float, object]:
    """Median time of a batch-1 inference over the rows of ``x``, and the outputs of all."""
    import torch
    model.eval()
    with torch.inference_mode():
        model(x[:1])
        times = []
        for i in range(x.shape[0]):
            t = time.perf_counter()
            model(x[i:i + 1])
            times.append(time.perf_counter() - t)
        return statistics.median(times) * 1e3, model(x).clone()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("state", type=Path, help="a <task>-<modality>.resume.pt or a checkpoint .pt")
    ap.add_argument("--repeats", type=int, default=5, help="repeats per variant (default 5)")
    ap.add_argument("--batch", type=int, default=32, help="training batch (default 32)")
    ap.add_argument("--threads", type=int, default=1,
                    help="torch threads (default 1, as the study's trainings)")
    ap.add_argument("--json", help="also write the report here")
    args = ap.parse_args(argv)
    import torch
    if not args.state.exists():
        ap.error(f"{args.state}: no such file")
    torch.set_num_threads(args.threads)
    model, adam, about = load(args.state)
    lr, wd = about.get("lr", 5e-4), about.get("weight_decay", 1e-4)
    g = torch.Generator().manual_seed(0)
    shape = (model.in_channels, model.size, model.size)
    x = torch.rand(args.batch, *shape, generator=g)
    with torch.no_grad():
        outputs_per_item = model.eval()(x[:1]).shape[1]
    y = 0.1 * torch.rand(args.batch, outputs_per_item, generator=g)
    fresh = fresh_like(model)
    zeroed = fresh_like(model)
    zeroed.load_state_dict(model.state_dict())
    zero_subnormals_(zeroed)
    runs = {mode: {"step_ms": [], "infer_ms": []} for mode in MODES}
    outputs = {}
    try:
        for r in range(args.repeats):
            for name, how in MODES[r % len(MODES):] + MODES[:r % len(MODES)]:   # turn
                torch.set_flush_denormal(how == "flush")
                m, state = (model, adam) if name == "saved" else (fresh, None)
                runs[name, how]["step_ms"].append(
                    step_ms(m, state, lr, wd, x, y, zero=how == "zeroed"))
                ms, out = infer_ms(zeroed if how == "zeroed" else m, x[:8])
                runs[name, how]["infer_ms"].append(ms)
                outputs[name, how] = out
    finally:
        torch.set_flush_denormal(False)
    med = {f"{name}_{how}": {k: round(statistics.median(v), 2) for k, v in t.items()}
           for (name, how), t in runs.items()}
    saved = med["saved_as_trained"]
    report = {
        "state": str(args.state), **about, "threads": args.threads, "batch": args.batch,
        "repeats": args.repeats,
        "subnormals": census(model, adam),
        "flush_to_zero_supported": torch.set_flush_denormal(False),
        "median_ms": med,
        "step_slowdown": {name: round(saved["step_ms"] / med[key]["step_ms"], 2)
                          for name, key in (("flush", "saved_flush"), ("zeroed", "saved_zeroed"),
                                            ("fresh", "fresh_as_trained"))},
        "inference_outputs_identical": {
            how: bool(torch.equal(outputs["saved", "as_trained"], outputs["saved", how]))
            for how in ("flush", "zeroed")},
    }
    print_report(report, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
