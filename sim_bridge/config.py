"""sim-bridge's own configuration: what the simulated vehicle needs to stand in for the real one.

Plain data — no file format, no validation of the daemon's keys. The contract between the two
processes is the daemon's configuration file (its ``[sensors]`` ports and ``[can]`` bus are
where sim-bridge must answer), so a :class:`BridgeConfig` is made from a validated daemon
configuration by the layer that knows both (``uvd.commands.sim_bridge.bridge_config``, behind
``sim-bridge --config FILE``); sim_bridge itself imports nothing of uvd.runtime.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from drivers.can.config import CanConfig
from drivers.digiquartz import DepthConverter
from sim_bridge.instruments.models import InstrumentConfig
from uvd.model.vehicle import Vehicle


@dataclass(frozen=True)
class BridgeConfig:
    """The simulated vehicle: its model, where it starts, and its instruments and CAN nodes.

    Attributes
    ----------
    vehicle : Vehicle
        The plant's model (rigid body, thrusters).
    trajectory : str
        Name of the reference trajectory whose pose at t = 0 is the start pose
        (:func:`uvd.control.trajectory.start_pose`).
    start_north_m, start_east_m : float
        Start position in the world frame (metres).
    serial_ports : dict
        Pseudo-terminal link of each serial instrument emulated (``ins``, ``dvl``, ``depth``
        when the depth sensor is serial): absolute paths.
    ins_protocol : {"stdbin", "ascii"}
        PHINS binary (STDBIN) or ASCII ("PHINS standard") output.
    depth : DepthConverter
        The Digiquartz conversion the daemon applies (sim-bridge emits its inverse).
    instruments : InstrumentConfig
        Rates and noise of the simulated instruments.
    leak_path : Path or None
        The leak input's value file (a GPIO's sysfs value as a file); None: no leak input.
    leak_active_level : {0, 1}
        The level that means water.
    can : CanConfig
        The bus, the amplifiers' node ids and object dictionary, the pressure transmitter.
    """

    vehicle: Vehicle
    trajectory: str = "hold"
    start_north_m: float = 0.0
    start_east_m: float = 0.0
    serial_ports: dict[str, Path] = field(default_factory=dict)
    ins_protocol: Literal["stdbin", "ascii"] = "stdbin"
    depth: DepthConverter = field(default_factory=DepthConverter)
    instruments: InstrumentConfig = field(default_factory=InstrumentConfig)
    leak_path: Path | None = None
    leak_active_level: int = 1
    can: CanConfig = field(default_factory=CanConfig)

    def __post_init__(self) -> None:
        if self.ins_protocol not in ("stdbin", "ascii"):
            raise ValueError(f"sim-bridge ins_protocol must be 'stdbin' or 'ascii', got "
                             f"{self.ins_protocol!r}")
        if self.leak_active_level not in (0, 1):
            raise ValueError(f"sim-bridge leak_active_level must be 0 or 1, got "
                             f"{self.leak_active_level!r}")
        for name, port in self.serial_ports.items():
            if not str(port).startswith("/"):
                raise ValueError(f"sim-bridge emulates serial instruments on pseudo-terminals: "
                                 f"sensors.{name}.port must be a path, not {str(port)!r}")
