"""tcp ports for a run's endpoints, chosen before the actors that bind them start.

The supervisor names every endpoint before it spawns anyone (a consumer may connect
before its producer binds: zmq retries), so a port is probed free at one moment and bound
by an actor a second or so later. Two takers in between are common on a busy machine:

- the kernel, handing the port out as the local end of an outgoing connection, when the
  port lies in the ephemeral range (on Linux /proc/sys/net/ipv4/ip_local_port_range,
  32768-60999 by default). Every zmq reconnect attempt to a not yet bound endpoint takes
  a fresh one, so a starting run is its own most frequent taker;
- the same run, when the kernel answers two probes for a free port with the same one.

So ports are drawn at random below the ephemeral range, probed, and never handed out twice
by one ``TcpPorts``. What is left (another process binding the port in the moment between
probe and bind) is rare, and the actor's bind error then names the port.
"""
from __future__ import annotations

import random
import socket
from pathlib import Path

# below this are the ports services are configured on; above the ephemeral range's start
# the kernel hands ports out by itself
LOWEST = 20000
# where the ephemeral range starts when the system does not say (IANA's dynamic ports,
# the BSDs' and macOS's default)
IANA_EPHEMERAL_START = 49152
EPHEMERAL_RANGE_FILE = Path("/proc/sys/net/ipv4/ip_local_port_range")


def ephemeral_start(path: Path = EPHEMERAL_RANGE_FILE) -> int:
    """The first port the kernel may pick for an outgoing connection."""
    try:
        return int(path.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return IANA_EPHEMERAL_START


def bindable(host: str, ports: range) -> bool:
    """Whether every port of ``ports`` can be bound on ``host`` just now."""
    socks = []
    try:
        for port in ports:
            socks.append(socket.socket())
            socks[-1].bind((host, port))
        return True
    except OSError:
        return False
    finally:
        for sock in socks:
            sock.close()


class TcpPorts:
    """The ports one run (or one test) hands out on ``host``: each free when probed, none
    twice, none in the ephemeral range unless that range leaves no room below it."""

    def __init__(self, host: str = "127.0.0.1", tries: int = 200):
        self.host = host
        self.tries = tries
        self.given: set[int] = set()
        self._random = random.SystemRandom()
        self._top = ephemeral_start()       # read once: a run asks for a port per endpoint

    def one(self) -> int:
        return self.block(1)

    def block(self, n: int) -> int:
        """The first of ``n`` consecutive ports: a `[hosts]` table's `port` for tests and
        benchmarks that run several hosts on one machine."""
        top = self._top
        for _ in range(self.tries):
            base = (self._random.randrange(LOWEST, top - n + 1) if top - n >= LOWEST
                    else self._kernel_pick())
            ports = range(base, base + n)
            if base + n > 65536 or self.given.intersection(ports):
                continue
            if bindable(self.host, ports):
                self.given.update(ports)
                return base
        raise RuntimeError(f"no {n} consecutive free tcp ports on {self.host} in "
                           f"{self.tries} tries")

    def _kernel_pick(self) -> int:
        with socket.socket() as s:
            s.bind((self.host, 0))
            return s.getsockname()[1]


def free_port_block(n: int, host: str = "127.0.0.1") -> int:
    """``n`` consecutive ports free just now, for one caller that needs one block; callers
    that need several share one ``TcpPorts`` so that the blocks cannot overlap."""
    return TcpPorts(host).block(n)
