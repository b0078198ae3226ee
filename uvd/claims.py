"""One process a resource: an abstract UNIX socket named for it, bound and held while the
process runs. The kernel frees the name when the process ends, however it ends (no stale lock
file after a crash or a SIGKILL), and a second claimant learns which process holds it.

The daemon claims its CAN bus (:func:`uvd.runtime.can_component.claim_bus`); sim-bridge
claims the bus its emulated drives answer on and the links of its instruments
(:meth:`sim_bridge.bridge.SimBridge.run`): a second one would answer as the same nodes and take
the links over. ``uvd campaign`` claims the folder it fills (:mod:`uvd.commands.campaign`): a
second campaign into it would run every run again beside the first.
"""

from __future__ import annotations

import errno
import hashlib
import socket
import struct


class Taken(OSError):
    """The resource is held by another process (``holder``: "process N" or "another
    process")."""

    def __init__(self, what: str, holder: str):
        super().__init__(errno.EADDRINUSE, f"{what} is held by {holder}")
        self.what, self.holder = what, holder


def bus_name(bus) -> str:
    """A CAN bus (``[can.bus]``, drivers' CanBusConfig) as it is claimed and named:
    ``"<interface> <channel>"``, with ``" port N"`` for udp_multicast."""
    where = f"{bus.interface} {bus.channel}"
    return where + f" port {bus.port}" if bus.interface == "udp_multicast" else where


def claim(kind: str, where: str) -> socket.socket:
    """Hold ``where`` (a bus, a path) for this process under ``kind``; the returned socket is
    the claim (closing it, or the process ending, gives it up).

    Raises
    ------
    Taken
        Another process holds it.
    OSError
        The claim cannot be made at all.
    """
    # an abstract name holds 107 bytes: a longer one (an slcan adapter's by-id path) by its
    # digest
    key = where if len(where) <= 90 else hashlib.sha256(where.encode()).hexdigest()
    name = f"\0uvd-{kind} {key}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        sock.bind(name)
        sock.listen(4)
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise Taken(where, _holder(name)) from None
        raise
    return sock


def _holder(name: str) -> str:
    """Who holds the claim ``name``: "process N" from its socket's credentials."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(0.5)
        try:
            s.connect(name)
            pid, _, _ = struct.unpack("3i", s.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED,
                                                         struct.calcsize("3i")))
        except OSError:
            return "another process"
    return f"process {pid}"
