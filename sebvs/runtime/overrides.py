"""Topology overrides: nested mappings merged in order, and the one parser of ``--set``.

    from sebvs.runtime.overrides import merge, parse_set, replace
    hdr = {"sim": {"config": {"lighting": "hdr"}}, "camera": {"sensor": "physical"}}
    merge(hdr, {"sim": {"config": {"target_speed": "fast"}}}, parse_set("topology.seed=5"))
    # {"sim": {"config": {"lighting": "hdr", "target_speed": "fast"}},
    #  "camera": {"sensor": "physical"}, "topology": {"seed": 5}}
    merge(hdr, {"policy": {"inputs": replace({"rgb": "camera/rgb"})}})  # the table, whole

An override mapping is shaped as the ``--set`` paths are: its keys are actor names,
``topology`` and ``hosts``, and below them the keys of their tables. Library code builds
these mappings; the ``actor.key=value`` text of ``--set`` (and of ``sebvs ctl ... set``) is
parsed here and nowhere else, at the command line.

``merge`` is the one rule: later wins; a mapping merges into a mapping key by key; anything
else replaces what was there. A table that must replace another whole (dropping the keys
it does not name) is given as ``replace(table)``, JSON ``{"$replace": {...}}``: that is
what ``--set 'key={...}'`` means, as it always did. Overrides stay plain JSON values, so
they cross process boundaries (fan-out tasks, Ray) as they are.

``overrides`` arguments (``load_topology``, ``EvalPlan.extra``, the recorder's) take a
mapping, or a sequence of layers applied in order, each a mapping or a ``--set`` line as a
user typed it (a user's script, provenance); ``layers`` and ``as_mapping`` read both.
"""
from __future__ import annotations

import tomllib
from collections.abc import Iterator, Mapping, Sequence
from typing import Any, Union

from .params import clip, short_repr

# the key of a table that replaces, where a plain mapping would merge
REPLACE = "$replace"
# what an `overrides` argument may be: one mapping, or layers (mappings or --set lines)
Overrides = Union[Mapping, Sequence[Union[str, Mapping]]]


class TopologyError(ValueError):
    """A topology (or an override of one) that cannot run; the message names the file,
    the table and the key, or the ``--set`` line."""


def replace(table: Mapping) -> dict:
    """``table`` as a value that replaces the table it lands on, whole.

    Parameters:
        table: the new table's keys and values.

    Returns:
        {"$replace": a copy of table}: merge() puts it in place of what was there.
    """
    return {REPLACE: _copy(table)}


def is_replacement(value: Any) -> bool:
    """Whether ``value`` is a ``replace(table)``."""
    return isinstance(value, Mapping) and len(value) == 1 and REPLACE in value


def merge(*layers: Mapping) -> dict:
    """The layers merged in order: later wins; a mapping merges into a mapping key by key;
    anything else (a value, a list, a ``replace(table)``) replaces what was there.

    Parameters:
        layers: override mappings (or a topology document first, then overrides).

    Returns:
        A new mapping; the layers are not changed and share nothing with it. A
        ``replace(table)`` stays marked (a later layer may still merge into it) until
        ``resolved()`` turns it into its table.
    """
    out: dict = {}
    for layer in layers:
        if not isinstance(layer, Mapping):
            raise TypeError(f"an override layer is a mapping, got {short_repr(layer)}")
        out = _merge_value(out, layer)
    return out


def _merge_value(base: Any, later: Any) -> Any:
    if is_replacement(later) or not isinstance(later, Mapping):
        return _copy(later)
    if is_replacement(base):        # keys merged into a table that replaces: it still does
        return {REPLACE: _merge_value(base[REPLACE], later)}
    if not isinstance(base, Mapping):
        return _copy(later)
    out = dict(base)
    for key, value in later.items():
        out[key] = _merge_value(out[key], value) if key in out else _copy(value)
    return out


def _copy(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _copy(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_copy(v) for v in value]
    return value


def resolved(value: Any) -> Any:
    """``value`` with every ``replace(table)`` turned into its table: what a topology
    document holds once its overrides are merged in."""
    if is_replacement(value):
        return resolved(value[REPLACE])
    if isinstance(value, Mapping):
        return {k: resolved(v) for k, v in value.items()}
    return value


def leaves(overrides: Mapping, prefix: tuple[str, ...] = ()) -> Iterator[tuple[tuple, Any]]:
    """(key path, value) of every value an override mapping sets, a replaced table's
    keys included: ``{"sim": {"config": {"lighting": "hdr"}}}`` gives
    (("sim", "config", "lighting"), "hdr")."""
    for key, value in overrides.items():
        path = (*prefix, key)
        if is_replacement(value):
            value = value[REPLACE]
            if isinstance(value, Mapping) and value:
                yield from leaves(value, path)
            else:
                yield path, value
        elif isinstance(value, Mapping) and value:
            yield from leaves(value, path)
        else:
            yield path, value


def set_lines(overrides: Mapping) -> list[str]:
    """The ``--set`` lines that give a mapping's leaves, for a command run as a subprocess:
    ``{"topology": {"seed": 31}}`` -> ["topology.seed=31"]. Values are written as JSON,
    which the parser reads back as the same TOML values (strings, numbers, booleans, lists).
    (Replaced tables are written as their leaves: not for `replace` values.)"""
    import json
    return [f"{'.'.join(path)}={json.dumps(value)}" for path, value in leaves(overrides)]


def lookup(overrides: Mapping, *path: str, default: Any = None) -> Any:
    """The value an override mapping sets at ``path`` (through replaced tables), or
    ``default`` where it sets none."""
    node: Any = overrides
    for key in path:
        if is_replacement(node):
            node = node[REPLACE]
        if not isinstance(node, Mapping) or key not in node:
            return default
        node = node[key]
    return resolved(node)


def nested(path: Sequence[str], value: Any) -> dict:
    """{"a": {"b": value}} for the path ("a", "b")."""
    out: Any = value
    for key in reversed(path):
        out = {key: out}
    return out


# ------------------------------------------------------------------ the command line's text
def parse_key_value(text: str) -> tuple[list[str], Any]:
    """The one parser of ``key.path=value`` text (``--set``, ``sebvs ctl ... set``): the key
    path split at its dots, the value read as TOML when it parses, else taken as a bare
    word (a string). The callers check the form first (``parse_override``).

    Parameters:
        text: what the user typed, with an ``=``.

    Returns:
        (the key path as a list, the value).
    """
    path, _, raw = text.partition("=")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw  # a bare word: take it as a string
    return path.strip().split("."), value


def parse_override(text: str) -> tuple[list[str], Any]:
    """``actor.key=value`` -> (["actor", "key"], value), the value read as TOML when it
    parses; TopologyError, in one line, for text of another form."""
    if "=" not in text:
        raise TopologyError(f"--set {short_repr(text)}: expected actor.key=value")
    parts, value = parse_key_value(text)
    if len(parts) < 2 or not all(parts):
        raise TopologyError(f"--set {short_repr(text)}: expected actor.key=value "
                            f"(or topology.key=value)")
    return parts, value


def parse_set(text: str) -> dict:
    """One ``--set actor.key=value`` line as an override mapping; a table value replaces
    the table it lands on whole, as ``--set 'key={...}'`` always did."""
    parts, value = parse_override(text)
    return nested(parts, replace(value) if isinstance(value, Mapping) else value)


def layers(overrides: Overrides) -> list[tuple[Mapping, str | None]]:
    """An ``overrides`` argument as its layers in order: (mapping, the ``--set`` line it was
    parsed from, or None for a mapping given as one)."""
    if isinstance(overrides, Mapping):
        return [(overrides, None)]
    if isinstance(overrides, (str, bytes)):
        raise TypeError(f"overrides: a list of --set lines or a mapping, not the one line "
                        f"{clip(str(overrides))!r}")
    out = []
    for layer in overrides:
        if isinstance(layer, str):
            out.append((parse_set(layer), layer))
        elif isinstance(layer, Mapping):
            out.append((layer, None))
        else:
            raise TypeError(f"an override is a --set line or a mapping, got "
                            f"{short_repr(layer)}")
    return out


def as_mapping(overrides: Overrides) -> dict:
    """An ``overrides`` argument merged into one mapping (what crosses to a worker)."""
    return merge(*(mapping for mapping, _ in layers(overrides)))
