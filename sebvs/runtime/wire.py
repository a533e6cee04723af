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
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import msgpack
import numpy as np

SCHEMA_VERSION = 1
MAX_HEADER_BYTES = 1 << 20
MAX_ARRAY_BYTES = 1 << 31      # a header claiming more is malformed, not an allocation
MAX_ARRAYS = 64
MAX_NDIM = 8


class WireError(ValueError):
    """A message that cannot be decoded; the receiver counts it and goes on."""


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
        if isinstance(desc, str):
            dt = np.dtype(desc)
        else:
            fields, itemsize = desc
            dt = np.dtype({"names": [f[0] for f in fields],
                           "formats": [f[1] for f in fields],
                           "offsets": [f[2] for f in fields],
                           "itemsize": itemsize})
    except (TypeError, ValueError) as exc:
        raise WireError(f"bad dtype descriptor {desc!r}: {exc}") from None
    if dt.hasobject:
        raise WireError(f"object dtype {desc!r} refused")
    if isinstance(desc, str) and len(_DTYPES) < 256:
        _DTYPES[desc] = dt
    return dt


def encode_header(*, source: str, output: str, seq: int, t_sim: float | None,
                  tick: int | None, stamps: list, arrays: list, meta: dict | None) -> bytes:
    return msgpack.packb({"v": SCHEMA_VERSION, "src": source, "out": output, "seq": seq,
                          "ts": t_sim, "tick": tick, "st": stamps, "a": arrays,
                          "m": meta or {}}, use_bin_type=True)


def decode_header(raw) -> dict:
    """Parse and validate a header; raises WireError naming what is wrong."""
    if len(raw) > MAX_HEADER_BYTES:
        raise WireError(f"header of {len(raw)} bytes exceeds {MAX_HEADER_BYTES}")
    try:
        h = msgpack.unpackb(raw, raw=False, strict_map_key=True,
                            max_array_len=1 << 16, max_map_len=1 << 12)
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise WireError(f"header is not msgpack: {type(exc).__name__}: {exc}") from None
    if not isinstance(h, dict):
        raise WireError("header is not a map")
    if h.get("v") != SCHEMA_VERSION:
        raise WireError(f"schema version {h.get('v')!r}, expected {SCHEMA_VERSION}")
    for key, types in (("src", str), ("out", str), ("seq", int), ("st", list), ("a", list),
                       ("m", dict)):
        if not isinstance(h.get(key), types):
            raise WireError(f"header field {key!r} missing or of the wrong type")
    if h.get("ts") is not None and not isinstance(h["ts"], (int, float)):
        raise WireError("header field 'ts' is not a number")
    if h.get("tick") is not None and not isinstance(h["tick"], int):
        raise WireError("header field 'tick' is not an integer")
    if len(h["a"]) > MAX_ARRAYS:
        raise WireError(f"{len(h['a'])} arrays in one message (max {MAX_ARRAYS})")
    return h


def array_spec(desc) -> tuple[str, np.dtype, tuple[int, ...], int, Any]:
    """Validate one array descriptor: (name, dtype, shape, nbytes, loc)."""
    if not (isinstance(desc, list) and len(desc) == 4 and isinstance(desc[0], str)):
        raise WireError(f"bad array descriptor {desc!r}")
    name, dt_desc, shape, loc = desc
    dt = dtype_from_wire(dt_desc)
    if not isinstance(shape, list) or len(shape) > MAX_NDIM:
        raise WireError(f"array {name!r}: bad shape {shape!r}")
    nbytes = dt.itemsize
    for n in shape:
        if not isinstance(n, int) or n < 0:
            raise WireError(f"array {name!r}: bad shape {shape!r}")
        nbytes *= n
    if nbytes > MAX_ARRAY_BYTES:
        raise WireError(f"array {name!r} claims {nbytes} bytes (max {MAX_ARRAY_BYTES})")
    return name, dt, tuple(shape), nbytes, loc
