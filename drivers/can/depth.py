"""A CANopen pressure transmitter (CiA 404 measuring device) as a depth source.

The transmitter publishes its analog input process value (absolute pressure) by TPDO — on the
reference device (``drivers/can/pressure-transmitter.eds``) 0x9130:01 INTEGER32 in 0.1 Pa plus the
AI status 0x6150:01, every 50 ms. Each TPDO becomes a :class:`drivers.samples.DepthSample`
with ``source="can_depth"``; the serial Digiquartz remains the other depth source and the
daemon's configuration picks one (``[can.depth] enabled``; see ``docs/can.md``).

Depth is hydrostatic, d = (p − p_atm) / (ρ g) (:func:`depth_from_pressure`), positive down,
with ρ, g and p_atm from ``[can.depth]`` (fresh water by default: the JHU tank).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import replace

import canopen

from drivers.can.amplifier import NMT_OPERATIONAL, load_od
from drivers.can.bus import CanBus, FrameDropped
from drivers.can.config import DepthConfig
from drivers.samples import DepthSample
from uvd.errors import ConfigError

log = logging.getLogger(__name__)

#: AI process value objects, in order of preference: INTEGER32, INTEGER16, REAL32 (CiA 404).
_PV_OBJECTS = (0x9130, 0x7130, 0x6130)
_AI_STATUS = 0x6150
SOURCE = "can_depth"


def depth_from_pressure(pressure_pa: float, cfg: DepthConfig) -> float:
    """Hydrostatic depth (m, positive down) of absolute pressure ``pressure_pa`` (Pa).

    d = (p − p_atm) / (ρ g) with ``cfg.atmospheric_pa``, ``cfg.density_kg_m3`` and
    ``cfg.gravity_m_s2``.
    """
    return (pressure_pa - cfg.atmospheric_pa) / (cfg.density_kg_m3 * cfg.gravity_m_s2)


def pressure_from_depth(depth_m: float, cfg: DepthConfig) -> float:
    """Inverse of :func:`depth_from_pressure` (the emulator uses it)."""
    return cfg.atmospheric_pa + depth_m * cfg.density_kg_m3 * cfg.gravity_m_s2


class CanDepthSensor:
    """Receives the pressure transmitter's TPDOs and turns them into depth samples.

    Parameters
    ----------
    bus : CanBus
        An open bus.
    cfg : DepthConfig
        ``[can.depth]``.
    clock : callable, optional
        Monotonic nanoseconds.
    on_sample : callable, optional
        Called with every new :class:`DepthSample`, in the bus's receive thread (keep it
        short); :meth:`drain` is the thread-safe alternative.

    Raises
    ------
    ConfigError
        Unreadable EDS, or no enabled TPDO maps an AI process value (0x9130/0x7130/0x6130).
    """

    def __init__(self, bus: CanBus, cfg: DepthConfig, *, clock: Callable[[], int] | None = None,
                 on_sample: Callable[[DepthSample], None] | None = None) -> None:
        where = "[can.depth]"
        self.bus = bus
        self.cfg = cfg
        self.clock = clock or bus.clock
        self.on_sample = on_sample
        od = load_od(cfg.eds, cfg.node_id, where)
        self.remote = canopen.RemoteNode(cfg.node_id, od)
        bus.network.add_node(self.remote)
        self.remote.tpdo.read(from_od=True)
        self._pv = self._status = None
        for m in self.remote.tpdo.map.values():
            if not m.enabled:
                continue
            for v in m.map:
                if self._pv is None and v.index in _PV_OBJECTS:
                    self._pv, pdo = v, m
                if v.index == _AI_STATUS and v.subindex == 1:
                    self._status = v
        if self._pv is None:
            raise ConfigError(f"{where} eds: no enabled TPDO of node {cfg.node_id} maps an AI "
                              "process value (0x9130, 0x7130 or 0x6130)")
        if self._status is not None and self._status.pdo_parent is not pdo:
            self._status = None  # only a status that travels with the value describes it
        bus.expect(pdo.cob_id, (pdo.length + 7) // 8)
        bus.expect(0x80 + cfg.node_id, 8)
        bus.expect(0x700 + cfg.node_id, 1)
        bus.expect(0x580 + cfg.node_id, 8)
        bus.expect(0x000, 2)
        pdo.add_callback(self._on_tpdo)
        self.remote.nmt.add_heartbeat_callback(self._on_heartbeat)
        self.remote.emcy.add_callback(self._on_emcy)
        self._lock = threading.Lock()
        self._latest: DepthSample | None = None
        self._queue: deque[DepthSample] = deque(maxlen=64)
        self.hb_state: int | None = None
        self.hb_ns = 0
        self.counters = {"samples": 0, "invalid": 0, "emcy": 0, "heartbeats": 0}

    def _on_tpdo(self, pdo) -> None:
        now = self.clock()
        raw = self._pv.raw
        status = int(self._status.raw) if self._status is not None else 0
        pressure = float(raw) * self.cfg.pressure_pa_per_count
        valid = status & 0x07 == 0 and pressure == pressure
        sample = DepthSample(t_ns=now, depth_m=depth_from_pressure(pressure, self.cfg),
                             pressure_pa=pressure, valid=bool(valid), source=SOURCE)
        with self._lock:
            self._latest = sample
            self._queue.append(sample)
            self.counters["samples"] += 1
            if not valid:
                self.counters["invalid"] += 1
        if self.on_sample is not None:
            self.on_sample(sample)

    def _on_heartbeat(self, state: int) -> None:
        self.hb_state = state
        self.hb_ns = self.clock()
        self.counters["heartbeats"] += 1

    def _on_emcy(self, err) -> None:
        self.counters["emcy"] += 1
        del self.remote.emcy.log[:-16]
        log.warning("pressure transmitter %d EMCY 0x%04X", self.cfg.node_id, err.code)

    def start(self, timeout_s: float = 1.0) -> bool:
        """NMT-start the transmitter and wait (bounded) for its first sample."""
        try:
            self.remote.nmt.send_command(0x01)
        except FrameDropped as exc:
            log.error("pressure transmitter %d not started: %s", self.cfg.node_id, exc)
            return False
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.counters["samples"]:
                return True
            time.sleep(0.005)
        return False

    def latest(self) -> DepthSample | None:
        """The newest sample, marked invalid if older than ``max_age_ms``; ``None`` if none."""
        with self._lock:
            s = self._latest
        if s is None:
            return None
        if self.clock() - s.t_ns > self.cfg.max_age_ms * 1_000_000 and s.valid:
            return replace(s, valid=False)
        return s

    def drain(self) -> list[DepthSample]:
        """Every sample received since the last call (at most 64), oldest first."""
        with self._lock:
            out = list(self._queue)
            self._queue.clear()
        return out

    @property
    def operational(self) -> bool:
        return self.hb_state == NMT_OPERATIONAL
