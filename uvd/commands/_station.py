"""The ground station of the package: a command of the operator's sent to a running daemon
from a shell, as any ground station sends it (docs/mavlink.md) — what ``uvd eta`` and ``uvd
reset-failsafe`` share — and the operator of ``uvd bench chaos``.

pymavlink over UDP to ``[mavlink] listen`` of ``--config`` (or ``--to``), signed with
``signing_key_file`` when the configuration has one, as system ``--system`` (one of
``gcs_system_ids``): :func:`send_command` sends its HEARTBEAT, waits for the vehicle's, sends
one COMMAND_LONG, waits for its COMMAND_ACK and gathers the daemon's STATUSTEXTs about it, on a
:class:`GroundStation`.
"""

from __future__ import annotations

import argparse
import os
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from uvd.cliargs import int_in, positive_float

#: how long texts are gathered after the COMMAND_ACK, at most, and how long a quiet spell
#: after the last text ends it
TEXTS_S, QUIET_S = 2.0, 0.3


def add_station_options(p: argparse.ArgumentParser, timeout_s: float = 5.0) -> None:
    """``--config``, ``--to``, ``--system``, ``--timeout`` (default ``timeout_s``)."""
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="the daemon's configuration: its [mavlink] listen address and signing "
                        "key (default: the embedded config/sim.toml)")
    p.add_argument("--to", type=_udp_address, default=None, metavar="HOST:PORT",
                   help="the link's UDP address (default: [mavlink] listen)")
    p.add_argument("--system", type=int_in(1, 255), default=255,
                   help="this station's MAVLink system id (default 255)")
    p.add_argument("--timeout", type=positive_float, default=timeout_s,
                   help=f"seconds to wait for each answer (default {timeout_s:g})")


def _udp_address(text: str) -> str:
    """``--to``: ADDRESS:PORT as the configuration's [mavlink] listen is written."""
    from uvd.runtime.config import check_udp_address
    bad = check_udp_address(text, "--to")
    if bad:
        raise argparse.ArgumentTypeError(bad[0][1])
    return text


def station_of(args) -> tuple[str, int, bytes | None]:
    """The daemon's (host, port, signing key or None) from ``--config`` / ``--to``. Raises
    ValueError (or a UvdError of the configuration) when there is none."""
    from uvd.runtime.config import load_config
    cfg = load_config(args.config).mavlink
    addr = args.to or cfg.listen
    if not addr:
        raise ValueError("no address: [mavlink] listen is empty and --to is not given")
    host, _, port = addr.rpartition(":")
    key = None
    if cfg.signing_key_file:
        from uvd.links.mavlink.signing import load_key
        key = load_key(cfg.signing_key_file)
    return host, int(port), key


class GroundStation:
    """A ground station on a daemon's MAVLink link: pymavlink over UDP to ``host:port``
    (IPv4: pymavlink's UDP connection), MAVLink 2, as system ``system``, component
    MISSIONPLANNER, signed with ``key`` when given. From its start until :meth:`close` its own
    thread sends HEARTBEAT at 2 Hz (a station the link hears: it gets telemetry and answers).
    One thread at a time reads or sends on the connection: pymavlink's sequence numbers and
    signing timestamps are not thread-safe. A context manager: leaving it closes."""

    def __init__(self, host: str, port: int, system: int = 255,
                 key: bytes | None = None) -> None:
        os.environ.setdefault("MAVLINK20", "1")  # pymavlink's MAVLink 2 dialects
        from pymavlink import mavutil
        self.mav = mavutil.mavlink
        self.system = system
        #: (system, component) of the vehicle, from its heartbeat (:meth:`vehicle`)
        self.target: tuple[int, int] | None = None
        self.conn = mavutil.mavlink_connection(
            f"udpout:{host}:{port}", source_system=system,
            source_component=self.mav.MAV_COMP_ID_MISSIONPLANNER, dialect="ardupilotmega")
        self.conn.mav.WIRE_PROTOCOL_VERSION = "2.0"
        try:
            if key is not None:
                self.conn.setup_signing(key, sign_outgoing=True)
        except BaseException:
            self.conn.close()
            raise
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, name="uvd-station-heartbeat",
                                        daemon=True)
        self._thread.start()

    def __enter__(self) -> GroundStation:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _beat(self) -> None:
        while not self._stop.is_set():
            self.send("heartbeat", self.mav.MAV_TYPE_GCS, self.mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self._stop.wait(0.5)

    def send(self, message: str, *fields) -> None:
        """Send one ``message`` (pymavlink's name: ``"manual_control"`` sends with
        ``manual_control_send(*fields)``)."""
        with self._lock:
            getattr(self.conn.mav, f"{message}_send")(*fields)

    def wait(self, kind: str, cond: Callable[[Any], bool] | None, timeout_s: float):
        """The next ``kind`` message for which ``cond`` (None: any) holds, or None when none
        came within ``timeout_s``; the others before it are read and dropped."""
        end = time.monotonic() + timeout_s
        while True:
            with self._lock:  # no blocking read under the lock: the heartbeat goes on
                m = self.conn.recv_match(type=kind, blocking=False)
            if m is not None and (cond is None or cond(m)):
                return m
            left = end - time.monotonic()
            if left <= 0:
                return None
            if m is None:
                self.conn.select(left)  # until the next datagram

    def drain(self) -> None:
        """Read what waits: while nobody reads, a full socket buffer (the vehicle's telemetry,
        ~50 datagrams a second) drops what comes next — an answer too (found as 'unanswered'
        mode commands after the chaos bench's longest pauses)."""
        while True:
            with self._lock:
                if self.conn.recv_match(blocking=False) is None:
                    return

    def vehicle(self, timeout_s: float):
        """The vehicle's next HEARTBEAT (not a station's: another system, not a GCS) and
        :attr:`target` set from it, or None when none came within ``timeout_s``."""
        hb = self.wait("HEARTBEAT", lambda m: m.get_srcSystem() != self.system
                       and m.type != self.mav.MAV_TYPE_GCS, timeout_s)
        if hb is not None:
            self.target = (hb.get_srcSystem(), hb.get_srcComponent())
        return hb

    def command(self, cmd: int, *params: float, timeout_s: float = 5.0):
        """Send COMMAND_LONG ``cmd`` (``params``: param1…) to :attr:`target` and return its
        COMMAND_ACK, or None when none came within ``timeout_s``. What waits is drained first:
        an older answer is not this one's."""
        if self.target is None:
            raise RuntimeError("no vehicle heard yet: wait for its heartbeat (vehicle())")
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        self.drain()
        self.send("command_long", *self.target, cmd, 0, *p)
        return self.wait("COMMAND_ACK", lambda m: m.command == cmd, timeout_s)

    def close(self) -> None:
        """Stop the heartbeat (a bounded join) and close the connection (twice: harmless)."""
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(2.0)
        self.conn.close()


def send_command(host: str, port: int, command: int, params: Sequence[float],
                 about: Callable[[str], bool], *, name: str, system: int = 255,
                 key: bytes | None = None, timeout_s: float = 5.0) -> tuple[str, list[str]]:
    """Send COMMAND_LONG ``command`` (``params``: param1…) and wait for its answer:
    (``"accepted"``/``"denied"``/…, the daemon's STATUSTEXTs for which ``about(text)`` holds,
    whole — chunks of one id joined — in the order they came). Raises TimeoutError when the
    vehicle's heartbeat or the COMMAND_ACK does not come within ``timeout_s``; ``name``: the
    command's in that message."""
    if ":" in host:
        raise ValueError(f"{host}:{port}: uvd {name} speaks IPv4 only (pymavlink's UDP "
                         "connection); reach the daemon on an IPv4 address ([mavlink] listen)")
    with GroundStation(host, port, system, key) as st:
        def answer(m, what):
            if m is None:
                raise TimeoutError(f"no {what} from {host}:{port} within {timeout_s:g} s")
            return m

        answer(st.vehicle(timeout_s), "vehicle heartbeat")
        ack = answer(st.command(command, *params, timeout_s=timeout_s), "COMMAND_ACK")
        result = st.mav.enums["MAV_RESULT"][ack.result].name.removeprefix("MAV_RESULT_").lower()
        return result, _texts(st, about, min(timeout_s, TEXTS_S))


def _texts(st: GroundStation, about: Callable[[str], bool], within_s: float) -> list[str]:
    """The whole STATUSTEXTs ``about`` picks, up to ``within_s``, or :data:`QUIET_S` after the
    last such text was whole (STATUSTEXT chunks: 50 characters, the last one shorter)."""
    texts: list[str] = []
    parts: dict[int, str] = {}
    end = time.monotonic() + within_s
    quiet_end = end
    while (left := min(end, quiet_end) - time.monotonic()) > 0:
        m = st.wait("STATUSTEXT", None, left)
        if m is None:
            break
        text = parts.pop(m.id, "") + m.text
        if m.id and len(m.text) == 50:
            parts[m.id] = text  # more chunks to come
            continue
        if about(text):
            texts.append(text)
            quiet_end = time.monotonic() + QUIET_S
    return texts
