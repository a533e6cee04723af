"""Where a chain's time goes: each hop of an end-to-end chain split into four components.

A chain instance is one message's path, e.g. sim > camera > emulator > accumulator >
policy > sim: the stamps it carries ([actor, recv_ns, send_ns] per hop, recv_ns being the
handler start there) and, for each consumer on the path, the telemetry record of the
message it received (``RECORD_FIELDS`` in profiler.py), joined on (actor, handler start).
All times are ``time.monotonic_ns()`` of one host.

For the hop producer P -> consumer C, with

    s       P's send stamp (``emit`` called)
    slept   C's event loop entered select() in the loop iteration that took the message
    woke    ... and returned from it (``inputs.LoopClock``)
    taken   C's reader callback began to take the message off its socket
    start   C's handler started (= C's recv stamp)
    send'   C's send stamp on the chain (its emit), or its handler end at the chain's end

the components are, in ns:

    wakeup     = max(0, woke - max(s, slept))
                 C's loop was asleep in select() after the send, until it woke with the
                 message ready: ZeroMQ's hand-off through both I/O threads and the kernel
                 waking C (and waiting for a CPU). User space cannot tell the few us of the
                 hand-off itself from the wake-ups, so both are here.
    queueing   = taken - s - wakeup
                 C's loop was awake but doing something else: earlier messages of the same
                 input, other inputs' handlers, the actor's own coroutine (the sim's
                 physics), control, telemetry. A message that reached C while it was busy
                 waits here; so does an earlier sleep of C that a timer, not this message,
                 ended (only the last select() before the take is stamped).
    transport  = start - taken
                 C's receive path: recv of the frames, header decode, ring mapping, the
                 sequence bookkeeping (the runtime's own per-message cost).
    handler    = send' - start
                 C's handler up to the emit that carried the chain on (the part of its
                 compute on the chain's path), or to the handler's end at the last actor.

They telescope: summed over the hops, they equal the chain figure (last handler end - the
first actor's send stamp) exactly, for every instance.
"""
from __future__ import annotations

COMPONENTS = ("queueing", "wakeup", "transport", "handler")


def split_hops(stamps: list, end_ns: int, arrivals: list) -> list[dict] | None:
    """Per hop of one chain instance, the four components in ns.

    ``stamps`` the chain's stamps; ``end_ns`` the last actor's handler end; ``arrivals``
    for each consumer (stamps[1:] and the last actor), its (slept, woke, taken, start) or
    None when its record is missing. Returns None if any is missing, unstamped (woke 0: a
    loop without ``LoopClock``) or inconsistent (taken before the send, or after the
    handler start: not one host's clock).
    """
    if len(arrivals) != len(stamps):
        return None
    hops = []
    for j, arrival in enumerate(arrivals):
        if arrival is None:
            return None
        slept, woke, taken, start = arrival
        sent = stamps[j][2]
        leave = stamps[j + 1][2] if j + 1 < len(stamps) else end_ns
        if not (sent <= taken <= start <= leave) or not 0 < woke <= taken or woke < slept:
            return None
        wakeup = max(0, woke - max(sent, slept))
        hops.append({"queueing": taken - sent - wakeup, "wakeup": wakeup,
                     "transport": start - taken, "handler": leave - start})
    return hops
