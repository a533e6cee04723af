"""Actor parameters: a dataclass per actor, values type-checked where a topology sets them.

The same check runs when a topology loads, when the actor's process builds its params and
on `sebvs ctl RUN ACTOR set key=value`, so a value refused at one is refused at all three.

Supported annotations: bool, int, float (ints accepted), str, Literal[...], list[T],
dict, Optional of any of these, and ``Annotated[T, Range(...)]`` for bounds. Floats must
be finite unless their Range says ``finite=False``.
"""
from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Annotated, Any, Literal, Union

REPR_LIMIT = 200   # an error reply travels back to a terminal: never echo a megabyte


def clip(text: str, limit: int = REPR_LIMIT) -> str:
    return text if len(text) <= limit else text[:limit] + "..."


def short_repr(value: Any, limit: int = REPR_LIMIT) -> str:
    try:
        return clip(repr(value), limit)
    except ValueError:  # an int past Python's 4300-digit limit for str()
        return f"<a {type(value).__name__} too long to show>"


class OutOfRange(ValueError):
    """A value of the right type outside its declared bounds (or nan/inf)."""


@dataclasses.dataclass(frozen=True)
class Range:
    """Bounds of an int or float parameter: ``Annotated[int, Range(ge=1, le=8192)]``.

    ``finite=False`` lets a float field take nan and +-inf (bounds still apply to them).
    """
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    finite: bool = True

    def __str__(self) -> str:
        bounds = ((">=", self.ge), (">", self.gt), ("<=", self.le), ("<", self.lt))
        parts = [f"{op} {bound}" if isinstance(bound, int) else f"{op} {bound:g}"
                 for op, bound in bounds if bound is not None]
        return " and ".join(parts) or "any value"

    def check(self, value: Any, where: str) -> None:
        if value is None:
            return
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise TypeError(f"{where}: Range applies to int and float parameters, "
                            f"not {type(value).__name__}")
        ok = ((self.ge is None or value >= self.ge) and (self.gt is None or value > self.gt)
              and (self.le is None or value <= self.le) and (self.lt is None or value < self.lt))
        if not ok:
            raise OutOfRange(f"{where}: {short_repr(value)} is out of range (must be {self})")


def param_fields(params_cls: type) -> dict[str, Any]:
    """Field name -> resolved type annotation, Annotated bounds kept."""
    if not dataclasses.is_dataclass(params_cls):
        raise TypeError(f"{params_cls!r} is not a dataclass")
    hints = typing.get_type_hints(params_cls, include_extras=True)
    return {f.name: hints[f.name] for f in dataclasses.fields(params_cls)}


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin is Annotated:
        base, *extras = typing.get_args(tp)
        bounds = [str(e) for e in extras if isinstance(e, Range)]
        return _type_name(base) + (f" ({', '.join(bounds)})" if bounds else "")
    if origin in (Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(tp))
    return getattr(tp, "__name__", None) or str(tp)


def coerce_param(tp: Any, value: Any, *, where: str) -> Any:
    """Return ``value`` as type ``tp`` or raise ValueError naming ``where``."""
    return _coerce(tp, value, where, finite=True)


def _coerce(tp: Any, value: Any, where: str, finite: bool) -> Any:
    origin = typing.get_origin(tp)
    if origin is Annotated:
        base, *extras = typing.get_args(tp)
        ranges = [e for e in extras if isinstance(e, Range)]
        value = _coerce(base, value, where, finite=all(r.finite for r in ranges))
        for r in ranges:
            r.check(value, where)
        return value
    if origin in (Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(arg, value, where, finite)
            except ValueError as exc:
                errors.append(exc)
        # a bound the value missed says more than the types it is not
        bounded = [e for e in errors if isinstance(e, OutOfRange)]
        if bounded or len(errors) == 1:
            raise (bounded or errors)[0]
        raise ValueError(f"{where}: {short_repr(value)} matches none of {_type_name(tp)}")
    if origin is Literal:
        if value in typing.get_args(tp) and type(value) in {type(a) for a in typing.get_args(tp)}:
            return value
        raise ValueError(f"{where}: {short_repr(value)} is not {_type_name(tp)}")
    if tp in (list, tuple):
        tp, origin = list[Any], list
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{where}: expected a list, got {type(value).__name__} "
                             f"{short_repr(value)}")
        (item,) = typing.get_args(tp)[:1] or (Any,)
        if item is Any:
            return list(value)
        return [coerce_param(item, v, where=f"{where}[{i}]") for i, v in enumerate(value)]
    if origin is dict or tp is dict:
        if not isinstance(value, dict):
            raise ValueError(f"{where}: expected a table, got {type(value).__name__} "
                             f"{short_repr(value)}")
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
            try:
                number = float(value)
            except OverflowError:    # an int beyond any float
                raise OutOfRange(f"{where}: {short_repr(value)} is too large for a float") \
                    from None
            if finite and not math.isfinite(number):
                raise OutOfRange(f"{where}: {number!r} is not a finite number")
            return number
    elif tp is str:
        if isinstance(value, str):
            return value
    else:
        raise ValueError(f"{where}: unsupported parameter type {tp!r}")
    raise ValueError(f"{where}: expected {_type_name(tp)}, got {type(value).__name__} "
                     f"{short_repr(value)}")


def build_params(params_cls: type, raw: dict, *, where: str) -> Any:
    """Instantiate ``params_cls`` from a raw table; every key and type is checked."""
    fields = param_fields(params_cls)
    unknown = sorted(set(raw) - set(fields), key=str)
    if unknown:
        raise ValueError(f"{where}: unknown key {short_repr(unknown[0])} "
                         f"(known: {', '.join(sorted(fields)) or 'none'})")
    values = {k: coerce_param(fields[k], v, where=f"{where} key {k!r}") for k, v in raw.items()}
    try:
        return params_cls(**values)
    except TypeError as exc:  # a field without default left out
        raise ValueError(f"{where}: {exc}") from None


def params_to_dict(params: Any) -> dict:
    return dataclasses.asdict(params)
