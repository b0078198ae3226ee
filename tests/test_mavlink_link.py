"""The MAVLink link alone on loopback (no daemon): a station made of a UDP socket and
pymavlink's codec sends what an operator sends; the link's command queue shows what the cycle
would get. Bounded: every wait has a deadline."""

from __future__ import annotations

import asyncio
import collections
import contextlib
import os
import signal
import socket
import subprocess
import time

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from uvd.links.mavlink.link import TEXT_BURST, MavlinkLink
from uvd.runtime.commands import CommandQueue, HoldPose, ManualWrench
from uvd.runtime.config import DEFAULT_CONFIG, MavlinkSection, load_config

mav = mavlink


class Peer:
    def __init__(self, system: int = 255) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # room for what arrives while this thread reads late under load: a 256-chunk
        # STATUSTEXT at 250 a second is ~330 kB of datagrams in the kernel's count within a
        # second, more than the default 208 kB (one fresh clone beside other work lost
        # chunk 255 of an unpaced burst so: "no STATUSTEXT within 10.0 s")
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.enc = mavlink.MAVLink(None, system, 190)
        self.enc.WIRE_PROTOCOL_VERSION = "2.0"
        self.dec = mavlink.MAVLink(None, 255, 190)
        self.dec.robust_parsing = True

    @property
    def port(self) -> int:
        return self.sock.getsockname()[1]

    def send(self, msg, port: int) -> None:
        self.sock.sendto(msg.pack(self.enc), ("127.0.0.1", port))

    def wait(self, kind: str, cond=lambda m: True, timeout: float = 3.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            for m in self.dec.parse_buffer(data) or []:
                if m.get_type() == kind and cond(m):
                    return m
        raise AssertionError(f"no {kind} within {timeout} s")


def cycle_record(**kw):
    rec = {"type": "cycle", "t_ns": 1, "state": "STANDBY", "action": "none", "mode": "zero",
           "operator_mode": "auto", "p": np.array([1.0, 2.0, 3.0]), "R": np.eye(3),
           "v": np.zeros(6), "thrust": np.array([1.0, -2.0, 0, 0, 0, 0]),
           "ages": (0.01, 0.1, 0.05, 0.01), "armed_at_ns": None}
    return {**rec, **kw}


def run_link(scenario, **cfg):
    station = Peer()
    link = MavlinkLink(
        MavlinkSection(enabled=True, listen="127.0.0.1:0", params_file="",
                       connect=(f"127.0.0.1:{station.port}",), **cfg),
        CommandQueue(), lambda: load_config(DEFAULT_CONFIG),
        thresholds={"ins": 0.25, "dvl": 1.0, "depth": 0.5, "feedback": 0.5},
        max_thrust_n=[20.0] * 6)

    async def main():
        await link.open()
        try:
            await link.write([cycle_record()])
            return await asyncio.to_thread(scenario, link, station)
        finally:
            await link.aclose()
            station.sock.close()
    return asyncio.run(asyncio.wait_for(main(), 30.0))


def queued(link, n: int = 1, timeout: float = 2.0):
    deadline = time.monotonic() + timeout
    got = []
    while len(got) < n and time.monotonic() < deadline:
        got += [p.command for p in link.commands.drain()]
        time.sleep(0.01)
    return got


def test_connect_endpoint_telemetry_manual_setpoint_and_refusals():
    def scenario(link, st):
        hb = st.wait("HEARTBEAT")  # to the connect endpoint, before it said anything
        assert hb.type == mav.MAV_TYPE_SUBMARINE and hb.system_status == mav.MAV_STATE_STANDBY
        pos = st.wait("LOCAL_POSITION_NED")
        assert (pos.x, pos.y, pos.z) == (1.0, 2.0, 3.0)
        act = st.wait("ACTUATOR_OUTPUT_STATUS")
        assert list(act.actuator[:3]) == [1.0, -2.0, 0.0] and act.active == 0b111111
        servo = st.wait("SERVO_OUTPUT_RAW")
        assert (servo.servo1_raw, servo.servo2_raw, servo.servo3_raw) == (1520, 1460, 1500)
        st.send(st.enc.manual_control_encode(1, 500, -1000, 1000, 250, 0), link.port)
        (c,) = queued(link)
        assert isinstance(c, ManualWrench)
        assert np.allclose(c.u, (25.0, -50.0, -50.0, 0.0, 0.0, 2.5))  # z 1000: up = -z
        st.send(st.enc.set_position_target_local_ned_encode(
            0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 0b0000_1011_1111_1000, 4.0, 5.0, 6.0,
            0, 0, 0, 0, 0, 0, 0.5, 0), link.port)
        (c,) = queued(link)
        assert c == HoldPose(4.0, 5.0, 6.0, 0.5, source="mavlink 255")
        st.send(st.enc.set_position_target_local_ned_encode(  # yaw ignored: present heading
            0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 0b0000_1111_1111_1000, 4.0, 5.0, 6.0,
            0, 0, 0, 0, 0, 0, 0.5, 0), link.port)
        (c,) = queued(link)
        assert c.heading_rad == 0.0
        st.send(st.enc.command_long_encode(1, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0,
                                           0), link.port)
        ack = st.wait("COMMAND_ACK")
        assert ack.command == mav.MAV_CMD_NAV_TAKEOFF
        assert ack.result == mav.MAV_RESULT_UNSUPPORTED
        st.send(st.enc.timesync_encode(0, 12345), link.port)
        assert st.wait("TIMESYNC", lambda m: m.ts1 == 12345).tc1 > 0
        other = Peer(system=42)
        other.send(other.enc.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0), link.port)
        other.sock.close()
        deadline = time.monotonic() + 5.0  # the datagram passes the receiver and the thread
        while link.counters["not_a_gcs"] < 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert queued(link, timeout=0.2) == [] and link.counters["not_a_gcs"] == 1

    run_link(scenario)


def test_a_malformed_arm_or_mode_command_is_refused_never_guessed():
    """param1 NaN of ARM_DISARM was read as a disarm (NaN >= 0.5 is false): a running demo
    went ARMED → STANDBY "disarm: ground station" on it; DO_SET_MODE with NaN got no answer
    at all (int(NaN) raised in the handler). Both are now DENIED with a STATUSTEXT, counted,
    and nothing reaches the cycle; 1 and 0 still arm and disarm."""
    from uvd.runtime.commands import Arm, Disarm, ResetFailsafe

    def scenario(link, st):
        st.wait("HEARTBEAT")
        nan = float("nan")
        for command, p1, p2, says in (
                (mav.MAV_CMD_COMPONENT_ARM_DISARM, nan, 0.0, "arm/disarm refused: param1 nan"),
                (mav.MAV_CMD_COMPONENT_ARM_DISARM, 0.7, 0.0, "arm/disarm refused: param1 0.7"),
                (mav.MAV_CMD_DO_SET_MODE, nan, 4.0, "mode refused: base mode nan"),
                (mav.MAV_CMD_DO_SET_MODE, 1.0, float("inf"), "custom mode inf must"),
                (31011, 3.0, 0.0, "failsafe reset refused: param1 3 must be 0"),
                (31011, nan, 0.0, "failsafe reset refused: param1 nan")):
            st.send(st.enc.command_long_encode(1, 1, command, 0, p1, p2, 0, 0, 0, 0, 0),
                    link.port)
            ack = st.wait("COMMAND_ACK")
            assert (ack.command, ack.result) == (command, mav.MAV_RESULT_DENIED)
            text = st.wait("STATUSTEXT", lambda m: "refused" in m.text).text
            assert says in text, text
        assert queued(link, timeout=0.3) == []
        assert link.counters["commands_refused"] == 6 and link.counters["bad_messages"] == 0
        for p1, kind in ((1.0, Arm), (0.0, Disarm)):
            st.send(st.enc.command_long_encode(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, p1,
                                               0, 0, 0, 0, 0, 0), link.port)
            (c,) = queued(link)
            assert isinstance(c, kind)
        st.send(st.enc.command_long_encode(1, 1, 31011, 0, 0, 0, 0, 0, 0, 0, 0), link.port)
        (c,) = queued(link)
        assert c == ResetFailsafe(None, source="mavlink 255/190")

    run_link(scenario)


def test_a_parameter_of_another_type_is_refused_not_read_as_a_float():
    """PARAM_SET's value is a float; a station that takes a parameter for an INT32 packs the
    integer's bytes into it (pymavlink's mavset: 350 → 4.9e-43). It was read as the float it
    looks like: CTL_KP_2 set to 4.9e-43, inside its range (≥ 0), the surge gain gone. Now any
    param_type but REAL32 is refused by name, counted, and answered with the value in force."""
    import struct

    def scenario(link, st):
        st.wait("HEARTBEAT")
        bytewise = struct.unpack(">f", struct.pack(">i", 350))[0]
        assert 0.0 < bytewise < 1e-40
        for ptype, value in ((mav.MAV_PARAM_TYPE_INT32, bytewise), (200, 350.0)):
            st.send(st.enc.param_set_encode(1, 1, b"CTL_KP_2", value, ptype), link.port)
            pv = st.wait("PARAM_VALUE", lambda m: m.param_id == "CTL_KP_2")
            assert pv.param_value == 300.0  # unchanged
            text = st.wait("STATUSTEXT", lambda m: "param_type" in m.text).text
            assert text.startswith(f"CTL_KP_2: param_type {ptype} is not MAV_PARAM_TYP"), \
                text  # its first 50-character chunk
        assert queued(link, timeout=0.3) == []
        assert link.counters["params_refused"] == 2
        st.send(st.enc.param_set_encode(1, 1, b"CTL_KP_2", 350.0, mav.MAV_PARAM_TYPE_REAL32),
                link.port)
        (c,) = queued(link)
        assert c.values == {"control.kp": (300.0, 350.0, 300.0, 300.0, 300.0, 300.0)}

    run_link(scenario)


def test_a_position_target_no_vehicle_can_hold_is_refused_and_counted():
    """SET_POSITION_TARGET_LOCAL_NED carries float32s up to 3.4e38: x = 1e30 m was queued as a
    HoldPose and held — on a running daemon the aft thrusters at their 300 N limit, two-step
    AMBC stopped adapting; yaw 1e30 rad too. Positions beyond the navigation frame's ±1e6 m and
    a yaw beyond ±2π are refused (STATUSTEXT naming the field, counted); a wrong frame was
    told but not counted, and is now."""
    def scenario(link, st):
        st.wait("HEARTBEAT")
        for x, z, yaw, says in ((1e30, 2.0, 0.0, "x 1e+30"), (0.0, -3e38, 0.0, "z -3e+38"),
                                (0.0, 2.0, 1e30, "yaw 1e+30")):
            st.send(st.enc.set_position_target_local_ned_encode(
                0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 0b0000_1011_1111_1000, x, 0.0, z,
                0, 0, 0, 0, 0, 0, yaw, 0), link.port)
            text = st.wait("STATUSTEXT", lambda m: "refused" in m.text).text
            assert text.startswith("SET_POSITION_TARGET_LOCAL_NED refused: " + says), text
        st.send(st.enc.set_position_target_local_ned_encode(
            0, 1, 1, mav.MAV_FRAME_BODY_NED, 0b0000_1011_1111_1000, 1.0, 0.0, 2.0,
            0, 0, 0, 0, 0, 0, 0.0, 0), link.port)
        st.wait("STATUSTEXT", lambda m: m.text.endswith("refused: needs MAV_F"))
        assert queued(link, timeout=0.3) == []
        assert link.counters["commands_refused"] == 4
        # the edge of the frame, and a yaw the station ignores whatever it holds: taken
        st.send(st.enc.set_position_target_local_ned_encode(
            0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 0b0000_1111_1111_1000, -1e6, 1e6, 2.0,
            0, 0, 0, 0, 0, 0, 1e30, 0), link.port)
        (c,) = queued(link)
        assert c == HoldPose(-1e6, 1e6, 2.0, 0.0, source="mavlink 255")

    run_link(scenario)


def test_a_long_reason_goes_out_in_statustext_chunks():
    reason = "x" * 120

    def scenario(link, st):
        st.wait("HEARTBEAT")
        asyncio.run(link.write([{"type": "failsafe", "kind": "fired", "trigger": "leak",
                                 "action": "disarm", "reason": reason}]))
        text = f"failsafe fired: leak -> disarm ({reason})"  # 153 bytes: 4 chunks of <= 50
        parts = [st.wait("STATUSTEXT", lambda m, i=i: m.chunk_seq == i) for i in range(4)]
        assert len({p.id for p in parts}) == 1 and parts[0].id > 0
        assert parts[0].severity == mav.MAV_SEVERITY_WARNING
        assert "".join(p.text for p in parts) == text

    run_link(scenario)


def test_a_text_of_whole_chunks_ends_with_an_empty_one():
    """A station knows a STATUSTEXT's last chunk by a NUL in it (MAVLink's STATUSTEXT): a
    text of exactly two chunks (100 characters) is followed by an empty third of the same id,
    else a station waits for more. Before (session 26) the text never ended."""
    reason = "z" * (100 - len("failsafe fired: leak -> disarm ()"))

    def scenario(link, st):
        st.wait("HEARTBEAT")
        asyncio.run(link.write([{"type": "failsafe", "kind": "fired", "trigger": "leak",
                                 "action": "disarm", "reason": reason}]))
        parts = [st.wait("STATUSTEXT", lambda m, i=i: m.chunk_seq == i) for i in range(3)]
        assert len({p.id for p in parts}) == 1 and parts[0].id > 0
        assert [len(p.text) for p in parts] == [50, 50, 0]
        assert "".join(p.text for p in parts) == f"failsafe fired: leak -> disarm ({reason})"

    run_link(scenario)


def test_a_text_beyond_256_chunks_is_cut_there_and_the_link_goes_on():
    """MAVLink numbers a STATUSTEXT's chunks in one byte: chunk 256 of a long reason could not
    be packed (struct.error, caught by the link's thread as an error). The text is cut at 256
    chunks (12 800 characters), with no error, and the next text goes out."""
    reason = "y" * 13_000

    def scenario(link, st):
        st.wait("HEARTBEAT")
        asyncio.run(link.write([{"type": "failsafe", "kind": "fired", "trigger": "leak",
                                 "action": "disarm", "reason": reason}]))
        last = st.wait("STATUSTEXT", lambda m: m.chunk_seq == 255, timeout=10.0)
        assert last.text == "y" * 50
        asyncio.run(link.write([{"type": "failsafe", "kind": "cleared", "trigger": "leak",
                                 "action": "none", "reason": "dry"}]))
        assert "dry" in st.wait("STATUSTEXT", lambda m: "dry" in m.text).text
        assert link.counters["errors"] == 0

    run_link(scenario, statustext_hz=250.0)


def test_a_long_text_is_paced_not_one_burst():
    """A 40-chunk text at ``statustext_hz`` 20 through the running link: all 40 chunks, in
    order, one id; the last no sooner than the 30 beyond the first TEXT_BURST (10) allow at
    20 a second (1.5 s after the text was written)."""
    hz, n = 20.0, 40
    reason = "".join(f"{i:02d}" * 25 for i in range(n - 1))

    def scenario(link, st):
        st.wait("HEARTBEAT")
        t_written = time.monotonic()
        asyncio.run(link.write([{"type": "lifecycle", "from": "STANDBY", "to": "ARMED",
                                 "cause": reason}]))
        got = [st.wait("STATUSTEXT", lambda m, i=i: m.chunk_seq == i, timeout=10.0)
               for i in range(n)]
        t_last = time.monotonic()
        assert len({m.id for m in got}) == 1 and got[0].id != 0
        assert "".join(m.text for m in got).endswith(reason)
        assert t_last - t_written >= (n - TEXT_BURST) / hz - 0.01

    run_link(scenario, statustext_hz=hz)


def test_a_flood_of_command_texts_never_crowds_out_the_vehicles_events():
    """400 refused commands' texts (a client flooding: found with 19 300 uvd-fdc samples in
    4 s, whose 328 accepted reports' texts pushed the disarm's lifecycle text out of the one
    paced queue) and one lifecycle transition among them: the transition's text goes out; the
    flood's texts beyond the queue are counted dropped."""
    def refused(i):
        return {"type": "command", "t_ns": i, "command": "FaultReport", "ok": False,
                "reason": f"flood {i}"}

    def scenario(link, st):
        st.wait("HEARTBEAT")
        asyncio.run(link.write([refused(i) for i in range(200)]
                               + [{"type": "lifecycle", "from": "ARMED", "to": "STANDBY",
                                   "cause": "disarm (ground station)"}]
                               + [refused(i) for i in range(200, 400)]))
        told = st.wait("STATUSTEXT", lambda m: "ARMED -> STANDBY" in m.text, timeout=5.0)
        assert told.text == "ARMED -> STANDBY: disarm (ground station)"
        assert told.severity == mav.MAV_SEVERITY_NOTICE
        assert link.counters["statustext_dropped"] >= 400 - 2 * 64 - TEXT_BURST

    run_link(scenario, statustext_hz=20.0)


def test_the_pacing_is_a_token_bucket_on_the_link_clock():
    """The link's pacing driven by a given clock (its thread not started), sending on a real
    socket to a station: TEXT_BURST chunks at once, then ``statustext_hz`` a second, never
    more than TEXT_BURST after a pause; the next text after the last chunk of the one before."""
    station = Peer()
    link = MavlinkLink(
        MavlinkSection(enabled=True, listen="", params_file="", statustext_hz=20.0,
                       connect=(f"127.0.0.1:{station.port}",)),
        CommandQueue(), lambda: load_config(DEFAULT_CONFIG),
        thresholds={"ins": 0.25, "dvl": 1.0, "depth": 0.5, "feedback": 0.5},
        max_thrust_n=[20.0] * 6)
    link._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def arrived():
        out = []
        while True:
            try:
                data = station.sock.recv(4096)
            except TimeoutError:
                return out
            out += [m for m in station.dec.parse_buffer(data) or []
                    if m.get_type() == "STATUSTEXT"]
    try:
        link._text(("info", "a" * (50 * 40 - 1)))  # 40 chunks, the last one short
        link._text(("info", "next"))
        t = link._tokens_t
        link._send_texts(t)
        assert [m.chunk_seq for m in arrived()] == list(range(TEXT_BURST))
        link._send_texts(t + 0.5)  # 10 more at 20 a second
        assert [m.chunk_seq for m in arrived()] == list(range(10, 20))
        link._send_texts(t + 0.52)
        assert [m.chunk_seq for m in arrived()] == []  # 0.4 of a token
        link._send_texts(t + 60.0)  # a long pause: the bucket holds TEXT_BURST, no more
        assert [m.chunk_seq for m in arrived()] == list(range(20, 30))
        link._send_texts(t + 61.0)  # the last 10: the bucket is empty again
        assert [m.chunk_seq for m in arrived()] == list(range(30, 40))
        link._send_texts(t + 61.1)  # two tokens: the next text, one chunk
        got = arrived()
        assert [(m.chunk_seq, m.id, m.text) for m in got] == [(0, 0, "next")]
        assert link.counters["sent"] == 41 and link.counters["send_errors"] == 0
    finally:
        link._sock.close()
        station.sock.close()


def test_an_amplifier_fault_accommodated_is_told_as_a_warning():
    reason = "thruster 1 eta 0 (amplifier); given up: surge"

    def scenario(link, st):
        st.wait("HEARTBEAT")
        asyncio.run(link.write([{"type": "failsafe", "kind": "accommodated",
                                 "trigger": "amplifier_fault", "action": "warn",
                                 "reason": reason}]))
        text = f"failsafe accommodated: amplifier_fault -> warn ({reason})"
        parts = [st.wait("STATUSTEXT", lambda m, i=i: m.chunk_seq == i) for i in range(2)]
        assert all(p.severity == mav.MAV_SEVERITY_WARNING for p in parts)
        assert "".join(p.text for p in parts) == text

    run_link(scenario)


def test_serial_line_carries_telemetry_and_commands(tmp_path):
    """A pseudo-terminal as the radio: the station writes a HEARTBEAT and an ARM on the master
    side; the link queues the Arm and sends its telemetry down the line."""
    from uvd.runtime.commands import Arm
    master, slave = os.openpty()
    os.set_blocking(master, False)
    enc = mavlink.MAVLink(None, 255, 190)
    enc.WIRE_PROTOCOL_VERSION = "2.0"
    dec = mavlink.MAVLink(None, 255, 190)
    dec.robust_parsing = True
    link = MavlinkLink(
        MavlinkSection(enabled=True, listen="127.0.0.1:0", params_file="",
                       serial=os.ttyname(slave), serial_baud=115200),
        CommandQueue(), lambda: load_config(DEFAULT_CONFIG),
        thresholds={"ins": 0.25, "dvl": 1.0, "depth": 0.5, "feedback": 0.5},
        max_thrust_n=[20.0] * 6)

    def scenario():
        # split mid-packet: the line is a byte stream
        data = enc.heartbeat_encode(6, 8, 0, 0, 0).pack(enc) + \
            enc.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(enc)
        os.write(master, data[:15])
        time.sleep(0.05)
        os.write(master, data[15:])
        (c,) = queued(link)
        assert isinstance(c, Arm) and link.operator_heartbeat_ns is not None
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            try:
                msgs = dec.parse_buffer(os.read(master, 4096)) or []
            except BlockingIOError:
                time.sleep(0.02)
                continue
            if any(m.get_type() == "HEARTBEAT" and m.type == mav.MAV_TYPE_SUBMARINE
                   for m in msgs):
                return
        raise AssertionError("no HEARTBEAT down the serial line")

    _with_link(link, scenario, 30.0, close=(master, slave))


def _with_link(link, scenario, timeout_s: float, close=()) -> None:
    """Open ``link``, give it a cycle record, run ``scenario`` in a thread (a station's
    side), close the link and then the file descriptors ``close``."""
    async def main():
        await link.open()
        try:
            await link.write([cycle_record()])
            await asyncio.to_thread(scenario)
        finally:
            await link.aclose()
            for fd in close:
                os.close(fd)
    asyncio.run(asyncio.wait_for(main(), timeout_s))


def test_a_radio_missing_or_lost_is_told_and_opened_again_beside_the_udp_link(tmp_path,
                                                                            caplog):
    """A telemetry radio not there at start took the whole link off, UDP too ("MAVLink link
    off: [mavlink] serial …"); one lost while running (its USB adapter unplugged) logged a
    warning at every wake of the link's thread. Now: the UDP link opens, the line is told once
    and tried again; a pseudo-terminal linked at its path later is opened and carries the
    telemetry; its loss (the master closed) is told once and the line is opened again when a
    new one is linked there."""
    import logging
    path = tmp_path / "radio"
    link = MavlinkLink(
        MavlinkSection(enabled=True, listen="127.0.0.1:0", params_file="", serial=str(path),
                       serial_baud=57600),
        CommandQueue(), lambda: load_config(DEFAULT_CONFIG),
        thresholds={"ins": 0.25, "dvl": 1.0, "depth": 0.5, "feedback": 0.5},
        max_thrust_n=[20.0] * 6)
    dec = mavlink.MAVLink(None, 255, 190)
    dec.robust_parsing = True

    def radio() -> int:
        master, slave = os.openpty()
        os.set_blocking(master, False)
        path.unlink(missing_ok=True)
        path.symlink_to(os.ttyname(slave))
        os.close(slave)  # the link opens it by its name
        return master

    def heartbeat_down(master: int) -> bool:
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            try:
                msgs = dec.parse_buffer(os.read(master, 4096)) or []
            except (BlockingIOError, OSError):
                time.sleep(0.05)
                continue
            if any(m.get_type() == "HEARTBEAT" for m in msgs):
                return True
        return False

    def scenario():
        st = Peer()
        st.sock.sendto(st.enc.heartbeat_encode(6, 8, 0, 0, 0).pack(st.enc),
                       ("127.0.0.1", link.port))
        assert st.wait("HEARTBEAT") is not None  # the UDP link is up without its radio
        assert link.serial_error.startswith("[Errno 2] No such file or directory")
        master = radio()
        assert heartbeat_down(master), "no HEARTBEAT down the line once it is there"
        assert link.serial_error is None
        os.close(master)  # the radio lost
        deadline = time.monotonic() + 5.0
        while link.counters["serial_lost"] == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert link.counters["serial_lost"] == 1
        master = radio()
        assert heartbeat_down(master), "no HEARTBEAT down the line once it is back"
        os.close(master)
        st.sock.close()

    with caplog.at_level(logging.INFO, logger="uvd.mavlink"):
        _with_link(link, scenario, 60.0)
    said = [r.getMessage() for r in caplog.records if "serial" in r.getMessage()]
    assert len(said) <= 6, said  # told, not at every wake
    assert f"MAVLink serial {path} not open: [Errno 2] No such file or directory; the UDP " \
           "link goes on, the line is tried again every 5 s at most" in said, said
    assert f"MAVLink serial {path} open" in said
    assert any(s.startswith(f"MAVLink serial {path} lost (") for s in said), said


@contextlib.contextmanager
def _receiver(rcvbuf: int | None = None):
    """A receiver process on a loopback UDP socket (with a ``rcvbuf`` receive buffer) and a
    station to send to it: ``(process, the daemon's end of the pair, socket, station)``. After:
    the pair closed (the receiver ends on it, killed if it has not within 5 s), the sockets
    closed; a test that passed also asserts the receiver's exit code 0."""
    from uvd.links.mavlink.receiver import spawn_receiver
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    if rcvbuf is not None:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    sock.bind(("127.0.0.1", 0))
    proc, pair = spawn_receiver(sock)
    st = Peer()
    try:
        yield proc, pair, sock, st
    finally:
        pair.close()
        try:
            code = proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            code = proc.wait(timeout=5.0)
        sock.close()
        st.sock.close()
    assert code == 0


def test_the_receiver_process_forwards_only_good_mavlink_and_counts_the_rest():
    from uvd.links.mavlink.receiver import read_forwarded
    with _receiver() as (_proc, pair, sock, st):
        good = st.enc.heartbeat_encode(6, 8, 0, 0, 0).pack(st.enc)
        flipped = bytearray(good)
        flipped[-1] ^= 0xFF  # bad CRC
        for dg in (b"\x00garbage", good[:5], bytes(flipped), good):
            st.sock.sendto(dg, sock.getsockname())
        counts, got, deadline = collections.Counter(), [], time.monotonic() + 5.0
        while (len(got) < 1 or counts["datagrams"] < 4) and time.monotonic() < deadline:
            got += read_forwarded(pair, counts)
            time.sleep(0.02)
        assert got == [(good, ("127.0.0.1", st.port))]
        assert counts == {"datagrams": 4, "bad_datagrams": 3}


def test_the_receiver_outlives_a_ctrl_c_and_ends_when_the_daemon_ends_it():
    """Ctrl-C in the terminal of ``uvd run`` reaches the receiver too, and so do SIGTERM and
    SIGHUP sent to the group (``timeout``, ``kill -- -PGID``): it goes on forwarding (the
    daemon, stopping in order, ends it) and ends, with its last counts, when the daemon shuts
    its end."""
    from uvd.links.mavlink.receiver import read_forwarded, stop_receiver
    with _receiver() as (proc, pair, sock, st):
        good = st.enc.heartbeat_encode(6, 8, 0, 0, 0).pack(st.enc)
        counts, got, deadline = collections.Counter(), [], time.monotonic() + 20.0
        while not got and time.monotonic() < deadline:  # up: it has installed its handlers
            st.sock.sendto(good, sock.getsockname())
            got = read_forwarded(pair, counts)
            time.sleep(0.05)
        assert got, "the receiver forwarded nothing in 20 s"
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):  # a group's signals
            os.kill(proc.pid, sig)
        time.sleep(0.3)
        assert proc.poll() is None, f"the receiver died: {proc.returncode}"
        got = []
        while not got and time.monotonic() < deadline:
            st.sock.sendto(good, sock.getsockname())
            got = read_forwarded(pair, counts)
            time.sleep(0.05)
        assert got == [(good, ("127.0.0.1", st.port))] * len(got) and got
        stop_receiver(proc, pair, counts, timeout_s=5.0)
        assert proc.returncode == 0
        assert counts["datagrams"] >= 2 and counts["bad_datagrams"] == 0, counts


def test_datagrams_the_kernel_drops_while_the_receiver_waits_are_counted():
    """A receiver kept from the CPU (stopped here; a saturated machine alike) while 400
    datagrams arrive at a small buffer: each one is either judged or counted dropped by the
    kernel (``kernel_dropped``, reported with the next datagram) — none lost uncounted."""
    from uvd.links.mavlink.receiver import read_forwarded
    with _receiver(rcvbuf=8192) as (proc, pair, sock, st):
        good = st.enc.heartbeat_encode(6, 8, 0, 0, 0).pack(st.enc)
        st.sock.sendto(good, sock.getsockname())  # the receiver is up and reading
        counts, deadline = collections.Counter(), time.monotonic() + 10.0
        while counts["datagrams"] < 1 and time.monotonic() < deadline:
            read_forwarded(pair, counts)
            time.sleep(0.02)
        os.kill(proc.pid, signal.SIGSTOP)
        for _ in range(400):
            st.sock.sendto(b"\x00garbage", sock.getsockname())
        os.kill(proc.pid, signal.SIGCONT)
        time.sleep(0.2)
        st.sock.sendto(good, sock.getsockname())  # carries the drop count
        while counts["datagrams"] + counts["kernel_dropped"] < 402 \
                and time.monotonic() < deadline:
            read_forwarded(pair, counts)
            time.sleep(0.02)
        assert counts["kernel_dropped"] > 0, counts  # the buffer did overflow
        assert counts["datagrams"] + counts["kernel_dropped"] == 402, counts
        assert counts["bad_datagrams"] == counts["datagrams"] - 2, counts


def test_a_receiver_that_dies_is_replaced_and_commands_go_on():
    def scenario(link, st):
        st.wait("HEARTBEAT")
        link._receiver.kill()
        # a bound, not the property: a new receiver is a new Python process, whose start
        # took more than 5 s at load 17 on the 2-core VM
        deadline = time.monotonic() + 30.0
        while link.counters["receiver_restarts"] < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert link.counters["receiver_ended"] == 1
        got = []
        while not got and time.monotonic() < deadline:  # the new one reads the same socket
            st.send(st.enc.manual_control_encode(1, 500, 0, 500, 0, 0), link.port)
            got = queued(link, timeout=0.3)
        assert isinstance(got[0], ManualWrench)

    run_link(scenario)


def test_bench_loop_fuzzes_the_link_in_every_other_block(tmp_path):
    """``uvd bench loop --mavlink-fuzz``'s wiring (its figures are the benchmark's): quiet and
    fuzzed blocks in turn, every datagram sent in the fuzzed ones read and judged bad."""
    import json

    from uvd.cli import main
    out = tmp_path / "loop.json"
    assert main(["bench", "loop", "--rate", "100", "--cycle", "none", "--no-naive",
                 "--duration", "2", "--warmup", "0", "--mavlink-fuzz", "600", "--json",
                 str(out)]) == 0
    f = json.loads(out.read_text())["mavlink_fuzz"]
    assert f["blocks"] == 3 and f["quiet"]["n"] >= 300 and f["fuzzed"]["n"] >= 150
    c = f["link_counters"]
    assert f["sent"] == 600 and c["datagrams"] == 600 and c["bad_datagrams"] == 600
    assert isinstance(f["lateness_p99_change"], float)


def test_bench_loop_fuzz_control_sends_to_a_bare_receiver(tmp_path):
    """``--fuzz-control``: the same datagrams in the same blocks, to a process that only judges
    them as the link's receiver does — no link in the measured process."""
    import json

    from uvd.cli import main
    out = tmp_path / "loop.json"
    assert main(["bench", "loop", "--rate", "100", "--cycle", "none", "--no-naive",
                 "--duration", "2", "--warmup", "0", "--mavlink-fuzz", "600",
                 "--fuzz-control", "--json", str(out)]) == 0
    f = json.loads(out.read_text())["mavlink_fuzz"]
    assert f["blocks"] == 3 and f["fuzzed"]["n"] >= 150
    assert f["sent"] == 600 and f["link_counters"] == {"control": True, "datagrams": 600}


def test_statustext_is_plain_ascii_as_pymavlink_decodes_it():
    """A refusal naming "1…6" and a told η with "±" reach the station in plain ASCII, whole:
    pymavlink decodes each STATUSTEXT's 50 bytes, and nothing is garbled or split mid-character."""
    refused = "thruster 9 is not one of 1…6"
    told = "uvd-fdc: thruster 4 eta 0.48 (confidence 3.2); residual η 0.47 ± 0.03 → accepted"

    def scenario(link, st):
        st.wait("HEARTBEAT")
        asyncio.run(link.write([
            {"type": "command", "command": "SetThrusterEta", "ok": False, "reason": refused}]))
        first = st.wait("STATUSTEXT", lambda m: "refused" in m.text)  # 52 bytes: 2 chunks
        rest = st.wait("STATUSTEXT", lambda m: m.id == first.id and m.chunk_seq == 1)
        assert first.text + rest.text == "SetThrusterEta refused: thruster 9 is not one of 1..6"
        asyncio.run(link.write([
            {"type": "command", "command": "FaultReport", "ok": True, "reason": told}]))
        parts = [st.wait("STATUSTEXT", lambda m, i=i: m.chunk_seq == i and m.id > first.id)
                 for i in range(2)]
        text = "".join(p.text for p in parts)
        assert text == ("uvd-fdc: thruster 4 eta 0.48 (confidence 3.2); residual eta 0.47 "
                        "+/- 0.03 -> accepted")
        assert all(p.severity == mav.MAV_SEVERITY_WARNING for p in parts)
        assert text.isascii()

    run_link(scenario)


def test_a_receiver_that_cannot_finish_is_killed_and_the_stop_does_not_raise():
    """A receiver that does not run (stopped here; kept from the CPU on a saturated
    machine alike) is killed after the timeout; stop_receiver returns, it never raises."""
    from uvd.links.mavlink.receiver import spawn_receiver, stop_receiver
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    proc, pair = spawn_receiver(sock)
    try:
        os.kill(proc.pid, signal.SIGSTOP)
        t0 = time.monotonic()
        stop_receiver(proc, pair, collections.Counter(), timeout_s=0.2)
        assert proc.returncode == -signal.SIGKILL and time.monotonic() - t0 < 6.0
    finally:
        sock.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait(5.0)


def test_a_receiver_never_reaped_after_its_kill_is_counted_not_raised():
    """The branch seen only on a saturated machine (the killed receiver, then at SCHED_IDLE,
    not reaped within the wait): a process whose wait always times out — no real receiver can
    be made to do that on demand — is counted as not reaped; stop_receiver returns."""
    import collections
    import socket
    import subprocess

    class Unreaped:
        pid, killed = 2**22 + 1, False  # above the kernel's pid_max: sched_* raise OSError

        def wait(self, timeout=None):
            raise subprocess.TimeoutExpired("receiver", timeout)

        def kill(self):
            self.killed = True

    from uvd.links.mavlink.receiver import stop_receiver
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    theirs.close()
    counters, proc = collections.Counter(), Unreaped()
    stop_receiver(proc, ours, counters, timeout_s=0.05)
    assert proc.killed and counters["receiver_not_reaped"] == 1
