"""Checkpoints: ``<task>-<modality>.pt`` (a state_dict) beside ``<task>-<modality>.json`` (config).

The weights are a plain state_dict saved with torch.save and read back with
``torch.load(weights_only=True)``: no pickled code runs when a checkpoint is opened.
Everything needed to rebuild the model and prepare its input (task, modality, size,
channels, normalisation) is in the JSON config.
"""
from __future__ import annotations

import json
import pickle
from pathlib import Path

from .inputs import Normalisation, channel_names, channels, check_modality
from .resume import RESUME_SUFFIX

CONFIG_VERSION = 1


class CheckpointError(ValueError):
    """A checkpoint or its config that cannot be used; the message names the file."""


def checkpoint_paths(out_dir: str | Path, task: str, modality: str) -> tuple[Path, Path]:
    stem = Path(out_dir) / f"{task}-{modality}"
    return stem.with_suffix(".pt"), stem.with_suffix(".json")


def checkpoints_in(directory: str | Path) -> list[Path]:
    """The checkpoints in a directory, sorted: every ``*.pt`` but a stopped training's
    resume state (``*.resume.pt``, sebvs/policy/resume.py), which is not a model."""
    return sorted(p for p in Path(directory).glob("*.pt") if not p.name.endswith(RESUME_SUFFIX))


def save_checkpoint(model, config: dict, out_dir: str | Path) -> Path:
    """Write the state_dict and its config; returns the .pt path."""
    import torch
    pt, js = checkpoint_paths(out_dir, config["task"], config["modality"])
    pt.parent.mkdir(parents=True, exist_ok=True)
    torch.save(model.state_dict(), pt)
    js.write_text(json.dumps({"version": CONFIG_VERSION, **config}, indent=2) + "\n")
    return pt


def model_config(task: str, modality: str, norm: Normalisation, stem: str = "patch") -> dict:
    """The part of a config that decides the architecture and its input."""
    return {"task": task, "modality": modality, "size": norm.size, "stem": stem,
            "channels": channels(modality, norm.event_bins),
            "channel_order": channel_names(modality, norm.event_bins),
            "normalisation": norm.to_dict()}


def read_config(pt_path: str | Path) -> dict:
    js = Path(pt_path).with_suffix(".json")
    if not js.exists():
        raise FileNotFoundError(f"checkpoint {pt_path}: its config {js.name} is missing")
    try:
        cfg = json.loads(js.read_text(encoding="utf-8"))
    except ValueError as exc:   # not UTF-8, or not JSON
        raise CheckpointError(f"checkpoint config {js}: unreadable ({_first_line(exc)})") \
            from None
    if not isinstance(cfg, dict):
        raise CheckpointError(f"checkpoint config {js}: expected a JSON object")
    return cfg


def _first_line(exc: BaseException, limit: int = 200) -> str:
    text = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return text if len(text) <= limit else text[:limit] + "..."


def load_checkpoint(pt_path: str | Path, *, expect: dict | None = None):
    """Rebuild an ERP from a checkpoint -> (model in eval mode, config dict, Normalisation).

    ``expect`` (e.g. {"task": "nav", "modality": "event"}) is checked against the config
    first; any difference, or weights that do not fit the architecture the config
    describes, raises ValueError naming the file and the field.
    """
    import torch

    from .model import ERP
    pt_path = Path(pt_path)
    cfg = read_config(pt_path)
    for key, want in (expect or {}).items():
        if cfg.get(key) != want:
            raise CheckpointError(f"checkpoint {pt_path}: config has {key}={cfg.get(key)!r}, "
                                  f"expected {want!r}")
    try:
        check_modality(cfg["modality"])
        norm = Normalisation.from_dict(cfg["normalisation"])
        want = channels(cfg["modality"], norm.event_bins)
        if cfg["channels"] != want:
            raise CheckpointError(f"checkpoint {pt_path}: {cfg['channels']} channels do not "
                                  f"match modality {cfg['modality']!r} with "
                                  f"{norm.event_bins} event bin(s) ({want})")
        if norm.size != cfg["size"]:
            raise CheckpointError(f"checkpoint {pt_path}: normalisation size {norm.size} != "
                                  f"size {cfg['size']}")
        # configs written before the conv stem existed have no "stem": theirs is the patch one
        model = ERP(cfg["task"], cfg["channels"], cfg["size"], stem=cfg.get("stem", "patch"))
    except CheckpointError:
        raise
    except (KeyError, TypeError, ValueError) as exc:   # a field missing or of the wrong kind
        raise CheckpointError(f"checkpoint config {pt_path.with_suffix('.json')}: "
                              f"{type(exc).__name__}: {_first_line(exc)}") from None
    try:
        state = torch.load(pt_path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        # torch's own message suggests weights_only=False: the one thing not to do here
        raise CheckpointError(f"checkpoint {pt_path}: refused, it holds pickled objects "
                              f"besides tensors (loading them could run code)") from None
    except Exception as exc:    # a truncated or foreign file fails in many ways
        raise CheckpointError(f"checkpoint {pt_path}: damaged or not a torch state_dict "
                              f"({type(exc).__name__}: {_first_line(exc)})") from None
    if not isinstance(state, dict):
        raise CheckpointError(f"checkpoint {pt_path}: holds a {type(state).__name__}, "
                              f"not a state_dict")
    try:
        model.load_state_dict(state)
    except (RuntimeError, TypeError, AttributeError) as exc:
        raise CheckpointError(f"checkpoint {pt_path}: weights do not match the config "
                              f"(task {cfg['task']}, modality {cfg['modality']}, size "
                              f"{cfg['size']}, stem {cfg.get('stem', 'patch')}): "
                              f"{_first_line(exc)}") from None
    model.eval()
    return model, cfg, norm
