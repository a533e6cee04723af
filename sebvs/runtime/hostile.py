"""Hostile messages for one input, by class, and the counter each must land in.

What tools/checks/fuzz_run.py sends through a live run (actors/fuzz.py): every class of message a
broken or hostile producer can put on a topic, made from a seeded generator, each with the
place a receiving input must count it (`EXPECTED`). A message of any class must be counted
there and must not stop the input: the next valid message is handled.

Classes (counter in InputStats):
  garbage       random bytes as the header                       malformed_kinds["header"]
  not_map       msgpack that is not a map                        malformed_kinds["header"]
  version       another schema version                           malformed_kinds["version"]
  field         a field missing or of the wrong type             malformed_kinds["field"]
  stamps        malformed hop stamps                             malformed_kinds["stamps"]
  dtype         a dtype that is object, empty, huge or nonsense  malformed_kinds["dtype"]
  shape         a shape that is negative, deep or claims > 2 GiB malformed_kinds["shape"]
  buffer        an inline array with no, short or extra buffers  malformed_kinds["frames"]
  no_header     the topic alone                                  malformed_kinds["frames"]
  topic         a topic the SUB prefix-matches but is not ours   malformed_kinds["topic"]
  ring          a shared-memory location outside this run        malformed_kinds["ring"]
  seq_back      a valid message whose seq goes back              seq_resets (and handled)
  seq_jump      a valid message whose seq leaps by 2**21         seq_jumps (and handled)
  oversize      a valid message over the input's max_bytes       oversize (ZeroMQ drops the
                                                                 peer; the input reconnects)
"""
from __future__ import annotations

import msgpack
import numpy as np

from .wire import SCHEMA_VERSION, encode_header

EXPECTED = {"garbage": ("malformed", "header"), "not_map": ("malformed", "header"),
            "version": ("malformed", "version"), "field": ("malformed", "field"),
            "stamps": ("malformed", "stamps"), "dtype": ("malformed", "dtype"),
            "shape": ("malformed", "shape"), "buffer": ("malformed", "frames"),
            "no_header": ("malformed", "frames"), "topic": ("malformed", "topic"),
            "ring": ("malformed", "ring"), "seq_back": ("seq_resets", None),
            "seq_jump": ("seq_jumps", None), "oversize": ("oversize", None)}
# the classes sent in every round (oversize is paced apart: each one costs a reconnection)
ROUND = tuple(c for c in EXPECTED if c != "oversize")


class HostileFactory:
    """Messages for the topic ``<source>/<output>``; valid ones carry increasing seqs."""

    def __init__(self, source: str, output: str, seed: int = 0) -> None:
        self.source, self.output = source, output
        self.topic = f"{source}/{output}".encode()
        self.rng = np.random.default_rng(seed)
        self.seq = 0

    def _header(self, seq=None, **kw) -> bytes:
        base = dict(source=self.source, output=self.output,
                    seq=self.seq if seq is None else seq, t_sim=0.0, tick=0,
                    stamps=[[self.source, 0, 1]], arrays=[], meta={})
        base.update(kw)
        return encode_header(**base)

    def _raw(self, **changes) -> bytes:
        h = {"v": SCHEMA_VERSION, "src": self.source, "out": self.output, "seq": 0,
             "ts": 0.0, "tick": 0, "st": [], "a": [], "m": {}}
        h.update(changes)
        return msgpack.packb({k: v for k, v in h.items() if v is not ...}, use_bin_type=True)

    def valid(self, meta: dict | None = None, payload: bytes = b"") -> list[bytes]:
        """A well-formed message (an inline uint8 array when ``payload``)."""
        arrays = [["a", "|u1", [len(payload)], None]] if payload else []
        frames = [self.topic, self._header(arrays=arrays, meta=meta or {})]
        if payload:
            frames.append(payload)
        self.seq += 1
        return frames

    def make(self, kind: str, max_bytes: int = 0) -> list[bytes]:
        r = self.rng
        pick = lambda options: options[int(r.integers(len(options)))]   # noqa: E731
        t = self.topic
        if kind == "garbage":
            return [t, r.bytes(int(r.integers(1, 200)))]
        if kind == "not_map":
            return [t, msgpack.packb(pick([[1, 2, 3], 7, "text", None, 1.5, [{}]]))]
        if kind == "version":
            return [t, self._raw(v=pick([0, SCHEMA_VERSION + 1, "1", None, -1]))]
        if kind == "field":
            return [t, self._raw(**pick([{"src": 3}, {"seq": -1}, {"seq": "x"}, {"m": []},
                                         {"ts": "now"}, {"tick": 1.5}, {"st": ...},
                                         {"seq": 1 << 63}, {"a": {}}]))]
        if kind == "stamps":
            return [t, self._raw(st=pick([[["x"]], [[1, 2, 3]], [["a", -1, 0]],
                                          [["a", 0, 1]] * 65, [None]]))]
        if kind == "dtype":
            desc = pick(["O", "|V0", "<U1000000", "not a dtype", [[["x", "O", 0]], 8],
                         [[["x", "<f4", 0]] * 70, 4]])
            return [t, self._header(arrays=[["a", desc, [1], None]]), b"\0" * 8]
        if kind == "shape":
            shape = pick([[-1], [1] * 9, [1 << 40, 1 << 40], "x", [2 ** 63]])
            return [t, self._header(arrays=[["a", "<f8", shape, None]]), b"x"]
        if kind == "buffer":
            hdr = self._header(arrays=[["a", "|u1", [16], None]])
            return pick([[t, hdr], [t, hdr, b"short"], [t, hdr, b"x" * 16, b"extra"]])
        if kind == "no_header":
            return [t]
        if kind == "topic":
            return [t + pick([b"2", b"/x", b"\xff"]), self._header()]
        if kind == "ring":
            loc = pick([["sebvs-other-run-x", 0, 0, 2], ["/etc/passwd", 0, 0, 2],
                        ["sebvs-../../x", 0, 0, 2]])
            return [t, self._header(arrays=[["a", "|u1", [8], loc]])]
        if kind == "seq_back":
            frames = [t, self._header(seq=max(self.seq - 5, 0))]
            return frames
        if kind == "seq_jump":
            self.seq += 1 << 21
            frames = [t, self._header()]
            self.seq += 1
            return frames
        if kind == "oversize":
            return self.valid(payload=b"\0" * (max_bytes + 1024))
        raise ValueError(f"unknown hostile class {kind!r} (one of {', '.join(EXPECTED)})")
