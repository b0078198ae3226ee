"""The ``[can]`` part of the uvd configuration, validated into frozen dataclasses.

Every error is a :class:`uvd.errors.ConfigError` whose message names the key, e.g.
``[can.amplifiers] node_ids: expected 6 node ids (one per thruster), got 5``.

Example (TOML)::

    [can]
    interface = "socketcan"       # any python-can interface: socketcan, slcan, pcan, virtual,
    channel = "can0"              # udp_multicast, ...
    bitrate = 1000000

    [can.amplifiers]
    node_ids = [1, 2, 3, 4, 5, 6]  # in the vehicle's thruster order
    mode = "cst"                   # cyclic synchronous torque; "pt" = profile torque
    command_timeout_ms = 200       # the drives zero their output after this long without RPDO

    [can.depth]
    enabled = true                 # a CiA 404 pressure transmitter as a second depth source
    node_id = 32

    [can.log]
    path = "logs/can.log"          # .log (candump), .asc or .blf
    max_bytes = 50000000           # rotate by size; 0 = never
"""

from __future__ import annotations

import ipaddress
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from uvd.errors import ConfigError

#: Interface-local IPv6 multicast group (scope 1): the kernel never puts it on a wire.
DEFAULT_UDP_GROUP = "ff11::7576:6463"
DEFAULT_UDP_PORT = 43113
_REPO_CONFIG = Path(__file__).resolve().parents[2] / "config"
DEFAULT_AMPLIFIER_EDS = _REPO_CONFIG / "amplifier.eds"
DEFAULT_PRESSURE_EDS = _REPO_CONFIG / "pressure-transmitter.eds"
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

    def __post_init__(self) -> None:
        where = "[can]"
        _need(isinstance(self.interface, str) and self.interface, where, "interface",
              "a python-can interface name such as 'socketcan'", self.interface)
        _need(isinstance(self.channel, str) and self.channel, where, "channel",
              "a non-empty string", self.channel)
        if self.bitrate is not None:
            _need(_is_int(self.bitrate) and 10_000 <= self.bitrate <= 8_000_000, where,
                  "bitrate", "an integer bit rate in 10000..8000000", self.bitrate)
        _need(_is_int(self.port) and 1 <= self.port <= 65535, where, "port",
              "a UDP port in 1..65535", self.port)
        _need(isinstance(self.loopback_only, bool), where, "loopback_only", "true or false",
              self.loopback_only)
        _need(_is_num(self.send_timeout_s) and 0 <= self.send_timeout_s <= 0.1, where,
              "send_timeout_s", "seconds in 0..0.1 (a cycle must never wait long)",
              self.send_timeout_s)
        _need(_is_int(self.busoff_send_failures) and self.busoff_send_failures >= 1, where,
              "busoff_send_failures", "an integer >= 1", self.busoff_send_failures)
        _need(_is_num(self.busoff_holdoff_s) and self.busoff_holdoff_s >= 0, where,
              "busoff_holdoff_s", "seconds >= 0", self.busoff_holdoff_s)
        _need(_is_int(self.error_passive_frames) and self.error_passive_frames >= 1, where,
              "error_passive_frames", "an integer >= 1", self.error_passive_frames)
        _need(_is_num(self.reopen_after_s) and self.reopen_after_s > 0, where,
              "reopen_after_s", "seconds > 0", self.reopen_after_s)
        b = self.reopen_backoff_s
        _need(isinstance(b, (tuple, list)) and len(b) == 2 and all(_is_num(x) for x in b)
              and 0 < b[0] <= b[1], where, "reopen_backoff_s",
              "[first, largest] seconds with 0 < first <= largest", b)
        object.__setattr__(self, "reopen_backoff_s", (float(b[0]), float(b[1])))
        _need(isinstance(self.options, Mapping), where, "options", "a table", self.options)
        object.__setattr__(self, "options", dict(self.options))
        if self.interface == "udp_multicast":
            self._check_group(where)

    def _check_group(self, where: str) -> None:
        try:
            group = ipaddress.ip_address(self.channel)
        except ValueError:
            raise ConfigError(f"{where} channel: udp_multicast needs a multicast IP group, "
                              f"got {self.channel!r}") from None
        if not group.is_multicast:
            raise ConfigError(f"{where} channel: {self.channel!r} is not a multicast group")
        if self.loopback_only:
            scope = int(group) >> 112 & 0xF if group.version == 6 else None
            if scope != 1:
                raise ConfigError(
                    f"{where} channel: {self.channel!r} could leave this machine; with "
                    "loopback_only = true use an interface-local IPv6 group (ff11::/16, e.g. "
                    f"{DEFAULT_UDP_GROUP!r}) or set loopback_only = false deliberately")

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
        Write the objects above to every amplifier by SDO at start.
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
    command_timeout_ms: int = 200
    max_failed_cycles: int = 5
    thrust_per_permille_n: tuple[float, ...] | None = None
    max_torque_permille: int = 1000
    velocity_rad_s_per_count: float = 0.001
    configure: bool = True
    sdo_timeout_s: float = 0.3

    def __post_init__(self) -> None:
        where = "[can.amplifiers]"
        ids = self.node_ids
        _need(isinstance(ids, (tuple, list)) and len(ids) >= 1
              and all(_is_int(i) and 1 <= i <= 127 for i in ids), where, "node_ids",
              "a list of CANopen node ids in 1..127", ids)
        _need(len(set(ids)) == len(ids), where, "node_ids", "distinct node ids", ids)
        object.__setattr__(self, "node_ids", tuple(int(i) for i in ids))
        object.__setattr__(self, "eds", _path(self.eds, where, "eds"))
        _need(_is_int(self.master_node_id) and 1 <= self.master_node_id <= 127
              and self.master_node_id not in self.node_ids, where, "master_node_id",
              "a node id in 1..127 that no amplifier uses", self.master_node_id)
        _need(self.mode in ("cst", "pt"), where, "mode",
              "'cst' (cyclic synchronous torque) or 'pt' (profile torque)", self.mode)
        for key, lo, hi in (("heartbeat_period_ms", 0, 10_000), ("node_heartbeat_ms", 0, 10_000),
                            ("heartbeat_timeout_ms", 1, 60_000), ("node_consumer_ms", 0, 60_000),
                            ("command_timeout_ms", 10, 10_000), ("max_failed_cycles", 1, 1000),
                            ("max_torque_permille", 1, 32767)):
            v = getattr(self, key)
            _need(_is_int(v) and lo <= v <= hi, where, key, f"an integer in {lo}..{hi}", v)
        if self.node_consumer_ms and self.heartbeat_period_ms:
            _need(self.node_consumer_ms > self.heartbeat_period_ms, where, "node_consumer_ms",
                  "longer than heartbeat_period_ms (or 0)", self.node_consumer_ms)
        if self.node_consumer_ms and not self.heartbeat_period_ms:
            raise ConfigError(f"{where} node_consumer_ms: the amplifiers would consume a "
                              "heartbeat the daemon does not produce (heartbeat_period_ms = 0)")
        t = self.thrust_per_permille_n
        if t is not None:
            _need(isinstance(t, (tuple, list)) and len(t) == len(self.node_ids)
                  and all(_is_num(x) and x > 0 and math.isfinite(x) for x in t), where,
                  "thrust_per_permille_n",
                  f"{len(self.node_ids)} positive numbers (one per node id)", t)
            object.__setattr__(self, "thrust_per_permille_n", tuple(float(x) for x in t))
        _need(_is_num(self.velocity_rad_s_per_count) and self.velocity_rad_s_per_count > 0,
              where, "velocity_rad_s_per_count", "a positive number",
              self.velocity_rad_s_per_count)
        _need(isinstance(self.configure, bool), where, "configure", "true or false",
              self.configure)
        _need(_is_num(self.sdo_timeout_s) and 0.01 <= self.sdo_timeout_s <= 5, where,
              "sdo_timeout_s", "seconds in 0.01..5", self.sdo_timeout_s)


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

    def __post_init__(self) -> None:
        where = "[can.depth]"
        _need(isinstance(self.enabled, bool), where, "enabled", "true or false", self.enabled)
        _need(_is_int(self.node_id) and 1 <= self.node_id <= 127, where, "node_id",
              "a node id in 1..127", self.node_id)
        object.__setattr__(self, "eds", _path(self.eds, where, "eds"))
        for key in ("pressure_pa_per_count", "density_kg_m3", "gravity_m_s2"):
            v = getattr(self, key)
            _need(_is_num(v) and v > 0 and math.isfinite(v), where, key, "a positive number", v)
        _need(_is_num(self.atmospheric_pa) and 0 <= self.atmospheric_pa < 2e5, where,
              "atmospheric_pa", "pascals in 0..200000", self.atmospheric_pa)
        _need(_is_int(self.max_age_ms) and self.max_age_ms >= 1, where, "max_age_ms",
              "an integer >= 1", self.max_age_ms)


@dataclass(frozen=True)
class CanLogConfig:
    """Recording of every frame sent and received (python-can writers).

    ``path`` picks the format by suffix: ``.log`` (candump), ``.asc`` (Vector ASCII) or
    ``.blf`` (Vector binary); ``None`` records nothing. ``max_bytes`` > 0 rotates the file
    when it grows past that size (python-can's ``SizedRotatingLogger``).
    """

    path: Path | None = None
    max_bytes: int = 0

    def __post_init__(self) -> None:
        where = "[can.log]"
        if self.path is not None:
            p = _path(self.path, where, "path")
            _need(p.suffix.lower() in LOG_SUFFIXES, where, "path",
                  f"a file ending in one of {', '.join(LOG_SUFFIXES)}", str(p))
            object.__setattr__(self, "path", p)
        _need(_is_int(self.max_bytes) and self.max_bytes >= 0, where, "max_bytes",
              "an integer >= 0 (0 = no rotation)", self.max_bytes)


@dataclass(frozen=True)
class CanConfig:
    """The whole ``[can]`` table."""

    bus: CanBusConfig = field(default_factory=CanBusConfig)
    amplifiers: AmplifierConfig = field(default_factory=AmplifierConfig)
    depth: DepthConfig = field(default_factory=DepthConfig)
    log: CanLogConfig = field(default_factory=CanLogConfig)

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None, where: str = "[can]") -> CanConfig:
        """Validate a parsed ``[can]`` TOML table (``None`` or ``{}`` gives the defaults).

        Raises
        ------
        ConfigError
            Unknown key, wrong type or value out of range; the message names the key.
        """
        m = dict(m or {})
        sub = {name: m.pop(name, None) for name in ("amplifiers", "depth", "log")}
        bus = _build(CanBusConfig, m, where)
        amps = _build(AmplifierConfig, sub["amplifiers"] or {}, f"{where[:-1]}.amplifiers]")
        depth = _build(DepthConfig, sub["depth"] or {}, f"{where[:-1]}.depth]")
        log = _build(CanLogConfig, sub["log"] or {}, f"{where[:-1]}.log]")
        if depth.enabled and depth.node_id in amps.node_ids + (amps.master_node_id,):
            raise ConfigError(f"{where[:-1]}.depth] node_id: {depth.node_id} is already used "
                              "by an amplifier or the daemon")
        return cls(bus=bus, amplifiers=amps, depth=depth, log=log)


def _build(kind, m: Any, where: str):
    if not isinstance(m, Mapping):
        raise ConfigError(f"{where}: expected a table, got {type(m).__name__}")
    known = set(kind.__dataclass_fields__)
    unknown = sorted(set(m) - known)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; known: {sorted(known)}")
    try:
        return kind(**m)
    except ConfigError as exc:
        if where.startswith("[can]") or str(exc).startswith(where):
            raise
        # re-anchor the message on the caller's table name
        msg = str(exc)
        raise ConfigError(where + msg[msg.index("]") + 1:]) from None


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _need(ok: Any, where: str, key: str, expected: str, got: Any) -> None:
    if not ok:
        raise ConfigError(f"{where} {key}: expected {expected}, got {got!r}")


def _path(v: Any, where: str, key: str) -> Path:
    if isinstance(v, Path):
        return v
    _need(isinstance(v, str) and v, where, key, "a file path", v)
    return Path(v).expanduser()
