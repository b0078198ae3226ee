"""The vehicle's hardware interfaces a configuration describes (:mod:`uvd.runtime.interfaces`):
the serial or network instruments with their mailboxes, the CAN bus with the amplifiers and the
CAN depth sensor, the leak input — the components the :class:`~uvd.runtime.app.App` starts and
stops, and the parts of the cycle's inputs the daemon reads each period."""

from __future__ import annotations

from typing import Any

import numpy as np

from uvd.runtime.can_component import CanComponent, GcFreeze
from uvd.runtime.config import Config
from uvd.runtime.leak import LeakInput
from uvd.runtime.sensors import Instruments, make_sensors

__all__ = ["Hardware"]


class Hardware:
    """The hardware interfaces of ``config``: :attr:`inputs` read in this order, the
    amplifiers written."""

    def __init__(self, config: Config, vehicle) -> None:
        self.instruments = Instruments(sync=config.loop.trigger == "ins")
        i = self.instruments
        self.sensors = make_sensors(config, i.ins_box, i.dvl_box, i.depth_box)
        self.can = CanComponent(config, vehicle, i.depth_box)
        self.leak = LeakInput(config.sensors.leak) if config.sensors.leak.enabled else None
        leak = [self.leak] if self.leak is not None else []
        #: what the App starts and stops (GcFreeze last: it freezes what the others made)
        self.components = [*self.sensors, *leak, self.can, GcFreeze()]
        #: the interfaces that provide a part of the cycle's inputs, in the order read (a
        #: link's heartbeat is added by the daemon)
        self.inputs: list[Any] = [self.can, *leak, i]

    def tap(self, recorder) -> None:
        """A black box (``uvd.links.mcap``) taps every serial chunk and CAN frame."""
        for s in self.sensors:
            s.reader.tap = recorder.tap_serial
        self.can.tap = recorder.tap_can

    def wake_on_ins(self, wake) -> None:
        """The sensor-synchronous cycle: each INS sample calls ``wake`` (docs/runtime.md)."""
        for s in self.sensors:
            if s.name == "ins":
                s.on_sample = wake

    def write(self, t_ns: int, thrust_n: np.ndarray) -> None:
        """The cycle's command to the amplifiers."""
        self.can.write(t_ns, thrust_n)

    @property
    def counters(self) -> dict[str, int]:
        return {**self.can.counters, **self.instruments.counters}

    def stats(self) -> dict[str, Any]:
        """``sensors`` and, with amplifiers, ``can`` of the daemon's summary."""
        out: dict[str, Any] = {"sensors": {s.name: s.stats() for s in self.sensors}}
        if self.leak is not None:
            out["sensors"]["leak"] = self.leak.stats()
        if self.can.group is not None:
            out["can"] = self.can.group.stats()
            out["can"]["start"] = None if self.can.start_report is None else \
                self.can.start_report.nodes
        return out

    def close_now(self) -> None:
        """Close a port or the bus the App's bounded shutdown had no time left for (a daemon
        run inside a longer-lived process — tests, tools — leaves none locked). In this
        thread: the App's worker threads are gone by now."""
        for s in self.sensors:
            s.close_now()
        if self.can.bus is not None and self.can.bus.is_open:
            self.can.close_now()
