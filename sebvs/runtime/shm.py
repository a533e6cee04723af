"""Shared-memory rings: one per actor output, so large arrays are written once and read in place.

A ring is a file in /dev/shm (what POSIX ``shm_open`` creates on Linux) mapped by the
producer and by every consumer::

    [ page 0: magic, n_slots, slot_bytes, generation[n_slots] (int64) | slot 0 | slot 1 | ... ]

Each slot carries a generation counter used as a seqlock: the producer makes it odd
while it writes and even once the slot is published; the descriptor on the wire carries
the even value. A reader whose slot no longer shows that value knows the producer has
lapped it and drops the message instead of reading torn data.

We map files directly instead of using ``multiprocessing.shared_memory``: on Python 3.11
every process that attaches registers the segment with its resource tracker, which then
unlinks it (and warns) when any consumer exits. Ownership here is simple and explicit:
the producer creates, the supervisor removes everything of the run by name prefix, also
after a crash.

/dev/shm is shared by every local user, and ring names arrive in message headers, so
neither side trusts a name: the producer creates its files exclusively (O_EXCL) under a
name with a random part nobody can create ahead of it, and a reader opens only a plain
file of its own user, without following links or blocking on a FIFO, whose header
describes exactly the file's size.

Every page of a ring is allocated when the ring is created (posix_fallocate): a full
/dev/shm then fails there, with ShmFull naming the sizes, never later as a SIGBUS in the
middle of a write.

A ring grows by moving to a new, larger file. The outgrown file stays until the new one
has gone round once: messages already sent still name it, and a consumer that has not
mapped it yet would otherwise lose them to a missing file. Once n_slots newer messages
have been sent, an old one is lapped whichever file it names.
"""
from __future__ import annotations

import mmap
import os
import re
import secrets
import stat
from pathlib import Path

import numpy as np

SHM_DIR = Path("/dev/shm")
MAGIC = 0x53454256_53524E47  # "SEBVSRNG"
PAGE = 4096
ALIGN = 64
MAX_SLOTS = (PAGE - 24) // 8      # generation counters that fit the header page
RING_NAME = re.compile(r"sebvs-[A-Za-z0-9_.-]{1,200}")


def _round_up(n: int, to: int) -> int:
    return (n + to - 1) // to * to


def packed_offsets(nbytes: list[int]) -> tuple[list[int], int]:
    """Offsets of arrays packed into one slot, each 64-byte aligned, and the total size."""
    offsets, pos = [], 0
    for n in nbytes:
        offsets.append(pos)
        pos = _round_up(pos + n, ALIGN)
    return offsets, pos


class ShmFull(OSError):
    """A ring does not fit the shared-memory file system: raised when the ring is created,
    naming the budget, instead of a SIGBUS at the first write past the free pages."""


def _reserve_pages(fd: int, size: int, path: Path) -> None:
    """Allocate every page of the ring now (ftruncate alone leaves a sparse file, and a
    write to a page tmpfs cannot back kills the writer with SIGBUS)."""
    try:
        os.posix_fallocate(fd, 0, size)
    except OSError as exc:
        try:
            st = os.statvfs(path.parent)
            free = f"{st.f_bavail * st.f_frsize:,} bytes free of {st.f_blocks * st.f_frsize:,}"
        except OSError:
            free = "free space unknown"
        raise ShmFull(exc.errno, f"shared-memory ring {path} needs {size:,} bytes and "
                      f"{path.parent} has {free} ({exc.strerror}): free space there or "
                      f"lower the topology's queue / image sizes") from None


def ring_bytes(n_slots: int, payload_bytes: int) -> int:
    """What a ring of `n_slots` slots for `payload_bytes`-byte messages takes in SHM_DIR."""
    return PAGE + int(n_slots) * _round_up(max(int(payload_bytes), PAGE), PAGE)


def free_bytes(directory: Path = SHM_DIR) -> int:
    """Bytes an unprivileged writer may still allocate in `directory`."""
    st = os.statvfs(directory)
    return st.f_bavail * st.f_frsize


def check_budget(rings: dict[str, int], directory: Path = SHM_DIR) -> None:
    """Refuse, before any process starts, a set of rings ({label: bytes}) that the
    shared-memory file system cannot hold all at once, naming the largest."""
    need = sum(rings.values())
    if not rings or need <= (free := free_bytes(directory)):
        return
    largest = ", ".join(f"{label} {n / 2**20:,.1f} MiB"
                        for label, n in sorted(rings.items(), key=lambda kv: -kv[1])[:3])
    raise ShmFull(28, f"this topology's shared-memory rings need {need / 2**20:,.1f} MiB and "
                      f"{directory} has {free / 2**20:,.1f} MiB free (largest: {largest}): "
                      f"free space there, or lower queue depths or image sizes")


class RingWriter:
    """The producer side of one output's ring; grows (as a new file) when a sample outgrows it."""

    def __init__(self, prefix: str, n_slots: int, slot_bytes: int = 0):
        self.prefix = prefix          # e.g. "sebvs-1a2b3c4d-camera-rgb"
        self.n_slots = int(n_slots)
        self.generation_count = 0     # how many files this ring has had
        self.name = ""
        self.slot_bytes = 0
        self._mm = None
        self._gen = None
        self._next = 0
        # outgrown files, each with the reserves left before it is unlinked
        self._retired: list[list] = []
        if slot_bytes:
            self._create(slot_bytes)

    def _create(self, slot_bytes: int) -> None:
        if self.name:
            self._retired.append([self.name, self.n_slots])
        self.close(unlink=False)
        self.generation_count += 1
        # pid and generation say whose it is (the supervisor removes a dead producer's by
        # them); the random part makes the name impossible to create ahead of us
        self.name = f"{self.prefix}-{os.getpid()}-{self.generation_count}-{secrets.token_hex(4)}"
        self.slot_bytes = _round_up(max(slot_bytes, PAGE), PAGE)
        size = PAGE + self.n_slots * self.slot_bytes
        if not 1 <= self.n_slots <= MAX_SLOTS:
            raise ValueError(f"{self.n_slots} slots: a ring has 1..{MAX_SLOTS} "
                             "(the generation counters fill one header page)")
        try:
            fd = os.open(SHM_DIR / self.name,
                         os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
        except FileExistsError:
            raise FileExistsError(f"ring {SHM_DIR / self.name} already exists: another "
                                  "process created it first; refusing to share it") from None
        try:
            os.ftruncate(fd, size)
            _reserve_pages(fd, size, SHM_DIR / self.name)
            self._mm = mmap.mmap(fd, size)
        except BaseException:
            os.unlink(SHM_DIR / self.name)
            self.name, self.slot_bytes = "", 0     # no ring: the next reserve tries again
            raise
        finally:
            os.close(fd)
        head = np.ndarray((3,), np.int64, buffer=self._mm)
        head[:] = (MAGIC, self.n_slots, self.slot_bytes)
        self._gen = _generations(self._mm, self.n_slots)
        self._next = 0

    def reserve(self, nbytes: int) -> tuple[int, memoryview]:
        """Claim the next slot for writing (generation made odd); returns (slot, writable view)."""
        if nbytes > self.slot_bytes:
            # grow with headroom so a slowly growing payload does not recreate every time
            self._create(max(nbytes, 2 * self.slot_bytes) if self.slot_bytes else nbytes)
        elif self._retired:
            self._unlink_lapped()
        slot = self._next
        self._next = (slot + 1) % self.n_slots
        self._gen[slot] += 2 if self._gen[slot] & 1 else 1
        start = PAGE + slot * self.slot_bytes
        return slot, memoryview(self._mm)[start:start + nbytes]

    def commit(self, slot: int) -> int:
        """Publish a reserved slot; returns the (even) generation to put on the wire."""
        gen = self._gen[slot] + 1
        self._gen[slot] = gen
        return gen

    def _unlink_lapped(self) -> None:
        """Count one reserve against every outgrown file; unlink those now lapped."""
        for entry in self._retired:
            entry[1] -= 1
        for name, _ in [e for e in self._retired if e[1] <= 0]:
            _unlink(name)
        self._retired = [e for e in self._retired if e[1] > 0]

    def close(self, unlink: bool = True) -> None:
        if unlink:
            for name, _ in self._retired:
                _unlink(name)
            self._retired = []
        if self._mm is not None:
            self._gen.release()
            self._gen = None
            try:
                self._mm.close()
            except BufferError:
                pass  # a numpy view is still alive; the mapping goes when it does
            self._mm = None
        if unlink and self.name:
            _unlink(self.name)


class RingReader:
    """The consumer side: maps rings by name on first use and checks slot generations."""

    def __init__(self, max_maps: int = 16):
        self._maps: dict[str, tuple[mmap.mmap, memoryview, int, int]] = {}
        self.max_maps = max_maps

    def _map(self, name: str):
        entry = self._maps.get(name)
        if entry is not None:
            return entry
        if not RING_NAME.fullmatch(name):
            raise ValueError(f"refusing ring name {name[:80]!r}")
        # O_NONBLOCK: opening a FIFO planted under a ring's name would otherwise hang us
        fd = os.open(SHM_DIR / name, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
        try:
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode):
                raise ValueError(f"ring {name!r} is not a regular file")
            if st.st_uid != os.geteuid():
                raise ValueError(f"ring {name!r} belongs to uid {st.st_uid}, not us")
            if st.st_size < PAGE:
                raise ValueError(f"ring {name!r} is {st.st_size} bytes, smaller than its header")
            mm = mmap.mmap(fd, st.st_size, prot=mmap.PROT_READ)
        finally:
            os.close(fd)
        magic, n_slots, slot_bytes = (int(v) for v in np.ndarray((3,), np.int64, buffer=mm))
        if (magic != MAGIC or not 1 <= n_slots <= MAX_SLOTS or slot_bytes < PAGE
                or slot_bytes % PAGE or PAGE + n_slots * slot_bytes != st.st_size):
            mm.close()
            raise ValueError(f"ring {name!r} has a bad header ({n_slots} slots of "
                             f"{slot_bytes} B in a {st.st_size} B file)")
        gen = _generations(mm, int(n_slots))
        if len(self._maps) >= self.max_maps:  # producers that grew or restarted leave old rings
            _release(self._maps.pop(next(iter(self._maps))))
        entry = (mm, gen, int(n_slots), int(slot_bytes))
        self._maps[name] = entry
        return entry

    def view(self, name: str, slot: int, offset: int, nbytes: int, generation: int):
        """A read-only view of the bytes, or None if the slot was overwritten (or is being written)."""
        mm, gen, n_slots, slot_bytes = self._map(name)
        if not (0 <= slot < n_slots and 0 <= offset and offset + nbytes <= slot_bytes):
            raise ValueError(f"location slot={slot} offset={offset} nbytes={nbytes} "
                             f"outside ring {name!r} ({n_slots} x {slot_bytes} B)")
        if gen[slot] != generation:
            return None
        start = PAGE + slot * slot_bytes + offset
        return memoryview(mm)[start:start + nbytes]

    def still_valid(self, name: str, slot: int, generation: int) -> bool:
        entry = self._maps.get(name)
        return entry is not None and entry[1][slot] == generation

    def close(self) -> None:
        for entry in self._maps.values():
            _release(entry)
        self._maps.clear()


def _unlink(name: str) -> None:
    try:
        os.unlink(SHM_DIR / name)
    except FileNotFoundError:
        pass


def _generations(mm: mmap.mmap, n_slots: int) -> memoryview:
    """The ring's per-slot generation counters as int64 items.

    A memoryview rather than a numpy array: reading or bumping one counter is a plain
    Python int operation, several times cheaper than a numpy scalar, and both sit on
    every message's path.
    """
    return memoryview(mm)[24:24 + 8 * n_slots].cast("q")


def _release(entry: tuple) -> None:
    mm, gen = entry[0], entry[1]
    gen.release()
    try:
        mm.close()
    except BufferError:
        pass  # a consumer still holds a view; the mapping goes when it does


def remove_run_rings(run_id: str, pattern: str = "*") -> list[str]:
    """Unlink the rings of a run matching ``pattern`` (all by default), e.g. after a crash."""
    removed = []
    for path in SHM_DIR.glob(f"sebvs-{run_id}-{pattern}"):
        try:
            path.unlink()
            removed.append(path.name)
        except FileNotFoundError:
            pass
    return removed
