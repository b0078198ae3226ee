"""A test rig: the emulators on a fresh bus, in this process or in a second one.

Shared by the CAN contract tests and ``uvd bench can``. :func:`start_rig` gives the same
interface whichever way the emulators run:

* ``"virtual"`` — :class:`~sim_bridge.amplifiers.emulators.CanEmulators` in this process on a
  python-can ``virtual`` channel of a unique name;
* ``"udp_multicast"`` — ``python -m sim_bridge.amplifiers`` in a second process, on an
  interface-local IPv6 group (``ff11::``, never leaves this machine) and a free UDP port, so
  concurrent runs do not hear each other.
"""

from __future__ import annotations

import contextlib
import os
import time
import uuid
from dataclasses import dataclass, field

import numpy as np

from drivers.can.config import CanBusConfig, DepthConfig
from sim_bridge.amplifiers.emulators import CanEmulators
from sim_bridge.amplifiers.process import EmulatorProcess
from uvd.io.vehicle import load_vehicle
from uvd.netports import free_port

KINDS = ("virtual", "udp_multicast")


@contextlib.contextmanager
def realtime_priority(priority: int = 10):
    """Run this thread, and threads it starts, at SCHED_FIFO (best effort), as a daemon would.

    Yields whether it applied; restores normal scheduling on exit.
    """
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        applied = True
    except (OSError, AttributeError):
        applied = False
    try:
        yield applied
    finally:
        if applied:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def local_group() -> str:
    """A random interface-local IPv6 multicast group (ff11::/16)."""
    a, b = (int(x) for x in np.random.default_rng().integers(1, 0xFFFF, 2))
    return f"ff11::7576:{a:x}:{b:x}"


@dataclass
class Rig:
    """The emulators and the bus configuration a driver needs to reach them."""

    kind: str
    bus_cfg: CanBusConfig
    handle: object
    node_ids: tuple[int, ...]
    pressure_node: int | None
    extra: dict = field(default_factory=dict)

    def call(self, op: str, **kw) -> dict:
        """A control command (see :meth:`CanEmulators.call`)."""
        return self.handle.call(op, **kw)

    def close(self) -> dict | None:
        if isinstance(self.handle, EmulatorProcess):
            stats = self.handle.stop()
            self.handle.kill()
            return stats
        stats = self.handle.stats(history=True)
        self.handle.close()
        return stats


def start_rig(kind: str, *, vehicle: str = "jhu-rov", node_ids=(1, 2, 3, 4, 5, 6),
              pressure_node: int | None = 32, depth_m: float = 1.0,
              duration_s: float = 300.0, realtime: bool = True) -> Rig:
    """Start the emulators of ``vehicle`` on a fresh bus of ``kind`` (bounded in time).

    ``realtime``: the second process asks for SCHED_FIFO priority (best effort) — it stands
    in for drives, which answer on time whatever else the machine is doing.
    """
    if kind == "virtual":
        cfg = CanBusConfig(interface="virtual", channel=f"uvd-{uuid.uuid4().hex[:12]}")
        emu = CanEmulators(cfg, load_vehicle(vehicle).thrusters, node_ids,
                           pressure_node=pressure_node, depth_m=depth_m,
                           depth_cfg=DepthConfig()).open()
        return Rig(kind, cfg, emu, tuple(node_ids), pressure_node)
    if kind == "udp_multicast":
        group, port = local_group(), free_port("udp", "::1")
        cfg = CanBusConfig(interface="udp_multicast", channel=group, port=port)
        extra = ["--vehicle", vehicle, "--nodes", ",".join(str(n) for n in node_ids),
                 "--depth", str(depth_m)]
        if pressure_node is not None:
            extra += ["--pressure-node", str(pressure_node)]
        if realtime:
            extra.append("--realtime")
        proc = EmulatorProcess(group, port, duration_s=duration_s, extra=extra).start()
        return Rig(kind, cfg, proc, tuple(node_ids), pressure_node)
    raise ValueError(f"unknown rig kind {kind!r}; known: {KINDS}")


def run_cycles(group, n: int, thrust_n, period_s: float = 0.01, on_cycle=None) -> list:
    """``n`` command cycles at absolute deadlines ``period_s`` apart; returns the statuses.

    ``thrust_n`` is an array (N,) or a function of the cycle index returning one;
    ``on_cycle(i, status)`` is called after each write.
    """
    statuses = []
    t_next = time.monotonic()
    for i in range(n):
        cmd = thrust_n(i) if callable(thrust_n) else thrust_n
        st = group.write(cmd)
        statuses.append(st)
        if on_cycle is not None:
            on_cycle(i, st)
        t_next += period_s
        delay = t_next - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    return statuses
