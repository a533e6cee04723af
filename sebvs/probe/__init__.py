"""What a recording's streams hold, measured before any policy (docs/probe.md).

    from sebvs.probe import Recipe, load_frames, probe
    frames = load_frames("datasets/probe/still/hdr__indoor")
    probe(frames, "event", Recipe(), seed=0)["error_px"]["median"]

A small CNN (sebvs/probe/model.py), the same for every sensor and cell, is trained on a
recording's frames as a policy of that modality sees them (sebvs.policy.inputs), with the
sim's truth (the target's centroid and visibility) as labels, and measured on episodes it
never trained on (sebvs/probe/fit.py), beside the no-information baselines. Where the
probe cannot localise the target from a stream, a policy reading that stream alone cannot
be expected to servo on it either: the stream, not the learner, is short. `sebvs probe`
runs it over datasets (sebvs/probe/cli.py).

The names below are imported on first use, so that `sebvs`'s command line, which registers
`sebvs probe`, does not pay for OpenCV and the policy inputs on every command.
"""
from __future__ import annotations

import importlib

_NAMES = {"SENSORS": "data", "Frames": "data", "ProbeDataError": "data",
          "load_frames": "data", "Recipe": "fit", "probe": "fit", "roc_auc": "fit"}

__all__ = sorted(_NAMES)


def __getattr__(name: str):
    if name in _NAMES:
        return getattr(importlib.import_module(f".{_NAMES[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
