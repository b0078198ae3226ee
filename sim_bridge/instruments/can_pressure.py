"""Emulated CANopen pressure transmitter (CiA 404 analog input) — a depth sensor on CAN.

It publishes the absolute pressure at the vehicle's depth by TPDO, event-driven every
0x1800:05 ms (50 ms on the reference device), once NMT-started; it produces its heartbeat and
answers SDO like any node. The pressure is p = p_atm + ρ g d (the inverse of the driver's
:func:`drivers.can.depth.depth_from_pressure`), plus optional Gaussian noise from a seeded
generator. Fault injection: :meth:`CanPressureTransmitter.set_valid` clears the AI status
"valid" bit; silence comes from :class:`~sim_bridge.amplifiers.node.EmulatedNode`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import canopen
import numpy as np

from drivers.can.bus import FrameDropped
from drivers.can.config import DEFAULT_PRESSURE_EDS, DepthConfig
from drivers.can.depth import pressure_from_depth
from sim_bridge.amplifiers.node import NMT_OPERATIONAL, EmulatedNode


class CanPressureTransmitter(EmulatedNode):
    """The pressure transmitter node.

    Parameters
    ----------
    network : canopen.Network
        The emulators' network.
    node_id : int
        Its node id (32 by default, as ``[can.depth] node_id``).
    eds : Path
        Object dictionary (``drivers/can/pressure-transmitter.eds``).
    cfg : DepthConfig
        Fluid density, gravity, atmospheric pressure and the PV scaling — the same numbers the
        driver uses to turn pressure back into depth.
    depth_m : float or callable
        Depth (m, positive down), or a function returning it (e.g. the plant's z).
    noise_pa : float
        Standard deviation of the pressure noise; needs ``rng``.
    rng : numpy.random.Generator, optional
        Seeded generator for the noise.
    """

    def __init__(self, network: canopen.Network, node_id: int = 32,
                 eds: Path = DEFAULT_PRESSURE_EDS, cfg: DepthConfig | None = None,
                 depth_m: float | Callable[[], float] = 0.0, noise_pa: float = 0.0,
                 rng: np.random.Generator | None = None, **kw) -> None:
        super().__init__(network, node_id, eds, **kw)
        self.cfg = cfg or DepthConfig()
        self.depth = depth_m
        self.noise_pa = noise_pa
        self.rng = rng
        self.valid = True
        self.local.tpdo.read(from_od=True)
        self.tpdo_maps = [m for m in self.local.tpdo.map.values() if m.enabled]
        for m in self.tpdo_maps:
            network.unsubscribe(m.cob_id, m.on_message)
        self._last_tx: dict[int, int] = {}
        self.counters.update(tpdo_tx=0)
        self.last_pressure_pa = float("nan")

    def set_depth(self, depth_m: float | Callable[[], float]) -> None:
        self.depth = depth_m

    def set_valid(self, valid: bool) -> None:
        """Fault injection: ``False`` reports the process value as not valid (status bit 0)."""
        self.valid = bool(valid)

    def pressure_pa(self) -> float:
        d = self.depth() if callable(self.depth) else float(self.depth)
        p = pressure_from_depth(d, self.cfg)
        if self.noise_pa and self.rng is not None:
            p += float(self.rng.normal(0.0, self.noise_pa))
        return p

    def tick(self, now: int) -> None:
        super().tick(now)
        if self.silent or self.nmt_state != NMT_OPERATIONAL:
            return
        for m in self.tpdo_maps:
            period = m.event_timer or 0
            if m.trans_type in (254, 255) and period and \
                    now - self._last_tx.get(m.cob_id, 0) >= period * 1_000_000:
                self._last_tx[m.cob_id] = now
                self._transmit(m)

    def _transmit(self, m) -> None:
        p = self.pressure_pa()
        self.last_pressure_pa = p
        for var in m.map:
            value = self.od_value(var.index, var.subindex, p)
            if value is not None:
                var.raw = value
        try:
            m.transmit()
            self.counters["tpdo_tx"] += 1
        except FrameDropped:
            self.counters["dropped_tx"] += 1

    def od_value(self, index: int, subindex: int = 0, pressure_pa: float | None = None):
        """Live value of the AI objects (PV in counts or REAL32, status)."""
        if index in (0x9130, 0x7130, 0x6130):
            p = self.pressure_pa() if pressure_pa is None else pressure_pa
            if index == 0x6130:
                return float(p)
            lim = 2**31 - 1 if index == 0x9130 else 2**15 - 1
            return max(-lim - 1, min(lim, int(round(p / self.cfg.pressure_pa_per_count))))
        if index == 0x6150:
            return 0 if self.valid else 0x01
        return None

    def _on_read(self, index: int, subindex: int, od):
        value = self.od_value(index, subindex)
        return value if value is not None else super()._on_read(index, subindex, od)

    def snapshot(self) -> dict:
        return {"node_id": self.node_id, "nmt": self.nmt_state, "silent": self.silent,
                "valid": self.valid, "pressure_pa": self.last_pressure_pa, **self.counters}
