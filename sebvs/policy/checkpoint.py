"""Checkpoints: ``<task>-<modality>.pt`` (a state_dict) beside ``<task>-<modality>.json`` (config).

    save_checkpoint(model, {**model_config("nav", "event", norm), ...}, "ck")
    model, cfg, norm = load_checkpoint("ck/nav-event.pt", expect={"task": "nav"})

The weights are a plain state_dict, read back with ``torch.load(weights_only=True)``: no
pickled code runs when a checkpoint is opened. What rebuilds the model and prepares its
input (task, modality, size, channels, normalisation) is in the JSON config, validated
before anything is allocated from it (checkpoint_schema.py). The state_dict also holds
``CONFIG_RECORD``, the architecture and input fields of the config it was saved with:
the size, the modality and the normalisation change no weight's shape, so a config edited
away from its weights (320 px beside weights trained at 160) would otherwise load and run
on inputs the model never saw. Checkpoints saved before the record load without that
check. docs/policy.md, "Training".
"""
from __future__ import annotations

import json
import pickle
from pathlib import Path

from sebvs.runtime.params import short_repr

from .checkpoint_schema import (CONFIG_VERSION, MAX_CONFIG_BYTES, check_consistency,
                                check_fields, validate_config)
from .inputs import Modality, Normalisation
from .resume import RESUME_SUFFIX, first_non_finite

# the state_dict key of the config record; no module attribute can be named so (a dot-free
# name with a leading underscore is not a parameter or buffer path of ERP)
CONFIG_RECORD = "_sebvs_config"
RECORDED = ("task", "modality", "size", "stem", "memory", "aux", "channels", "channel_order",
            "normalisation")


class CheckpointError(ValueError):
    """A checkpoint or its config that cannot be used; the message names the file."""


def checkpoint_paths(out_dir: str | Path, task: str, modality: Modality | str
                     ) -> tuple[Path, Path]:
    """``<out_dir>/<task>-<modality>.pt`` and the ``.json`` beside it."""
    stem = Path(out_dir) / f"{task}-{modality}"
    return stem.with_suffix(".pt"), stem.with_suffix(".json")


def checkpoints_in(directory: str | Path) -> list[Path]:
    """The checkpoints in a directory, sorted: every ``*.pt`` but a stopped training's
    resume state (``*.resume.pt``, sebvs/policy/resume.py), which is not a model."""
    return sorted(p for p in Path(directory).glob("*.pt") if not p.name.endswith(RESUME_SUFFIX))


def save_checkpoint(model, config: dict, out_dir: str | Path) -> Path:
    """Write the state_dict (with its config record) and its config; returns the .pt path.

    Refused, with nothing written and an earlier checkpoint of that name left as it was,
    when a weight is not finite or the config does not describe the model.
    """
    import torch
    pt, js = checkpoint_paths(out_dir, config["task"], config["modality"])
    written = {"version": CONFIG_VERSION, **config}
    try:    # a checkpoint that load_checkpoint would refuse is not written
        validate_config(written, js)
    except ValueError as exc:
        raise CheckpointError(f"not written: {exc}") from None
    state = model.state_dict()
    bad = first_non_finite(state)
    if bad is not None:
        raise CheckpointError(f"checkpoint {pt}: not written, weight {bad} is not finite")
    # what the model itself says it is, where it says it (ERP does), over the config's word
    for key, attr in (("task", "task"), ("size", "size"), ("stem", "stem"),
                      ("memory", "memory"), ("aux", "aux"), ("channels", "in_channels")):
        if hasattr(model, attr) and key in config and config[key] != getattr(model, attr):
            raise CheckpointError(f"checkpoint {pt}: not written, config {key} "
                                  f"{config[key]!r} is not the model's {getattr(model, attr)!r}")
    record = json.dumps({k: config[k] for k in RECORDED if k in config}, sort_keys=True)
    state[CONFIG_RECORD] = torch.tensor(list(record.encode()), dtype=torch.uint8)
    pt.parent.mkdir(parents=True, exist_ok=True)
    torch.save(state, pt)
    js.write_text(json.dumps(written, indent=2) + "\n")
    return pt


def model_config(task: str, modality: Modality | str, norm: Normalisation,
                 stem: str = "patch", memory: str = "none", aux: bool = False) -> dict:
    """The part of a config that decides the architecture and its input (the modality by
    its name, as the JSON holds it)."""
    modality = Modality.parse(modality)
    return {"task": task, "modality": modality.value, "size": norm.size, "stem": stem,
            "memory": memory, "aux": bool(aux),
            "channels": modality.channels(norm.event_bins),
            "channel_order": modality.channel_names(norm.event_bins),
            "normalisation": norm.to_dict()}


def read_config(pt_path: str | Path) -> dict:
    """The JSON object beside a checkpoint, as it is: read, not validated (its readers
    want a field or two; load_checkpoint validates the whole before building a model).

    Parameters:
        pt_path: the checkpoint's .pt path; its config is the .json beside it.

    Returns:
        The config. FileNotFoundError when it is missing; CheckpointError, naming the
        file, when it is over MAX_CONFIG_BYTES, not UTF-8 JSON, too deeply nested for the
        parser, or not an object.
    """
    js = Path(pt_path).with_suffix(".json")
    if not js.exists():
        raise FileNotFoundError(f"checkpoint {pt_path}: its config {js.name} is missing")
    with open(js, "rb") as f:
        raw = f.read(MAX_CONFIG_BYTES + 1)
    if len(raw) > MAX_CONFIG_BYTES:
        raise CheckpointError(f"checkpoint config {js}: over {MAX_CONFIG_BYTES:,} bytes, "
                              f"not a config")
    try:
        cfg = json.loads(raw.decode("utf-8"))
    except RecursionError:
        raise CheckpointError(f"checkpoint config {js}: too deeply nested to read") from None
    except ValueError as exc:   # not UTF-8, or not JSON
        raise CheckpointError(f"checkpoint config {js}: unreadable ({_first_line(exc)})") \
            from None
    if not isinstance(cfg, dict):
        raise CheckpointError(f"checkpoint config {js}: expected a JSON object")
    return cfg


def _first_line(exc: BaseException, limit: int = 200) -> str:
    text = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return text if len(text) <= limit else text[:limit] + "..."


def _read_record(state: dict, pt_path: Path) -> dict | None:
    """Pop the config record out of a state_dict -> the fields it was saved with, or None
    for a checkpoint saved before records existed."""
    import torch
    record = state.pop(CONFIG_RECORD, None)
    if record is None:
        return None
    try:
        if not (isinstance(record, torch.Tensor) and record.dtype == torch.uint8
                and record.dim() == 1 and record.numel() <= MAX_CONFIG_BYTES):
            raise ValueError("not a short uint8 vector")
        fields = json.loads(bytes(record.tolist()).decode("utf-8"))
        if not isinstance(fields, dict):
            raise ValueError("not a JSON object")
    except (ValueError, RecursionError) as exc:
        raise CheckpointError(f"checkpoint {pt_path}: damaged, its {CONFIG_RECORD} entry is "
                              f"unreadable ({_first_line(exc)})") from None
    return fields


def _check_record(record: dict, fields: dict, pt_path: Path, js: Path) -> None:
    """CheckpointError naming the first key where the config (validated ``fields``) says
    other than the config the weights were saved with (``record``)."""
    # in RECORDED's order: a modality named wrong says more than the channel names it implies
    pairs = [(k, fields[k], record[k]) for k in RECORDED if k in record and k != "normalisation"]
    if isinstance(record.get("normalisation"), dict):
        pairs += [(f"normalisation.{k}", fields["normalisation"].get(k), v)
                  for k, v in record["normalisation"].items()]
    for key, now, then in pairs:
        if now != then:
            raise CheckpointError(
                f"checkpoint {pt_path}: weights do not match the config (task "
                f"{fields['task']}, modality {fields['modality']}, size {fields['size']}, "
                f"stem {fields['stem']}): {key} is {short_repr(now)} in {js.name}, but the "
                f"weights were saved with {key} {short_repr(then)}")


def load_checkpoint(pt_path: str | Path, *, expect: dict | None = None):
    """Rebuild an ERP from a checkpoint -> (model in eval mode, config dict, Normalisation).

    Each field of the config is type- and range-checked first (checkpoint_schema), so that
    no hostile or mistaken value reaches torch; ``expect`` (e.g. {"task": "nav",
    "modality": "event"}) is then checked against it; the weights are read, and the config
    compared with the one they were saved with (CONFIG_RECORD), its fields with each other
    and, by load_state_dict, the weights' shapes with the architecture it describes. Any
    refusal is a CheckpointError (a ValueError) of one line naming the file and the key.
    """
    import torch

    from .model import ERP
    pt_path = Path(pt_path)
    js = pt_path.with_suffix(".json")
    cfg = read_config(pt_path)
    try:    # each field in its type and range: nothing below allocates more than they say
        fields, norm = check_fields(cfg, js)
    except ValueError as exc:
        raise CheckpointError(str(exc)) from None
    for key, want in (expect or {}).items():
        if cfg.get(key) != want:
            raise CheckpointError(f"checkpoint {pt_path}: config has {key}="
                                  f"{short_repr(cfg.get(key))}, expected {want!r}")
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
    # before the fields are checked against each other: where a config was edited away
    # from its weights, what the weights were saved with says more than an inconsistency
    record = _read_record(state, pt_path)
    if record is not None:
        _check_record(record, fields, pt_path, js)
    try:
        check_consistency(fields, norm, js)
    except ValueError as exc:
        raise CheckpointError(str(exc)) from None
    describes = (f"task {fields['task']}, modality {fields['modality']}, size "
                 f"{fields['size']}, stem {fields['stem']}")
    try:
        model = ERP(fields["task"], fields["channels"], fields["size"], stem=fields["stem"],
                    memory=fields["memory"], aux=fields["aux"])
    except ValueError as exc:   # validated above: a stem that refuses these channels
        raise CheckpointError(f"checkpoint config {js}: {_first_line(exc)}") from None
    try:
        model.load_state_dict(state)
    except (RuntimeError, TypeError, AttributeError) as exc:
        raise CheckpointError(f"checkpoint {pt_path}: weights do not match the config "
                              f"({describes}): {_first_line(exc)}") from None
    model.eval()
    return model, cfg, norm
