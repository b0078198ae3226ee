"""A free local port for the listeners of tests, benchmarks and simulated runs.

Asking the kernel for port 0 and closing the socket hands back a port from the *ephemeral*
range (``/proc/sys/net/ipv4/ip_local_port_range``, 32768–60999 by default). Until the caller
binds it again, the kernel may give that very port to any outgoing connection or unbound
sender on the machine — a Zenoh session connecting to its peers is enough — and the listener
then fails with "Address already in use". :func:`free_port` instead picks at random from
below (or above) that range, where the kernel never assigns ports by itself, and checks that
nobody is bound to it now. Only another explicit bind to the same port can still take it.
"""

from __future__ import annotations

import random
import socket

_RANGE_FILE = "/proc/sys/net/ipv4/ip_local_port_range"
_LOWEST = 10000  # keep clear of well-known and registered service ports below
_TRIES = 200
_rng = random.Random()  # its own generator: never draws from (or reseeds) the global one


def ephemeral_range() -> tuple[int, int]:
    """The kernel's ephemeral port range (the Linux default where it cannot be read)."""
    try:
        with open(_RANGE_FILE) as f:
            lo, hi = (int(v) for v in f.read().split())
        return lo, hi
    except (OSError, ValueError):
        return 32768, 60999


def _candidates() -> range:
    lo, hi = ephemeral_range()
    if lo - _LOWEST >= 1000:
        return range(_LOWEST, lo)
    if 65535 - hi >= 1000:
        return range(hi + 1, 65536)
    return range(1024, 65536)  # a machine with no room outside: any unprivileged port


def free_port(kind: str = "tcp", host: str = "127.0.0.1") -> int:
    """A ``kind`` ("tcp" or "udp") port on ``host`` that nobody is bound to right now,
    outside the ephemeral range. Raises :class:`OSError` if none is found in 200 tries."""
    if kind not in ("tcp", "udp"):
        raise ValueError(f"free_port: kind must be 'tcp' or 'udp', got {kind!r}")
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    stype = socket.SOCK_STREAM if kind == "tcp" else socket.SOCK_DGRAM
    ports = _candidates()
    for _ in range(_TRIES):
        port = _rng.choice(ports)
        with socket.socket(family, stype) as s:
            try:
                s.bind((host, port))
            except OSError:
                continue
        return port
    raise OSError(f"free_port: no free {kind} port on {host} in {_TRIES} tries "
                  f"({ports.start}–{ports.stop - 1})")


def port_taken(kind: str, host: str, port: int) -> bool:
    """Whether a ``kind`` ("tcp" or "udp") socket cannot be bound to ``host``:``port`` now
    (somebody holds it; a TCP port in TIME_WAIT counts too)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    stype = socket.SOCK_STREAM if kind == "tcp" else socket.SOCK_DGRAM
    with socket.socket(family, stype) as s:
        try:
            s.bind((host, port))
        except OSError:
            return True
    return False
