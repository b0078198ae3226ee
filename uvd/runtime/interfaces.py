"""The daemon's hardware interfaces, as ros2_control's: read → update → write.

Each component that feeds the cycle provides its part of the cycle's inputs through
``read(t_ns, armed, parts)`` — the instruments (:class:`uvd.runtime.sensors.Instruments`: the
newest INS, DVL and depth samples), the CAN bus (:class:`uvd.runtime.can_component.CanComponent`:
the amplifiers' typed status), the leak input (:class:`uvd.runtime.leak.LeakInput`) and the
ground-station link's heartbeat (:class:`uvd.runtime.triggers.OperatorHeartbeat`) — and the
amplifiers take the output through ``write(t_ns, thrust)``. The daemon knows none of them by
name: it reads each into one :class:`InputParts`, runs the update and writes.

A ``read`` never waits and never raises for bad data: a missing or faulty device is a value
(None, a named fault) the arbiter acts on.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from uvd.runtime.cycle import CycleInputs

__all__ = ["InputParts", "ReadsInputs", "TakesOutput"]


class InputParts:
    """The read phase's parts of one cycle's :class:`~uvd.runtime.cycle.CycleInputs`."""

    __slots__ = ("ins", "dvl", "depth", "actuators", "leak", "extra")

    def __init__(self) -> None:
        self.ins = self.dvl = self.depth = self.actuators = self.leak = None
        self.extra: dict[str, Any] | None = None

    def signal(self, key: str, value: Any) -> None:
        """A plug-in trigger's signal (``CycleInputs.extra``, uvd/runtime/triggers.py)."""
        if self.extra is None:
            self.extra = {}
        self.extra[key] = value

    def inputs(self, t_ns: int, overrun_streak: int = 0, exceeded: bool = False
               ) -> CycleInputs:
        return CycleInputs(t_ns, self.ins, self.dvl, self.depth, self.actuators,
                           overrun_streak, exceeded, self.leak, self.extra)


class ReadsInputs(Protocol):
    """A hardware interface that provides part of the cycle's inputs."""

    def read(self, t_ns: int, armed: bool, parts: InputParts) -> None: ...


class TakesOutput(Protocol):
    """A hardware interface that takes the cycle's command (the amplifiers)."""

    def write(self, t_ns: int, thrust_n: np.ndarray) -> None: ...
