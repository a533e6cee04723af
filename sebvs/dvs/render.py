"""Accumulated event frames as pictures: ON blue, OFF red, on white."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .accumulator import EventAccumulator, EventGeometry
from .eventfile import read_events


# the count at which event_image's colour is full
FULL_COUNT = 4


def event_counts(frame: np.ndarray, representation: str = "counts") -> np.ndarray:
    """An accumulator's frame as [2, H, W] ON/OFF counts, whatever its representation:
    what event_image draws.

    Parameters:
        frame: counts [2, H, W], kept as is; histogram [2K, H, W] (ON bins then OFF
            bins), summed per polarity; voxel [K, H, W] (signed), summed over bins, its
            positive part ON and its negative part OFF; time_surface [2, H, W] (255 for an
            event at the window's end, decaying with its age), scaled so that a fresh
            event draws in full colour and an old one fades, not every pixel the episode
            ever saw at full colour.
        representation: the accumulator's name for it (its frames' meta says it).

    Returns:
        [2, H, W] counts (or count-like floats); ValueError, in one line, for a frame
        whose planes cannot be ON then OFF.
    """
    frame = np.asarray(frame)
    if frame.ndim != 3:
        raise ValueError(f"an event frame is [C, H, W], got shape {frame.shape}")
    if representation == "voxel":
        total = frame.astype(np.float32).sum(axis=0)
        return np.stack([np.maximum(total, 0), np.maximum(-total, 0)])
    if frame.shape[0] % 2:
        raise ValueError(f"a {representation} frame has an even number of planes (ON "
                         f"then OFF), got {frame.shape[0]}")
    if representation == "time_surface":
        return frame.astype(np.float32) * (FULL_COUNT / 255.0)
    k = frame.shape[0] // 2
    if k == 1:
        return frame
    wide = frame.astype(np.uint32)
    return np.stack([wide[:k].sum(axis=0), wide[k:].sum(axis=0)])


def event_image(counts: np.ndarray) -> np.ndarray:
    """[2, H, W] counts -> [H, W, 3] uint8 RGB: ON blue, OFF red, both purple."""
    on, off = (np.minimum(counts[i].astype(np.float32), FULL_COUNT) / FULL_COUNT
               for i in (0, 1))
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
