"""Accumulated event frames as pictures: ON blue, OFF red, on white."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .accumulator import EventAccumulator, EventGeometry
from .eventfile import read_events


def event_image(counts: np.ndarray) -> np.ndarray:
    """[2, H, W] counts -> [H, W, 3] uint8 RGB: ON blue, OFF red, both purple."""
    on, off = (np.minimum(counts[i].astype(np.float32), 4) / 4 for i in (0, 1))
    img = np.ones(counts.shape[1:] + (3,), np.float32)
    img[..., 0] -= on          # less red where ON: blue
    img[..., 1] -= np.maximum(on, off)
    img[..., 2] -= off         # less blue where OFF: red
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def render_file(path: str | Path, out: str | Path, n: int = 6, window_ms: float = 33.0) -> int:
    """A row of `n` event frames spread over the file's duration, saved as a PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    events, attrs = read_events(path)
    if not events.size:
        raise ValueError(f"{path}: no events")
    geo = EventGeometry((int(attrs["width"]), int(attrs["height"])),
                        (int(attrs["width"]), int(attrs["height"])))
    t0, t1 = int(events["t"][0]), int(events["t"][-1])
    fig, axes = plt.subplots(1, n, figsize=(2.6 * n, 2.8), squeeze=False)
    for ax, t_end in zip(axes[0], np.linspace(t0 + window_ms * 1e6, t1, n)):
        acc = EventAccumulator(geo, "counts", window_s=window_ms / 1e3)
        acc.add(events)
        ax.imshow(event_image(acc.frame(int(t_end))))
        ax.set_title(f"t = {(t_end - t0) / 1e9:.2f} s", fontsize=8)
        ax.axis("off")
    fig.suptitle(f"{Path(path).name}: {events.size} events, {window_ms:g} ms windows "
                 f"(ON blue, OFF red)", fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return n
