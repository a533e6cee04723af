"""Property tests of what arrives from outside (issue 35): wire headers, array descriptors
and control values. Whatever comes in is decoded into valid values or refused with the
documented error (WireError for the wire, ValueError for control), never another
exception, and a refused control value leaves the running one as it was. 1,500 examples
per property here; tools/checks/wire_properties_study.py runs 100,000."""
import asyncio
import copy
import math
import os

import msgpack
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sebvs_actors.camera import Camera
from sebvs_actors.synthetic import PatternSource
from sebvs.runtime.params import params_to_dict
from sebvs.runtime.wire import (MAX_ARRAY_BYTES, MAX_HOPS, MAX_SEQ, SCHEMA_VERSION, WireError,
                                array_spec, decode_header, encode_header)

# tools/checks/wire_properties_study.py raises it (100,000) through the environment
N_EXAMPLES = int(os.environ.get("SEBVS_PROPERTY_EXAMPLES", "1500"))
EXAMPLES = settings(max_examples=N_EXAMPLES, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])

# what msgpack can carry: ints within its 64-bit range, floats of every kind, nesting
scalars = (st.none() | st.booleans() | st.integers(-(1 << 63), (1 << 64) - 1)
           | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=12)
           | st.binary(max_size=12))
values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=4)
                      | st.dictionaries(st.text(max_size=6), inner, max_size=4), max_leaves=12)
ints = st.integers(-(1 << 63), (1 << 64) - 1)
stamp = st.one_of(st.lists(st.one_of(st.text(max_size=6), ints), min_size=3, max_size=3),
                  values)


@st.composite
def header_like(draw):
    """A header with the real keys, each either plausible or arbitrary, some left out:
    the decoder's every check is reached, not only its msgpack parse."""
    plausible = {"v": st.sampled_from([SCHEMA_VERSION, 0, 2, "1", None]),
                 "src": st.text(max_size=8), "out": st.text(max_size=8), "seq": ints,
                 "ts": st.one_of(st.none(), st.floats(), ints), "tick": st.one_of(st.none(), ints),
                 "st": st.lists(stamp, max_size=4), "a": st.lists(values, max_size=3),
                 "m": st.dictionaries(st.text(max_size=6), values, max_size=3)}
    h = {}
    for key, good in plausible.items():
        choice = draw(st.integers(0, 9))
        if choice == 0:
            continue                                   # left out
        h[key] = draw(values) if choice == 1 else draw(good)
    return h


def decode_or_refuse(raw):
    try:
        return decode_header(raw)
    except WireError as exc:
        assert exc.kind and str(exc)                   # it names what was wrong
        return None


@EXAMPLES
@given(st.binary(max_size=512))
def test_any_bytes_decode_or_raise_wire_error(raw):
    decode_or_refuse(raw)


@EXAMPLES
@given(header_like())
def test_header_like_maps_decode_valid_or_raise_wire_error(h):
    out = decode_or_refuse(msgpack.packb(h, use_bin_type=True))
    if out is None:
        return
    # what a receiver may rely on once decode_header returned
    assert out["v"] == SCHEMA_VERSION and 0 <= out["seq"] <= MAX_SEQ
    assert isinstance(out["src"], str) and isinstance(out["out"], str)
    assert out["ts"] is None or (isinstance(out["ts"], (int, float))
                                 and not isinstance(out["ts"], bool))
    assert len(out["st"]) <= MAX_HOPS and all(
        len(s) == 3 and s[1] >= 0 and s[2] >= 0 for s in out["st"])


@EXAMPLES
@given(source=st.text(max_size=8), output=st.text(max_size=8), seq=st.integers(0, MAX_SEQ),
       t_sim=st.one_of(st.none(), st.floats(allow_nan=False)),
       tick=st.one_of(st.none(), st.integers(-(1 << 63), (1 << 63) - 1)),
       stamps=st.lists(st.tuples(st.text(max_size=6), st.integers(0, 1 << 62),
                                 st.integers(0, 1 << 62)).map(list), max_size=MAX_HOPS),
       meta=st.dictionaries(st.text(max_size=6), ints | st.text(max_size=6),
                            max_size=4))
def test_what_encode_header_writes_decodes_to_the_same(source, output, seq, t_sim, tick,
                                                        stamps, meta):
    raw = encode_header(source=source, output=output, seq=seq, t_sim=t_sim, tick=tick,
                        stamps=stamps, arrays=[], meta=meta)
    h = decode_header(raw)
    assert (h["src"], h["out"], h["seq"], h["tick"], h["st"], h["m"]) == \
        (source, output, seq, tick, stamps, meta)
    assert h["ts"] == t_sim or (t_sim is not None and math.isnan(t_sim))


@EXAMPLES
@given(st.one_of(values, st.tuples(st.text(max_size=4),
                                   st.sampled_from(["<u1", "<f4", "<i8", "|V0", "O", "<U3",
                                                    "x", "<f16"]) | values,
                                   st.lists(st.integers(-2, 1 << 40), max_size=9) | values,
                                   st.none() | st.lists(ints, max_size=5)).map(list)))
def test_array_descriptors_give_a_bounded_array_or_raise_wire_error(desc):
    try:
        name, dt, shape, nbytes, loc = array_spec(desc)
    except WireError:
        return
    assert not dt.hasobject and 0 < dt.itemsize
    assert nbytes == math.prod(shape) * dt.itemsize <= MAX_ARRAY_BYTES
    assert all(n >= 0 for n in shape)


class _Node:
    def emit(self, *a, **k):
        pass


def control_actors():
    return [PatternSource("source", PatternSource.Params(), node=_Node()),
            Camera("camera", Camera.Params(), node=_Node())]


KEYS = sorted({k for a in control_actors() for k in params_to_dict(a.params)})


@settings(max_examples=N_EXAMPLES, deadline=None)
@given(key=st.sampled_from(KEYS) | st.text(max_size=8), value=values)
def test_control_sets_a_valid_value_or_refuses_and_keeps_the_old(key, value):
    for actor in control_actors():
        before = copy.deepcopy(params_to_dict(actor.params))
        try:
            result = asyncio.run(actor.control(key, value))
        except ValueError as exc:
            assert str(exc)
            assert params_to_dict(actor.params) == before      # nothing half-set
            continue
        assert set(result) == {key}
        after = params_to_dict(actor.params)
        assert {k: v for k, v in after.items() if k != key} == \
            {k: v for k, v in before.items() if k != key}
