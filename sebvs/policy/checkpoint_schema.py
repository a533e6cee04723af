"""What a checkpoint's JSON config must hold, checked before a model is built from it.

    fields, norm = validate_config(json.loads(text), "ck/nav-event.json")

Nothing in a config is trusted: it decides how big a model `load_checkpoint` allocates and
how the actor prepares its input. Each field is type- and range-checked with the topology
parameters' scheme (``Annotated[T, Range(...)]``, sebvs/runtime/params.py), then the
fields against each other (channels and their order follow the modality and the event
bins, the normalisation's size is the model's). Every refusal is a ValueError of one line
naming the file and the key; checkpoint.py raises it as a CheckpointError.

Required: version, task, modality, size, channels, channel_order, normalisation.
Optional: stem ("patch" where absent: configs written before the conv stem existed),
memory ("none") and aux (false) where absent (configs written before the recurrent state
and the target head existed), and
the record emulator {"preset", "preset_version"} (the event emulator the training data
was recorded with; where absent, preset_version 1: the shipped checkpoints'). Other keys
(dataset, training, target_stats, event_frames, ...) are records, not read to build the
model, and are left to their readers.
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal, Optional

from sebvs.dvs.params import PRESET_VERSIONS
from sebvs.runtime.params import Range, clip, coerce_param, short_repr

from .inputs import MAX_SIZE, Modality, Normalisation

CONFIG_VERSION = 1
# ERP's patch side (model.ERP's default): no config records it, every checkpoint uses it
PATCH = 16
MAX_CONFIG_BYTES = 1 << 20     # shipped configs are under 40 kB (their episode lists)
FUSION_STEMS = ("dual", "gated")     # a stem per modality: rgb+event inputs only


def check_stem(stem: str, modality: Modality | str) -> None:
    """ValueError unless ``stem`` can embed ``modality``'s input: the dual and gated stems
    fuse rgb with events, so they take rgb+event alone (rgb+diff has as many planes, so
    the stem's own channel check would let it through)."""
    modality = Modality.parse(modality)
    if stem in FUSION_STEMS and modality is not Modality.RGB_EVENT:
        raise ValueError(f"the {stem} stem fuses rgb and event planes: it needs modality "
                         f"rgb+event, not {modality}")


def _fields() -> dict[str, Any]:
    """Key -> type of the fields a model is built from (model.py read lazily: torch)."""
    from .model import MEMORIES, STEMS, TASK_OUTPUTS
    return {"version": Literal[CONFIG_VERSION],
            "task": Literal[tuple(TASK_OUTPUTS)],
            "modality": Literal[tuple(m.value for m in Modality)],
            "size": Annotated[int, Range(ge=PATCH, le=MAX_SIZE)],
            "stem": Literal[tuple(STEMS)],
            "memory": Literal[tuple(MEMORIES)],
            "aux": bool,
            "channels": Annotated[int, Range(ge=1, le=3 + 2 * 64)],
            "channel_order": list[str],
            "normalisation": dict}


# where absent, a config written before the field existed: the paper's architecture
OPTIONAL = {"stem": "patch", "memory": "none", "aux": False}
# the emulator record (train.py writes it for modalities with events), key -> type; its
# preset_version is what an evaluation runs the emulator's noise model at
EMULATOR_FIELDS = {"preset": Optional[str], "preset_version": Literal[PRESET_VERSIONS]}


def validate_config(cfg: Any, path: str | Path) -> tuple[dict, Normalisation]:
    """Check a checkpoint config before anything is allocated from it: `check_fields`,
    then `check_consistency`.

    Parameters:
        cfg: the parsed JSON (checkpoint.read_config).
        path: the config file, named in every error.

    Returns:
        (the fields a model is built from, the optional ones filled in and the
        normalisation as Normalisation.to_dict gives it, its Normalisation). ValueError of
        one line, naming the file and the key, for the first field that is missing, of
        the wrong type, out of range or inconsistent with another.
    """
    fields, norm = check_fields(cfg, path)
    check_consistency(fields, norm, path)
    return fields, norm


def check_fields(cfg: Any, path: str | Path) -> tuple[dict, Normalisation]:
    """Each field on its own: present (or optional), of its type, within its range.
    What bounds an allocation (the size) is checked here.

    Parameters:
        cfg: the parsed JSON.
        path: the config file, named in every error.

    Returns:
        As `validate_config`, the fields not yet checked against each other.
    """
    where = f"checkpoint config {path}"
    if not isinstance(cfg, dict):
        raise ValueError(f"{where}: expected a JSON object, got {type(cfg).__name__}")
    fields = {}
    for key, tp in _fields().items():
        if key not in cfg and key not in OPTIONAL:
            raise ValueError(f"{where}: {key} is missing")
        fields[key] = coerce_param(tp, cfg.get(key, OPTIONAL.get(key)),
                                   where=f"{where}: {key}")
    if fields["size"] % PATCH:
        raise ValueError(f"{where}: size: {fields['size']} is not a multiple of the patch "
                         f"size {PATCH}")
    norm = Normalisation.from_dict(fields["normalisation"], where=f"{where}: normalisation")
    fields["normalisation"] = norm.to_dict()
    if "emulator" in cfg:
        check_emulator(cfg["emulator"], f"{where}: emulator")
    return fields, norm


def check_emulator(record: Any, where: str) -> dict:
    """A config's emulator record, each key in its type: "preset" a name (or null where
    the recording did not say), "preset_version" 1 or 2 (required); no other key.

    Parameters:
        record: the config's "emulator" value.
        where: what it is, for errors (each names ``<where>.<key>``).

    Returns:
        The record, preset filled in as None where absent. ValueError, one line, naming
        the key that is missing, unknown or of the wrong type.
    """
    if not isinstance(record, dict):
        raise ValueError(f"{where}: expected a table, got {type(record).__name__} "
                         f"{short_repr(record)}")
    unknown = sorted((k for k in record if k not in EMULATOR_FIELDS), key=str)
    if unknown:
        raise ValueError(f"{where}.{clip(str(unknown[0]), 80)}: unknown key (known: "
                         f"{', '.join(EMULATOR_FIELDS)})")
    if "preset_version" not in record:
        raise ValueError(f"{where}.preset_version: missing")
    return {k: coerce_param(tp, record.get(k), where=f"{where}.{k}")
            for k, tp in EMULATOR_FIELDS.items()}


def check_consistency(fields: dict, norm: Normalisation, path: str | Path) -> None:
    """The fields against each other: the normalisation's size is the model's, the stem
    can embed the modality, channels and their order are the modality's with its event
    bins. ValueError of one line naming the file and the key.

    Parameters:
        fields, norm: what `check_fields` returned.
        path: the config file, named in every error.
    """
    where = f"checkpoint config {path}"
    size, modality = fields["size"], Modality.parse(fields["modality"])
    if norm.size != size:
        raise ValueError(f"{where}: normalisation.size: {norm.size} is not the model's size "
                         f"{size}")
    try:
        check_stem(fields["stem"], modality)
    except ValueError as exc:
        raise ValueError(f"{where}: stem: {exc}") from None
    want = modality.channels(norm.event_bins)
    if fields["channels"] != want:
        raise ValueError(f"{where}: channels: {fields['channels']} do not match modality "
                         f"{modality!r} with {norm.event_bins} event bin(s) ({want})")
    order = modality.channel_names(norm.event_bins)
    if fields["channel_order"] != order:
        raise ValueError(f"{where}: channel_order: {short_repr(fields['channel_order'])} is "
                         f"not modality {modality!r}'s with {norm.event_bins} event bin(s) "
                         f"({order})")
