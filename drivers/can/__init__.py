"""CAN: thruster amplifiers (CiA 402) and a pressure transmitter (CiA 404) over CANopen.

python-can carries the frames, the ``canopen`` library speaks the protocol. Start at
:class:`drivers.can.bus.CanBus` and :class:`drivers.can.amplifier.AmplifierGroup`; the
configuration is :class:`drivers.can.config.CanConfig`; ``docs/can.md`` tells the whole story.
"""

from drivers.can.amplifier import (
    AmplifierFeedback,
    AmplifierGroup,
    FaultEvent,
    GroupFeedback,
    StartReport,
    WriteStatus,
)
from drivers.can.bus import BusOpenError, BusStatus, CanBus, FrameDropped, open_bus
from drivers.can.config import (
    AmplifierConfig,
    CanBusConfig,
    CanConfig,
    CanLogConfig,
    DepthConfig,
)
from drivers.can.depth import CanDepthSensor, depth_from_pressure
from drivers.can.logging import CanRecorder

__all__ = [
    "AmplifierConfig", "AmplifierFeedback", "AmplifierGroup", "BusOpenError", "BusStatus",
    "CanBus", "CanBusConfig", "CanConfig", "CanDepthSensor", "CanLogConfig", "CanRecorder",
    "DepthConfig", "FaultEvent", "FrameDropped", "GroupFeedback", "StartReport", "WriteStatus",
    "depth_from_pressure", "open_bus",
]
