"""The one place that turns raw observations into model input; training and the actor share it.

    m = Modality.parse("rgb+event")            # the modality's name, parsed once
    norm = Normalisation(size=160)              # as the checkpoint config records it
    x = model_input(m, norm, rgb=rgb, events=events)    # float32 [m.channels(), 160, 160]

rgb uint8 [H, W, 3] -> x / 255; events uint8 [2K, H, W] (K time bins per polarity, K = 1
the paper's ON/OFF counts) -> min(n, event_clip) / event_clip; rgb_prev, the previous
control tick's RGB frame (the control rgb+diff) -> its lin-log luma change, scaled as
event counts (`diff_input`). Each stream is area-resized to S x S on its own, events
clipped first. The streams are concatenated rgb first: rgb 3, event 2K, rgb+event 3 + 2K,
rgb+diff 3 + 2 channels. The shapes, the resizing and why: docs/policy.md, "Inputs".
"""
from __future__ import annotations

import functools
from dataclasses import asdict, dataclass
from enum import StrEnum
from typing import Annotated, Literal

import cv2
import numpy as np

from sebvs.dvs.emulator import linlog
from sebvs.dvs.params import PRESETS
from sebvs.runtime.params import Range, clip, coerce_param, param_fields, short_repr


class Modality(StrEnum):
    """A policy's input modality: the observation streams its model reads, in channel order.

    A str whose value is its name, so that it is the name wherever a name goes: JSON
    configs and results, ``<task>-<modality>.pt``, CLI choices, and the dict keys, set
    members and comparisons of code that still holds the bare string (``Modality.RGB ==
    "rgb"``, equal hashes, ``str``, ``format`` and ``repr`` as the name's).

        m = Modality.parse("rgb+event")       # ValueError, one line, for another name
        m.streams, m.channels(event_bins=4)    # ("rgb", "events"), 11
        m.is_control, m.has_events            # False, True
    """
    RGB = "rgb", ("rgb",), False
    EVENT = "event", ("events",), False
    RGB_EVENT = "rgb+event", ("rgb", "events"), False
    # a control: not one of the paper's modalities, but an input that tests a claim about
    # them. rgb+diff asks whether events give a policy more than a frame camera's own
    # change between two frames would (research/ideal8/events_vs_frame_difference.md).
    # Trained and evaluated when named; never part of "all" or of the default rows
    RGB_DIFF = "rgb+diff", ("rgb", "rgb_prev"), True

    def __new__(cls, name: str, streams: tuple[str, ...], is_control: bool):
        member = str.__new__(cls, name)
        member._value_ = name
        member.streams = streams          # observation streams read, in channel order
        member.is_control = is_control    # a control, not one of the paper's three
        return member

    @classmethod
    def parse(cls, value) -> "Modality":
        """The modality a name (or a Modality) names.

        Parameters:
            value: "rgb", "event", "rgb+event" or "rgb+diff", or a Modality.

        Returns:
            The Modality. ValueError of one line for any other value: ``unknown modality
            'x' (one of rgb, event, rgb+event, rgb+diff)``.
        """
        if isinstance(value, cls):
            return value
        return cls(value)

    @classmethod
    def _missing_(cls, value):
        # what Modality(name) raises for an unknown name: parse's one line, not Enum's
        raise ValueError(f"unknown modality {short_repr(value)} (one of "
                         f"{', '.join(m.value for m in cls)})")

    def __repr__(self) -> str:
        # the name's repr: messages that say {modality!r} read the same for a Modality
        # as for the string it replaced
        return repr(self.value)

    @property
    def has_events(self) -> bool:
        """Whether the model reads event frames (and so the emulator's output)."""
        return "events" in self.streams

    @property
    def reads_rgb(self) -> bool:
        """Whether the model reads RGB frames (its own tick's, or the previous one's)."""
        return "rgb" in self.streams or "rgb_prev" in self.streams

    @property
    def reads_previous_frame(self) -> bool:
        """Whether the model reads the previous control tick's RGB frame (rgb+diff)."""
        return "rgb_prev" in self.streams

    def channels(self, event_bins: int = 1) -> int:
        """Input channels of the model: rgb 3, event 2K, rgb+event 3 + 2K, rgb+diff 5.

        Parameters:
            event_bins: K, the event frames' time bins per polarity (1: ON, OFF counts).
        """
        return sum(_stream_channels(s, event_bins) for s in self.streams)

    def channel_names(self, event_bins: int = 1) -> list[str]:
        """The model's input channels in order: r, g, b, then on, off (counts) or
        on_t0 .. on_t{K-1}, off_t0 .. off_t{K-1} (time bins, oldest first), or up, down
        (the frame difference of rgb+diff).

        Parameters:
            event_bins: K, as for `channels`.
        """
        events = (["on", "off"] if event_bins == 1 else
                  [f"{p}_t{k}" for p in ("on", "off") for k in range(event_bins)])
        names = {"rgb": ["r", "g", "b"], "events": events, "rgb_prev": ["up", "down"]}
        return [c for s in self.streams for c in names[s]]


def _stream_channels(stream: str, event_bins: int) -> int:
    """Model input channels one observation stream becomes (rgb_prev: the frame difference)."""
    return {"rgb": 3, "events": 2 * event_bins, "rgb_prev": 2}[stream]


# The names as plain strings, for code that holds names (sebvs/eval, sebvs/demo.py, the
# actors, research/): the paper's three, the controls, and each name's streams
PAPER_MODALITIES = tuple(m for m in Modality if not m.is_control)
MODALITIES = tuple(m.value for m in PAPER_MODALITIES)
CONTROL_MODALITIES = tuple(m.value for m in Modality if m.is_control)
MODALITY_INPUTS = {m.value: m.streams for m in Modality}


# input sides by name: the CPU default (100 tokens) and the paper's (1600, for GPUs)
SIZE_PRESETS = {"cpu": 160, "paper": 640}
# the largest input side a Normalisation (and so a checkpoint) may name: twice the paper's.
# The positional table grows as (S/16)^2 and attention as its square, so a side far beyond
# it is a typo or a hostile config, not a model (48000 px took 2.3 GB before failing)
MAX_SIZE = 1280


def parse_size(value: str | int) -> int:
    """An input side S in px (a positive multiple of 16: the patch size) or a preset name;
    ValueError says which rule it breaks. `sebvs train --size` and sweep grids share it."""
    if isinstance(value, str) and value in SIZE_PRESETS:
        return SIZE_PRESETS[value]
    try:
        if isinstance(value, (bool, float)):
            raise ValueError
        size = int(value)
    except ValueError:
        raise ValueError(f"{value!r} is neither a size in pixels nor a preset "
                         f"({', '.join(SIZE_PRESETS)})") from None
    if size <= 0 or size % 16:
        raise ValueError(f"size {size} must be a positive multiple of 16")
    return size


def channels(modality: Modality | str, event_bins: int = 1) -> int:
    """`Modality.channels` of a modality or its name (ValueError for an unknown name)."""
    return Modality.parse(modality).channels(event_bins)


def channel_names(modality: Modality | str, event_bins: int = 1) -> list[str]:
    """`Modality.channel_names` of a modality or its name (ValueError for an unknown name)."""
    return Modality.parse(modality).channel_names(event_bins)


def check_modality(modality: Modality | str) -> None:
    """ValueError, one line, unless ``modality`` names a modality (`Modality.parse`)."""
    Modality.parse(modality)


@dataclass(frozen=True)
class Normalisation:
    """How raw frames become model input; recorded in the checkpoint config.

    Every field is type- and range-checked on construction (the topology parameters'
    ``Annotated[T, Range(...)]`` scheme, sebvs/runtime/params.py): a checkpoint's config
    is read back into one, and a NaN scale there would make every action NaN.
    """
    size: Annotated[int, Range(ge=1, le=MAX_SIZE)] = 160        # model input side S
    rgb_scale: Annotated[float, Range(gt=0, le=1)] = 1.0 / 255.0  # rgb uint8 -> [0, 1]
    # event counts above this saturate (per time bin); a uint8 count cannot pass 255
    event_clip: Annotated[int, Range(ge=1, le=255)] = 8
    # the one resampling _resize does: a config naming another would be a lie
    resize: Literal["INTER_AREA"] = "INTER_AREA"
    # time bins per polarity: 1 = the paper's counts
    event_bins: Annotated[int, Range(ge=1, le=64)] = 1

    def __post_init__(self):
        for name, tp in _normalisation_fields().items():
            # coerced back in: an int scale becomes the float that to_dict then records
            object.__setattr__(self, name, coerce_param(tp, getattr(self, name), where=name))

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict, where: str = "normalisation") -> "Normalisation":
        """A Normalisation from its ``to_dict`` form (a key left out keeps its default:
        older configs have no event_bins).

        Parameters:
            d: the table, e.g. a checkpoint config's "normalisation".
            where: what the table is, for errors: each names ``<where>.<key>``.

        Returns:
            The Normalisation. ValueError, naming the key, for a table that is not one, an
            unknown key, or a value of the wrong type or out of its range.
        """
        if not isinstance(d, dict):
            raise ValueError(f"{where}: expected a table, got {type(d).__name__} "
                             f"{short_repr(d)}")
        fields = _normalisation_fields()
        unknown = sorted((k for k in d if k not in fields), key=str)
        if unknown:
            # a setting this code would not honour: the input would differ from training's
            raise ValueError(f"{where}.{clip(str(unknown[0]), 80)}: unknown key (known: "
                             f"{', '.join(fields)})")
        return cls(**{k: coerce_param(fields[k], d[k], where=f"{where}.{k}") for k in d})


@functools.cache
def _normalisation_fields() -> dict:
    return param_fields(Normalisation)


def _resize(img: np.ndarray, size: int) -> np.ndarray:
    """[H, W] or [H, W, C] -> [size, size(, C)] by area averaging (no-op if already S x S)."""
    if img.shape[0] == size and img.shape[1] == size:
        return img
    return cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)


def _output(out: np.ndarray | None, planes: int, size: int) -> np.ndarray:
    """``out`` (float32 [planes, S, S], written in place), or a new such array."""
    if out is None:
        return np.empty((planes, size, size), np.float32)
    if out.shape != (planes, size, size) or out.dtype != np.float32:
        raise ValueError(f"out must be float32 [{planes}, {size}, {size}], got {out.dtype} "
                         f"{list(out.shape)}")
    return out


def rgb_input(rgb: np.ndarray, norm: Normalisation, out: np.ndarray | None = None
              ) -> np.ndarray:
    """RGB uint8 [H, W, 3] -> float32 [3, S, S] in [0, 1] (into ``out`` when given)."""
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"rgb must be uint8 [H, W, 3], got {rgb.dtype} {list(rgb.shape)}")
    img = _resize(np.ascontiguousarray(rgb), norm.size)
    # split into planes on uint8, then widen: ~10x faster than a float HWC -> CHW transpose
    out = _output(out, 3, norm.size)
    for c, plane in enumerate(cv2.split(img)):
        out[c] = plane
    out *= np.float32(norm.rgb_scale)
    return out


def event_input(events: np.ndarray, norm: Normalisation, out: np.ndarray | None = None
                ) -> np.ndarray:
    """Event counts uint8 [2K, H, W] (ON bins, OFF bins) -> float32 [2K, S, S] in [0, 1]
    (into ``out`` when given)."""
    planes = 2 * norm.event_bins
    if events.ndim != 3 or events.shape[0] != planes:
        what = ("[2, H, W] (ON, OFF counts)" if planes == 2 else
                f"[{planes}, H, W] ({norm.event_bins} time bins per polarity)")
        raise ValueError(f"events must be {what}, got {list(events.shape)}")
    if events.dtype.kind not in "ui":
        # a voxel grid's signed floats would wrap in the uint8 lookup (-1.0 -> 255): its
        # time bins would read as polarity counts
        raise ValueError(f"event frames must be counts or a time surface (unsigned "
                         f"integers), got {events.dtype}: a voxel grid cannot feed an ERP "
                         f"policy (accumulator representation histogram or time_surface)")
    table = _event_table(norm.event_clip)
    out = _output(out, planes, norm.size)
    for c in range(planes):
        # per polarity on a contiguous 2-D plane: one table lookup clips, scales and widens
        # to float32 (4x faster than min + astype + multiply), then the area resize
        plane = np.ascontiguousarray(events[c])
        if plane.dtype != np.uint8:
            plane = np.minimum(plane, 255).astype(np.uint8)
        out[c] = _resize(cv2.LUT(plane, table), norm.size)
    return out


@functools.lru_cache(maxsize=8)
def _event_table(clip: int) -> np.ndarray:
    """uint8 count -> min(count, clip) / clip, as a 256-entry float32 lookup table."""
    if not 1 <= clip <= 255:
        raise ValueError(f"event_clip must be in 1..255, got {clip}")
    return (np.minimum(np.arange(256), clip) / clip).astype(np.float32)


def event_clip_for(representation: str, requested: int) -> int:
    """The Normalisation.event_clip a model of these event frames takes.

    A time surface's uint8 is not a count: 0..255 is 255 exp(-age / tau), so it must reach
    the model as value / 255. Clipped at a count's event_clip (8 by default), every pixel
    that fired within about 3.5 tau would read 1.0 and the decay, the recency the surface
    is for, would be lost. Counts and histograms keep the clip asked for.

    Parameters:
        representation: the frames' accumulator representation ("counts", "histogram",
            "time_surface"; sebvs.dvs.accumulator.REPRESENTATIONS).
        requested: the event_clip asked for (a setting or the default), 1..255.

    Returns:
        255 for "time_surface", ``requested`` otherwise.
    """
    return 255 if representation == "time_surface" else requested


def diff_input(rgb: np.ndarray, rgb_prev: np.ndarray, norm: Normalisation,
               out: np.ndarray | None = None) -> np.ndarray:
    """Two RGB uint8 [H, W, 3] frames, the earlier one second -> float32 [2, S, S] in [0, 1]:
    the lin-log luma change from `rgb_prev` to `rgb`, its increase in channel 0 and its
    decrease in channel 1, each divided by the emulator's paper threshold (ON, OFF),
    clipped at `norm.event_clip` and scaled by it, as event counts are.

    What an ideal, noiseless event sensor at the frame's resolution would count between
    the two frames, without its threshold's rounding: the frame camera's own motion cue,
    made on the same scale as the events it is compared with. Luma is BT.601 of the 8-bit
    frame (the emulator's luma is 8-bit too), through the emulator's lin-log. Written
    into ``out`` when given.
    """
    if rgb_prev.shape != rgb.shape or rgb_prev.dtype != np.uint8:
        raise ValueError(f"rgb_prev must be uint8 {list(rgb.shape)} like rgb, got "
                         f"{rgb_prev.dtype} {list(rgb_prev.shape)}")
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"rgb must be uint8 [H, W, 3], got {rgb.dtype} {list(rgb.shape)}")
    paper = PRESETS["paper"]
    now, before = (linlog(cv2.cvtColor(np.ascontiguousarray(f), cv2.COLOR_RGB2GRAY))
                   for f in (rgb, rgb_prev))
    change = now - before
    clip = float(norm.event_clip)
    out = _output(out, 2, norm.size)
    for c, (signed, threshold) in enumerate(((change, paper.pos_thres),
                                             (-change, paper.neg_thres))):
        plane = np.clip(signed / np.float32(threshold), 0.0, clip) / np.float32(clip)
        out[c] = _resize(plane.astype(np.float32, copy=False), norm.size)
    return out


def model_input(modality: Modality | str, norm: Normalisation, *,
                rgb: np.ndarray | None = None, events: np.ndarray | None = None,
                rgb_prev: np.ndarray | None = None, out: np.ndarray | None = None
                ) -> np.ndarray:
    """The observation a modality needs -> float32 [C, S, S] (rgb channels first).

    Each stream is written into its channels of one array: ``out`` when given (the policy
    actor keeps one per modality), else a new one. Not a concatenation of per-stream
    arrays: with two such arrays alive, each call paid ~0.2-0.4 ms in fresh pages at 160 px
    (rgb+event: 404 us against 19 + 17 us for its two parts alone).
    """
    modality = Modality.parse(modality)
    out = _output(out, modality.channels(norm.event_bins), norm.size)
    first = 0
    for stream in modality.streams:
        block = out[first:first + _stream_channels(stream, norm.event_bins)]
        first += len(block)
        if stream == "rgb":
            if rgb is None:
                raise ValueError(f"modality {modality!r} needs an rgb frame")
            rgb_input(rgb, norm, block)
        elif stream == "rgb_prev":
            if rgb is None or rgb_prev is None:
                raise ValueError(f"modality {modality!r} needs an rgb frame and the "
                                 f"previous tick's")
            diff_input(rgb, rgb_prev, norm, block)
        else:
            if events is None:
                raise ValueError(f"modality {modality!r} needs an event frame")
            event_input(events, norm, block)
    return out
