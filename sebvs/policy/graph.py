"""How a loaded ERP runs at inference: the eager module as trained, or a frozen graph.

    run, used, why = inference_graph(model, torch.zeros(1, C, S, S), "frozen")
    y = run(x)            # used: "frozen", or "eager" with why it could not be frozen

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
    """The callable to run ``model`` (eval mode) on inputs shaped like ``example`` [1, C, S, S].

    Returns (fn, graph used, why the requested graph was not used or None). ``fn`` takes
    and returns tensors as ``model`` does; call it under ``torch.inference_mode()``.
    """
    check_graph(graph)
    if graph == "eager":
        return model, "eager", None
    import torch
    try:
        with warnings.catch_warnings():
            # TorchScript's deprecation notice, and the tracer's note that the model's
            # input-shape check becomes a constant: the graph only ever sees this shape
            warnings.simplefilter("ignore")
            with torch.inference_mode():
                traced = torch.jit.trace(model, example, check_trace=False)
                frozen = torch.jit.optimize_for_inference(torch.jit.freeze(traced.eval()))
    except Exception as exc:    # an old or future torch, an operator the tracer refuses
        return model, "eager", f"cannot freeze: {type(exc).__name__}: {str(exc)[:200]}"
    gen = torch.Generator().manual_seed(0)
    checks = (example, torch.rand(example.shape, generator=gen, dtype=example.dtype))
    with torch.inference_mode():
        diff = max(float((frozen(x) - model(x)).abs().max()) for x in checks)
    if not diff <= FROZEN_ATOL:     # NaN included
        return model, "eager", (f"frozen graph differs from eager by {diff:.3g} "
                                f"(> {FROZEN_ATOL:g})")
    return frozen, "frozen", None
