"""Wire format: one ZeroMQ multipart message per published sample.

    [topic, header, *buffers]

``topic`` is ``b"<actor>/<output>"`` (SUB sockets filter on it). ``header`` is msgpack:

    v      schema version (int)
    src    producing actor (str)
    out    output name (str)
    seq    per-output sequence number, from 0 (int)
    ts     t_sim, simulation time of the observation in seconds (float | None)
    tick   control tick index (int | None)
    st     stamps, one per hop: [actor, recv_ns, send_ns] (time.monotonic_ns(); recv 0 at a source)
    a      array descriptors: [name, dtype, shape, loc]
             loc None                    -> the next inline buffer
             loc [ring, slot, off, gen]  -> bytes in a shared-memory ring slot
    m      meta: small msgpack-able values (dict)

Arrays never travel inside msgpack: inline arrays are raw buffers sent zero-copy, large
ones sit in shared memory and only their descriptor crosses the socket.

The decoder's contract: whatever bytes arrive, `decode_header` and `array_spec` either
return validated values or raise `WireError`, whose `kind` names the part that was wrong
("header", "field", "stamps", "dtype", "shape", ...). Receivers count errors per kind.
"""
from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass, field
from typing import Any

import msgpack
import numpy as np

from .params import clip, short_repr

SCHEMA_VERSION = 1
MAX_HEADER_BYTES = 1 << 20
MAX_ARRAY_BYTES = 1 << 31      # a header claiming more is malformed, not an allocation
MAX_ARRAYS = 64
MAX_NDIM = 8
MAX_HOPS = 64                  # stamps per message: a longer chain is a loop or a forgery
MAX_SEQ = (1 << 63) - 1        # seq is a uint63: the producer's count of messages sent
MAX_DTYPE_FIELDS = 64
MAX_ITEMSIZE = 1 << 16
SHOWN = 120                    # characters of a bad value an error message quotes
_shown = functools.partial(short_repr, limit=SHOWN)


class WireError(ValueError):
    """A message that cannot be decoded; the receiver counts it (per ``kind``) and goes on."""

    def __init__(self, message: str, kind: str = "malformed"):
        super().__init__(message)
        self.kind = kind


@dataclass
class Message:
    """One received sample, as an actor's handler sees it.

    Arrays that arrived through shared memory are read-only views that stay valid only
    while the handler runs: copy what you keep.
    """
    topic: str
    source: str
    output: str
    seq: int
    t_sim: float | None
    tick: int | None
    stamps: list
    meta: dict
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    input: str = ""
    recv_ns: int = 0    # when this actor's handler started on it (monotonic ns)
    # array name -> shared-memory location, so a relay can forward it without a copy
    shm_locs: dict[str, list] = field(default_factory=dict, repr=False)


def dtype_to_wire(dtype: np.dtype) -> Any:
    if dtype.hasobject:
        raise TypeError(f"object arrays cannot cross the wire (dtype {dtype})")
    if dtype.names is None:
        if dtype.subdtype is not None:
            raise TypeError(f"sub-array dtypes are not supported ({dtype})")
        return dtype.str
    fields = []
    for name in dtype.names:
        sub, offset = dtype.fields[name][:2]
        if sub.names is not None or sub.subdtype is not None:
            raise TypeError(f"nested structured dtypes are not supported ({dtype})")
        fields.append([name, sub.str, offset])
    return [fields, dtype.itemsize]


_DTYPES: dict[str, np.dtype] = {}   # wire string -> dtype, as every message asks again


def dtype_from_wire(desc: Any) -> np.dtype:
    if isinstance(desc, str) and desc in _DTYPES:
        return _DTYPES[desc]
    try:
        with warnings.catch_warnings():
            # an alias numpy deprecates ('a' for 'S') is refused like any odd descriptor,
            # not taken with a warning that a later numpy turns into an error; the sender
            # writes dtype.str, which never is one
            warnings.simplefilter("error", DeprecationWarning)
            if isinstance(desc, str):
                dt = np.dtype(desc)
            else:
                fields, itemsize = desc
                if len(fields) > MAX_DTYPE_FIELDS:
                    raise ValueError(f"{len(fields)} fields (max {MAX_DTYPE_FIELDS})")
                dt = np.dtype({"names": [f[0] for f in fields],
                               "formats": [f[1] for f in fields],
                               "offsets": [f[2] for f in fields],
                               "itemsize": itemsize})
    except Exception as exc:   # numpy raises many types on odd descriptors; all mean "bad"
        raise WireError(f"bad dtype descriptor {_shown(desc)}: {type(exc).__name__}: "
                        f"{clip(str(exc), SHOWN)}", "dtype") from None
    if dt.hasobject:
        raise WireError(f"object dtype {_shown(desc)} refused", "dtype")
    if dt.itemsize > MAX_ITEMSIZE or dt.itemsize == 0:
        raise WireError(f"dtype {_shown(desc)} has itemsize {dt.itemsize} "
                        f"(1..{MAX_ITEMSIZE})", "dtype")
    if isinstance(desc, str) and len(_DTYPES) < 256:
        _DTYPES[desc] = dt
    return dt


def encode_header(*, source: str, output: str, seq: int, t_sim: float | None,
                  tick: int | None, stamps: list, arrays: list, meta: dict | None) -> bytes:
    return msgpack.packb({"v": SCHEMA_VERSION, "src": source, "out": output, "seq": seq,
                          "ts": t_sim, "tick": tick, "st": stamps, "a": arrays,
                          "m": meta or {}}, use_bin_type=True)


def unpack_bounded(raw, what: str = "header", max_bytes: int = MAX_HEADER_BYTES,
                   max_len: int = 1 << 16) -> Any:
    """msgpack from outside, within bounds (bytes, array and map lengths); WireError of
    kind ``what`` otherwise. The one decoder for every msgpack a process receives: data
    headers, telemetry batches, control and clock replies."""
    if len(raw) > max_bytes:
        raise WireError(f"{what} of {len(raw)} bytes exceeds {max_bytes}", what)
    try:
        return msgpack.unpackb(raw, raw=False, strict_map_key=True,
                               max_array_len=max_len, max_map_len=min(max_len, 1 << 12))
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise WireError(f"{what} is not msgpack: {type(exc).__name__}: "
                        f"{clip(str(exc), SHOWN)}", what) from None


def decode_header(raw) -> dict:
    """Parse and validate a header; raises WireError naming what is wrong."""
    h = unpack_bounded(raw, "header")
    if not isinstance(h, dict):
        raise WireError("header is not a map", "header")
    if h.get("v") != SCHEMA_VERSION:
        raise WireError(f"schema version {_shown(h.get('v'))}, expected {SCHEMA_VERSION}",
                        "version")
    for key, types in (("src", str), ("out", str), ("seq", int), ("st", list), ("a", list),
                       ("m", dict)):
        if not isinstance(h.get(key), types) or isinstance(h[key], bool):
            raise WireError(f"header field {key!r} missing or of the wrong type", "field")
    # present even when None: a header that leaves them out was not written by encode_header
    for key, types, what in (("ts", (int, float), "a number"), ("tick", int, "an integer")):
        if key not in h:
            raise WireError(f"header field {key!r} missing", "field")
        if h[key] is not None and (not isinstance(h[key], types) or isinstance(h[key], bool)):
            raise WireError(f"header field {key!r} is not {what} or None", "field")
    if not 0 <= h["seq"] <= MAX_SEQ:
        raise WireError(f"header field 'seq' {h['seq']} is outside 0..2**63-1", "field")
    _check_stamps(h["st"])
    if len(h["a"]) > MAX_ARRAYS:
        raise WireError(f"{len(h['a'])} arrays in one message (max {MAX_ARRAYS})", "shape")
    return h


def _check_stamps(stamps: list) -> None:
    """Each hop [actor, recv_ns, send_ns]: what the profiler and every relay reads."""
    if len(stamps) > MAX_HOPS:
        raise WireError(f"{len(stamps)} stamps (max {MAX_HOPS})", "stamps")
    # `type(x) is int` rather than isinstance: it also refuses bools, and it is on every
    # message's path, so no generator per stamp
    for st in stamps:
        if not (type(st) is list and len(st) == 3 and type(st[0]) is str
                and type(st[1]) is int and type(st[2]) is int and st[1] >= 0 and st[2] >= 0):
            raise WireError(f"bad stamp {_shown(st)} (expected [actor, recv_ns, send_ns])",
                            "stamps")


def array_spec(desc) -> tuple[str, np.dtype, tuple[int, ...], int, Any]:
    """Validate one array descriptor: (name, dtype, shape, nbytes, loc)."""
    if not (isinstance(desc, list) and len(desc) == 4 and isinstance(desc[0], str)):
        raise WireError(f"bad array descriptor {_shown(desc)}", "shape")
    name, dt_desc, shape, loc = desc
    dt = dtype_from_wire(dt_desc)
    if not isinstance(shape, list) or len(shape) > MAX_NDIM:
        raise WireError(f"array {_shown(name)}: bad shape {_shown(shape)}", "shape")
    # every dimension bounded too: numpy refuses an empty array with a 2**64 dimension
    elements = 1
    for n in shape:
        if not isinstance(n, int) or isinstance(n, bool) or not 0 <= n <= MAX_ARRAY_BYTES:
            raise WireError(f"array {_shown(name)}: bad shape {_shown(shape)}", "shape")
        elements *= n
    nbytes = elements * dt.itemsize
    if nbytes > MAX_ARRAY_BYTES:
        raise WireError(f"array {_shown(name)} claims {nbytes} bytes "
                        f"(max {MAX_ARRAY_BYTES})", "shape")
    if loc is not None and not (type(loc) is list and len(loc) == 4 and type(loc[0]) is str
                                and type(loc[1]) is int and type(loc[2]) is int
                                and type(loc[3]) is int and loc[1] >= 0 and loc[2] >= 0
                                and loc[3] >= 0):
        raise WireError(f"array {_shown(name)}: bad shared-memory location {_shown(loc)}",
                        "ring")
    return name, dt, tuple(shape), nbytes, loc

