"""A ground station written from the MAVLink specification with pymavlink's ``mavutil`` only —
it imports nothing of uvd (the wire contract is docs/mavlink.md).

:class:`Station` sends its HEARTBEAT at 1 Hz from its own thread (MAV_TYPE_GCS, system 255
unless told), and offers the operator's actions: arm, disarm, set a custom mode, fetch, read
and set parameters, manual control, a position target; each waits, bounded, for the vehicle's
answer.
"""

from __future__ import annotations

import os
import threading
import time

os.environ.setdefault("MAVLINK20", "1")  # mavutil's MAVLink 2 dialects (signed packets)
from pymavlink import mavutil  # noqa: E402

mav = mavutil.mavlink


class Station:
    def __init__(self, port: int, system: int = 255, signing_key: bytes | None = None,
                 host: str = "127.0.0.1") -> None:
        self.conn = mavutil.mavlink_connection(f"udpout:{host}:{port}", source_system=system,
                                               source_component=mav.MAV_COMP_ID_MISSIONPLANNER,
                                               dialect="ardupilotmega")
        self.conn.mav.WIRE_PROTOCOL_VERSION = "2.0"
        if signing_key is not None:
            self.conn.setup_signing(signing_key, sign_outgoing=True)
        self.target = (1, 1)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.beating = True
        self._thread = threading.Thread(target=self._beat, daemon=True)
        self._thread.start()

    def _beat(self) -> None:
        while not self._stop.is_set():
            if self.beating:
                with self._lock:
                    self.conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID,
                                                 0, 0, 0)
            self._stop.wait(0.5)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.conn.close()

    def send(self, name: str, *args) -> None:
        with self._lock:
            getattr(self.conn.mav, f"{name}_send")(*args)

    def wait(self, kind: str | list[str], cond=lambda m: True, timeout: float = 5.0):
        """The first message of ``kind`` that satisfies ``cond`` (AssertionError after
        ``timeout``)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            m = self.conn.recv_match(type=kind, blocking=True, timeout=0.1)
            if m is not None and cond(m):
                return m
        raise AssertionError(f"no {kind} within {timeout} s")

    def heartbeat(self, timeout: float = 10.0):
        hb = self.wait("HEARTBEAT", lambda m: m.get_srcSystem() != 255, timeout)
        self.target = (hb.get_srcSystem(), hb.get_srcComponent())
        return hb

    def drain(self) -> None:
        """Read what waits: while a test does other things nobody reads this socket, and once
        its buffer is full (the vehicle's telemetry fills the default in ~5 s) the kernel
        drops what comes next — the answer to the next command too."""
        while self.conn.recv_match(blocking=False) is not None:
            pass

    def command(self, cmd: int, *params: float, timeout: float = 5.0):
        self.drain()
        p = list(params) + [0.0] * (7 - len(params))
        self.send("command_long", *self.target, cmd, 0, *p)
        return self.wait("COMMAND_ACK", lambda m: m.command == cmd, timeout)

    def sensor_bits(self, bit: int, timeout: float = 5.0) -> tuple[bool, bool, bool]:
        """The next SYS_STATUS's ``bit`` (e.g. MAV_SYS_STATUS_LOGGING): present, enabled,
        healthy."""
        m = self.wait("SYS_STATUS", timeout=timeout)
        return tuple(bool(x & bit) for x in (m.onboard_control_sensors_present,
                                             m.onboard_control_sensors_enabled,
                                             m.onboard_control_sensors_health))

    def arm(self, on: bool = True):
        return self.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if on else 0.0)

    def set_mode(self, custom_mode: int):
        return self.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                            float(custom_mode))

    def params(self, timeout: float = 10.0) -> dict[str, float]:
        """PARAM_REQUEST_LIST: every PARAM_VALUE until param_count are in."""
        self.send("param_request_list", *self.target)
        got: dict[int, tuple[str, float]] = {}
        count = None
        deadline = time.monotonic() + timeout
        while count is None or len(got) < count:
            if time.monotonic() > deadline:
                raise AssertionError(f"{len(got)} of {count} parameters within {timeout} s")
            m = self.conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.1)
            if m is not None:
                count = m.param_count
                got[m.param_index] = (m.param_id, m.param_value)
        return dict(got.values())

    def param_read(self, name: str, timeout: float = 2.0, retries: int = 3) -> float:
        """PARAM_REQUEST_READ, sent again after ``timeout`` (UDP may lose it), as a station
        does."""
        for i in range(retries):
            self.send("param_request_read", *self.target, name.encode(), -1)
            try:
                return self.wait("PARAM_VALUE", lambda m: m.param_id == name,
                                 timeout).param_value
            except AssertionError:
                if i + 1 == retries:
                    raise

    def param_set(self, name: str, value: float, timeout: float = 5.0) -> float:
        """PARAM_SET; the vehicle's PARAM_VALUE answer (the value in force)."""
        self.send("param_set", *self.target, name.encode(), value, mav.MAV_PARAM_TYPE_REAL32)
        return self.wait("PARAM_VALUE", lambda m: m.param_id == name, timeout).param_value

    def manual(self, x: int = 0, y: int = 0, z: int = 500, r: int = 0) -> None:
        self.send("manual_control", self.target[0], x, y, z, r, 0)
