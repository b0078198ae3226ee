"""The CAN bus: opening it from config, its health, and the receive path into canopen.

:class:`CanBus` owns one python-can bus, a python-can ``Notifier`` thread and a
:class:`UvdNetwork` (a ``canopen.Network``). Every received frame passes one dispatcher that

* takes error frames out of the data path, decodes them (SocketCAN layout) and feeds the
  :class:`BusMonitor`;
* drops remote, extended-id and CAN FD frames, frames of a wrong length for a known COB-ID,
  and frames nobody subscribed to — each kind counted;
* drops the echo of our own frames on ``udp_multicast`` (which loops every datagram back to
  its sender), so they are neither decoded twice nor logged twice;
* hands the rest to canopen (PDO, EMCY, heartbeat, SDO), catching anything a callback raises.

Sends never block and never queue: :meth:`CanBus.send` tries once with
``send_timeout_s`` (0 by default) and returns ``False`` on a full queue or any error. Nothing
in this module sends periodically from a background thread.

Bus states and the reconnect policy
-----------------------------------
python-can's ``bus.state`` is not implemented by most interfaces, so the state is inferred:

``active``
    normal.
``warning`` / ``passive``
    an error frame reports the controller error-warning / error-passive (SocketCAN
    ``CAN_ERR_CRTL`` flags or error counters ≥ 96 / ≥ 128), or ``error_passive_frames``
    bus-error frames arrived within one second. Frames are still sent. Back to ``active`` on a
    "restarted"/"active" error frame, or after one second without error frames.
``bus_off``
    an error frame reports bus-off, or ``busoff_send_failures`` sends in a row failed. Sends
    are suppressed for ``busoff_holdoff_s`` (the controller or the kernel's ``restart-ms``
    recovers the link); then the next send probes the bus. The first frame received after a
    successful probe returns the state to ``active``.

If reception fails (the interface went away) or every send fails for ``reopen_after_s``, the
bus is closed and opened again, waiting ``reopen_backoff_s[0]`` doubling up to
``reopen_backoff_s[1]`` between attempts. The bus never re-enables anything by itself: the
amplifiers will have faulted on their command timeout meanwhile, and re-enabling them is the
daemon's decision (``AmplifierGroup.reset_faults`` + ``enable``).
"""

from __future__ import annotations

import errno
import logging
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import can
import canopen

from drivers.can.config import CanBusConfig
from uvd.errors import BusError

log = logging.getLogger(__name__)

ACTIVE = "active"
WARNING = "warning"
PASSIVE = "passive"
BUS_OFF = "bus_off"
CLOSED = "closed"


class BusOpenError(BusError):
    """The CAN interface could not be opened (names the interface and channel)."""


class FrameDropped(BusError):
    """A frame was not sent (full queue, bus-off hold-off, closed bus or interface error)."""


# --- error frames (SocketCAN layout, linux/can/error.h) ---------------------------------------

CAN_ERR_TX_TIMEOUT = 0x001
CAN_ERR_LOSTARB = 0x002
CAN_ERR_CRTL = 0x004
CAN_ERR_PROT = 0x008
CAN_ERR_TRX = 0x010
CAN_ERR_ACK = 0x020
CAN_ERR_BUSOFF = 0x040
CAN_ERR_BUSERROR = 0x080
CAN_ERR_RESTARTED = 0x100
CAN_ERR_CNT = 0x200

CAN_ERR_CRTL_RX_OVERFLOW = 0x01
CAN_ERR_CRTL_TX_OVERFLOW = 0x02
CAN_ERR_CRTL_RX_WARNING = 0x04
CAN_ERR_CRTL_TX_WARNING = 0x08
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20
CAN_ERR_CRTL_ACTIVE = 0x40

_CLASS_NAMES = ((CAN_ERR_TX_TIMEOUT, "tx_timeout"), (CAN_ERR_LOSTARB, "lost_arbitration"),
                (CAN_ERR_CRTL, "controller"), (CAN_ERR_PROT, "protocol"),
                (CAN_ERR_TRX, "transceiver"), (CAN_ERR_ACK, "no_ack"),
                (CAN_ERR_BUSOFF, "bus_off"), (CAN_ERR_BUSERROR, "bus_error"),
                (CAN_ERR_RESTARTED, "restarted"), (CAN_ERR_CNT, "counters"))


@dataclass(frozen=True, slots=True)
class ErrorFrameInfo:
    """A decoded error frame.

    Attributes
    ----------
    classes : tuple of str
        Error classes set in the frame's id (``bus_off``, ``controller``, ``no_ack``, ...).
    state : str or None
        Bus state the frame implies (``active``/``warning``/``passive``/``bus_off``), or
        ``None`` if it implies none.
    tx_errors, rx_errors : int or None
        Transmit/receive error counters when the frame carries them.
    """

    classes: tuple[str, ...]
    state: str | None
    tx_errors: int | None
    rx_errors: int | None

    @property
    def is_bus_error(self) -> bool:
        """A protocol/ack/bus error: a disturbance on the wire, no state by itself."""
        return bool({"protocol", "no_ack", "bus_error", "transceiver"} & set(self.classes))


def make_error_frame(classes: int, controller: int = 0, tx_errors: int | None = None,
                     rx_errors: int | None = None) -> can.Message:
    """An error frame in SocketCAN layout (what a Linux CAN controller reports).

    Used by the fault injection of the emulators and by tests; the driver decodes it with
    :func:`decode_error_frame`.
    """
    data = bytearray(8)
    data[1] = controller & 0xFF
    if tx_errors is not None or rx_errors is not None:
        classes |= CAN_ERR_CNT
        data[6] = min(int(tx_errors or 0), 255)
        data[7] = min(int(rx_errors or 0), 255)
    return can.Message(arbitration_id=classes & 0x1FFFFFFF, is_error_frame=True,
                       is_extended_id=False, data=bytes(data), dlc=8)


def decode_error_frame(msg: can.Message) -> ErrorFrameInfo:
    """Decode an error frame in SocketCAN layout; never raises.

    Interfaces that report errors in another layout produce frames whose classes decode to
    nonsense or nothing; those still count as bus errors for the rate-based inference.
    """
    cid = int(msg.arbitration_id)
    data = bytes(msg.data or b"")
    classes = tuple(name for bit, name in _CLASS_NAMES if cid & bit)
    ctrl = data[1] if len(data) > 1 else 0
    tx = rx = None
    if len(data) >= 8 and (cid & CAN_ERR_CNT or data[6] or data[7]):
        tx, rx = data[6], data[7]
    state = None
    if cid & CAN_ERR_BUSOFF:
        state = BUS_OFF
    elif cid & CAN_ERR_CRTL and ctrl & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE):
        state = PASSIVE
    elif cid & CAN_ERR_CRTL and ctrl & (CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING):
        state = WARNING
    elif cid & CAN_ERR_RESTARTED or (cid & CAN_ERR_CRTL and ctrl & CAN_ERR_CRTL_ACTIVE):
        state = ACTIVE
    elif tx is not None:
        worst = max(tx, rx or 0)
        state = PASSIVE if worst >= 128 else WARNING if worst >= 96 else ACTIVE
    if not classes:
        classes = ("unknown",)
    return ErrorFrameInfo(classes, state, tx, rx)


class BusMonitor:
    """Infers the bus state from error frames, sends and receptions (see module docstring).

    Not thread-safe by itself; :class:`CanBus` calls it under its lock. Times are monotonic
    nanoseconds.
    """

    _SEVERITY = {ACTIVE: 0, WARNING: 1, PASSIVE: 2, BUS_OFF: 3}

    def __init__(self, cfg: CanBusConfig) -> None:
        self.cfg = cfg
        self.state = ACTIVE
        self.reason = ""
        self.since_ns = 0
        self.busoff_count = 0
        self.passive_count = 0
        self.send_failures_in_row = 0
        self._bus_errors: deque[int] = deque(maxlen=max(cfg.error_passive_frames, 1) * 4)
        self._last_error_ns = 0
        self._busoff_ns = 0
        self._probe_ok = False

    def _set(self, state: str, reason: str, now: int) -> None:
        if state != self.state:
            log.info("CAN bus %s -> %s (%s)", self.state, state, reason)
            if state == BUS_OFF:
                self.busoff_count += 1
            elif state == PASSIVE:
                self.passive_count += 1
            self.state, self.reason, self.since_ns = state, reason, now

    def on_error_frame(self, info: ErrorFrameInfo, now: int) -> None:
        self._last_error_ns = now
        if info.state == BUS_OFF:
            self._busoff_ns = now
            self._probe_ok = False
            self._set(BUS_OFF, "error frame: bus-off", now)
            return
        if info.state == ACTIVE and "restarted" in info.classes:
            self._set(ACTIVE, "error frame: controller restarted", now)
            return
        if info.state is not None and self.state != BUS_OFF:
            self._set(info.state, f"error frame: {'/'.join(info.classes)}", now)
        if info.is_bus_error or info.state is None:
            self._bus_errors.append(now)
            window = [t for t in self._bus_errors if now - t <= 1_000_000_000]
            if len(window) >= self.cfg.error_passive_frames and self.state in (ACTIVE, WARNING):
                self._set(PASSIVE, f"{len(window)} bus-error frames within 1 s", now)

    def on_send_ok(self, now: int) -> None:
        self.send_failures_in_row = 0
        if self.state == BUS_OFF:
            self._probe_ok = True

    def on_send_failed(self, now: int) -> None:
        self.send_failures_in_row += 1
        if self.send_failures_in_row >= self.cfg.busoff_send_failures:
            self._busoff_ns = now
            self._probe_ok = False
            self._set(BUS_OFF, f"{self.send_failures_in_row} sends failed in a row", now)

    def on_rx(self, now: int) -> None:
        if self.state == BUS_OFF and self._probe_ok:
            self._set(ACTIVE, "frames flow again after bus-off", now)

    def tick(self, now: int, interface_state: str | None = None) -> None:
        """Time-based transitions; ``interface_state`` is python-can's own (advisory) state."""
        if interface_state == BUS_OFF and self.state != BUS_OFF:
            self._busoff_ns = now
            self._set(BUS_OFF, "interface reports bus-off", now)
        elif interface_state == PASSIVE and self.state in (ACTIVE, WARNING):
            self._set(PASSIVE, "interface reports error-passive", now)
        elif self.state in (WARNING, PASSIVE) and now - self._last_error_ns > 1_000_000_000 \
                and interface_state in (None, ACTIVE):
            self._set(ACTIVE, "no error frame for 1 s", now)

    def allow_send(self, now: int) -> bool:
        if self.state != BUS_OFF:
            return True
        return now - self._busoff_ns >= int(self.cfg.busoff_holdoff_s * 1e9)


# --- opening ---------------------------------------------------------------------------------

def open_bus(cfg: CanBusConfig) -> can.BusABC:
    """Open the python-can bus described by ``cfg``.

    ``udp_multicast`` is opened with hop limit 0 when ``loopback_only`` (the default), and the
    socket is checked afterwards; together with the interface-local group the config insists
    on, no datagram can leave this machine.

    Raises
    ------
    BusOpenError
        The interface is unknown, its driver is missing, or the channel cannot be opened;
        chained ``from`` python-can's exception.
    """
    kwargs = dict(cfg.options)
    if cfg.interface == "udp_multicast":
        kwargs.update(port=cfg.port, fd=False)
        if cfg.loopback_only:
            kwargs["hop_limit"] = 0
    elif cfg.interface == "virtual":
        kwargs.setdefault("receive_own_messages", False)
    elif cfg.bitrate is not None and cfg.interface != "socketcan":
        kwargs.setdefault("bitrate", cfg.bitrate)
    try:
        bus = can.Bus(interface=cfg.interface, channel=cfg.channel, **kwargs)
    except (can.CanError, OSError, ValueError, ImportError, TypeError) as exc:
        raise BusOpenError(f"cannot open CAN interface {cfg.interface!r} channel "
                           f"{cfg.channel!r}: {exc}{_socketcan_hint(cfg, exc)}") from exc
    if cfg.interface == "udp_multicast":
        _enlarge_receive_buffer(bus)
    if cfg.interface == "udp_multicast" and cfg.loopback_only:
        hops = udp_hop_limit(bus)
        if hops != 0:
            bus.shutdown()
            raise BusOpenError(f"udp_multicast on {cfg.channel!r}: hop limit is {hops}, not 0; "
                               "refusing a bus whose datagrams could leave this machine")
    return bus


#: what the operator of a Linux machine does about SocketCAN's errors when opening
_SOCKETCAN_HINTS = {
    errno.EAFNOSUPPORT: "this kernel has no SocketCAN (load it: modprobe can_raw; a container "
                        "shares its host's kernel, and needs it loaded there), or a sandbox "
                        "refuses AF_CAN (systemd's RestrictAddressFamilies= must list it)",
    errno.ENODEV: "no network interface {ch} (ip -details link show; a USB adapter "
                  "unplugged? a virtual bus for a test: ip link add dev {ch} type vcan)",
    errno.EPERM: "not permitted (a sandbox's system-call filter? systemd's SystemCallFilter=; "
                 "a CAN_RAW socket itself needs no privilege)",
}


def _socketcan_hint(cfg: CanBusConfig, exc: BaseException) -> str:
    """``" — <what to do>"`` for a SocketCAN error the operator can act on at opening (a
    down interface opens, and fails at its first send), else ``""``."""
    hint = _SOCKETCAN_HINTS.get(getattr(exc, "errno", None))
    if cfg.interface != "socketcan" or hint is None:
        return ""
    return " — " + hint.format(ch=cfg.channel)


def udp_hop_limit(bus: can.BusABC) -> int | None:
    """Multicast hop limit (IPv6) / TTL (IPv4) of a ``udp_multicast`` bus's socket."""
    try:
        fd = bus.fileno()
    except (NotImplementedError, OSError, AttributeError):
        return None
    if fd is None or fd < 0:
        return None
    with socket.socket(fileno=_dup(fd)) as sock:
        if sock.family == socket.AF_INET6:
            return sock.getsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS)
        return sock.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL)


def _enlarge_receive_buffer(bus: can.BusABC, size: int = 4 << 20) -> None:
    """Give a ``udp_multicast`` socket room for ~a second of traffic (best effort).

    The kernel's default (~200 kB, a few hundred datagrams) overflows — and drops frames —
    if the receive thread is held up for a fraction of a second on a busy machine.
    """
    try:
        with socket.socket(fileno=_dup(bus.fileno())) as sock:
            try:
                sock.setsockopt(socket.SOL_SOCKET, getattr(socket, "SO_RCVBUFFORCE", 33), size)
            except OSError:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)
    except (OSError, NotImplementedError, AttributeError, TypeError) as exc:
        log.debug("could not enlarge the receive buffer: %s", exc)


def _dup(fd: int) -> int:
    import os
    return os.dup(fd)


# --- the canopen network ---------------------------------------------------------------------

class _InertTask:
    """What :meth:`UvdNetwork.send_periodic` returns: a task that sends nothing."""

    def stop(self) -> None:  # noqa: D102 - canopen's PeriodicMessageTask interface
        pass

    def update(self, data: bytes) -> None:  # noqa: D102
        pass


class UvdNetwork(canopen.Network):
    """A ``canopen.Network`` whose every send goes through :meth:`CanBus.send`.

    ``send_message`` raises :class:`FrameDropped` when the frame was not sent (canopen's SDO
    client relies on an exception); ``send_periodic`` sends nothing — uvd never lets a
    background task repeat a frame (a hung daemon must not keep the last command going).
    """

    def __init__(self, owner: CanBus) -> None:
        super().__init__(None)
        self._owner = owner
        self.periodic_refused = 0

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        msg = can.Message(arbitration_id=can_id, data=bytes(data), is_extended_id=can_id > 0x7FF,
                          is_remote_frame=remote)
        if not self._owner.send(msg):
            raise FrameDropped(f"frame 0x{can_id:03X} not sent: {self._owner.last_send_error}")

    def send_periodic(self, can_id: int, data: bytes, period: float,
                      remote: bool = False) -> _InertTask:
        self.periodic_refused += 1
        log.debug("refused periodic send of 0x%03X (uvd sends every frame from its cycle)",
                  can_id)
        return _InertTask()


# --- the bus ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class BusStatus:
    """A snapshot of the bus health and its counters."""

    state: str
    reason: str
    open: bool
    counters: dict[str, int]


class _Dispatcher(can.Listener):
    def __init__(self, owner: CanBus) -> None:
        self.owner = owner

    def on_message_received(self, msg: can.Message) -> None:
        self.owner._on_rx(msg)

    def on_error(self, exc: Exception) -> None:
        self.owner._on_rx_error(exc)

    def stop(self) -> None:
        pass


_RX_COUNTERS = ("rx_frames", "rx_error_frames", "rx_remote", "rx_extended", "rx_fd",
                "rx_malformed", "rx_unknown", "rx_echo", "rx_callback_errors", "rx_errors")
_TX_COUNTERS = ("tx_frames", "tx_failed", "tx_full", "tx_busoff_held", "tx_closed", "tx_gated",
                "reopens", "reopen_failures")


class CanBus:
    """One CAN bus, its health, its receive dispatcher and its canopen network.

    Parameters
    ----------
    cfg : CanBusConfig
        How to open the bus.
    recorder : drivers.can.logging.CanRecorder, optional
        Receives every frame sent and received.
    clock : callable
        Monotonic nanoseconds.
    tx_gate : callable, optional
        ``tx_gate(msg) -> bool``; a frame it rejects is not sent (the emulators use it to
        silence a node). ``send`` then returns ``False``.

    Examples
    --------
    >>> from drivers.can.config import CanBusConfig
    >>> bus = CanBus(CanBusConfig(interface="virtual", channel="doc")).open()
    >>> bus.status().state
    'active'
    >>> bus.close()
    """

    def __init__(self, cfg: CanBusConfig, *, recorder=None,
                 clock: Callable[[], int] = time.monotonic_ns,
                 tx_gate: Callable[[can.Message], bool] | None = None) -> None:
        self.cfg = cfg
        self.recorder = recorder
        #: ``tap(msg, t_ns, is_rx)`` sees every frame sent and received (a black-box
        #: recorder); called from the sending thread and the notifier thread, must be cheap
        #: and must not raise
        self.tap: Callable[[can.Message, int, bool], None] | None = None
        self.clock = clock
        self.tx_gate = tx_gate
        self.monitor = BusMonitor(cfg)
        self.network = UvdNetwork(self)
        self.counters: dict[str, int] = dict.fromkeys(_RX_COUNTERS + _TX_COUNTERS, 0)
        self.malformed_by_id: dict[int, int] = {}
        self.unknown_by_id: dict[int, int] = {}
        self.last_send_error = ""
        self.last_rx_error = ""
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._dispatcher = _Dispatcher(self)
        self._send_lock = threading.Lock()
        self._state_lock = threading.Lock()
        self._expected_len: dict[int, frozenset[int]] = {}
        self._echo: deque[tuple[int, bytes, bool, int]] = deque(maxlen=4096)
        self._echo_filter = cfg.is_udp_multicast
        self._rx_error_since = 0
        self._rx_ok_ns = 0
        self._tx_fail_since = 0
        self._next_reopen_ns = 0
        self._backoff_s = cfg.reopen_backoff_s[0]
        self._want_open = False

    # -- lifecycle --
    def open(self) -> CanBus:
        """Open the interface and start the receive thread; raises :class:`BusOpenError`."""
        self._start()
        self._want_open = True
        self._backoff_s = self.cfg.reopen_backoff_s[0]
        return self

    def close(self) -> None:
        """Stop the receive thread and close the interface (idempotent, never raises)."""
        self._want_open = False
        self._shutdown()

    def _start(self) -> None:
        self._bus = open_bus(self.cfg)
        self.network.bus = self._bus
        self._notifier = can.Notifier(self._bus, [self._dispatcher], timeout=0.05)
        self.network.notifier = self._notifier
        now = self.clock()
        self._rx_ok_ns = now
        self.monitor.since_ns = now

    def _shutdown(self) -> None:
        notifier, bus = self._notifier, self._bus
        self._notifier = self._bus = None
        self.network.notifier = None
        self.network.bus = None
        if notifier is not None:
            try:
                notifier.stop(timeout=1.0)
            except Exception as exc:  # noqa: BLE001 - closing must not raise
                log.warning("stopping the CAN notifier: %s", exc)
        if bus is not None:
            try:
                bus.shutdown()
            except Exception as exc:  # noqa: BLE001
                log.warning("closing the CAN bus: %s", exc)

    def __enter__(self) -> CanBus:
        return self if self._bus is not None else self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def is_open(self) -> bool:
        return self._bus is not None

    @property
    def python_can_bus(self) -> can.BusABC | None:
        """The underlying python-can bus (``None`` while closed)."""
        return self._bus

    def expect(self, cob_id: int, lengths: int | tuple[int, ...]) -> None:
        """Declare the valid data lengths of frames with ``cob_id`` (others are dropped)."""
        lengths = (lengths,) if isinstance(lengths, int) else tuple(lengths)
        self._expected_len[cob_id] = frozenset(lengths)

    # -- sending --
    def send(self, msg: can.Message) -> bool:
        """Send one frame now, or drop it; never blocks longer than ``send_timeout_s``.

        Returns
        -------
        bool
            ``True`` if the interface accepted the frame. ``False`` if it was dropped: bus
            closed, bus-off hold-off, gated, full transmit queue or interface error (see
            :attr:`last_send_error` and :attr:`counters`). A dropped frame is never retried.
        """
        c = self.counters
        bus = self._bus
        if bus is None:
            c["tx_closed"] += 1
            self.last_send_error = "bus closed"
            return False
        now = self.clock()
        if not self.monitor.allow_send(now):
            c["tx_busoff_held"] += 1
            self.last_send_error = "bus-off hold-off"
            return False
        if self.tx_gate is not None and not self.tx_gate(msg):
            c["tx_gated"] += 1
            self.last_send_error = "gated"
            return False
        msg.timestamp = time.time()  # wall time, for logs only
        if self._echo_filter:
            # before sending: the loopback may deliver the echo before send() returns
            echo = (msg.arbitration_id, bytes(msg.data), msg.is_error_frame, now)
            self._echo.append(echo)
        try:
            with self._send_lock:
                bus.send(msg, timeout=self.cfg.send_timeout_s)
        except Exception as exc:  # noqa: BLE001 - every interface raises its own
            if self._echo_filter:
                try:
                    self._echo.remove(echo)
                except ValueError:
                    pass
            full = _is_full_queue(exc)
            c["tx_full" if full else "tx_failed"] += 1
            self.last_send_error = f"{type(exc).__name__}: {exc}"
            with self._state_lock:
                self.monitor.on_send_failed(now)
                if not full and not self._tx_fail_since:
                    self._tx_fail_since = now
            return False
        c["tx_frames"] += 1
        self._tx_fail_since = 0
        if self.monitor.state == BUS_OFF or self.monitor.send_failures_in_row:
            with self._state_lock:
                self.monitor.on_send_ok(now)
        if self.recorder is not None:
            self.recorder.record(msg, is_rx=False)
        if self.tap is not None:
            self.tap(msg, now, False)
        return True

    # -- receiving (notifier thread) --
    def _on_rx(self, msg: can.Message) -> None:
        c = self.counters
        now = self.clock()
        self._rx_ok_ns = now
        self._rx_error_since = 0
        if self._echo_filter and self._is_echo(msg, now):
            c["rx_echo"] += 1
            return
        c["rx_frames"] += 1
        if self.recorder is not None:
            self.recorder.record(msg, is_rx=True)
        if self.tap is not None:
            self.tap(msg, now, True)
        if msg.is_error_frame:
            c["rx_error_frames"] += 1
            info = decode_error_frame(msg)
            with self._state_lock:
                self.monitor.on_error_frame(info, now)
            return
        with self._state_lock:
            self.monitor.on_rx(now)
        if msg.is_remote_frame:
            c["rx_remote"] += 1
            return
        if msg.is_extended_id:
            c["rx_extended"] += 1
            return
        if msg.is_fd:
            c["rx_fd"] += 1
            return
        cob_id = msg.arbitration_id
        data = msg.data if msg.data is not None else bytearray()
        lengths = self._expected_len.get(cob_id)
        if lengths is not None and len(data) not in lengths:
            c["rx_malformed"] += 1
            self.malformed_by_id[cob_id] = self.malformed_by_id.get(cob_id, 0) + 1
            return
        if cob_id not in self.network.subscribers:
            c["rx_unknown"] += 1
            if len(self.unknown_by_id) < 256 or cob_id in self.unknown_by_id:
                self.unknown_by_id[cob_id] = self.unknown_by_id.get(cob_id, 0) + 1
            return
        try:
            self.network.notify(cob_id, bytearray(data), msg.timestamp)
        except Exception as exc:  # noqa: BLE001 - a bad frame must not stop reception
            c["rx_callback_errors"] += 1
            log.debug("callback for 0x%03X raised %r", cob_id, exc)

    def _is_echo(self, msg: can.Message, now: int) -> bool:
        echo = self._echo
        while echo and now - echo[0][3] > 500_000_000:
            echo.popleft()  # an echo that never came back
        if not echo:
            return False
        key = (msg.arbitration_id, bytes(msg.data), msg.is_error_frame)
        for i, (cid, data, err, _t) in enumerate(echo):
            if (cid, data, err) == key:
                for _ in range(i + 1):
                    echo.popleft()
                return True
            if i >= 63:
                break
        return False

    def _on_rx_error(self, exc: Exception) -> None:
        self.counters["rx_errors"] += 1
        self.last_rx_error = f"{type(exc).__name__}: {exc}"
        now = self.clock()
        if not self._rx_error_since:
            self._rx_error_since = now
        time.sleep(0.01)  # a persistent error must not spin the notifier thread hot

    # -- health --
    def poll(self) -> BusStatus:
        """Time-based health checks and the reopen policy; call once per cycle."""
        self.poll_state()
        return self.status()

    def poll_state(self) -> str:
        """:meth:`poll`, returning only the bus state (cheaper; the cycle uses it)."""
        now = self.clock()
        iface = None
        bus = self._bus
        if bus is not None:
            try:
                st = bus.state
                iface = {can.BusState.PASSIVE: PASSIVE, can.BusState.ERROR: BUS_OFF}.get(st, ACTIVE)
            except Exception:  # noqa: BLE001 - not implemented by many interfaces
                iface = None
        with self._state_lock:
            self.monitor.tick(now, iface)
        after = int(self.cfg.reopen_after_s * 1e9)
        if self._want_open and now >= self._next_reopen_ns:
            failing = bus is None \
                or (self._rx_error_since and now - self._rx_error_since >= after) \
                or (self._tx_fail_since and now - self._tx_fail_since >= after)
            if failing:
                self._reopen(now)
        return self.monitor.state if self._bus is not None else CLOSED

    def _reopen(self, now: int) -> None:
        log.warning("reopening CAN bus %s/%s (rx: %s; tx: %s)", self.cfg.interface,
                    self.cfg.channel, self.last_rx_error, self.last_send_error)
        self._shutdown()
        self._next_reopen_ns = now + int(self._backoff_s * 1e9)
        self._backoff_s = min(self._backoff_s * 2, self.cfg.reopen_backoff_s[1])
        try:
            self._start()
        except BusOpenError as exc:
            self.counters["reopen_failures"] += 1
            self.last_rx_error = str(exc)
            return
        self.counters["reopens"] += 1
        self._rx_error_since = self._tx_fail_since = 0

    def status(self) -> BusStatus:
        """Bus state, why, and a copy of the counters."""
        counters = dict(self.counters)
        counters["busoff_events"] = self.monitor.busoff_count
        counters["passive_events"] = self.monitor.passive_count
        counters["periodic_refused"] = self.network.periodic_refused
        state = self.monitor.state if self._bus is not None else CLOSED
        return BusStatus(state, self.monitor.reason, self._bus is not None, counters)


def _is_full_queue(exc: Exception) -> bool:
    if isinstance(exc, can.CanTimeoutError | TimeoutError):
        return True
    cause = exc.__cause__ or exc.__context__
    for e in (exc, cause):
        if isinstance(e, OSError) and e.errno in (errno.ENOBUFS, errno.EAGAIN):
            return True
        if e is not None and e.__class__.__name__ == "Full":
            return True
    text = str(exc).lower()
    return "buffer full" in text or "queue" in text or "one or more recipients" in text
