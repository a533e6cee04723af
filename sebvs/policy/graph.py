"""How a loaded ERP runs at inference: the eager module as trained, or a frozen graph.

    run, used, why = inference_graph(model, torch.zeros(1, C, S, S), "frozen")
    y = run(x)            # used: "frozen", or "eager" with why it could not be frozen
    step, used, why = inference_graph(step_module(recurrent), (x, state), "frozen")
    y, state = step(x, state)         # a model with memory: one tick and its state

eager   model(x): the arithmetic of training's validation pass, so a lockstep evaluation
        reproduces bit for bit. The default.
frozen  the model traced at its one input shape [1, C, S, S], frozen (weights become
        constants, BatchNorm folded into the convolution before it) and optimised for
        inference: outputs within FROZEN_ATOL of eager (about 1e-7 on the shipped
        checkpoints, checked when built), not bit for bit, and a cold call (a realtime
        control tick after 0.1 s idle) 1.86 -> 1.37 ms for the shipped nav rgb+event at
        160 px, one thread.

Where the torch at hand cannot freeze the model, or the frozen graph disagrees with eager,
``inference_graph`` says why and returns the eager module. Why frozen, the measurements,
and why TorchScript rather than torch.compile: docs/policy.md, "Inference graphs".
"""
from __future__ import annotations

import warnings
from typing import Callable

GRAPHS = ("eager", "frozen")
FROZEN_ATOL = 1e-4     # largest |frozen - eager| accepted on the check inputs


def check_graph(graph: object) -> str:
    if graph not in GRAPHS:
        raise ValueError(f"unknown inference graph {graph!r} (one of {', '.join(GRAPHS)})")
    return graph


def inference_graph(model, example, graph: str = "eager") -> tuple[Callable, str, str | None]:
    """The callable to run ``model`` (eval mode) on inputs shaped like ``example``:
    x [1, C, S, S], or a tuple of tensors (a recurrent step's (x, state), `step_module`).

    Returns (fn, graph used, why the requested graph was not used or None). ``fn`` takes
    and returns tensors as ``model`` does; call it under ``torch.inference_mode()``.
    """
    check_graph(graph)
    if graph == "eager":
        return model, "eager", None
    import torch
    args = example if isinstance(example, tuple) else (example,)
    try:
        with warnings.catch_warnings():
            # TorchScript's deprecation notice, and the tracer's note that the model's
            # input-shape check becomes a constant: the graph only ever sees this shape
            warnings.simplefilter("ignore")
            with torch.inference_mode():
                traced = torch.jit.trace(model, args, check_trace=False)
                frozen = torch.jit.optimize_for_inference(torch.jit.freeze(traced.eval()))
    except Exception as exc:    # an old or future torch, an operator the tracer refuses
        return model, "eager", f"cannot freeze: {type(exc).__name__}: {str(exc)[:200]}"
    gen = torch.Generator().manual_seed(0)
    checks = (args, tuple(torch.rand(a.shape, generator=gen, dtype=a.dtype) for a in args))
    with torch.inference_mode():
        diff = max(_largest_difference(frozen(*a), model(*a)) for a in checks)
    if not diff <= FROZEN_ATOL:     # NaN included
        return model, "eager", (f"frozen graph differs from eager by {diff:.3g} "
                                f"(> {FROZEN_ATOL:g})")
    return frozen, "frozen", None


def _largest_difference(a, b) -> float:
    """max |a - b| over a tensor or a tuple of tensors (NaN where any is NaN)."""
    pairs = zip(a, b) if isinstance(a, tuple) else ((a, b),)
    return max(float((x - y).abs().max()) if x.numel() else 0.0 for x, y in pairs)


def step_module(model):
    """A recurrent ERP's one tick as a module of its own, for `inference_graph`:
    forward(x [1, C, S, S], state [1, D]) -> (action, next state) = model.step(x, state).
    (A function: the class is made where torch is, and torch only where a policy runs.)"""
    from torch import nn

    class ERPStep(nn.Module):
        def __init__(self, inner):
            super().__init__()
            self.inner = inner

        def forward(self, x, state):
            return self.inner.step(x, state)

    return ERPStep(model).eval()
