"""Sweep grids: a TOML file naming a task, a dataset, base `sebvs train` settings and axes;
every combination of the axes' values is one training point.

    task = "nav"
    data = "datasets/nav"          # relative paths are taken from the current directory
    [train]                        # one value per setting, shared by every point
    epochs = 10
    [axes]                         # a list per setting; the grid is their product
    modality = ["rgb", "event", "rgb+event"]
    seed = [0, 1, 2]

The settings are `sebvs train`'s options, spelled with underscores (SETTINGS); one left
out takes `sebvs train`'s default. Torch threads and the device are the command's, not
the grid's: they decide how points run, not what they learn. A point's name, and its
directory, is ``key=value`` joined by ``__``: modality and seed always, then every other
axis in name order (``modality=event__seed=1__lr=0.0005``). It depends on the values
only, not on the order the file lists them in, so a rerun finds its points again.
"""
from __future__ import annotations

import itertools
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from .inputs import CONTROL_MODALITIES, MODALITIES, parse_size

TASKS = ("nav", "arm")
STEMS = ("patch", "conv", "dual", "gated")    # model.STEMS, named without importing torch
MEMORIES = ("none", "gru")                     # model.MEMORIES, likewise


class GridError(ValueError):
    """A grid file that cannot be used; the message names the file, the key and why."""


def _integer(low: int) -> Callable[[Any], int]:
    def check(value: Any) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"expected an integer, got {value!r}")
        if value < low:
            raise ValueError(f"must be at least {low}, got {value}")
        return value
    return check


def _seed(value: Any) -> int:
    """A training seed, in the project's one seed range (sebvs/runtime/topology.py)."""
    from sebvs.runtime.topology import check_seed
    return check_seed(value, "seed")


def _number(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"expected a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"expected a finite number, got {value!r}")
    return float(value)


def _positive(value: Any) -> float:
    value = _number(value)
    if value <= 0:
        raise ValueError(f"must be positive, got {value!r}")
    return value


def _fraction(value: Any) -> float:
    value = _number(value)
    if not 0 < value < 1:
        raise ValueError(f"must be between 0 and 1 (exclusive), got {value!r}")
    return value


def _share(value: Any) -> float:
    value = _number(value)
    if not 0 <= value <= 1:
        raise ValueError(f"must be between 0 and 1, got {value!r}")
    return value


def _non_negative(value: Any) -> float:
    value = _number(value)
    if value < 0:
        raise ValueError(f"must be 0 or more, got {value!r}")
    return value


def _one_of(options: tuple[str, ...]) -> Callable[[Any], str]:
    def check(value: Any) -> str:
        if value not in options:
            raise ValueError(f"expected one of {', '.join(options)}, got {value!r}")
        return value
    return check


def _size(value: Any) -> int:
    if not isinstance(value, (int, str)):
        raise ValueError(f"expected a size in px or a preset, got {value!r}")
    return parse_size(value)


# setting -> check (returns the value in its canonical type, or raises ValueError saying why)
SETTINGS: dict[str, Callable[[Any], Any]] = {
    "modality": _one_of(MODALITIES + CONTROL_MODALITIES),
    "seed": _seed,
    "lr": _positive,
    "stem": _one_of(STEMS),
    "epochs": _integer(1),
    "batch": _integer(1),
    "size": _size,
    "event_clip": _integer(1),
    "max_frames": _integer(0),
    "patience": _integer(1),
    "val_fraction": _fraction,
    # the recipe options (docs/policy.md, "Memory, target head and modality dropout")
    "memory": _one_of(MEMORIES),
    "aux_weight": _non_negative,
    "modality_dropout": _share,
    "seq_len": _integer(1),
    "lanes": _integer(1),
    "burn_in": _integer(0),
}
# keys that belong to the command line: how points run, not what they learn
COMMAND_LINE = {"threads": "--threads", "device": "--device", "workers": "--workers",
                "out": "--out", "ray": "--ray"}
NAME_FIRST = ("modality", "seed")     # always in a point's name, first


@dataclass(frozen=True)
class Point:
    """One training run of the grid: its name (= its directory) and every setting given
    for it (base and axes; settings not given keep `sebvs train`'s defaults)."""
    name: str
    settings: dict
    axes: dict              # this point's value of each axis (for grouping the table)


@dataclass(frozen=True)
class Grid:
    path: str
    task: str
    data: str               # absolute
    base: dict              # the [train] settings
    axes: dict              # setting -> list of values, in name order

    def points(self) -> list[Point]:
        keys = list(self.axes)
        out = []
        for values in itertools.product(*(self.axes[k] for k in keys)):
            chosen = dict(zip(keys, values))
            settings = {**self.base, **chosen}
            seed = settings.setdefault("seed", 0)
            named = {"modality": settings["modality"], "seed": seed,
                     **{k: v for k, v in chosen.items() if k not in NAME_FIRST}}
            out.append(Point(point_name(named), settings, chosen))
        return out


def format_value(value: Any) -> str:
    """How a value reads in a point's name: ints as written, floats in Python's shortest
    round-tripping form (2e-4 -> 0.0002), strings as they are."""
    return repr(value) if isinstance(value, float) else str(value)


def point_name(named: dict) -> str:
    return "__".join(f"{k}={format_value(v)}" for k, v in named.items())


def load_grid(path: str | Path) -> Grid:
    """Read and check a grid file; GridError names the file, the key and what is wrong."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            raw = tomllib.load(f)
    except FileNotFoundError:
        raise GridError(f"grid {path}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise GridError(f"grid {path}: not valid TOML ({exc})") from None
    return parse_grid(raw, str(path))


def parse_grid(raw: dict, where: str = "<grid>") -> Grid:
    def fail(key: str, why: str) -> GridError:
        return GridError(f"grid {where}: {key}: {why}")

    unknown = set(raw) - {"task", "data", "train", "axes"}
    if unknown:
        key = sorted(unknown)[0]
        hint = (f"set it on the command line ({COMMAND_LINE[key]})" if key in COMMAND_LINE
                else "a setting belongs in [train] or [axes]" if key in SETTINGS
                else "the top level holds task, data, [train] and [axes]")
        raise fail(key, f"unknown key ({hint})")
    if raw.get("task") not in TASKS:
        raise fail("task", f"expected one of {', '.join(TASKS)}, got {raw.get('task')!r}")
    data = raw.get("data")
    if not isinstance(data, str) or not data:
        raise fail("data", f"expected the dataset directory as a string, got {data!r}")

    base = {}
    for key, value in _table(raw, "train", fail).items():
        base[key] = _setting(f"[train] {key}", key, value, fail)

    axes = {}
    for key, values in _table(raw, "axes", fail).items():
        label = f"[axes] {key}"
        if key in base:
            raise fail(label, "also set in [train]; give a setting in one of the two")
        if not isinstance(values, list) or not values:
            raise fail(label, f"expected a non-empty list of values, got {values!r}")
        checked = [_setting(f"{label}[{i}]", key, v, fail) for i, v in enumerate(values)]
        names = [format_value(v) for v in checked]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise fail(label, f"{', '.join(twice)} listed twice (two points would share a "
                              f"directory)")
        axes[key] = checked
    if "modality" not in base and "modality" not in axes:
        raise fail("modality", "not set: give one in [train] or a list in [axes]")

    ordered = {k: axes[k] for k in NAME_FIRST if k in axes}
    ordered.update({k: axes[k] for k in sorted(axes) if k not in NAME_FIRST})
    return Grid(where, raw["task"], str(Path(data).resolve()), base, ordered)


def _table(raw: dict, name: str, fail) -> dict:
    table = raw.get(name, {})
    if not isinstance(table, dict):
        raise fail(f"[{name}]", f"expected a table, got {table!r}")
    return table


def _setting(label: str, key: str, value: Any, fail) -> Any:
    if key in COMMAND_LINE:
        raise fail(label, f"set on the command line ({COMMAND_LINE[key]}), not in the grid")
    if key not in SETTINGS:
        raise fail(label, f"unknown setting (settings: {', '.join(SETTINGS)})")
    try:
        return SETTINGS[key](value)
    except ValueError as exc:
        raise fail(label, str(exc)) from None
