"""Six emulated CiA 402 thruster amplifiers (and a pressure transmitter) on one CAN bus.

:class:`CanEmulators` puts one :class:`~sim_bridge.amplifiers.node.EmulatedAmplifier` per
thruster on a python-can bus (``virtual`` in-process, ``udp_multicast`` across processes, or a
real interface), drives a :class:`sim_bridge.thrusters.ThrusterBank` with their outputs
(propeller lag, reversal stiction, saturation) and reports the bank's propeller speeds as the
amplifiers' velocity feedback. A tick thread (5 ms) advances the bank, produces heartbeats,
runs the heartbeat consumers and the **command timeout**: an amplifier in OPERATION ENABLED
that has received no RPDO for ``0x1400:05`` ms (200 by default) zeroes its output, reports
EMCY 0x8250 (``command_timeout``, with the measured milliseconds in its manufacturer bytes)
and faults.

Fault injection (also reachable as control commands, see :meth:`CanEmulators.call`):

* :meth:`~CanEmulators.inject_fault` — a node in fault (any name of
  :data:`drivers.can.cia402.EMCY_FAULTS`), optionally persistent across fault resets;
* :meth:`~CanEmulators.silence` — a node that goes silent (hears and says nothing);
* :meth:`~CanEmulators.set_health` — a weak (0.5) or dead (0) thruster;
* :meth:`~CanEmulators.bus_off` — the bus goes off: a SocketCAN bus-off error frame, no
  traffic for the duration, then a "restarted" error frame and EMCY 0x8140 from every node.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from drivers.can import cia402
from drivers.can.bus import (
    CAN_ERR_BUSOFF,
    CAN_ERR_CRTL,
    CAN_ERR_CRTL_ACTIVE,
    CAN_ERR_RESTARTED,
    CanBus,
    make_error_frame,
)
from drivers.can.config import DEFAULT_AMPLIFIER_EDS, CanBusConfig, DepthConfig
from sim_bridge.amplifiers.node import EmulatedAmplifier
from sim_bridge.instruments.can_pressure import CanPressureTransmitter
from sim_bridge.thrusters import ThrusterBank, ThrusterEffects
from uvd.errors import ConfigError
from uvd.model.thrusters import ThrusterSpec

log = logging.getLogger(__name__)


#: the commands :meth:`CanEmulators.call` carries out
OPS = ("bus_off", "depth", "fault", "health", "ping", "pressure_valid", "reset", "silence",
       "stats", "unsilence")


def command_problem(op: str, kw: dict, node_ids: Sequence[int],
                    pressure_node: int | None) -> str | None:
    """Why ``op`` with ``kw`` is not a command :meth:`CanEmulators.call` can carry out on
    amplifiers ``node_ids`` (and the pressure transmitter ``pressure_node``), or None.

    Checked without carrying it out, so that a command scheduled for later (``sim-bridge --at
    S JSON``) is refused when it is given, not when it comes due; and a value the emulators
    would take but no amplifier could have (a thruster's health of NaN or 7) is refused too.
    """
    amps = tuple(node_ids)
    nodes = amps + ((pressure_node,) if pressure_node is not None else ())

    def node(among: tuple[int, ...]) -> str | None:
        n = kw.get("node")
        if isinstance(n, bool) or not isinstance(n, int) or n not in among:
            return f"node {n!r} is not one of {list(among)}"
        return None

    def number(key: str, default=None, ok=lambda x: True, what: str = "a finite number"):
        x = kw.get(key, default)
        if x is None and default is None and key not in kw:
            return f"{key} is missing"
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) \
                or not ok(x):
            return f"{key} must be {what}, not {x!r}"
        return None

    if op in ("ping", "stats", "reset"):
        return None
    if op == "fault":
        name = kw.get("name", "overcurrent")
        if name not in cia402.FAULT_CODES:
            return f"unknown fault {name!r}; known: {sorted(cia402.FAULT_CODES)}"
        return node(amps)
    if op == "silence":
        return node(nodes) or (None if kw.get("seconds") is None else number(
            "seconds", ok=lambda x: x >= 0.0, what="a finite number of seconds >= 0 (or absent)"))
    if op == "unsilence":
        return node(nodes)
    if op == "health":
        return node(amps) or number("value", ok=lambda x: 0.0 <= x <= 1.0,
                                    what="a thruster's gain in [0, 1]")
    if op == "bus_off":
        return number("seconds", 0.5, ok=lambda x: x > 0.0, what="a finite number of seconds > 0")
    if op == "depth":
        return number("value")
    if op == "pressure_valid":
        return None if "value" in kw else "value is missing"
    return f"unknown op {op!r}; known: {', '.join(OPS)}"


class CanEmulators:
    """The amplifiers of a vehicle (and optionally its CAN pressure transmitter) on one bus.

    Parameters
    ----------
    bus_cfg : CanBusConfig
        The bus to join (same interface/channel as the driver's).
    thrusters : sequence of ThrusterSpec
        The vehicle's thrusters (the bank they drive).
    node_ids : sequence of int
        Amplifier node ids, in thruster order.
    eds : Path
        Amplifier object dictionary.
    effects : ThrusterEffects
        Which thruster dynamics the bank models.
    thrust_per_permille_n : sequence of float, optional
        Calibration; default ``max_thrust_n / 1000`` per thruster (as the driver's default).
    velocity_rad_s_per_count : float
        Unit of the velocity feedback.
    pressure_node : int, optional
        Also emulate the pressure transmitter on this node id.
    depth_m : float or callable
        The transmitter's depth.
    depth_cfg : DepthConfig, optional
        Fluid and scaling of the transmitter.
    tick_s : float
        Period of the tick thread.
    clock : callable
        Monotonic nanoseconds.
    """

    def __init__(self, bus_cfg: CanBusConfig, thrusters: Sequence[ThrusterSpec],
                 node_ids: Sequence[int] = (1, 2, 3, 4, 5, 6), *,
                 eds: Path = DEFAULT_AMPLIFIER_EDS,
                 effects: ThrusterEffects | None = None,
                 thrust_per_permille_n: Sequence[float] | None = None,
                 velocity_rad_s_per_count: float = 0.001,
                 pressure_node: int | None = None, depth_m: float | Callable[[], float] = 0.0,
                 depth_cfg: DepthConfig | None = None, pressure_noise_pa: float = 0.0,
                 rng: np.random.Generator | None = None,
                 tick_s: float = 0.005, clock: Callable[[], int] = time.monotonic_ns) -> None:
        if len(node_ids) != len(thrusters):
            raise ConfigError(f"emulators: {len(node_ids)} node ids for {len(thrusters)} "
                              "thrusters")
        self.bus_cfg = bus_cfg
        self.thrusters = tuple(thrusters)
        self.node_ids = tuple(node_ids)
        self.eds = Path(eds)
        self.bank = ThrusterBank(self.thrusters, effects or ThrusterEffects())
        self.bank.step(np.zeros(len(self.thrusters)), 1e-3)  # load compiled code before ticking
        self.bank.reset()
        self.tpp = (tuple(thrust_per_permille_n) if thrust_per_permille_n is not None
                    else tuple(t.max_thrust_n / 1000.0 for t in self.thrusters))
        self.velocity_scale = velocity_rad_s_per_count
        self.pressure_node = pressure_node
        self._depth = depth_m
        self._depth_cfg = depth_cfg
        self._noise = pressure_noise_pa
        self._rng = rng
        self.tick_s = tick_s
        self.clock = clock
        self.lock = threading.RLock()
        self.bus: CanBus | None = None
        self.amps: list[EmulatedAmplifier] = []
        self.pressure: CanPressureTransmitter | None = None
        self._by_id: dict[int, object] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._bus_off_until = 0
        self._bus_off_nodes: list = []
        self.counters = {"sync_rx": 0, "ticks": 0, "late_ticks": 0, "bus_off_events": 0}
        self.peak_omega = np.zeros(len(self.thrusters))  # largest |ω| since the last reset
        # per SYNC: (receive → handler, handler → last TPDO sent), seconds
        self._sync_timing: deque[tuple[float, float]] = deque(maxlen=20_000)
        self._last_tick_ns = 0

    # -- lifecycle --
    def open(self) -> CanEmulators:
        """Join the bus, boot every node (boot-up message, PRE-OPERATIONAL), start ticking."""
        self.bus = CanBus(self.bus_cfg, clock=self.clock, tx_gate=self._gate).open()
        net = self.bus.network
        with self.lock:
            for i, nid in enumerate(self.node_ids):
                amp = EmulatedAmplifier(net, nid, self.eds, i, self.tpp[i], self.velocity_scale,
                                        lock=self.lock, clock=self.clock)
                self.amps.append(amp)
                self._by_id[nid] = amp
                for m in amp.rpdo_maps:
                    self.bus.expect(m.cob_id, (m.length + 7) // 8)
                self.bus.expect(0x600 + nid, 8)
            if self.pressure_node is not None:
                self.pressure = CanPressureTransmitter(
                    net, self.pressure_node, cfg=self._depth_cfg, depth_m=self._depth,
                    noise_pa=self._noise, rng=self._rng, lock=self.lock, clock=self.clock)
                self._by_id[self.pressure_node] = self.pressure
                self.bus.expect(0x600 + self.pressure_node, 8)
            net.subscribe(0x000, self._on_nmt)
            net.subscribe(0x080, self._on_sync)
            self.bus.expect(0x000, 2)
            self.bus.expect(0x080, (0, 1))
            now = self.clock()
            for node in self._nodes():
                node.boot(now)
        self._last_tick_ns = self.clock()
        self._thread = threading.Thread(target=self._run, name="can-emulators", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop ticking and leave the bus (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        if self.bus is not None:
            self.bus.close()

    def __enter__(self) -> CanEmulators:
        return self if self.bus is not None else self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def _nodes(self):
        yield from self.amps
        if self.pressure is not None:
            yield self.pressure

    # -- frames --
    def _gate(self, msg) -> bool:
        if msg.is_error_frame:
            return True
        node = self._by_id.get(msg.arbitration_id & 0x7F)
        return not (node is not None and node.silent and msg.arbitration_id & 0x780)

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        now = self.clock()
        with self.lock:
            self._advance(now)
            for node in self._nodes():
                node.on_nmt(bytes(data), now)

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        now = self.clock()
        wait_s = time.time() - timestamp if timestamp else 0.0  # kernel receive -> here
        with self.lock:
            self.counters["sync_rx"] += 1
            self._advance(now)  # the targets held until this SYNC, then the new ones
            omega = self.bank.omega
            for amp in self.amps:
                amp.omega = float(omega[amp.index])
                amp.on_sync(now)
            self._sync_timing.append((wait_s, (self.clock() - now) / 1e9))

    # -- time --
    def _run(self) -> None:
        period = int(self.tick_s * 1e9)
        next_t = self.clock()
        while not self._stop.is_set():
            next_t += period
            try:
                self.tick(self.clock())
            except Exception:  # noqa: BLE001 - an emulator must keep running
                log.exception("emulator tick failed")
            delay = (next_t - self.clock()) / 1e9
            if delay > 0:
                time.sleep(delay)
            else:
                self.counters["late_ticks"] += 1
                if delay < -0.05:
                    next_t = self.clock()  # far behind: do not try to catch up

    def tick(self, now: int) -> None:
        """Advance everything to ``now`` (the tick thread calls it; tests may too)."""
        with self.lock:
            self.counters["ticks"] += 1
            self._advance(now)
            if self._bus_off_until and now >= self._bus_off_until:
                self._end_bus_off(now)
            for node in self._nodes():
                node.tick(now)

    def _advance(self, now: int) -> None:
        """The propellers from the last advance to ``now`` under the commands held since
        (the caller holds the lock). Called at every tick and every SYNC, so a command
        applied at a SYNC acts from that SYNC however late the ticks come on a loaded
        machine; the lag's step is exact over any interval (``ThrusterBank.step``)."""
        dt = (now - self._last_tick_ns) / 1e9
        if dt <= 0.0:
            return
        self._last_tick_ns = now
        cmd = np.array([a.thrust_command_n() for a in self.amps])
        self.bank.step(cmd, dt)
        np.maximum(self.peak_omega, np.abs(self.bank.omega), out=self.peak_omega)

    # -- fault injection --
    def amp(self, node_id: int) -> EmulatedAmplifier:
        node = self._by_id.get(node_id)
        if not isinstance(node, EmulatedAmplifier):
            raise KeyError(f"no emulated amplifier with node id {node_id}; "
                           f"have {list(self.node_ids)}")
        return node

    def inject_fault(self, node_id: int, name: str = "overcurrent",
                     persistent: bool = False) -> int:
        """Put amplifier ``node_id`` in FAULT with the EMCY of fault ``name``; returns the code."""
        code = cia402.FAULT_CODES.get(name)
        if code is None:
            raise KeyError(f"unknown fault {name!r}; known: {sorted(cia402.FAULT_CODES)}")
        with self.lock:
            now = self.clock()
            self._advance(now)
            self.amp(node_id).fault(code, now, persistent=persistent)
        return code

    def silence(self, node_id: int, seconds: float | None = None) -> None:
        """Node ``node_id`` hears and says nothing (for ``seconds``, or until unsilenced)."""
        with self.lock:
            node = self._by_id[node_id]
            node.silent = True
            node.silent_until_ns = self.clock() + int(seconds * 1e9) if seconds else 0

    def unsilence(self, node_id: int) -> None:
        with self.lock:
            node = self._by_id[node_id]
            node.silent = False
            node.silent_until_ns = 0

    def set_health(self, node_id: int, health: float) -> None:
        """Thruster gain: 1 healthy, 0.5 weak, 0 dead (the propeller turns, no thrust)."""
        with self.lock:
            self.bank.health[self.amp(node_id).index] = float(health)

    def bus_off(self, seconds: float = 0.5) -> None:
        """Emulate a bus-off of ``seconds``: error frame, no traffic, recovery."""
        with self.lock:
            now = self.clock()
            self.bus.send(make_error_frame(CAN_ERR_BUSOFF | CAN_ERR_CRTL, tx_errors=255,
                                           rx_errors=0))
            self.counters["bus_off_events"] += 1
            self._bus_off_until = now + int(seconds * 1e9)
            for node in self._nodes():
                if not node.silent:
                    node.silent = True
                    node.silent_until_ns = 0
                    self._bus_off_nodes.append(node)

    def _end_bus_off(self, now: int) -> None:
        self._bus_off_until = 0
        self.bus.send(make_error_frame(CAN_ERR_RESTARTED | CAN_ERR_CRTL, CAN_ERR_CRTL_ACTIVE,
                                       tx_errors=0, rx_errors=0))
        for node in self._bus_off_nodes:
            node.silent = False
            node.emcy(cia402.FAULT_CODES["bus_off_recovered"])
        self._bus_off_nodes = []

    def set_depth(self, depth_m: float) -> None:
        with self.lock:
            if self.pressure is not None:
                self.pressure.set_depth(float(depth_m))

    def set_pressure_valid(self, valid: bool) -> None:
        with self.lock:
            if self.pressure is not None:
                self.pressure.set_valid(valid)

    def reset(self) -> None:
        """Power-cycle everything: nodes to defaults (boot-up), bank at rest, healthy."""
        with self.lock:
            now = self.clock()
            self._bus_off_until = 0
            self._bus_off_nodes = []
            self.bank.reset()
            self.bank.health[:] = 1.0
            self.peak_omega[:] = 0.0
            self._sync_timing.clear()
            for node in self._nodes():
                node.silent = False
                node.silent_until_ns = 0
                node.reset(now, application=True)
                if isinstance(node, EmulatedAmplifier):
                    node.history.clear()
                    node.last_timeout_ms = None
                    for k in node.counters:
                        node.counters[k] = 0
            if self.pressure is not None:
                self.pressure.set_valid(True)

    # -- reports --
    def stats(self, history: bool = False) -> dict:
        """JSON-friendly state: every node, the bank, counters.

        ``history``: each amplifier's applied targets, one per SYNC (``history``), and the
        emulator-clock times (ns) they were applied at (``history_t_ns``).
        """
        with self.lock:
            out = {
                "t_ns": self.clock(),
                "counters": dict(self.counters),
                "nodes": {str(a.node_id): a.snapshot(self.bank) for a in self.amps},
                "bus": self.bus.status().counters if self.bus is not None else {},
                "bus_off": bool(self._bus_off_until),
                "peak_omega_rad_s": [float(x) for x in self.peak_omega],
            }
            if self._sync_timing:
                t = np.array(self._sync_timing) * 1e3
                out["sync_ms"] = {
                    "wait_p50": float(np.percentile(t[:, 0], 50)),
                    "wait_p99": float(np.percentile(t[:, 0], 99)),
                    "wait_max": float(t[:, 0].max()),
                    "answer_p50": float(np.percentile(t[:, 1], 50)),
                    "answer_p99": float(np.percentile(t[:, 1], 99)),
                    "answer_max": float(t[:, 1].max())}
            if self.pressure is not None:
                out["pressure"] = self.pressure.snapshot()
            if history:
                out["history"] = {str(a.node_id): [v for _t, v in a.history] for a in self.amps}
                out["history_t_ns"] = {str(a.node_id): [t for t, _v in a.history]
                                       for a in self.amps}
        return out

    def call(self, op: str, **kw) -> dict:
        """Run one control command (the protocol of ``python -m sim_bridge.amplifiers``).

        ``op`` is one of ``stats`` (``history``), ``fault`` (``node``, ``name``,
        ``persistent``), ``silence`` (``node``, ``seconds``), ``unsilence`` (``node``),
        ``health`` (``node``, ``value``), ``bus_off`` (``seconds``), ``depth`` (``value``),
        ``pressure_valid`` (``value``), ``reset``, ``ping``. Returns ``{"ok": true, ...}``, or
        ``{"ok": false, "error": ...}`` for a bad command (never raises;
        :func:`command_problem`).
        """
        why = command_problem(op, kw, self.node_ids, self.pressure_node)
        if why:
            return {"ok": False, "error": f"{op}: {why}"}
        try:
            if op == "ping":
                return {"ok": True, "t_ns": self.clock()}
            if op == "stats":
                return {"ok": True, **self.stats(bool(kw.get("history", False)))}
            if op == "fault":
                code = self.inject_fault(int(kw["node"]), str(kw.get("name", "overcurrent")),
                                         bool(kw.get("persistent", False)))
                return {"ok": True, "code": code, "t_ns": self.clock()}
            if op == "silence":
                self.silence(int(kw["node"]), kw.get("seconds"))
                return {"ok": True, "t_ns": self.clock()}
            if op == "unsilence":
                self.unsilence(int(kw["node"]))
                return {"ok": True}
            if op == "health":
                self.set_health(int(kw["node"]), float(kw["value"]))
                return {"ok": True}
            if op == "bus_off":
                self.bus_off(float(kw.get("seconds", 0.5)))
                return {"ok": True, "t_ns": self.clock()}
            if op == "depth":
                self.set_depth(float(kw["value"]))
                return {"ok": True}
            if op == "pressure_valid":
                self.set_pressure_valid(bool(kw["value"]))
                return {"ok": True}
            if op == "reset":
                self.reset()
                return {"ok": True}
            # command_problem refused every op not in OPS: one of OPS lacks its branch here
            return {"ok": False, "error": f"{op}: known but not carried out by this emulator"}
        except (KeyError, ValueError, TypeError) as exc:
            return {"ok": False, "error": f"{op}: {exc}"}
