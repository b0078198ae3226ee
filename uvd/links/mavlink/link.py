"""The MAVLink ground-station link (``[mavlink]``, docs/mavlink.md): a telemetry sink and a
command receiver, never on the loop's critical path.

:class:`MavlinkLink` is a :class:`~uvd.telemetry.sink.TelemetrySink` of the daemon's hub: its
``write`` (event loop, off the cycle) only keeps the newest cycle and estimate records and
queues a STATUSTEXT for each failsafe event, lifecycle transition and refused command, a
WARNING for each thruster effectiveness set or cleared (thruster, η, source, DOFs given up),
and for a telemetry sink that cannot open or write (a full disk under the black box), a
NOTICE when it writes again. The
UDP socket at ``listen`` is read by a process of its own (:mod:`uvd.links.mavlink.receiver`),
which judges every datagram and forwards only good MAVLink, so that a flood of garbage never
holds this process's interpreter lock against the loop. One daemon thread owns the socket's
sending side and the pymavlink codecs; it

* reads what the receiver forwards and, when ``serial`` is set, a serial line (a telemetry
  radio; a radio's few kB/s are read here). A radio that is not there at start, or is lost
  (its USB adapter unplugged), is told once and opened again every few seconds; the UDP link
  goes on meanwhile (before session 34 a radio missing at start took the whole link off, and
  one lost while running logged a warning at every wake, 50 a second);
* sends HEARTBEAT and SYS_STATUS at ``heartbeat_hz``; ATTITUDE, LOCAL_POSITION_NED,
  SCALED_PRESSURE, VFR_HUD, SERVO_OUTPUT_RAW and ACTUATOR_OUTPUT_STATUS at ``state_hz``;
  NAMED_VALUE_FLOAT of the online estimates at ``estimate_hz`` — to every station heard within
  ``station_timeout_s``, to the ``connect`` addresses and down the serial line; STATUSTEXT
  chunks at most ``statustext_hz``, so that a long text is never one burst;
* turns what stations send into commands of :mod:`uvd.runtime.commands` on the daemon's one
  command queue (``App.commands``) — the cycle applies them at its next start — and answers
  each with COMMAND_ACK (and a STATUSTEXT with the reason of a refusal) once the cycle has
  resolved it; PARAM_* and TIMESYNC it answers itself.

Everything bad that arrives (not MAVLink, bad CRC, unknown or malformed message, a command
for another system, from a station not in ``gcs_system_ids``, unsigned or wrongly signed when
signing is on) is counted under a named reason (:attr:`MavlinkLink.counters`) and dropped.
The loop reads one thing of the link: :attr:`MavlinkLink.operator_heartbeat_ns`, the time of
the newest operator HEARTBEAT (the operator-loss failsafe, :mod:`uvd.runtime.triggers`).
"""

from __future__ import annotations

import collections
import contextlib
import logging
import math
import select
import socket
import threading
import time
import unicodedata
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from uvd.links.mavlink import params as mp
from uvd.links.mavlink.receiver import (
    decode_datagram,
    read_forwarded,
    spawn_receiver,
    stop_receiver,
)
from uvd.links.mavlink.signing import (
    SigningState,
    load_key,
    load_timestamp,
    save_timestamp,
)
from uvd.model.params import N_DECOUPLED, N_THETA_UV, decoupled_from_theta
from uvd.runtime import schema
from uvd.runtime.commands import (
    Arm,
    CommandQueue,
    CommandResult,
    Disarm,
    HoldPose,
    ManualWrench,
    ResetFailsafe,
    SetMode,
    SetParams,
    SetThrusterEta,
)
from uvd.runtime.config import MavlinkSection
from uvd.telemetry.records import euler_of

__all__ = ["MavlinkLink", "CUSTOM_MODES", "APPLIED_MODES", "custom_mode_of"]

log = logging.getLogger("uvd.mavlink")

#: HEARTBEAT custom_mode, low byte: the operator's mode (what SET_MODE / DO_SET_MODE set)
CUSTOM_MODES = {"auto": 1, "pdc": 2, "hold-depth": 3, "manual": 4, "observe": 5}
_MODE_OF = {v: k for k, v in CUSTOM_MODES.items()}
#: HEARTBEAT custom_mode, second byte: what the cycle applies (report only)
APPLIED_MODES = {"standby": 0, "pdc": 1, "ambc": 2, "two-step-1": 3, "two-step-2": 4,
                 "observe": 5, "manual": 6, "hold-depth": 7, "zero-thrust": 8}
_SEVERITY = {"emergency": 0, "alert": 1, "critical": 2, "error": 3, "warning": 4,
             "notice": 5, "info": 6}
#: STATUSTEXT chunks that go at once before ``statustext_hz`` paces them
TEXT_BURST = 10
_STATE_STATUS = {"BOOT": 1, "STANDBY": 3, "ARMED": 4, "FAILSAFE": 5, "SHUTDOWN": 7}
#: SYS_STATUS sensor bits: INS (gyro, accelerometer, magnetometer), DVL (as optical flow:
#: velocity over ground), depth (absolute pressure), amplifiers (motor outputs), the recording
#: (MAV_SYS_STATUS_LOGGING)
_INS_BITS, _DVL_BIT, _DEPTH_BIT, _MOTOR_BIT, _LOGGING_BIT = 0x7, 0x40, 0x8, 0x8000, 0x1000000
_RHO_G = 1000.0 * 9.80665  # fresh water, for SCALED_PRESSURE from depth (docs/mavlink.md)
_SIGNED_ONLY = {"COMMAND_LONG", "COMMAND_INT", "SET_MODE", "MANUAL_CONTROL",
                "SET_POSITION_TARGET_LOCAL_NED", "PARAM_SET", "HEARTBEAT"}


def custom_mode_of(rec: Mapping[str, Any], controller: str, step1_s: float) -> int:
    """HEARTBEAT custom_mode of a cycle record: operator mode | applied mode << 8."""
    op = CUSTOM_MODES.get(str(rec.get("operator_mode")), 0)
    mode = str(rec.get("mode"))
    if rec.get("state") != "ARMED":
        applied = "standby"
    elif mode == "control":
        if controller == "two-step-ambc":
            armed = rec.get("armed_at_ns")
            t = 0.0 if armed is None else (int(rec["t_ns"]) - int(armed)) * 1e-9
            applied = "two-step-1" if t < step1_s else "two-step-2"
        else:
            applied = controller
    else:
        applied = {"pdc-fallback": "pdc", "hold-depth": "hold-depth", "manual": "manual",
                   "zero": "observe" if rec.get("operator_mode") == "observe"
                   else "zero-thrust"}.get(mode, "zero-thrust")
    return op | APPLIED_MODES[applied] << 8


#: the station at the end of the serial line (a radio): always a destination when configured
SERIAL = ("serial",)
#: the first and the longest wait before a serial line that did not open is tried again (s)
SERIAL_RETRY_S = (0.5, 5.0)


def _addr(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    return host.strip("[]"), int(port)


class _Out:
    """pymavlink's encoder writes here; the link sends the bytes to every station."""

    def __init__(self) -> None:
        self.buf = b""

    def write(self, b: bytes) -> None:
        self.buf = bytes(b)


#: COMMAND_LONG that sets a thruster's effectiveness: param1 the thruster (1-based, the
#: vehicle's order), param2 η ∈ [0, 1] (1 clears it) — MAV_CMD_USER_1, as no standard command
#: carries it (docs/mavlink.md)
MAV_CMD_THRUSTER_ETA = 31010

#: COMMAND_LONG that resets the failsafe triggers whose condition no longer holds (param1 0:
#: all of them; disarmed, the amplifiers are brought back first, uvd.runtime.recovery) —
#: MAV_CMD_USER_2, as no standard command carries it; without it a latched trigger (a leak, a
#: drive's fault, a bus-off) keeps the vehicle disarmed until the daemon restarts
#: (docs/mavlink.md)
MAV_CMD_RESET_FAILSAFE = 31011

#: the farthest a SET_POSITION_TARGET_LOCAL_NED position may lie from the local origin, per
#: axis (m): the navigation frame's range ([navigation] initial_north_m, initial_east_m)
HOLD_MAX_M = 1e6


#: what the operator's texts hold beyond ASCII, spelled in ASCII for STATUSTEXT
_ASCII = str.maketrans({"…": "..", "η": "eta", "±": "+/-", "σ": "sigma", "θ": "theta",
                        "→": "->", "×": "x", "—": "-", "–": "-", "≤": "<=", "≥": ">=",
                        "µ": "u", "μ": "u", "°": "deg", "²": "^2", "³": "^3"})


def ascii_text(text: str) -> str:
    """``text`` in plain ASCII for a STATUSTEXT (50 bytes of char[] that ground stations read
    as ASCII: a UTF-8 "…" shows garbled, and a chunk boundary can split a multi-byte one). The
    characters of :data:`_ASCII` are spelled out ("1…6" → "1..6", "η" → "eta"), accents dropped,
    anything else "?"."""
    s = unicodedata.normalize("NFKD", str(text).translate(_ASCII))
    return "".join(ch for ch in s if not unicodedata.combining(ch)).encode(
        "ascii", "replace").decode("ascii")


class MavlinkLink:
    """The ground-station link (module docstring).

    Parameters
    ----------
    cfg : MavlinkSection
    commands : CommandQueue
        The daemon's command queue (``App.commands``).
    config : callable
        Returns the running :class:`~uvd.runtime.config.Config` (parameter values).
    thresholds : mapping
        Source ages that count as healthy in SYS_STATUS (``ins``, ``dvl``, ``depth``,
        ``feedback`` in s).
    max_thrust_n : sequence of float
        Per-thruster thrust limit (SERVO_OUTPUT_RAW's scale).
    controller : str
        ``[control] controller``; ``step1_s`` its step-1 length (custom mode).
    loop_cpus : sequence of int
        ``[loop] cpu_affinity``: the receiver process keeps off these CPUs when it can.
    recorders : sequence of str
        What records the run (the sinks ``mcap``, ``jsonl``; the CAN log ``canlog``, told
        as a sink is: :meth:`~uvd.telemetry.sink.TelemetryHub.watch`): SYS_STATUS reports logging
        present and enabled when there is one, and unhealthy while the operator was last told
        (a ``"sink"`` record) that one of them cannot write — what a station that connects
        after the STATUSTEXT learns.
    """

    name = "mavlink"

    def __init__(self, cfg: MavlinkSection, commands: CommandQueue, config: Callable[[], Any],
                 *, thresholds: Mapping[str, float], max_thrust_n: Sequence[float],
                 controller: str = "pdc", step1_s: float = 0.0,
                 loop_cpus: Sequence[int] = (), recorders: Sequence[str] = ()) -> None:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink
        self.mavlink = mavlink
        self.cfg = cfg
        self.commands = commands
        self.config = config
        self.thresholds = dict(thresholds)
        self.max_thrust_n = np.asarray(max_thrust_n, dtype=float)
        self.controller = controller
        self.step1_s = float(step1_s)
        self.loop_cpus = tuple(loop_cpus)
        self.recorders = frozenset(recorders)
        self.failing_sinks: set[str] = set()  # as the "sink" records told
        self._out = _Out()
        self.tx = mavlink.MAVLink(self._out, cfg.system_id, cfg.component_id, use_native=False)
        self.tx.WIRE_PROTOCOL_VERSION = "2.0"
        self.rx = mavlink.MAVLink(None, cfg.system_id, cfg.component_id, use_native=False)
        self.rx.robust_parsing = True
        self._receiver = None  # the receiver process (uvd.links.mavlink.receiver) and its pair
        self._pair = None
        self.signing: SigningState | None = None
        if cfg.signing_key_file:
            key = load_key(cfg.signing_key_file)
            self.signing = SigningState(key, load_timestamp(cfg.signing_timestamp_file))
            self.tx.signing.secret_key = key
            self.tx.signing.sign_outgoing = True
            self.tx.signing.timestamp = self.signing.timestamp
        self.gcs_ids = frozenset(cfg.gcs_system_ids)
        self.connect = [_addr(a) for a in cfg.connect]
        self.peers: dict[tuple, float] = {}
        #: monotonic ns of the newest HEARTBEAT of a configured ground station (None: none)
        self.operator_heartbeat_ns: int | None = None
        self.counters: collections.Counter = collections.Counter()
        #: parameters set during this run that apply at the next start
        self.pending: dict[str, Any] = {}
        self._cycle: Mapping[str, Any] | None = None
        self._estimate: Mapping[str, Any] | None = None
        #: texts of the vehicle's own events (failsafe, lifecycle), sent before the others:
        #: what stations and clients send (refusals, η reports) cannot crowd them out
        self._events: collections.deque = collections.deque(maxlen=64)
        self._texts: collections.deque = collections.deque(maxlen=64)
        self._replies: collections.deque = collections.deque(maxlen=256)
        self._text_id = 0
        self._chunks: collections.deque = collections.deque()  # of the text being sent
        self._tokens, self._tokens_t = TEXT_BURST, time.monotonic()
        self._sock: socket.socket | None = None
        self._serial = None
        #: when the serial line is tried again (monotonic s), the wait after it, and why it
        #: is not open (None: open, or not configured)
        self._serial_next, self._serial_wait = 0.0, SERIAL_RETRY_S[0]
        self.serial_error: str | None = None
        self.rx_serial = mavlink.MAVLink(None, cfg.system_id, cfg.component_id,
                                         use_native=False)
        self.rx_serial.robust_parsing = True
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._t0 = time.monotonic()

    def _text(self, item: tuple[str, str], *, event: bool = False) -> None:
        self._push(self._events if event else self._texts, item, "statustext")

    def _push(self, queue: collections.deque, item: Any, what: str) -> None:
        """Append to a bounded deque; when full its oldest item is dropped and counted."""
        if len(queue) == queue.maxlen:
            self.counters[f"{what}_dropped"] += 1
        queue.append(item)

    # ------------------------------------------------------------------ sink (event loop)

    async def open(self) -> None:
        fam = socket.AF_INET6 if ":" in self.cfg.listen.rpartition(":")[0] else socket.AF_INET
        sock = socket.socket(fam, socket.SOCK_DGRAM)
        try:
            if self.cfg.listen:
                sock.bind(_addr(self.cfg.listen))
            sock.setblocking(False)
        except OSError as exc:
            sock.close()
            log.error("MAVLink link off: [mavlink] listen %s: %s", self.cfg.listen,
                      exc.strerror or exc)
            raise OSError(f"[mavlink] listen {self.cfg.listen}: {exc.strerror or exc}") from exc
        self._sock = sock
        try:
            self._receiver, self._pair = spawn_receiver(sock, self.loop_cpus)
        except OSError as exc:
            sock.close()
            log.error("MAVLink link off: its receiver process: %s", exc)
            raise
        if self.cfg.serial:
            self._open_serial(time.monotonic())
        self._thread = threading.Thread(target=self._run, name="uvd-mavlink", daemon=True)
        self._thread.start()
        log.info("MAVLink link on udp %s:%d (system %d, signing %s)",
                 self.cfg.listen.rpartition(":")[0], self.port, self.cfg.system_id,
                 "on" if self.signing else "off")  # the port bound: listen's may be 0

    @property
    def port(self) -> int:
        """The UDP port bound (tests listen on port 0)."""
        return self._sock.getsockname()[1] if self._sock is not None else 0

    async def write(self, records: Sequence[Mapping[str, Any]]) -> None:
        for r in records:
            kind = r.get("type")
            if kind == "cycle":
                self._cycle = r
            elif kind == "estimate" and r.get("source", "estimator") == "estimator":
                self._estimate = r
            elif kind == "failsafe":
                # "accommodated": the amplifier's or uvd-fdc's source of η (thruster, η,
                # source, given up); "refused": a uvd-fdc sample its wait did not confirm
                sev = "warning" if r["kind"] in ("fired", "action", "accommodated",
                                                 "refused") else "info"
                self._text((sev, f"failsafe {r['kind']}: {r['trigger']} -> "
                                 f"{r['action']} ({r['reason']})"), event=True)
            elif kind == "lifecycle":
                self._text(("notice", f"{r['from']} -> {r['to']}: {r['cause']}"), event=True)
            elif kind == "sink":  # a recording that fails, or works again
                (self.failing_sinks.discard if r["ok"] else self.failing_sinks.add)(r["sink"])
                self._text(("notice" if r["ok"] else "warning", str(r["text"])), event=True)
            elif kind == "command" and not r.get("ok"):
                self._text(("warning", f"{r['command']} refused: {r['reason']}"))
            elif kind == "command" and r.get("command") in ("SetThrusterEta", "FaultReport"):
                self._text(("warning", str(r.get("reason"))))  # thruster, η, source, given up

    async def flush(self) -> None:
        pass

    async def aclose(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=0.5)
        self._end_receiver()
        if self._sock is not None:
            self._sock.close()
        if self._serial is not None:
            self._serial.close()
        self._save_timestamp()

    def _end_receiver(self) -> None:
        if self._receiver is not None:
            stop_receiver(self._receiver, self._pair, self.counters)
        self._pair = self._receiver = None

    def stats(self) -> dict[str, Any]:
        out = dict(self.counters)
        out["stations"] = len(self.peers)
        if self.signing is not None:
            out["signing"] = dict(self.signing.counts)
        return out

    # ------------------------------------------------------------------ the link's thread

    def _run(self) -> None:
        next_hb = next_state = next_est = next_ts = next_spawn = time.monotonic()
        c = self.cfg
        while not self._stop.is_set():
            try:
                now = time.monotonic()
                if self._pair is None and now >= next_spawn:  # the receiver ended: again
                    next_spawn = now + 1.0
                    self._receiver, self._pair = spawn_receiver(self._sock, self.loop_cpus)
                    self.counters["receiver_restarts"] += 1
                if self.cfg.serial and self._serial is None and now >= self._serial_next:
                    self._open_serial(now)
                ins = [f for f in (self._pair, self._serial) if f is not None]
                readable, _, _ = select.select(ins, [], [], 0.02)
                if self._pair is not None and self._pair in readable:
                    self._receive()
                if self._serial is not None and self._serial in readable:
                    self._receive_serial()
                while self._replies:
                    done, result = self._replies.popleft()
                    done(result)
                now = time.monotonic()
                if now >= next_hb:
                    next_hb = now + 1.0 / c.heartbeat_hz
                    self._send_status()
                if c.state_hz > 0 and now >= next_state:
                    next_state = now + 1.0 / c.state_hz
                    self._send_state()
                if c.estimate_hz > 0 and now >= next_est:
                    next_est = now + 1.0 / c.estimate_hz
                    self._send_estimates()
                self._send_texts(now)
                if self.signing is not None and now >= next_ts:
                    next_ts = now + 10.0
                    self._save_timestamp()
            except Exception as exc:  # noqa: BLE001 - the link's thread must not die
                self.counters["errors"] += 1
                log.warning("MAVLink link: %s: %s", type(exc).__name__, exc)

    # ------------------------------------------------------------------ the serial line

    def _open_serial(self, now: float) -> None:
        """Open ``[mavlink] serial``; when it does not open, say why (once for each new
        reason) and when it is tried again (the wait doubling up to the longest)."""
        import serial

        from drivers.serial_transport import why_not_open
        port = self.cfg.serial
        try:
            self._serial = serial.Serial(port, self.cfg.serial_baud, timeout=0,
                                         write_timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            why = why_not_open(exc, port)
            if why != self.serial_error:
                log.warning("MAVLink serial %s not open: %s; the UDP link goes on, the line "
                            "is tried again every %g s at most", port, why, SERIAL_RETRY_S[1])
            self.serial_error = why
            self.counters["serial_open_failed"] += 1
            self._serial_next = now + self._serial_wait
            self._serial_wait = min(2.0 * self._serial_wait, SERIAL_RETRY_S[1])
            return
        if self.serial_error is not None:
            log.info("MAVLink serial %s open", port)
        self.serial_error, self._serial_wait = None, SERIAL_RETRY_S[0]

    def _lose_serial(self, exc: BaseException) -> None:
        """The line failed under a read (a USB adapter unplugged): closed, told once, tried
        again after the wait it opened with (:data:`SERIAL_RETRY_S`'s first)."""
        with contextlib.suppress(Exception):
            self._serial.close()
        self._serial = None
        self.rx_serial.buf = bytearray()  # a packet cut by the loss is not continued
        self.rx_serial.buf_index = 0
        self.counters["serial_lost"] += 1
        self.serial_error = f"lost: {exc}"
        log.warning("MAVLink serial %s lost (%s); the UDP link goes on, the line is tried "
                    "again", self.cfg.serial, exc)
        self._serial_next = time.monotonic() + self._serial_wait

    def _save_timestamp(self) -> None:
        if self.signing is None or not self.cfg.signing_timestamp_file:
            return
        ts = max(self.signing.timestamp, self.tx.signing.timestamp)
        try:
            save_timestamp(self.cfg.signing_timestamp_file, ts)
        except OSError as exc:
            self.counters["timestamp_save_failed"] += 1
            log.warning("cannot keep the signing timestamp: %s", exc)

    def _receive(self) -> None:
        """What the receiver process forwarded: good datagrams only (its counters of the
        bad ones come with them, uvd.links.mavlink.receiver)."""
        try:
            got = read_forwarded(self._pair, self.counters)
        except EOFError:
            self.counters["receiver_ended"] += 1
            log.error("MAVLink link: its receiver process ended; starting another")
            self._end_receiver()
            return
        for data, addr in got:
            self._datagram(data, addr)

    def _receive_serial(self) -> None:
        """A byte stream: one parser keeps its state across reads (at most 4 KiB a wake)."""
        try:
            data = self._serial.read(4096)
        except OSError as exc:  # pyserial's SerialException too: "readiness to read but no data"
            self._lose_serial(exc)
            return
        self.counters["serial_bytes"] += len(data)
        try:
            msgs = self.rx_serial.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 - whatever pymavlink raises on garbage
            msgs = []
        for m in msgs:
            if m.get_type() == "BAD_DATA":
                self.counters["bad_serial"] += 1
                continue
            try:
                self._message(m, SERIAL)
            except Exception as exc:  # noqa: BLE001 - a message we cannot use is dropped
                self.counters["bad_messages"] += 1
                log.debug("MAVLink %s on serial dropped: %s", m.get_type(), exc)

    def _datagram(self, data: bytes, addr: tuple) -> None:
        msgs = decode_datagram(self.rx, data)
        if msgs is None:  # the receiver passed it: not expected, but never trusted
            self.counters["bad_datagrams"] += 1
            return
        for m in msgs:
            try:
                self._message(m, addr)
            except Exception as exc:  # noqa: BLE001 - a message we cannot use is dropped
                self.counters["bad_messages"] += 1
                log.debug("MAVLink %s from %s dropped: %s", m.get_type(), addr, exc)

    def _message(self, m: Any, addr: tuple) -> None:
        kind = m.get_type()
        src = m.get_srcSystem()
        if src not in self.gcs_ids:
            self.counters["not_a_gcs"] += 1
            return
        if addr not in self.peers and len(self.peers) >= 16:
            self.peers.pop(min(self.peers, key=self.peers.get))
        self.peers[addr] = time.monotonic()
        if self.signing is not None and kind in _SIGNED_ONLY:  # telemetry still goes out
            why = self.signing.verify(m.get_msgbuf())
            if why is not None:
                self.counters[f"refused_{why.split()[0]}"] += 1
                if kind != "HEARTBEAT":
                    self._text(("warning", f"{kind} refused: {why}"))
                    if kind == "COMMAND_LONG":
                        self._ack(m, self.mavlink.MAV_RESULT_DENIED)
                return
            self.tx.signing.timestamp = max(self.tx.signing.timestamp, self.signing.timestamp)
        handler = getattr(self, f"_on_{kind.lower()}", None)
        if handler is None:
            self.counters["ignored"] += 1
            return
        self.counters[kind.lower()] += 1
        handler(m, addr)

    def _for_us(self, m: Any) -> bool:
        ok = m.target_system in (0, self.cfg.system_id) and getattr(
            m, "target_component", 0) in (0, self.cfg.component_id)
        if not ok:
            self.counters["other_target"] += 1
        return ok

    # ------------------------------------------------------------------ commands in

    def _on_heartbeat(self, m: Any, addr: tuple) -> None:
        self.operator_heartbeat_ns = time.monotonic_ns()

    def _queue(self, command: Any, done: Callable[[CommandResult], None] | None = None) -> None:
        fut = self.commands.put(command)
        if done is not None:  # runs where the cycle resolves it: only a deque append
            fut.add_done_callback(lambda f: self._push(self._replies, (done, f.result()),
                                                       "replies"))

    def _ack(self, m: Any, result: int) -> None:
        cmd = m.command if m.get_type() == "COMMAND_LONG" else m.get_msgId()
        self._send(self.tx.command_ack_encode(cmd, result, 0, 0, m.get_srcSystem(),
                                              m.get_srcComponent()))

    def _ack_when_done(self, m: Any) -> Callable[[CommandResult], None]:
        mav = self.mavlink

        def done(res: CommandResult) -> None:  # the reason goes out with the command record
            full = res.reason == "command queue full"
            self._ack(m, mav.MAV_RESULT_ACCEPTED if res.ok else
                      mav.MAV_RESULT_TEMPORARILY_REJECTED if full else mav.MAV_RESULT_DENIED)
        return done

    def _refuse(self, m: Any, why: str, ack: bool = True) -> None:
        """A malformed command: counted, told (STATUSTEXT) and, unless it is a stream's
        message (a setpoint: ``ack`` False), answered DENIED; never guessed."""
        self.counters["commands_refused"] += 1
        self._text(("warning", why))
        if ack:
            self._ack(m, self.mavlink.MAV_RESULT_DENIED)

    def _on_command_long(self, m: Any, addr: tuple) -> None:
        if not self._for_us(m):
            return
        mav = self.mavlink
        source = f"mavlink {m.get_srcSystem()}/{m.get_srcComponent()}"
        if m.command == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            if m.param1 not in (0.0, 1.0):   # MAVLink's 1 arm, 0 disarm; NaN or 0.7 is neither
                self._refuse(m, f"arm/disarm refused: param1 {m.param1:g} is neither 1 (arm) "
                                "nor 0 (disarm)")
                return
            c = Arm(cause="ground station", source=source) if m.param1 == 1.0 else \
                Disarm(cause="ground station", source=source)
        elif m.command == mav.MAV_CMD_DO_SET_MODE:
            if not all(math.isfinite(v) and v == int(v) for v in (m.param1, m.param2)):
                self._refuse(m, f"mode refused: base mode {m.param1:g} and custom mode "
                                f"{m.param2:g} must be whole numbers")
                return
            c = self._set_mode(int(m.param1), int(m.param2), source)
            if c is None:
                self._ack(m, mav.MAV_RESULT_DENIED)
                return
        elif m.command == MAV_CMD_THRUSTER_ETA:
            if not (math.isfinite(m.param1) and m.param1 == int(m.param1)):
                self._refuse(m, f"thruster effectiveness refused: thruster {m.param1!r} is "
                                "not a thruster number")
                return
            c = SetThrusterEta(int(m.param1), float(m.param2), source=source)
        elif m.command == MAV_CMD_RESET_FAILSAFE:
            if m.param1 != 0.0:
                self._refuse(m, f"failsafe reset refused: param1 {m.param1:g} must be 0 (every "
                                "trigger that no longer holds)")
                return
            c = ResetFailsafe(source=source)
        else:
            self.counters["unsupported_commands"] += 1
            self._ack(m, mav.MAV_RESULT_UNSUPPORTED)
            return
        self._queue(c, self._ack_when_done(m))

    def _on_command_int(self, m: Any, addr: tuple) -> None:
        if self._for_us(m):
            self.counters["unsupported_commands"] += 1
            self._ack(m, self.mavlink.MAV_RESULT_UNSUPPORTED)

    def _set_mode(self, base_mode: int, custom: int, source: str) -> SetMode | None:
        mode = _MODE_OF.get(custom & 0xFF)
        if not base_mode & self.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED or mode is None:
            self._text(("warning", f"mode {custom} refused: custom modes are "
                                f"{', '.join(f'{v} {k}' for k, v in CUSTOM_MODES.items())}"))
            return None
        return SetMode(mode, source=source)

    def _on_set_mode(self, m: Any, addr: tuple) -> None:
        if m.target_system not in (0, self.cfg.system_id):
            self.counters["other_target"] += 1
            return
        c = self._set_mode(m.base_mode, m.custom_mode, f"mavlink {m.get_srcSystem()}")
        if c is None:
            self._ack(m, self.mavlink.MAV_RESULT_DENIED)
            return
        self._queue(c, self._ack_when_done(m))

    def _on_manual_control(self, m: Any, addr: tuple) -> None:
        """x forward, y right, r yaw at ±1000; z 0-1000 with 500 neutral, up above (ArduSub's
        convention): body force and yaw torque, [f; τ] with z keel-down."""
        if m.target not in (0, self.cfg.system_id):
            self.counters["other_target"] += 1
            return
        f, t = self.cfg.manual_force_n, self.cfg.manual_torque_nm
        x, y, z, r = (max(-1.0, min(1.0, v)) for v in (m.x / 1000, m.y / 1000,
                                                       (m.z - 500) / 500, m.r / 1000))
        self._queue(ManualWrench((x * f, y * f, -z * f, 0.0, 0.0, r * t),
                                 timeout_s=self.cfg.manual_timeout_s,
                                 source=f"mavlink {m.get_srcSystem()}"))

    def _on_set_position_target_local_ned(self, m: Any, addr: tuple) -> None:
        if not self._for_us(m):
            return
        if m.coordinate_frame != self.mavlink.MAV_FRAME_LOCAL_NED or m.type_mask & 0x7:
            self._refuse(m, "SET_POSITION_TARGET_LOCAL_NED refused: needs "
                            "MAV_FRAME_LOCAL_NED and a position", ack=False)
            return
        yaw_ignored = bool(m.type_mask & 0x400)
        far = [f"{n} {v:g}" for n, v in (("x", m.x), ("y", m.y), ("z", m.z))
               if not abs(v) <= HOLD_MAX_M]
        if not (yaw_ignored or abs(m.yaw) <= 2 * math.pi):
            far.append(f"yaw {m.yaw:g}")
        if far:  # float32 reaches 3.4e38: a position no vehicle can hold, never sent on
            self._refuse(m, f"SET_POSITION_TARGET_LOCAL_NED refused: {', '.join(far)} "
                            f"(positions within ±{HOLD_MAX_M:g} m, yaw within ±2π)", ack=False)
            return
        yaw = m.yaw
        if yaw_ignored:  # yaw ignored: keep the heading the vehicle has
            rec = self._cycle
            yaw = 0.0 if rec is None else euler_of(rec["R"])[2]
        self._queue(HoldPose(m.x, m.y, m.z, yaw, source=f"mavlink {m.get_srcSystem()}"))

    def _on_timesync(self, m: Any, addr: tuple) -> None:
        if m.tc1 == 0:
            self._send(self.tx.timesync_encode(time.monotonic_ns(), m.ts1), (addr,))

    # ------------------------------------------------------------------ parameters

    def _param_value(self, p: mp.Param, to: tuple | None = None) -> None:
        pending = self.pending.get(p.key)
        if pending is not None:
            v = float(pending if p.index is None else pending[p.index])
        else:
            v = mp.value_of(p, self.config())
        self._send(self.tx.param_value_encode(
            p.name.encode(), v, self.mavlink.MAV_PARAM_TYPE_REAL32, len(mp.PARAMS),
            mp.PARAMS.index(p)), None if to is None else (to,))

    def _on_param_request_list(self, m: Any, addr: tuple) -> None:
        if self._for_us(m):
            for p in mp.PARAMS:
                self._param_value(p, addr)

    def _on_param_request_read(self, m: Any, addr: tuple) -> None:
        if not self._for_us(m):
            return
        name = m.param_id.rstrip("\x00") if isinstance(m.param_id, str) else ""
        p = mp.BY_NAME.get(name) if m.param_index < 0 else (
            mp.PARAMS[m.param_index] if m.param_index < len(mp.PARAMS) else None)
        if p is None:
            self.counters["unknown_params"] += 1
            self._text(("warning", f"no parameter {name or m.param_index!r}"))
            return
        self._param_value(p, addr)

    def _on_param_set(self, m: Any, addr: tuple) -> None:
        if not self._for_us(m):
            return
        name = m.param_id.rstrip("\x00") if isinstance(m.param_id, str) else ""
        p = mp.BY_NAME.get(name)
        if p is None:
            self.counters["unknown_params"] += 1
            self._text(("warning", f"no parameter {name!r}"))
            return
        if m.param_type != self.mavlink.MAV_PARAM_TYPE_REAL32:  # every one here is REAL32:
            # another type's value comes byte-wise in the float (pymavlink's mavset packs an
            # INT32 350 so: 4.9e-43), never to be read as the number it looks like
            why = (f"{p.name}: param_type {m.param_type} is not MAV_PARAM_TYPE_REAL32 "
                   f"({self.mavlink.MAV_PARAM_TYPE_REAL32}), the type of every parameter here")
        else:
            why = mp.check_value(p, float(m.param_value))
        cfg = self.config()
        value = None if why else mp.key_value(p, float(m.param_value), cfg)
        if why is None and not p.reload:
            why = self._keep_for_restart(p, value, cfg)
            if why is None:
                self._param_value(p)
                self._text(("notice", f"{p.name} = {m.param_value:g} kept; applies at "
                                              "the next start"))
                return
        if why is not None:
            self.counters["params_refused"] += 1
            self._text(("warning", why))
            self._param_value(p, addr)
            return

        def done(res: CommandResult) -> None:
            if res.ok:  # a refusal's reason goes out with the command record
                why = self._persist({p.key: value})
                if why is not None:
                    self._text(("warning", why))
            self._param_value(p)
        self._queue(SetParams({p.key: value}, source=f"mavlink {m.get_srcSystem()}"), done)

    def _keep_for_restart(self, p: mp.Param, value: Any, cfg: Any) -> str | None:
        rec = self._cycle
        if rec is not None and rec.get("state") == "ARMED":
            return f"{p.name} cannot change while armed (it applies at a restart)"
        _, errors = schema.with_values(cfg, {**self.pending, p.key: value})
        if errors:
            return "; ".join(f"{k}: {r}" for k, r in errors)
        self.pending[p.key] = value
        return self._persist({p.key: value})

    def _persist(self, values: Mapping[str, Any]) -> str | None:
        if not self.cfg.params_file:
            return None
        try:
            kept = mp.read_params_file(self.cfg.params_file)
            mp.write_params_file(self.cfg.params_file, {**kept, **values})
        except (OSError, ValueError) as exc:
            self.counters["params_not_kept"] += 1
            return f"cannot keep the parameter in {self.cfg.params_file}: {exc}"
        return None

    # ------------------------------------------------------------------ telemetry out

    def _stations(self) -> list[tuple]:
        now = time.monotonic()
        live = [a for a, t in self.peers.items() if now - t <= self.cfg.station_timeout_s]
        out = live + [a for a in self.connect if a not in live]
        return out + [SERIAL] if self._serial is not None and SERIAL not in out else out

    def _send(self, msg: Any, to: Sequence[tuple] | None = None) -> None:
        self.tx.send(msg)
        buf = self._out.buf
        for a in (self._stations() if to is None else to):
            try:
                if a == SERIAL:  # never blocks: what the line cannot take is dropped
                    self._serial.write(buf)
                else:
                    self._sock.sendto(buf, a)
                self.counters["sent"] += 1
            except Exception:  # noqa: BLE001 - OSError, or pyserial's timeout on a full line
                self.counters["send_errors"] += 1

    def _send_texts(self, now: float) -> None:
        """The queued texts' STATUSTEXT chunks, paced: at most ``statustext_hz`` a second
        after a first :data:`TEXT_BURST` at once (a token bucket); the vehicle's events first.
        A text is cut into chunks only when the one before has gone, so the bounded text
        queues are where a flood of texts drops, oldest first (counted
        ``statustext_dropped``)."""
        self._tokens = min(TEXT_BURST, self._tokens
                           + (now - self._tokens_t) * self.cfg.statustext_hz)
        self._tokens_t = now
        while self._tokens >= 1.0:
            if not self._chunks:
                queue = self._events or self._texts
                if not queue:
                    return
                self._chunks.extend(self._statustext(*queue.popleft()))
            self._send(self._chunks.popleft())
            self._tokens -= 1.0

    def _statustext(self, severity: str, text: str) -> list[Any]:
        """One text's STATUSTEXT messages: 50-character chunks sharing an id when longer
        (MAVLink 2); the text in plain ASCII (:func:`ascii_text`), which every ground station
        shows as sent. A station knows a chunk is the last by a NUL in it: a text of a whole
        number of chunks ends with an empty one. MAVLink numbers the chunks in one byte: a
        text beyond 256 chunks is cut there."""
        data = ascii_text(text).encode("ascii")
        chunks = [data[i:i + 50] for i in range(0, len(data), 50)] or [b""]
        if len(chunks) > 1 and len(chunks[-1]) == 50:
            chunks.append(b"")  # all NUL: the text ended with the chunk before
        chunks = chunks[:256]
        self._text_id = self._text_id % 65535 + 1
        tid = self._text_id if len(chunks) > 1 else 0
        return [self.tx.statustext_encode(_SEVERITY[severity], ch, tid, i)
                for i, ch in enumerate(chunks)]

    def _ms(self) -> int:
        return int((time.monotonic() - self._t0) * 1000) & 0xFFFFFFFF

    def _send_status(self) -> None:
        mav = self.mavlink
        rec = self._cycle
        state = "BOOT" if rec is None else str(rec["state"])
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        custom = 0
        status = _STATE_STATUS.get(state, 0)
        if rec is not None:
            custom = custom_mode_of(rec, self.controller, self.step1_s)
            if state == "ARMED":
                base |= mav.MAV_MODE_FLAG_SAFETY_ARMED
                if rec.get("action") in ("hold-depth", "zero-thrust", "disarm"):
                    status = mav.MAV_STATE_CRITICAL
        self._send(self.tx.heartbeat_encode(mav.MAV_TYPE_SUBMARINE, mav.MAV_AUTOPILOT_GENERIC,
                                            base, custom, status))
        if rec is None:
            return
        ages = [math.inf if a is None else float(a) for a in rec["ages"]]
        th = self.thresholds
        bits = (_INS_BITS, _DVL_BIT, _DEPTH_BIT, _MOTOR_BIT)
        present = _INS_BITS | _DVL_BIT | _DEPTH_BIT | _MOTOR_BIT
        health = 0
        for b, a, lim in zip(bits, ages, (th["ins"], th["dvl"], th["depth"], th["feedback"]),
                             strict=True):
            if a <= lim:
                health |= b
        if self.recorders:
            present |= _LOGGING_BIT
            if not self.recorders & self.failing_sinks:
                health |= _LOGGING_BIT
        drops = self.counters["bad_datagrams"] + self.counters["bad_messages"]
        self._send(self.tx.sys_status_encode(present, present, health, 0, 65535, -1, -1, 0,
                                             min(drops, 65535), 0, 0, 0, 0))

    def _send_state(self) -> None:
        rec = self._cycle
        if rec is None:
            return
        ms = self._ms()
        p = np.asarray(rec["p"], dtype=float)
        R = np.asarray(rec["R"], dtype=float).reshape(3, 3)
        v = np.asarray(rec["v"], dtype=float)
        roll, pitch, yaw = euler_of(R)
        self._send(self.tx.attitude_encode(ms, roll, pitch, yaw, *map(float, v[3:6])))
        vw = R @ v[:3]
        self._send(self.tx.local_position_ned_encode(ms, *map(float, p), *map(float, vw)))
        depth = float(p[2])
        self._send(self.tx.scaled_pressure_encode(ms, 1013.25 + _RHO_G * depth / 100.0, 0.0,
                                                  0))
        hdg = int(round(math.degrees(yaw))) % 360
        self._send(self.tx.vfr_hud_encode(float(np.linalg.norm(v[:3])),
                                          float(np.hypot(vw[0], vw[1])), hdg, 0, -depth,
                                          -float(vw[2])))
        thrust = np.asarray(rec["thrust"], dtype=float)
        n = min(len(thrust), 16)
        scale = np.where(self.max_thrust_n[:n] > 0, self.max_thrust_n[:n], 1.0)
        pwm = np.clip(1500 + 400 * thrust[:n] / scale, 1100, 1900).astype(int).tolist()
        self._send(self.tx.servo_output_raw_encode(int(ms * 1000), 0, *(pwm + [0] * (16 - n))))
        act = [float(x) for x in thrust[:32]] + [0.0] * (32 - min(len(thrust), 32))
        self._send(self.tx.actuator_output_status_encode(int(ms * 1000),
                                                         (1 << min(len(thrust), 32)) - 1, act))

    def _send_estimates(self) -> None:
        rec = self._estimate
        if rec is None or rec.get("theta") is None:
            return
        theta = np.asarray(rec["theta"], dtype=float)
        if theta.size == N_THETA_UV:
            theta = decoupled_from_theta(theta)
        ms = self._ms()
        if theta.size == N_DECOUPLED:
            names = [f"M{i + 1}" for i in range(6)] + [f"D{i + 1}" for i in range(6)] + \
                ["G", "B1", "B2", "B3"]
            for n, x in zip(names, theta, strict=True):
                self._send(self.tx.named_value_float_encode(ms, n.encode(), float(x)))
        if rec.get("m_min_eig") is not None:
            self._send(self.tx.named_value_float_encode(ms, b"MMINEIG",
                                                        float(rec["m_min_eig"])))
