"""Actor parameters: a dataclass per actor, values type-checked where a topology sets them.

Supported annotations: bool, int, float (ints accepted), str, Literal[...], list[T],
dict, and Optional of any of these.
"""
from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, Literal, Union


def param_fields(params_cls: type) -> dict[str, Any]:
    """Field name -> resolved type annotation."""
    if not dataclasses.is_dataclass(params_cls):
        raise TypeError(f"{params_cls!r} is not a dataclass")
    hints = typing.get_type_hints(params_cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(params_cls)}


def _type_name(tp: Any) -> str:
    if typing.get_origin(tp) is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    return getattr(tp, "__name__", None) or str(tp)


def coerce_param(tp: Any, value: Any, *, where: str) -> Any:
    """Return ``value`` as type ``tp`` or raise ValueError naming ``where``."""
    origin = typing.get_origin(tp)
    if origin in (Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return coerce_param(arg, value, where=where)
            except ValueError as exc:
                errors.append(str(exc))
        raise ValueError(errors[0] if len(errors) == 1 else
                         f"{where}: {value!r} matches none of {_type_name(tp)}")
    if origin is Literal:
        if value in typing.get_args(tp) and type(value) in {type(a) for a in typing.get_args(tp)}:
            return value
        raise ValueError(f"{where}: {value!r} is not {_type_name(tp)}")
    if tp in (list, tuple):
        tp, origin = list[Any], list
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{where}: expected a list, got {type(value).__name__} {value!r}")
        (item,) = typing.get_args(tp)[:1] or (Any,)
        if item is Any:
            return list(value)
        return [coerce_param(item, v, where=f"{where}[{i}]") for i, v in enumerate(value)]
    if origin is dict or tp is dict:
        if not isinstance(value, dict):
            raise ValueError(f"{where}: expected a table, got {type(value).__name__} {value!r}")
        return dict(value)
    if tp is Any:
        return value
    if tp is bool:
        if isinstance(value, bool):
            return value
    elif tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif tp is str:
        if isinstance(value, str):
            return value
    else:
        raise ValueError(f"{where}: unsupported parameter type {tp!r}")
    raise ValueError(f"{where}: expected {_type_name(tp)}, got {type(value).__name__} {value!r}")


def build_params(params_cls: type, raw: dict, *, where: str) -> Any:
    """Instantiate ``params_cls`` from a raw table; every key and type is checked."""
    fields = param_fields(params_cls)
    unknown = sorted(set(raw) - set(fields))
    if unknown:
        raise ValueError(f"{where}: unknown key {unknown[0]!r} "
                         f"(known: {', '.join(sorted(fields)) or 'none'})")
    values = {k: coerce_param(fields[k], v, where=f"{where} key {k!r}") for k, v in raw.items()}
    try:
        return params_cls(**values)
    except TypeError as exc:  # a field without default left out
        raise ValueError(f"{where}: {exc}") from None


def params_to_dict(params: Any) -> dict:
    return dataclasses.asdict(params)
