import numpy as np
import pytest

from sebvs.runtime.shm import SHM_DIR, RingReader, RingWriter, packed_offsets, remove_run_rings
from sebvs.runtime.wire import (SCHEMA_VERSION, WireError, array_spec, decode_header,
                                dtype_from_wire, dtype_to_wire, encode_header)

EVENT_DTYPE = np.dtype([("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "i1")])


def header(**kw):
    base = dict(source="cam", output="rgb", seq=3, t_sim=0.5, tick=7,
                stamps=[["cam", 0, 123]], arrays=[], meta={"control": True})
    base.update(kw)
    return encode_header(**base)


def test_header_round_trip():
    h = decode_header(header())
    assert (h["src"], h["out"], h["seq"], h["ts"], h["tick"]) == ("cam", "rgb", 3, 0.5, 7)
    assert h["st"] == [["cam", 0, 123]] and h["m"] == {"control": True}
    assert h["v"] == SCHEMA_VERSION


@pytest.mark.parametrize("dtype", [np.uint8, np.float32, ">i4", EVENT_DTYPE])
def test_dtypes_round_trip(dtype):
    dt = np.dtype(dtype)
    assert dtype_from_wire(dtype_to_wire(dt)) == dt


def test_object_dtype_refused():
    with pytest.raises(TypeError):
        dtype_to_wire(np.dtype(object))
    with pytest.raises(WireError):
        dtype_from_wire("|O")


def test_a_deprecated_dtype_alias_is_a_bad_descriptor_not_a_warning():
    with pytest.raises(WireError, match="bad dtype descriptor 'a5'"):
        dtype_from_wire("a5")
    with pytest.raises(WireError, match="bad dtype descriptor"):
        dtype_from_wire([[["x", "a5", 0]], 5])
    assert dtype_from_wire("|S5") == np.dtype("S5")      # what a sender writes for it


@pytest.mark.parametrize("raw, reason", [
    (b"\xc1\xc1\xc1", "not msgpack"),
    (b"\x93\x01\x02\x03", "not a map"),
])
def test_garbage_headers(raw, reason):
    with pytest.raises(WireError, match=reason):
        decode_header(raw)


def test_wrong_schema_version():
    import msgpack
    with pytest.raises(WireError, match="schema version"):
        decode_header(msgpack.packb({"v": SCHEMA_VERSION + 1}))


def test_wrong_field_type():
    with pytest.raises(WireError, match="'seq'"):
        decode_header(header(seq="three"))


def test_huge_array_claim_rejected_without_allocating():
    with pytest.raises(WireError, match="claims"):
        array_spec(["a", "<f8", [10, 1024, 1024, 128], None])


def test_bad_shapes_rejected():
    for shape in ([-1], ["3"], [1] * 20, "12"):
        with pytest.raises(WireError):
            array_spec(["a", "|u1", shape, None])


def test_ring_write_read_and_overwrite_detection():
    w = RingWriter("sebvs-testring-a-b", n_slots=2)
    r = RingReader()
    try:
        slot, view = w.reserve(1000)
        np.frombuffer(view, np.uint8)[:] = 7
        gen = w.commit(slot)
        assert gen % 2 == 0
        got = r.view(w.name, slot, 0, 1000, gen)
        assert np.frombuffer(got, np.uint8).min() == 7
        # two more samples lap the 2-slot ring: the first location is now stale
        for _ in range(2):
            s, _ = w.reserve(1000)
            w.commit(s)
        assert r.view(w.name, slot, 0, 1000, gen) is None
        assert not r.still_valid(w.name, slot, gen)
    finally:
        r.close()
        w.close()


def test_slot_being_written_is_not_readable():
    w = RingWriter("sebvs-testring-c-d", n_slots=4)
    r = RingReader()
    try:
        slot, _ = w.reserve(100)
        gen = w.commit(slot)
        slot2, _ = w.reserve(100)   # reserved, not committed: odd generation
        assert r.view(w.name, slot2, 0, 100, gen) is None
    finally:
        r.close()
        w.close()


def test_ring_grows_into_a_new_file():
    w = RingWriter("sebvs-testring-e-f", n_slots=2)
    try:
        w.reserve(10)
        first = w.name
        w.reserve(10 * 4096)
        assert w.name != first and w.slot_bytes >= 10 * 4096
    finally:
        w.close()


def test_a_message_in_an_outgrown_ring_is_still_read_until_the_new_ring_laps_it():
    """A ring grows into a new file while a consumer still has a message naming the old
    one that it never mapped (a nav recording lost an event batch so: 'No such file').
    The old file stays until the new one has gone round once, then goes."""
    w = RingWriter("sebvs-testring-grow-race", n_slots=3)
    r = RingReader()
    try:
        slot, view = w.reserve(8)
        view[:] = b"old data"
        gen = w.commit(slot)
        old = w.name
        w.commit(w.reserve(3 * 4096)[0])                 # grows: a new file
        assert w.name != old and (SHM_DIR / old).exists()
        assert bytes(r.view(old, slot, 0, 8, gen)) == b"old data"
        for _ in range(2):
            w.commit(w.reserve(16)[0])
        assert (SHM_DIR / old).exists()                  # two of the three slots since
        w.commit(w.reserve(16)[0])
        assert not (SHM_DIR / old).exists()
        w.commit(w.reserve(5 * 4096)[0])                 # and a retired file goes at close
        second = [e[0] for e in w._retired]
        assert second and all((SHM_DIR / n).exists() for n in second)
    finally:
        r.close()
        w.close()
    assert not any((SHM_DIR / n).exists() for n in second)


def test_reader_refuses_foreign_names_and_out_of_bounds():
    w = RingWriter("sebvs-testring-g-h", n_slots=2, slot_bytes=4096)
    r = RingReader()
    try:
        with pytest.raises(ValueError):
            r.view("../etc/passwd", 0, 0, 1, 2)
        with pytest.raises(ValueError):
            r.view(w.name, 5, 0, 1, 2)
        with pytest.raises(ValueError):
            r.view(w.name, 0, 0, 10 ** 6, 2)
    finally:
        r.close()
        w.close()


def test_remove_run_rings():
    w = RingWriter("sebvs-deadbeef-cam-rgb", n_slots=2, slot_bytes=4096)
    name = w.name
    w.close(unlink=False)
    assert name in remove_run_rings("deadbeef")


def test_packed_offsets_are_aligned():
    offsets, total = packed_offsets([3, 100, 64])
    assert offsets == [0, 64, 192] and total == 256
