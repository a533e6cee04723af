"""Small statistics shared by actors, the profiler and the benchmarks."""
from __future__ import annotations

import numpy as np


def summarize(values, scale: float = 1.0) -> dict:
    """p50/p90/p99/max/mean and count of ``values`` multiplied by ``scale``."""
    a = np.asarray(values, dtype=np.float64) * scale
    if a.size == 0:
        return {"count": 0, "p50": None, "p90": None, "p99": None, "max": None, "mean": None}
    p50, p90, p99 = np.percentile(a, [50, 90, 99])
    return {"count": int(a.size), "p50": float(p50), "p90": float(p90), "p99": float(p99),
            "max": float(a.max()), "mean": float(a.mean())}
