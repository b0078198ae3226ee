"""The CAN side of the daemon: the bus, the amplifier group and the optional CiA 404 depth
sensor as one component, and the amplifiers' feedback as the cycle's typed
:class:`~uvd.runtime.cycle.ActuatorStatus` (:func:`actuator_status`).
"""

from __future__ import annotations

import asyncio
import gc
import logging
import socket

import numpy as np

from uvd.claims import Taken, bus_name, claim
from uvd.errors import TransportError
from uvd.runtime.config import Config, short_deadline
from uvd.runtime.cycle import ActuatorStatus
from uvd.runtime.mailbox import Mailbox

__all__ = ["CanComponent", "GcFreeze", "actuator_status", "claim_bus"]

log = logging.getLogger("uvd.daemon")

#: feedback faults the failsafe handles as missing feedback (``feedback_missing``), not as
#: amplifier faults: a silent node is an absence of data
_FEEDBACK_FAULTS = frozenset({"feedback_lost", "heartbeat_lost"})


def claim_bus(bus) -> socket.socket | None:
    """One daemon a CAN bus (``bus``: the ``[can.bus]`` section), held while the daemon runs
    (:func:`uvd.claims.claim`). A second daemon on the bus (``uvd run`` by hand beside the
    service) would configure the same amplifiers, restart them over NMT and send its zero
    targets between the first's: its start fails here, before it opens the bus, naming the
    process that holds it. None for ``virtual``, a bus within one process. ``uvd zero-thrust``
    claims nothing: it is how a vehicle is stopped, whoever runs."""
    if bus.interface == "virtual":
        return None
    where = bus_name(bus)
    try:
        return claim("can", where)
    except Taken as exc:
        raise TransportError(f"can: another daemon ({exc.holder}) already drives {where}: two "
                             "daemons would command the same amplifiers (stop it first, e.g. "
                             "systemctl stop uvd)") from None
    except OSError as exc:
        raise TransportError(f"can: cannot claim {where} for this daemon: {exc}") from exc


def actuator_status(fb, first_write_ns: int) -> ActuatorStatus:
    """The cycle's view of a :class:`drivers.can.amplifier.GroupFeedback`.

    Speeds only when every node's feedback is valid; faults named per node (node 0's are the
    bus's: ``bus_off``/``bus_closed`` set ``bus_off``, ``send_failed`` is a fault); the
    feedback's age counts from the first command at the earliest. ``faulted``: the thrusters
    whose node has a fault of its own — EMCY, FAULT, a reset, heartbeat lost (the amplifier
    source of η, :func:`uvd.runtime.cycle.amplifier_source`); ``feedback_lost`` alone (a few
    TPDOs missed: a loaded bus or machine, often transient) is not one — it stays the
    ``feedback_missing`` trigger's, aged against ``feedback_stale_s`` — and
    ``healthy_feedback_t_ns`` is the feedback's time over the nodes not ``faulted``."""
    faults: list[str] = []
    bus_off = False
    for nid, names in fb.faults.items():
        if nid == 0:
            for n in names:
                if n in ("bus_off", "bus_closed"):
                    bus_off = True
                elif n == "send_failed":
                    faults.append(f"bus: {n}")
            continue
        real = [n for n in names if n not in _FEEDBACK_FAULTS]
        if real:
            faults.append(f"node {nid}: {', '.join(real)}")
    oldest = max(min(n.t_ns for n in fb.nodes), first_write_ns)
    faulted = tuple(i + 1 for i, n in enumerate(fb.nodes)
                    if any(f != "feedback_lost" for f in n.faults))
    healthy = [n.t_ns for i, n in enumerate(fb.nodes) if i + 1 not in faulted]
    oldest_ok = max(min(healthy), first_write_ns) if healthy else 0
    return ActuatorStatus(omega_rad_s=fb.omega_rad_s if bool(fb.valid.all()) else None,
                          enabled=bool(fb.enabled.all()), faults=tuple(faults),
                          feedback_t_ns=oldest if oldest > 0 else None, bus_off=bus_off,
                          faulted=faulted,
                          healthy_feedback_t_ns=oldest_ok if oldest_ok > 0 else None)


def deadline_warnings(timeouts_ms: dict[int, int | None], rate_hz: float) -> list[str]:
    """What to warn of the RPDO deadlines drives left unconfigured keep
    (``[can.amplifiers] configure = false``: uvd wrote none, the drives run with their own;
    :meth:`drivers.can.AmplifierGroup.command_timeouts_ms`): one line per deadline, naming
    its nodes — too short for the loop (:func:`uvd.runtime.config.short_deadline`), or off
    (0: a drive keeps its last command when the daemon stops sending). Unknown ones (None)
    are not guessed at."""
    by_value: dict[int, list[int]] = {}
    for node, ms in timeouts_ms.items():
        if ms is not None:
            by_value.setdefault(ms, []).append(node)
    out = []
    for ms, nodes in sorted(by_value.items()):
        many = len(nodes) > 1
        who = (f"amplifier{'s' if many else ''} {', '.join(map(str, sorted(nodes)))} "
               f"{'keep their' if many else 'keeps its'} own")
        why = short_deadline(ms, rate_hz)
        if ms == 0:
            why = ("0 (off): a drive keeps its last command when the daemon stops sending "
                   "(its heartbeat consumer, 0x1016, is then the only guard)")
        if why:
            out.append(f"{who} RPDO deadline (0x1400:05; [can.amplifiers] "
                       f"configure = false): {why}")
    return out


class GcFreeze:
    """Last component to start: collect once, then freeze every object that exists.

    A full collection of the daemon's heap (numba, llvmlite, scipy: ~10⁵ objects) takes
    70–80 ms — a stall the loop would feel whenever Python decides to run one. Objects alive
    once the drivers are up live as long as the process; :func:`gc.freeze` moves them out of
    the collector's reach, so later collections only walk what the cycles allocate (µs).
    """

    name = "gc-freeze"

    async def start(self) -> None:
        gc.collect()
        gc.freeze()

    async def run(self) -> None:
        return None

    async def stop(self) -> None:
        return None


class CanComponent:
    """The CAN bus, the amplifier group and (optionally) the CiA 404 depth sensor.

    :meth:`start` opens the bus, configures and starts the amplifiers (SDO + NMT, blocking
    and bounded, in a worker thread), clears faults left from a previous run and sets the
    goal OPERATION ENABLED — reached over the next cycles with zero targets. A node that does
    not answer does not stop the start: it carries a fault and arming is refused.
    """

    name = "can"

    def __init__(self, cfg: Config, vehicle, depth_box: Mailbox | None = None, *,
                 tap=None) -> None:
        self.cfg = cfg
        self.tap = tap  # the bus's frame tap (a black-box recorder), set when it opens
        self.vehicle = vehicle
        self.depth_box = depth_box
        self.bus = None
        self.claim = None  # the bus held for this daemon (claim_bus)
        self.group = None
        self.depth = None
        self.recorder = None
        self.start_report = None
        self.last_can_depth = None
        self.first_write_ns = 0  # the feedback's age counts from the first command
        self.counters = {"feedback_invalid": 0, "write_failed": 0}

    def _open_bus(self) -> None:
        """Open the bus from the event loop's thread: its receive thread inherits that
        thread's scheduling (SCHED_FIFO when configured; the App then puts it one below the
        loop, with every other thread, :mod:`uvd.rtthreads`). A normally scheduled
        thread that holds the GIL while other processes preempt it would delay the loop by
        milliseconds (priority inversion through the GIL)."""
        from drivers.can import CanBus, CanRecorder
        c = self.cfg.can
        self.recorder = CanRecorder.from_config(c.log)
        self.bus = CanBus(c.bus, recorder=self.recorder)
        self.bus.tap = self.tap
        self.bus.open()

    def _open(self) -> None:
        from drivers.can import AmplifierGroup, CanDepthSensor
        c = self.cfg.can
        self.group = AmplifierGroup.from_config(self.bus, c.amplifiers, self.vehicle.thrusters)
        if c.depth.enabled:
            use = self.cfg.sensors.depth.source == "can" and self.depth_box is not None
            box = self.depth_box

            def on_sample(sample) -> None:
                self.last_can_depth = sample
                if use:
                    box.put(sample)
            self.depth = CanDepthSensor(self.bus, c.depth, on_sample=on_sample)
        self.start_report = self.group.start()
        if not self.start_report.ok:
            log.error("amplifiers not all started: %s", self.start_report.nodes)
        if not c.amplifiers.configure:
            for line in deadline_warnings(self.group.command_timeouts_ms(),
                                          self.cfg.loop.rate_hz):
                log.warning("%s", line)
        self.group.reset_faults()
        self.group.enable()
        if self.depth is not None and not self.depth.start():
            log.warning("CAN depth sensor %d: no sample within 1 s", c.depth.node_id)

    async def start(self) -> None:
        self.claim = claim_bus(self.cfg.can.bus)  # before any frame goes out
        self._open_bus()
        await asyncio.to_thread(self._open)  # SDO configuration: blocking, bounded

    async def run(self) -> None:
        return None

    async def recover(self) -> str:
        """The operator's failsafe reset, disarmed: the amplifiers that rebooted, left
        OPERATIONAL or failed their configuration started again, a fault reset to every drive
        in FAULT (:meth:`drivers.can.AmplifierGroup.recover`; its SDO exchanges in a thread,
        bounded). What was done, for the log ("" without amplifiers)."""
        if self.group is None:
            return ""
        report = await asyncio.to_thread(self.group.recover)
        started = ", ".join(f"node {n}: {why}" for n, why in report.nodes.items())
        return f"amplifiers started again ({started}), fault reset sent" if started else \
            "fault reset sent to the amplifiers"

    def log_trouble(self) -> str | None:
        """Why the CAN log (``[can.log]``) cannot write now; None: it writes, or there is
        none (yet)."""
        r = self.recorder
        return None if r is None else r.trouble()

    def log_counts(self) -> dict[str, int]:
        """The CAN log's frames lost (its queue full or their write failed) and failed
        writes, as the operator is told them."""
        r = self.recorder
        if r is None:
            return {"records_dropped": 0, "write_errors": 0, "bytes_given_up": 0}
        return {"records_dropped": r.dropped + r.write_errors, "write_errors": r.write_errors,
                "bytes_given_up": 0}

    # -- its part of the cycle (a hardware interface, uvd.runtime.interfaces) --

    def read(self, t_ns: int, armed: bool, parts) -> None:
        """The amplifiers' typed status (none fitted: None)."""
        group = self.group
        if group is not None:
            fb = group.read()
            if not bool(fb.valid.all()):
                self.counters["feedback_invalid"] += 1
            parts.actuators = actuator_status(fb, self.first_write_ns)

    def write(self, t_ns: int, thrust_n: np.ndarray) -> None:
        """The cycle's command to the amplifiers (RPDOs + SYNC); a failed send is counted
        (the bus reports it as a fault the next cycle reads)."""
        group = self.group
        if group is not None:
            if not self.first_write_ns:
                self.first_write_ns = t_ns
            if not group.write(thrust_n).ok:
                self.counters["write_failed"] += 1

    def zero(self) -> None:
        """Zero target on every amplifier (one cycle: RPDOs + SYNC); never raises."""
        if self.group is not None:
            self.group.write(np.zeros(len(self.group.nodes)))

    def disable(self) -> None:
        """Zero and disable voltage, release the heartbeat consumers, NMT pre-operational."""
        if self.group is not None:
            self.group.shutdown(cycles=2, period_s=0.01, release_consumer=True)

    def close_now(self) -> None:
        """Close the bus and stop its recorder, in this thread (blocking, bounded)."""
        if self.bus is not None:
            self.bus.close()
        if self.recorder is not None:
            self.recorder.stop(timeout=0.5)
        if self.claim is not None:
            self.claim.close()
            self.claim = None

    async def stop(self) -> None:
        await asyncio.to_thread(self.close_now)

