"""A training's state at the end of each epoch, so that a stopped training goes on from
there and ends with the same weights, bit for bit, as one that never stopped.

    path = resume_path("ck", "nav", "event")            # ck/nav-event.resume.pt
    state = load_state(path, fingerprint(settings, "event", digest))   # or None
    save_state(path, {"fingerprint": ..., "epoch": 3, "model": ..., ...})

The state holds the model, the optimizer, the learning-rate schedule, the shuffle's and
torch's random generators, the loss rows and the early stopping's bookkeeping. It is
written atomically after every epoch, continued only by the same settings on the same
data (its fingerprint: the content of what the training reads, `dataset.content_digest`,
so a recording made again from the same commands continues it), removed once the
checkpoint is written, and holds tensors and plain values only (``torch.load(...,
weights_only=True)``). Version 2; a version-1 file named the files' hash, and is not
continued. docs/policy.md, "A stopped training goes on".
"""
from __future__ import annotations

import json
import os
from dataclasses import asdict
from pathlib import Path

RESUME_VERSION = 2
RESUME_SUFFIX = ".resume.pt"    # <task>-<modality> + this, beside the checkpoint it becomes
# settings that change how long the epochs take but not the weights (tested: the loader
# workers and the frames cache leave every weight bit for bit the same)
NOT_IN_FINGERPRINT = ("num_workers", "cache")
# settings added after resume files were written: in the fingerprint only where they differ
# from their default, so that a file written before them still continues its training
ADDED_SETTINGS = {"zero_subnormals": False, "memory": "none", "aux_weight": 0.0,
                  "modality_dropout": 0.0, "seq_len": 2, "lanes": 32,
                  "burn_in": 6}


def resume_path(out: str | Path, task: str, modality) -> Path:
    """``<out>/<task>-<modality>.resume.pt`` (``modality`` a Modality or its name)."""
    return Path(out) / f"{task}-{modality}{RESUME_SUFFIX}"


def fingerprint(settings, modality, content: str) -> str:
    """What must match for a saved state to continue this training: the settings that
    decide the weights, the modality (a Modality or its name: the name either way) and
    the content digest of the data it reads."""
    fields = {k: v for k, v in asdict(settings).items() if k not in NOT_IN_FINGERPRINT
              and not (k in ADDED_SETTINGS and v == ADDED_SETTINGS[k])}
    return json.dumps({"version": RESUME_VERSION, "modality": str(modality), "data": content,
                       "settings": fields}, sort_keys=True, default=str)


class NonFiniteState(ValueError):
    """A training state holding a NaN or infinite float: not saved, nothing to go on from."""


def first_non_finite(tree, prefix: str = "") -> str | None:
    """The path ("model/embed.proj.weight") of the first floating tensor in ``tree`` (a
    tensor, or dicts and lists of them and plain values) holding a NaN or an infinity,
    or None when every one is finite. One reduction per tensor: cheap next to an epoch.

    Parameters:
        tree: a state_dict, an optimizer's state_dict, a training state.
        prefix: the path of ``tree`` itself, put before the paths it returns.

    Returns:
        The path, or None.
    """
    import torch
    if isinstance(tree, torch.Tensor):
        if tree.is_floating_point() or tree.is_complex():
            return None if bool(torch.isfinite(tree).all()) else (prefix or "tensor")
        return None
    if isinstance(tree, dict):
        items = tree.items()
    elif isinstance(tree, (list, tuple)):
        items = enumerate(tree)
    else:
        return None
    for key, value in items:
        found = first_non_finite(value, f"{prefix}/{key}" if prefix else str(key))
        if found is not None:
            return found
    return None


def save_state(path: Path, state: dict) -> None:
    """Write ``state`` so that a reader sees the previous epoch's file or this one, never
    half of one (a stop during the write leaves the old file). A state with a non-finite
    tensor raises NonFiniteState and leaves the previous file: continued, it could only
    train on from NaN."""
    import torch
    bad = first_non_finite(state)
    if bad is not None:
        raise NonFiniteState(f"{path.name}: not written, {bad} is not finite")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)


def load_state(path: Path, expected: str, log=print) -> dict | None:
    """The saved state when it continues this training, else None (with one line saying
    why it is not used, when a file is there)."""
    import torch
    if not path.exists():
        return None
    try:
        state = torch.load(path, weights_only=True)
    except Exception as exc:     # truncated, not a torch file, or holding other objects
        log(f"  {path.name}: unreadable ({str(exc).splitlines()[0][:120]}); training from "
            f"the start")
        return None
    if not isinstance(state, dict) or state.get("fingerprint") != expected:
        log(f"  {path.name}: made by other settings or data; training from the start")
        return None
    bad = first_non_finite(state)
    if bad is not None:     # written before save_state refused them
        log(f"  {path.name}: {bad} is not finite; training from the start")
        return None
    return state
