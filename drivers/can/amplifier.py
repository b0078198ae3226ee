"""Thruster amplifiers over CANopen: one CiA 402 drive per thruster, driven every cycle.

The JHU ROV commands each thruster's current-mode amplifier with a current computed from an
a-priori steady-state thruster calibration, without feedback (thesis App. A.1). Here each
amplifier is a CiA 402 drive in cyclic synchronous torque (or profile torque) mode:

* **command** — every control cycle :meth:`AmplifierGroup.write` sends each drive its RPDO
  (controlword 0x6040 + target torque 0x6071, in 1/1000 of rated torque) and then one SYNC.
  The target is ``thrust / thrust_per_permille_n`` (the linear steady-state calibration),
  rounded, clamped to ±``max_torque_permille``; non-finite commands become 0. Frames are sent
  directly, once, from the caller's thread; a frame the bus cannot take now is dropped, never
  queued (no ``send_periodic``: a hung daemon must not keep the last command going).
* **state machine** — the controlword of each cycle moves the drive one step towards the goal
  (:meth:`enable`, :meth:`disable`, :meth:`quick_stop`) from its last statusword; a non-zero
  target is only sent to a drive that reports OPERATION ENABLED and has no fault. A drive in
  FAULT stays there until :meth:`reset_faults` is called.
* **feedback** — each drive answers the SYNC with its TPDO: statusword, torque actual and
  velocity actual (propeller speed ω, from which thrust is estimated as f = k ω|ω|, App. A.1);
  a speed beyond :data:`SPEED_PLAUSIBLE_FACTOR` times the thruster's speed at its largest
  thrust is no propeller's (a corrupt or foreign frame): that feedback is not ``valid``, and is
  counted (``implausible_speed``) and logged.
* **safety** — a target is non-zero only for a drive in OPERATION ENABLED with no fault of
  its own while the bus has none of ``bus_off``, ``bus_closed``, ``send_failed``
  (``error_passive``/``error_warning`` are reported, but frames still get through);
* **faults** — EMCY codes are named (:data:`drivers.can.cia402.EMCY_FAULTS`); heartbeats are
  consumed (``heartbeat_lost``) and produced by the daemon from :meth:`write` itself;
  ``max_failed_cycles`` cycles in a row without a drive's feedback raise ``feedback_lost`` on
  it, and as many cycles with a failed send raise ``send_failed`` on the group.

Failure is data: nothing here raises through the cycle; :meth:`write` returns a
:class:`WriteStatus` and :meth:`read` a :class:`GroupFeedback` carrying the faults.

Examples
--------
The daemon's use, on the emulators (see ``docs/can.md``)::

    bus = CanBus(cfg.bus).open()
    group = AmplifierGroup.from_config(bus, cfg.amplifiers, vehicle.thrusters)
    report = group.start()            # SDO configuration + NMT start (blocking, bounded)
    group.enable()
    while running:                    # the fixed-rate loop, e.g. 100 Hz
        fb = group.read()             # feedback of the previous SYNC, faults
        status = group.write(thrust_n)
    group.shutdown()                  # zero, disable voltage
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import canopen
import numpy as np

from drivers.can import cia402
from drivers.can.bus import ACTIVE, BUS_OFF, CLOSED, CanBus, FrameDropped
from drivers.can.config import AmplifierConfig, CanConfig
from uvd.errors import ConfigError

log = logging.getLogger(__name__)


class Thruster(Protocol):
    """What the amplifiers need of a thruster (``uvd.model.thrusters.ThrusterSpec`` is one;
    drivers do not import uvd)."""

    name: str
    k_thrust: float  # f = k ω|ω|, N/(rad/s)²
    max_thrust_n: float

#: the largest plausible propeller speed, in multiples of the speed at the thruster's largest
#: thrust, √(max_thrust_n / k_thrust): a drive reporting more (2³¹ counts, 2.1e6 rad/s on a
#: 250 rad/s thruster) reports no propeller's speed
SPEED_PLAUSIBLE_FACTOR = 2.0

NMT_OPERATIONAL = 5
NMT_PRE_OPERATIONAL = 127
_NMT_NAMES = {0: "boot_up", 4: "stopped", 5: "operational", 127: "pre_operational"}
#: Bus faults on which every target is zeroed (``error_passive``/``error_warning`` are not).
_ZEROING_BUS_FAULTS = frozenset({"bus_off", "bus_closed", "send_failed"})

OD_CONTROLWORD = 0x6040
OD_STATUSWORD = 0x6041
OD_TARGET_TORQUE = 0x6071
OD_TORQUE_ACTUAL = 0x6077
OD_VELOCITY_ACTUAL = 0x606C
OD_MODE = 0x6060
OD_MODE_DISPLAY = 0x6061
OD_MAX_TORQUE = 0x6072


def load_od(path: Path, node_id: int, where: str) -> canopen.ObjectDictionary:
    """Parse an EDS/DCF for ``node_id``; a missing or broken file is a ConfigError naming it."""
    if not Path(path).is_file():
        raise ConfigError(f"{where} eds: no object dictionary file at {str(path)!r}")
    try:
        return canopen.import_od(str(path), node_id)
    except Exception as exc:  # noqa: BLE001 - canopen raises many kinds here
        raise ConfigError(f"{where} eds: cannot read {str(path)!r}: "
                          f"{' '.join(str(exc).split())}") from exc


@dataclass(frozen=True, slots=True)
class AmplifierFeedback:
    """The last feedback of one amplifier.

    Attributes
    ----------
    node_id : int
    name : str
        The thruster's name.
    state : str
        CiA 402 power state from the statusword (:mod:`drivers.can.cia402`).
    nmt_state : str
        NMT state from the heartbeat (``operational``, ``pre_operational``, ...; ``unknown``
        before the first heartbeat).
    statusword : int
    torque_permille : int
        Torque actual (0x6077), 1/1000 of rated torque.
    omega_rad_s : float
        Propeller speed (velocity actual, 0x606C), rad/s.
    thrust_est_n : float
        k ω|ω| (App. A.1), N.
    t_ns : int
        Monotonic receive time of that feedback (0: none yet).
    fresh : bool
        It answers the latest SYNC.
    faults : tuple of str
        Active faults of this amplifier (empty when healthy).
    """

    node_id: int
    name: str
    state: str
    nmt_state: str
    statusword: int
    torque_permille: int
    omega_rad_s: float
    thrust_est_n: float
    t_ns: int
    fresh: bool
    faults: tuple[str, ...]

    @property
    def enabled(self) -> bool:
        return self.state == cia402.OPERATION_ENABLED and not self.faults


@dataclass(frozen=True)
class GroupFeedback:
    """Feedback of all amplifiers, in thruster order, with the faults of the group.

    Arrays have shape (N,): ``omega_rad_s`` (rad/s), ``thrust_est_n`` (N, k ω|ω|),
    ``torque_permille`` and the boolean ``valid`` (fresh, OPERATION ENABLED, no fault, a
    plausible speed) and
    ``enabled``. ``faults`` maps a node id to its active faults; key 0 holds the faults of the
    bus/group (``bus_off``, ``send_failed``, ...).
    """

    t_ns: int
    nodes: tuple[AmplifierFeedback, ...]
    omega_rad_s: np.ndarray
    thrust_est_n: np.ndarray
    torque_permille: np.ndarray
    valid: np.ndarray
    enabled: np.ndarray
    faults: dict[int, tuple[str, ...]]
    bus_state: str

    @property
    def all_enabled(self) -> bool:
        """Every amplifier is in OPERATION ENABLED without fault, and the bus has none."""
        return bool(self.enabled.all()) and not self.faults

    @property
    def ok(self) -> bool:
        return not self.faults


@dataclass(frozen=True)
class WriteStatus:
    """Outcome of one command cycle (:meth:`AmplifierGroup.write`).

    Attributes
    ----------
    cycle : int
    t_ns : int
        Monotonic time the cycle started.
    ok : bool
        Every RPDO and the SYNC were accepted by the bus.
    sent, dropped : int
        Frames accepted / dropped this cycle.
    nonfinite, clamped : int
        Commands replaced by 0 (NaN/inf or wrong shape) / clamped to the torque limit.
    targets_permille : np.ndarray
        Target torques actually put on the bus, (N,).
    duration_ns : int
        Time spent encoding and sending.
    """

    cycle: int
    t_ns: int
    ok: bool
    sent: int
    dropped: int
    nonfinite: int
    clamped: int
    targets_permille: np.ndarray
    duration_ns: int


@dataclass(frozen=True, slots=True)
class FaultEvent:
    """A fault raised or cleared (node_id 0 = the bus/group)."""

    t_ns: int
    node_id: int
    name: str
    raised: bool


@dataclass(frozen=True)
class StartReport:
    """Result of :meth:`AmplifierGroup.start`: per node ``"ok"`` or the reason it failed."""

    nodes: dict[int, str]
    duration_s: float

    @property
    def ok(self) -> bool:
        return all(v == "ok" for v in self.nodes.values())


@dataclass
class _Node:
    node_id: int
    name: str
    remote: canopen.RemoteNode
    k_thrust: float
    thrust_per_permille: float
    rpdo: object
    var_cw: object
    var_target: object
    feedback_pdo: object
    var_sw: object
    var_vel: object
    var_torque: object | None
    rpdo_event_timer: tuple[int, int] | None
    # written by the notifier thread (under the group lock)
    statusword: int = 0
    torque: int = 0
    velocity: int = 0
    tpdo_count: int = 0
    tpdo_ns: int = 0
    hb_state: int | None = None
    hb_ns: int = 0
    hb_count: int = 0
    bootups: int = 0
    emcy_active: dict[int, int] = field(default_factory=dict)
    emcy_count: int = 0
    # cycle thread only
    count_at_sync: int = 0
    missed: int = 0
    missed_total: int = 0
    last_cw: int = 0
    reset_cycles: int = 0
    start_error: str = ""
    started_ns: int = 0
    command_timeout_ms: int | None = None  # the RPDO deadline it runs with (None: unknown)
    bootups_at_start: int = 0


class AmplifierGroup:
    """The six (or N) thruster amplifiers on one CAN bus.

    Parameters
    ----------
    bus : CanBus
        An open bus.
    cfg : AmplifierConfig
        ``[can.amplifiers]``.
    thrusters : sequence of Thruster
        The vehicle's thrusters, in the order of ``cfg.node_ids`` (k, max thrust, names).
    clock : callable, optional
        Monotonic nanoseconds (default :func:`time.monotonic_ns`).

    Raises
    ------
    ConfigError
        Node count ≠ thruster count, unreadable EDS, or a PDO mapping without the objects the
        driver needs (0x6040 + 0x6071 in one RPDO; 0x6041 and 0x606C in the TPDOs).
    """

    def __init__(self, bus: CanBus, cfg: AmplifierConfig, thrusters: Sequence[Thruster],
                 *, clock: Callable[[], int] | None = None) -> None:
        where = "[can.amplifiers]"
        if len(thrusters) != len(cfg.node_ids):
            raise ConfigError(f"{where} node_ids: {len(cfg.node_ids)} node ids for "
                              f"{len(thrusters)} thrusters; give one node id per thruster")
        self.bus = bus
        self.cfg = cfg
        self.clock = clock or bus.clock
        self.network = bus.network
        self._lock = threading.Lock()
        self._goal = cia402.GOAL_DISABLED
        self._cycle = 0
        self._failed_cycles = 0
        self._sync_sent = False
        self._last_hb_ns = 0
        self._fault_state: dict[int, tuple[str, ...]] = {}
        self.fault_log: deque[FaultEvent] = deque(maxlen=1000)
        self.counters = {"cycles": 0, "syncs_sent": 0, "lost_cycles": 0,
                         "send_failed_cycles": 0,
                         "nonfinite_commands": 0, "clamped_commands": 0, "emcy_rx": 0,
                         "heartbeats_tx": 0, "feedback_missed": 0, "fault_events": 0,
                         "implausible_speed": 0}
        per_permille = cfg.thrust_per_permille_n or tuple(t.max_thrust_n / 1000.0
                                                          for t in thrusters)
        self.nodes: list[_Node] = []
        for nid, spec, tpp in zip(cfg.node_ids, thrusters, per_permille, strict=True):
            self.nodes.append(self._make_node(nid, spec, tpp, where))
        self._tpp = np.array([n.thrust_per_permille for n in self.nodes])
        self._k = np.array([n.k_thrust for n in self.nodes])
        self._omega_max = np.array([SPEED_PLAUSIBLE_FACTOR * (t.max_thrust_n / t.k_thrust) ** 0.5
                                    for t in thrusters])
        self._max = float(cfg.max_torque_permille)

    @classmethod
    def from_config(cls, bus: CanBus, cfg: AmplifierConfig | CanConfig,
                    thrusters: Sequence[Thruster], **kw) -> AmplifierGroup:
        """Build the group from ``[can.amplifiers]`` (or the whole ``[can]`` config)."""
        if isinstance(cfg, CanConfig):
            cfg = cfg.amplifiers
        return cls(bus, cfg, thrusters, **kw)

    # -- construction --
    def _make_node(self, nid: int, spec: Thruster, tpp: float, where: str) -> _Node:
        od = load_od(self.cfg.eds, nid, where)
        remote = canopen.RemoteNode(nid, od)
        remote.sdo.RESPONSE_TIMEOUT = self.cfg.sdo_timeout_s
        self.network.add_node(remote)
        remote.tpdo.read(from_od=True)
        remote.rpdo.read(from_od=True)
        rpdo = var_cw = var_target = None
        for m in remote.rpdo.map.values():
            if m.enabled:
                # we send RPDOs, never receive them: no echo may overwrite the data we encode
                self.network.unsubscribe(m.cob_id, m.on_message)
                idx = [v.index for v in m.map]
                if OD_CONTROLWORD in idx and OD_TARGET_TORQUE in idx:
                    rpdo, var_cw, var_target = m, m[OD_CONTROLWORD], m[OD_TARGET_TORQUE]
        if rpdo is None:
            raise ConfigError(f"{where} eds: node {nid}: no enabled RPDO maps both controlword "
                              "0x6040 and target torque 0x6071 (see drivers/can/amplifier.eds)")
        found: dict[int, tuple[object, object]] = {}
        for m in remote.tpdo.map.values():
            if not m.enabled:
                continue
            for v in m.map:
                found.setdefault(v.index, (m, v))
            self.bus.expect(m.cob_id, (m.length + 7) // 8)
        if OD_STATUSWORD not in found or OD_VELOCITY_ACTUAL not in found:
            raise ConfigError(f"{where} eds: node {nid}: the enabled TPDOs must map statusword "
                              "0x6041 and velocity actual 0x606C (see drivers/can/amplifier.eds)")
        fb_pdo, var_sw = found[OD_STATUSWORD]
        var_vel = found[OD_VELOCITY_ACTUAL][1]
        var_torque = found.get(OD_TORQUE_ACTUAL, (None, None))[1]
        com_index = rpdo.com_record.od.index
        timer = (com_index, 5) if 5 in od[com_index] else None
        node = _Node(nid, spec.name, remote, spec.k_thrust, tpp, rpdo, var_cw, var_target,
                     fb_pdo, var_sw, var_vel, var_torque, timer)
        for m in {id(p): p for p, _ in found.values()}.values():
            m.add_callback(lambda pdo, node=node: self._on_tpdo(node, pdo))
        remote.emcy.add_callback(lambda err, node=node: self._on_emcy(node, err))
        remote.nmt.add_heartbeat_callback(lambda st, node=node: self._on_heartbeat(node, st))
        self.bus.expect(0x80 + nid, 8)
        self.bus.expect(0x700 + nid, 1)
        self.bus.expect(0x580 + nid, 8)
        self.bus.expect(0x000, 2)  # NMT (canopen mirrors NMT commands it hears)
        return node

    # -- notifier thread --
    def _on_tpdo(self, node: _Node, pdo) -> None:
        now = self.clock()
        with self._lock:
            if pdo is node.feedback_pdo:
                node.statusword = int(node.var_sw.raw)
                node.tpdo_count += 1
                node.tpdo_ns = now
            if node.var_vel.pdo_parent is pdo:
                node.velocity = int(node.var_vel.raw)
            if node.var_torque is not None and node.var_torque.pdo_parent is pdo:
                node.torque = int(node.var_torque.raw)

    def _on_emcy(self, node: _Node, err) -> None:
        now = self.clock()
        with self._lock:
            node.emcy_count += 1
            self.counters["emcy_rx"] += 1
            if err.code & 0xFF00 == 0:
                node.emcy_active.clear()
            elif err.code != cia402.FAULT_CODES["bus_off_recovered"]:
                node.emcy_active[err.code] = now
        log.log(logging.INFO if err.code & 0xFF00 == 0 else logging.WARNING,
                "amplifier %d (%s) EMCY 0x%04X %s", node.node_id, node.name, err.code,
                cia402.emcy_fault_name(err.code))
        del node.remote.emcy.log[:-16]  # canopen keeps every EMCY; keep memory bounded

    def _on_heartbeat(self, node: _Node, state: int) -> None:
        now = self.clock()
        with self._lock:
            node.hb_state = state
            node.hb_ns = now
            node.hb_count += 1
            if state == 0:
                node.bootups += 1

    # -- lifecycle --
    def start(self, timeout_s: float = 2.0) -> StartReport:
        """Configure every amplifier by SDO (if ``configure``) and start it (NMT).

        Blocking and bounded: each SDO exchange waits at most ``sdo_timeout_s`` (two tries),
        and the wait for every node's heartbeat to report OPERATIONAL at most ``timeout_s``.
        Never raises for a node that does not answer: its entry in the report says why, and
        it carries ``config_failed`` until the next successful start.
        """
        return self._start(self.nodes, timeout_s)

    def _start(self, nodes: Sequence[_Node], timeout_s: float) -> StartReport:
        """:meth:`start` of ``nodes`` only."""
        t0 = time.monotonic()
        report: dict[int, str] = {}
        for node in nodes:
            try:
                self._configure(node)
                node.remote.nmt.send_command(0x01)  # NMT start remote node
                report[node.node_id] = "ok"
                node.start_error = ""
            except Exception as exc:  # noqa: BLE001 - SDO/NMT failures become data
                node.start_error = f"{type(exc).__name__}: {exc}"
                report[node.node_id] = node.start_error
                log.error("amplifier %d (%s) not started: %s", node.node_id, node.name, exc)
            now = self.clock()
            with self._lock:
                node.emcy_active.clear()
                node.bootups_at_start = node.bootups
                node.started_ns = now
                node.missed = 0
        deadline = time.monotonic() + timeout_s
        waiting = [n for n in nodes if report[n.node_id] == "ok"]
        while waiting and time.monotonic() < deadline:
            self._heartbeat_if_due(self.clock())
            waiting = [n for n in waiting if n.hb_state != NMT_OPERATIONAL]
            time.sleep(0.005)
        for n in waiting:
            report[n.node_id] = n.start_error = (
                f"no heartbeat reporting OPERATIONAL within {timeout_s:g} s "
                f"(last NMT state {_NMT_NAMES.get(n.hb_state, n.hb_state)})")
        return StartReport(report, time.monotonic() - t0)

    def recover(self, timeout_s: float = 2.0) -> StartReport:
        """Bring the drives back after faults — the daemon's decision, disarmed, on the
        operator's failsafe reset (never the driver's own): every drive that rebooted (a
        boot-up seen since its start), left OPERATIONAL or failed its configuration is
        configured and started again (:meth:`start` of those nodes: blocking, bounded), then
        every drive in FAULT gets a fault reset (:meth:`reset_faults`); a drive whose fault
        persists stays in FAULT. The report names the nodes started again (empty: none)."""
        with self._lock:
            again = [n for n in self.nodes if n.start_error or n.bootups > n.bootups_at_start
                     or n.hb_state != NMT_OPERATIONAL]
        report = self._start(again, timeout_s) if again else StartReport({}, 0.0)
        self.reset_faults()
        return report

    def _configure(self, node: _Node) -> None:
        if not self.cfg.configure:
            node.command_timeout_ms = self._own_deadline(node)
            return
        c = self.cfg
        node.remote.nmt.send_command(0x80)  # enter pre-operational
        sdo = node.remote.sdo
        sdo.download(OD_MODE, 0, struct.pack("<b", cia402.MODES[c.mode]))
        sdo.download(0x1017, 0, struct.pack("<H", c.node_heartbeat_ms))
        if 0x1016 in node.remote.object_dictionary:
            consumer = (c.master_node_id << 16 | c.node_consumer_ms) if c.node_consumer_ms else 0
            sdo.download(0x1016, 1, struct.pack("<I", consumer))
        if node.rpdo_event_timer is not None:
            sdo.download(*node.rpdo_event_timer, struct.pack("<H", c.command_timeout_ms))
            node.command_timeout_ms = c.command_timeout_ms
        sdo.download(OD_MAX_TORQUE, 0, struct.pack("<H", c.max_torque_permille))
        shown = struct.unpack("<b", sdo.upload(OD_MODE_DISPLAY, 0)[:1])[0]
        if shown != cia402.MODES[c.mode]:
            raise ConfigError(f"[can.amplifiers] mode: node {node.node_id} runs mode {shown}, "
                              f"not {cia402.MODES[c.mode]} ({c.mode})")

    @staticmethod
    def _own_deadline(node: _Node) -> int | None:
        """The RPDO deadline a drive left unconfigured (``configure = false``) keeps, read
        by SDO; ``None`` when it has none in its EDS or does not answer (the read is only
        for the daemon's warning: it never fails a start that wrote nothing)."""
        if node.rpdo_event_timer is None:
            return None
        try:
            return struct.unpack("<H", node.remote.sdo.upload(*node.rpdo_event_timer)[:2])[0]
        except Exception as exc:  # noqa: BLE001 - SDO aborts and timeouts alike
            log.info("amplifier %d (%s): its RPDO deadline could not be read: %s",
                     node.node_id, node.name, exc)
            return None

    def command_timeouts_ms(self) -> dict[int, int | None]:
        """Per node, the RPDO deadline (0x1400:05, ms; 0 = off) it runs with since its
        start: the one written (``configure = true``) or its own, read (``None``: unknown,
        not started or no such object)."""
        return {n.node_id: n.command_timeout_ms for n in self.nodes}

    def enable(self) -> None:
        """Goal: OPERATION ENABLED on every drive (reached over the next cycles)."""
        self._goal = cia402.GOAL_ENABLED

    def disable(self) -> None:
        """Goal: voltage disabled on every drive; targets are zero from the next cycle."""
        self._goal = cia402.GOAL_DISABLED

    def quick_stop(self) -> None:
        """Goal: QUICK STOP ACTIVE (the drives stop at their quick-stop ramp, output zero)."""
        self._goal = cia402.GOAL_QUICK_STOP

    def reset_faults(self, cycles: int = 6) -> None:
        """Request a fault reset on every drive in FAULT for the next ``cycles`` cycles.

        The controlword toggles bit 7 so that the drive sees rising edges; a drive whose
        fault persists stays in FAULT. Active EMCY faults are cleared once the drive leaves
        FAULT; on a drive that is not in FAULT, EMCYs older than its latest statusword are
        acknowledged (cleared) during those cycles.
        """
        with self._lock:
            for node in self.nodes:
                node.reset_cycles = cycles

    @property
    def goal(self) -> str:
        return self._goal

    # -- the cycle --
    def write(self, thrust_n) -> WriteStatus:
        """One command cycle: every RPDO, then SYNC, then the daemon's heartbeat if due.

        Parameters
        ----------
        thrust_n : array_like, shape (N,)
            Thrust command per thruster (N), in the vehicle's thruster order.

        Returns
        -------
        WriteStatus
            Never raises; a wrong shape or non-finite entries command zero (counted).
        """
        t0 = self.clock()
        nonfinite = 0
        try:
            cmd = np.asarray(thrust_n, dtype=float).reshape(len(self.nodes))
        except (TypeError, ValueError):
            cmd = np.zeros(len(self.nodes))
            nonfinite = len(self.nodes)
        bad = ~np.isfinite(cmd)
        if bad.any():
            nonfinite += int(bad.sum())
            cmd = np.where(bad, 0.0, cmd)
        return self._write_permille(cmd / self._tpp, t0, nonfinite)

    def write_permille(self, targets) -> WriteStatus:
        """Like :meth:`write`, with targets in 1/1000 of rated torque (current) directly."""
        t0 = self.clock()
        try:
            p = np.asarray(targets, dtype=float).reshape(len(self.nodes))
        except (TypeError, ValueError):
            return self._write_permille(np.zeros(len(self.nodes)), t0, len(self.nodes))
        bad = ~np.isfinite(p)
        return self._write_permille(np.where(bad, 0.0, p), t0, int(bad.sum()))

    def _write_permille(self, p: np.ndarray, t0: int, nonfinite: int) -> WriteStatus:
        self._cycle += 1
        c = self.counters
        c["cycles"] += 1
        bus_state = self.bus.poll_state()
        bus_ok = bus_state not in (BUS_OFF, CLOSED)
        clamped = int((np.abs(p) > self._max).sum())
        targets = np.rint(np.clip(p, -self._max, self._max)).astype(np.int64).tolist()
        c["nonfinite_commands"] += nonfinite
        c["clamped_commands"] += clamped
        faults = self._update_faults(t0, bus_state)
        # error-passive/warning are reported but the frames still get through: keep driving
        group_fault = bool(set(faults.get(0, ())) & _ZEROING_BUS_FAULTS)
        enabled_goal = self._goal == cia402.GOAL_ENABLED
        with self._lock:
            snap = [(n.statusword, n.tpdo_count) for n in self.nodes]
        sent = dropped = 0
        late = False
        out = [0] * len(self.nodes)
        for i, node in enumerate(self.nodes):
            sw, count = snap[i]
            state = cia402.state_from_statusword(sw)
            if self._sync_sent and node.hb_state == NMT_OPERATIONAL:
                if count == node.count_at_sync:
                    node.missed += 1
                    node.missed_total += 1
                    c["feedback_missed"] += 1
                    late = True
                else:
                    node.missed = 0
            if node.reset_cycles and state != cia402.FAULT:
                with self._lock:
                    if node.last_cw & cia402.CW_FAULT_RESET:  # it left FAULT on our reset
                        node.emcy_active.clear()
                        node.reset_cycles = 1
                    else:  # acknowledge EMCYs that a later statusword shows were no fault
                        for code in [k for k, t in node.emcy_active.items() if t < node.tpdo_ns]:
                            del node.emcy_active[code]
            cw = cia402.master_controlword(state, self._goal, fault_reset=node.reset_cycles > 0,
                                           previous=node.last_cw)
            if node.reset_cycles:
                node.reset_cycles -= 1
            allowed = (enabled_goal and state == cia402.OPERATION_ENABLED
                       and cw == cia402.CW_ENABLE_OPERATION and bus_ok and not group_fault
                       and node.node_id not in faults)
            target = targets[i] if allowed else 0
            node.var_cw.raw = cw
            node.var_target.raw = target
            node.last_cw = cw
            node.count_at_sync = count
            try:
                node.rpdo.transmit()
                sent += 1
                out[i] = target
            except FrameDropped:
                dropped += 1
        try:
            self.network.sync.transmit()
            sent += 1
            self._sync_sent = True
            c["syncs_sent"] += 1
        except FrameDropped:
            dropped += 1
            self._sync_sent = False
        self._heartbeat_if_due(t0)
        if dropped:
            self._failed_cycles += 1
            c["send_failed_cycles"] += 1
        else:
            self._failed_cycles = 0
        if dropped or late:
            c["lost_cycles"] += 1
        t1 = self.clock()
        return WriteStatus(self._cycle, t0, dropped == 0, sent, dropped, nonfinite, clamped,
                           np.array(out, dtype=np.int64), t1 - t0)

    def _heartbeat_if_due(self, now: int) -> None:
        period = self.cfg.heartbeat_period_ms
        if period and now - self._last_hb_ns >= period * 1_000_000:
            self._last_hb_ns = now
            try:
                self.network.send_message(0x700 + self.cfg.master_node_id, b"\x05")
                self.counters["heartbeats_tx"] += 1
            except FrameDropped:
                pass

    # -- faults and feedback --
    def _node_faults(self, node: _Node, now: int) -> tuple[str, ...]:
        out: list[str] = []
        if node.start_error:
            out.append("config_failed")
        for code in node.emcy_active:
            out.append(cia402.emcy_fault_name(code))
        state = cia402.state_from_statusword(node.statusword)
        if state in (cia402.FAULT, cia402.FAULT_REACTION_ACTIVE) and not node.emcy_active:
            out.append("drive_fault")
        timeout = self.cfg.heartbeat_timeout_ms * 1_000_000
        if node.started_ns and now - max(node.hb_ns, node.started_ns) > timeout:
            out.append("heartbeat_lost")
        elif node.started_ns and node.hb_state not in (None, NMT_OPERATIONAL) \
                and now - node.started_ns > timeout:
            out.append("nmt_" + _NMT_NAMES.get(node.hb_state, str(node.hb_state)))
        if node.bootups > node.bootups_at_start:
            out.append("node_reset")
        if node.missed >= self.cfg.max_failed_cycles:
            out.append("feedback_lost")
        return tuple(out)

    def _update_faults(self, now: int, bus_state: str | None = None) -> dict[int, tuple[str, ...]]:
        faults: dict[int, tuple[str, ...]] = {}
        with self._lock:
            for node in self.nodes:
                f = self._node_faults(node, now)
                if f:
                    faults[node.node_id] = f
        state = bus_state if bus_state is not None else self.bus.status().state
        g: list[str] = []
        if state in (BUS_OFF, CLOSED):
            g.append("bus_off" if state == BUS_OFF else "bus_closed")
        elif state != ACTIVE:
            g.append("error_" + state)
        if self._failed_cycles >= self.cfg.max_failed_cycles:
            g.append("send_failed")
        if g:
            faults[0] = tuple(g)
        self._log_fault_changes(faults, now)
        self._fault_state = faults
        return faults

    def _log_fault_changes(self, faults: dict[int, tuple[str, ...]], now: int) -> None:
        keys = set(faults) | set(self._fault_state)
        for k in keys:
            new = set(faults.get(k, ()))
            old = set(self._fault_state.get(k, ()))
            for name in sorted(new - old):
                self.fault_log.append(FaultEvent(now, k, name, True))
                self.counters["fault_events"] += 1
                log.warning("CAN fault raised: %s on %s", name, f"node {k}" if k else "bus")
            for name in sorted(old - new):
                self.fault_log.append(FaultEvent(now, k, name, False))
                log.info("CAN fault cleared: %s on %s", name, f"node {k}" if k else "bus")

    def read(self) -> GroupFeedback:
        """The latest feedback of every amplifier and the active faults (never raises)."""
        now = self.clock()
        faults = self._update_faults(now)
        nodes = []
        scale = self.cfg.velocity_rad_s_per_count
        with self._lock:
            for node in self.nodes:
                omega = node.velocity * scale
                nodes.append(AmplifierFeedback(
                    node.node_id, node.name, cia402.state_from_statusword(node.statusword),
                    _NMT_NAMES.get(node.hb_state, "unknown") if node.hb_state is not None
                    else "unknown",
                    node.statusword, node.torque, omega,
                    node.k_thrust * omega * abs(omega), node.tpdo_ns,
                    self._sync_sent and node.tpdo_count != node.count_at_sync,
                    faults.get(node.node_id, ())))
        omega = np.array([n.omega_rad_s for n in nodes])
        enabled = np.array([n.state == cia402.OPERATION_ENABLED and not n.faults for n in nodes])
        plausible = np.abs(omega) <= self._omega_max
        if not plausible.all():
            self._implausible(nodes, plausible)
        valid = enabled & np.array([n.fresh for n in nodes]) & plausible & (0 not in faults)
        return GroupFeedback(now, tuple(nodes), omega, self._k * omega * np.abs(omega),
                             np.array([n.torque_permille for n in nodes]), valid, enabled,
                             faults, self.bus.status().state)

    def _implausible(self, nodes: Sequence[AmplifierFeedback], plausible: np.ndarray) -> None:
        """Count a read with a speed no propeller turns at; log the first and every 100th."""
        self.counters["implausible_speed"] += 1
        n = self.counters["implausible_speed"]
        if n == 1 or n % 100 == 0:
            log.warning("amplifier feedback not valid: %s (more than %g times the speed at "
                        "the largest thrust); %d such reads", ", ".join(
                            f"node {f.node_id} ({f.name}) {f.omega_rad_s:.4g} rad/s"
                            for f, ok in zip(nodes, plausible, strict=True) if not ok),
                        SPEED_PLAUSIBLE_FACTOR, n)

    def error_codes(self, only_faulted: bool = True) -> dict[int, tuple[int, str]]:
        """Read each drive's error code (0x603F) by SDO — outside the cycle, bounded.

        For a drive that reports FAULT but whose EMCY was lost (it was cut off, or the bus
        was off), this tells why. Nodes that do not answer are left out.
        """
        out: dict[int, tuple[int, str]] = {}
        for node in self.nodes:
            with self._lock:
                state = cia402.state_from_statusword(node.statusword)
            if only_faulted and state not in (cia402.FAULT, cia402.FAULT_REACTION_ACTIVE):
                continue
            try:
                raw = node.remote.sdo.upload(0x603F, 0)
                code = struct.unpack("<H", raw[:2])[0]
            except Exception as exc:  # noqa: BLE001 - diagnostics are best effort
                log.info("amplifier %d: no error code: %s", node.node_id, exc)
                continue
            out[node.node_id] = (code, cia402.emcy_fault_name(code) if code else "none")
        return out

    def stats(self) -> dict:
        """Counters of the group and of the bus (for the daemon's telemetry)."""
        out = dict(self.counters)
        out["feedback_missed_by_node"] = {n.node_id: n.missed_total for n in self.nodes}
        out["tpdo_rx_by_node"] = {n.node_id: n.tpdo_count for n in self.nodes}
        out["emcy_by_node"] = {n.node_id: n.emcy_count for n in self.nodes}
        out["bus"] = self.bus.status().counters
        return out

    # -- helpers for start-up and shut-down --
    def wait_enabled(self, timeout_s: float = 1.0, period_s: float = 0.01) -> bool:
        """Run zero-thrust cycles until every drive is enabled, at most ``timeout_s``.

        A convenience for start-up scripts and tests; the daemon simply keeps cycling.
        """
        self.enable()
        deadline = time.monotonic() + timeout_s
        zeros = np.zeros(len(self.nodes))
        while time.monotonic() < deadline:
            self.write(zeros)
            time.sleep(period_s)
            if self.read().all_enabled:
                return True
        return False

    def shutdown(self, cycles: int = 3, period_s: float = 0.01,
                 release_consumer: bool = True) -> None:
        """Zero every output and disable voltage; never raises, bounded in time.

        Sends ``cycles`` zero-target cycles with the controlword "disable voltage", then (if
        ``release_consumer``) switches the drives' heartbeat consumer off by SDO so that the
        daemon's absence is not reported as a heartbeat fault, and puts them in
        PRE-OPERATIONAL.
        """
        self.disable()
        zeros = np.zeros(len(self.nodes))
        for _ in range(max(1, cycles)):
            self.write(zeros)
            time.sleep(period_s)
        for node in self.nodes:
            try:
                if release_consumer and self.cfg.configure and self.cfg.node_consumer_ms \
                        and 0x1016 in node.remote.object_dictionary:
                    node.remote.sdo.download(0x1016, 1, struct.pack("<I", 0))
                node.remote.nmt.send_command(0x80)
            except Exception as exc:  # noqa: BLE001 - shut-down is best effort
                log.info("amplifier %d shut-down: %s", node.node_id, exc)

    def thrust_to_permille(self, thrust_n) -> np.ndarray:
        """The calibration used by :meth:`write`: target = thrust / thrust_per_permille_n."""
        return np.asarray(thrust_n, dtype=float) / self._tpp


__all__ = ["AmplifierGroup", "AmplifierFeedback", "GroupFeedback", "WriteStatus",
           "FaultEvent", "StartReport", "load_od"]
