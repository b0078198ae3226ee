"""A ground station on a daemon's MAVLink link, as any station is (docs/mavlink.md): pymavlink
over UDP, MAVLink 2, its own HEARTBEAT, bounded waits for the vehicle's answers. What ``uvd
eta`` and ``uvd reset-failsafe`` send their command through (``uvd.commands._station``) and
the operator of ``uvd bench chaos``. The tests' station (tests/mavlink_gcs.py) is written
apart on purpose: a client that imports nothing of uvd checks the wire contract.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from typing import Any

__all__ = ["GroundStation"]


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
