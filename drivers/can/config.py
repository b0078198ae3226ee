"""The CAN driver's configuration: plain frozen dataclasses, one per ``[can]`` table.

The driver takes them as they are. The ``[can]`` tables of the uvd configuration file are
declared and validated with the rest of the configuration (``uvd.runtime.config``: every key
with its type, unit, range and doc, errors naming file and key) and converted into these;
code that builds them directly (tests, emulators, benchmarks) passes values of the right type.

Example (TOML)::

    [can]
    interface = "socketcan"       # any python-can interface: socketcan, slcan, pcan, virtual,
    channel = "can0"              # udp_multicast, ...
    bitrate = 1000000

    [can.amplifiers]
    node_ids = [1, 2, 3, 4, 5, 6]  # in the vehicle's thruster order
    mode = "cst"                   # cyclic synchronous torque; "pt" = profile torque
    command_timeout_ms = 300       # the drives zero their output after this long without RPDO

    [can.depth]
    enabled = true                 # a CiA 404 pressure transmitter as a second depth source
    node_id = 32

    [can.log]
    path = "logs/can.log"          # .log (candump), .asc or .blf
    max_bytes = 50000000           # rotate by size; 0 = never
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

#: Interface-local IPv6 multicast group (scope 1): the kernel never puts it on a wire.
DEFAULT_UDP_GROUP = "ff11::7576:6463"
DEFAULT_UDP_PORT = 43113
#: The reference devices' object dictionaries, package data of this package (a checkout, an
#: editable install and an installed wheel alike find them here)
DEFAULT_AMPLIFIER_EDS = Path(str(resources.files("drivers.can") / "amplifier.eds"))
DEFAULT_PRESSURE_EDS = Path(str(resources.files("drivers.can") / "pressure-transmitter.eds"))
LOG_SUFFIXES = (".log", ".asc", ".blf")


@dataclass(frozen=True)
class CanBusConfig:
    """How to open the bus and how to judge its health.

    Attributes
    ----------
    interface, channel : str
        python-can interface name and channel (``socketcan``/``can0``, ``slcan``/``/dev/ttyACM0``,
        ``pcan``/``PCAN_USBBUS1``, ``virtual``/any name, ``udp_multicast``/a multicast group).
    bitrate : int or None
        Bit rate in bit/s, passed to interfaces that take one (not ``virtual``,
        ``udp_multicast``, nor ``socketcan``, whose bit rate is set with ``ip link``).
    port : int
        UDP port of ``udp_multicast``.
    loopback_only : bool
        ``udp_multicast`` only: refuse a group whose packets could leave this machine
        (anything but an interface-local ``ffx1::`` IPv6 group); the hop limit is 0.
    send_timeout_s : float
        How long a send may wait for room in the transmit queue; 0 means a full queue drops
        the frame at once (it is never queued for later).
    busoff_send_failures : int
        Consecutive failed sends after which the bus is taken as bus-off even without an
        error frame saying so.
    busoff_holdoff_s : float
        After bus-off, how long sends are suppressed before the bus is probed again.
    error_passive_frames : int
        Bus-error frames within one second after which the bus is taken as error-passive
        when the interface reports no error counters.
    reopen_after_s : float
        The bus is closed and opened again when reception has failed, or every send has
        failed, for this long.
    reopen_backoff_s : (float, float)
        First and largest wait between reopen attempts (doubling).
    options : dict
        Extra keyword arguments for ``can.Bus`` (e.g. ``{serial_port = ...}``).
    """

    interface: str = "socketcan"
    channel: str = "can0"
    bitrate: int | None = 1_000_000
    port: int = DEFAULT_UDP_PORT
    loopback_only: bool = True
    send_timeout_s: float = 0.0
    busoff_send_failures: int = 10
    busoff_holdoff_s: float = 0.2
    error_passive_frames: int = 32
    reopen_after_s: float = 1.0
    reopen_backoff_s: tuple[float, float] = (0.5, 10.0)
    options: Mapping[str, Any] = field(default_factory=dict)

    @property
    def is_udp_multicast(self) -> bool:
        return self.interface == "udp_multicast"


@dataclass(frozen=True)
class AmplifierConfig:
    """The thruster amplifiers: one CiA 402 node per thruster, in the vehicle's order.

    Attributes
    ----------
    node_ids : tuple of int
        CANopen node id (1..127) of each thruster's amplifier.
    eds : Path
        Object dictionary (EDS/DCF) of the amplifier; the PDO mapping is taken from it.
    master_node_id : int
        Node id under which the daemon produces its heartbeat (0x700 + id).
    mode : str
        ``"cst"`` cyclic synchronous torque (0x6060 = 10) or ``"pt"`` profile torque (4).
    heartbeat_period_ms : int
        The daemon's heartbeat period; sent from the control cycle, so a hung daemon stops it.
    node_heartbeat_ms : int
        Heartbeat period written to each amplifier (0x1017).
    heartbeat_timeout_ms : int
        An amplifier whose heartbeat is older than this is reported ``heartbeat_lost``.
    node_consumer_ms : int
        Heartbeat consumer time written to each amplifier (0x1016:01) for the daemon's
        heartbeat; 0 leaves it off.
    command_timeout_ms : int
        RPDO deadline written to each amplifier (0x1400:05, event timer): an amplifier that
        receives no command for this long zeroes its output, sends EMCY 0x8250 and faults.
    max_failed_cycles : int
        Consecutive cycles without feedback (per node) or with a failed send (per group)
        after which a fault is raised.
    thrust_per_permille_n : tuple of float or None
        Steady-state calibration, thrust (N) per 1/1000 of rated torque; ``None`` takes
        ``max_thrust_n / 1000`` of each thruster (rated torque = rated thrust).
    max_torque_permille : int
        Largest target torque ever sent (also written to 0x6072).
    velocity_rad_s_per_count : float
        Unit of the velocity actual value (0x606C); 0.001 on the reference amplifier.
    configure : bool
        Write the objects above to every amplifier by SDO at start; without, each drive's
        own RPDO deadline is read (:meth:`AmplifierGroup.command_timeouts_ms`).
    sdo_timeout_s : float
        Time allowed for one SDO response.
    """

    node_ids: tuple[int, ...] = (1, 2, 3, 4, 5, 6)
    eds: Path = DEFAULT_AMPLIFIER_EDS
    master_node_id: int = 127
    mode: str = "cst"
    heartbeat_period_ms: int = 100
    node_heartbeat_ms: int = 100
    heartbeat_timeout_ms: int = 350
    node_consumer_ms: int = 500
    command_timeout_ms: int = 300
    max_failed_cycles: int = 5
    thrust_per_permille_n: tuple[float, ...] | None = None
    max_torque_permille: int = 1000
    velocity_rad_s_per_count: float = 0.001
    configure: bool = True
    sdo_timeout_s: float = 0.3


@dataclass(frozen=True)
class DepthConfig:
    """A CANopen pressure transmitter (CiA 404 measuring device) used as a depth source.

    Depth is hydrostatic: d = (p − p_atm) / (ρ g), positive down.
    """

    enabled: bool = False
    node_id: int = 32
    eds: Path = DEFAULT_PRESSURE_EDS
    pressure_pa_per_count: float = 0.1
    atmospheric_pa: float = 101_325.0
    density_kg_m3: float = 998.0
    gravity_m_s2: float = 9.80665
    max_age_ms: int = 500


@dataclass(frozen=True)
class CanLogConfig:
    """Recording of every frame sent and received (python-can writers).

    ``path`` picks the format by suffix: ``.log`` (candump), ``.asc`` (Vector ASCII) or
    ``.blf`` (Vector binary); ``None`` records nothing. ``max_bytes`` > 0 rotates the file
    when it grows past that size (python-can's ``SizedRotatingLogger``).
    """

    path: Path | None = None
    max_bytes: int = 0


@dataclass(frozen=True)
class CanConfig:
    """The whole ``[can]`` table."""

    bus: CanBusConfig = field(default_factory=CanBusConfig)
    amplifiers: AmplifierConfig = field(default_factory=AmplifierConfig)
    depth: DepthConfig = field(default_factory=DepthConfig)
    log: CanLogConfig = field(default_factory=CanLogConfig)
