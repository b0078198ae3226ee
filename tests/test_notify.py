"""sd_notify over a real AF_UNIX datagram socket standing in for systemd's NOTIFY_SOCKET:
READY, periodic WATCHDOG from the loop only, STOPPING; a stalled loop stops WATCHDOG while
other tasks and threads live. And the unit file against ``systemd-analyze``."""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
import shutil
import socket
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest

from uvd.runtime.app import App
from uvd.runtime.clock import MonotonicClock
from uvd.runtime.config import load_config
from uvd.runtime.notify import SdNotifier, WatchdogPinger, watchdog_interval_ns

ROOT = Path(__file__).resolve().parents[1]


class Receiver:
    """A bound AF_UNIX datagram socket and a thread collecting (time, message)."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(path)
        self.sock.settimeout(0.05)
        self.msgs: list[tuple[float, str]] = []
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        deadline = time.monotonic() + 60.0  # bounded whatever happens
        while not self._stop.is_set() and time.monotonic() < deadline:
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                break
            self.msgs.append((time.monotonic(), data.decode()))

    def wait_for(self, text: str, timeout: float = 30.0) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if any(text in m for _, m in self.msgs):
                return True
            time.sleep(0.01)
        return False

    def close(self) -> None:
        self._stop.set()
        self.thread.join(timeout=2.0)
        self.sock.close()

    def count(self, text: str) -> int:
        return sum(text in m for _, m in self.msgs)


@pytest.fixture
def receiver(tmp_path):
    r = Receiver(str(tmp_path / "notify.sock"))
    yield r
    r.close()


def test_messages_reach_the_socket(receiver):
    n = SdNotifier(env={"NOTIFY_SOCKET": receiver.path})
    assert n.enabled
    assert n.ready("STANDBY") and n.status("ARMED\nsecond line") and n.watchdog()
    assert n.reloading() and n.stopping("SHUTDOWN")
    assert receiver.wait_for("STOPPING=1", 5.0)
    msgs = [m for _, m in receiver.msgs]
    assert msgs[0] == "READY=1\nSTATUS=STANDBY"
    assert msgs[1] == "STATUS=ARMED second line"
    assert msgs[2] == "WATCHDOG=1"
    assert msgs[3].startswith("RELOADING=1\nMONOTONIC_USEC=")
    assert msgs[4] == "STOPPING=1\nSTATUS=SHUTDOWN"
    assert n.sent == 5 and n.errors == 0
    n.close()


def test_abstract_socket_and_failures():
    name = f"uvd-test-{os.getpid()}-{time.monotonic_ns()}"
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind("\0" + name)
    s.settimeout(5.0)
    try:
        n = SdNotifier(env={"NOTIFY_SOCKET": "@" + name})
        assert n.ready()
        assert s.recv(100) == b"READY=1"
    finally:
        s.close()
    assert not n.watchdog() and n.errors == 1 and n.last_error  # peer gone: counted
    off = SdNotifier(env={})
    assert not off.enabled and off.ready() is False and off.sent == 0


def test_watchdog_interval_from_the_environment():
    assert watchdog_interval_ns({"WATCHDOG_USEC": "2000000"}) == 2_000_000_000
    assert watchdog_interval_ns({}) is None
    assert watchdog_interval_ns({"WATCHDOG_USEC": "0"}) is None
    assert watchdog_interval_ns({"WATCHDOG_USEC": "x"}) is None
    pid = os.getpid()
    assert watchdog_interval_ns({"WATCHDOG_USEC": "100", "WATCHDOG_PID": str(pid)}) == 100_000
    assert watchdog_interval_ns({"WATCHDOG_USEC": "100", "WATCHDOG_PID": str(pid + 1)}) is None


def test_pinger_rate_limits_and_respects_health(receiver):
    n = SdNotifier(env={"NOTIFY_SOCKET": receiver.path})
    healthy = [True]
    p = WatchdogPinger(n, 10_000_000, healthy=lambda: healthy[0])
    for k in range(100):            # 100 cycles at 1 kHz → one ping every 10 ms
        p(k * 1_000_000)
    assert p.pings == 10
    healthy[0] = False
    p(200_000_000)
    assert p.pings == 10
    assert WatchdogPinger.from_env(n, env={}) is None
    assert WatchdogPinger.from_env(n, env={"WATCHDOG_USEC": "50000"}).interval_ns == 25_000_000


class StallableClock(MonotonicClock):
    """The real clock, whose coarse wait can be held on purpose (a hung loop)."""

    def __init__(self) -> None:
        super().__init__()
        self.gate: asyncio.Event | None = None

    async def wait_until_ns(self, deadline_ns: int) -> None:
        if self.gate is not None:
            await self.gate.wait()
        await super().wait_until_ns(deadline_ns)


def test_daemon_sends_ready_watchdog_stopping_and_a_stalled_loop_stops_watchdog(
        receiver, monkeypatch):
    monkeypatch.setenv("WATCHDOG_USEC", "40000")          # ping every 20 ms
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    cfg = load_config(ROOT / "config" / "sim.toml")
    cfg = replace(cfg, loop=replace(cfg.loop, rate_hz=200.0),
                  mavlink=replace(cfg.mavlink, enabled=False))  # an App without its link
    clock = StallableClock()
    marks: dict[str, int] = {}
    thread_alive = threading.Event()

    def side_thread():  # another thread, alive during the stall
        thread_alive.set()
        time.sleep(1.0)

    class Director:
        name = "director"
        ticks = 0

        async def start(self):
            pass

        async def stop(self):
            pass

        async def run(self):
            threading.Thread(target=side_thread, daemon=True).start()
            await asyncio.sleep(0.3)
            marks["pings_before"] = app.watchdog.pings
            marks["cycles_before"] = app.loop.cycles
            clock.gate = asyncio.Event()                  # the loop hangs from here
            ticks0 = self.ticks
            for i in range(40):                           # 0.4 s of other work going on
                await asyncio.sleep(0.01)
                self.ticks += 1
                if i == 4:  # a cycle already in flight at the gate completes (and pings) by now
                    marks["pings_stall_start"] = app.watchdog.pings
                    marks["cycles_stall_start"] = app.loop.cycles
            marks["ticks_during"] = self.ticks - ticks0
            marks["pings_stalled"] = app.watchdog.pings
            marks["cycles_stalled"] = app.loop.cycles
            gate, clock.gate = clock.gate, None
            gate.set()                                    # the loop resumes
            await asyncio.sleep(0.3)
            marks["pings_after"] = app.watchdog.pings
            app.request_stop("test done")

    notifier = SdNotifier(env={"NOTIFY_SOCKET": receiver.path})
    app = App(cfg, lambda t, dt: None, components=[Director()], notifier=notifier, clock=clock,
              realtime=False)
    assert app.watchdog is not None and app.watchdog.interval_ns == 20_000_000
    rc = asyncio.run(asyncio.wait_for(app.run(), 30.0))
    clock.close()
    assert rc == 0
    assert receiver.wait_for("STOPPING=1", 5.0)
    msgs = [m for _, m in receiver.msgs]
    ready = [i for i, m in enumerate(msgs) if m.startswith("READY=1")]
    first_wd = next(i for i, m in enumerate(msgs) if "WATCHDOG=1" in m)
    assert ready and ready[0] < first_wd and "STATUS=STANDBY" in msgs[ready[0]]
    assert thread_alive.is_set()
    # pings while the loop ran, none while it hung (other tasks and threads kept going)
    assert marks["pings_before"] >= 3
    assert marks["pings_stall_start"] <= marks["pings_before"] + 1  # at most the in-flight cycle
    assert marks["cycles_stall_start"] <= marks["cycles_before"] + 1
    assert marks["pings_stalled"] == marks["pings_stall_start"]  # none for the 0.35 s after
    assert marks["cycles_stalled"] == marks["cycles_stall_start"]
    assert marks["ticks_during"] == 40
    assert marks["pings_after"] > marks["pings_stalled"]
    # the datagrams are really there, WATCHDOG only from the pinger
    assert receiver.count("WATCHDOG=1") == app.watchdog.pings
    stopping = [i for i, m in enumerate(msgs) if "STOPPING=1" in m]
    assert stopping and all("WATCHDOG" not in m for m in msgs[stopping[0] + 1:])


class _SlowSink:
    """A telemetry sink whose open takes ``open_s`` (a disk or a router that is slow to come)."""

    def __init__(self, open_s: float) -> None:
        self.name, self.open_s, self.records = "slow", open_s, []

    async def open(self):
        await asyncio.sleep(self.open_s)

    async def write(self, records):
        self.records += records

    async def flush(self):
        pass

    async def aclose(self):
        pass


def _ready_probe(app_of, station):
    """A notifier that, when the daemon says READY, notes what is open and at once sends a
    station's HEARTBEAT to the MAVLink port the link has then (0: none yet)."""
    from pymavlink.dialects.v20 import common as mav
    enc = mav.MAVLink(None, srcSystem=255, srcComponent=190)

    class Probe(SdNotifier):
        def __init__(self) -> None:
            super().__init__(env={})
            self.seen: list[dict] = []

        def ready(self, status=None):
            app = app_of()
            port = app.links["mavlink"].port
            self.seen.append({"port": port, "opening": app.hub.opening(),
                              "t": time.monotonic()})
            if port:
                station.sendto(enc.heartbeat_encode(mav.MAV_TYPE_GCS,
                                                    mav.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(enc),
                               ("127.0.0.1", port))
            return super().ready(status)
    return Probe()


@pytest.mark.parametrize("slow_open_s", [0.0, 3.0])
def test_ready_comes_with_the_links_open_and_a_station_at_once_is_answered(slow_open_s):
    """READY (systemd's, and STANDBY) came a few milliseconds before the MAVLink link was
    bound: a station that came at once got no answer until the bind. Now the links open first.
    A sink slower than ``[daemon] start_timeout_s`` does not hold the daemon back: it is up
    after the start's budget, and the slow sink goes on opening and gets its records."""
    cfg = load_config(ROOT / "config" / "sim.toml")
    cfg = replace(cfg, daemon=replace(cfg.daemon, start_timeout_s=1.0),
                  mavlink=replace(cfg.mavlink, enabled=True, listen="127.0.0.1:0",
                                  params_file="", connect=()))
    station = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    station.bind(("127.0.0.1", 0))
    station.settimeout(0.1)
    notifier = _ready_probe(lambda: app, station)
    answered: list[bytes] = []
    started: list[float] = []

    class Station:
        name = "station"

        async def start(self):
            started.append(time.monotonic())

        async def stop(self):
            pass

        async def run(self):
            deadline = time.monotonic() + 5.0
            while not answered and time.monotonic() < deadline:
                with contextlib.suppress(TimeoutError):
                    answered.append(await asyncio.to_thread(station.recv, 512))
            if slow_open_s:
                await asyncio.sleep(slow_open_s)  # the slow sink opens meanwhile
            app.request_stop("test done")

    slow = _SlowSink(slow_open_s)
    app = App(cfg, lambda t, dt: None, components=[Station()], notifier=notifier,
              sinks=[slow] if slow_open_s else (), realtime=False)
    t0 = time.monotonic()
    try:
        rc = asyncio.run(asyncio.wait_for(app.run(), 30.0))
    finally:
        station.close()
    assert rc == 0
    (seen,) = notifier.seen
    assert seen["port"] > 0, seen
    assert answered and answered[0][0] in (0xFD, 0xFE), answered  # a MAVLink frame back
    if slow_open_s:
        # the start's budget for the links, then the drivers (tests/test_daemon_faults.py:
        # started drives want the loop's heartbeat at once)
        assert seen["opening"] == ["slow"] and 0.9 < started[0] - t0 < slow_open_s, seen
        assert 0.9 < seen["t"] - t0 < slow_open_s, seen
        assert slow.records, "the slow sink got no records once open"
    else:
        assert seen["opening"] == [], seen


def _analyze(*args, timeout=60):
    return subprocess.run(["systemd-analyze", *args], capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture
def unit_file(tmp_path):
    if shutil.which("systemd-analyze") is None:
        pytest.skip("systemd-analyze is not installed (apt-get install systemd)")
    venv_uvd = Path(sys.executable).with_name("uvd")
    if not venv_uvd.exists():
        pytest.skip(f"no uvd console script next to {sys.executable}")
    text = (ROOT / "config" / "uvd.service").read_text()
    # verify checks that every Exec* binary exists: point them at this checkout's uvd
    text = text.replace("/opt/uvd/.venv/bin/uvd", str(venv_uvd))
    p = tmp_path / "uvd.service"
    p.write_text(text)
    return p


def test_unit_file_verifies(unit_file):
    r = _analyze("verify", str(unit_file))
    assert r.returncode == 0, r.stderr
    assert "uvd.service" not in r.stderr, r.stderr  # no warning about our unit


def test_unit_file_security_score(unit_file, record_property, capsys):
    r = _analyze("security", "--offline=yes", str(unit_file))
    m = re.search(r"Overall exposure level for uvd\.service: ([0-9.]+) (\w+)", r.stdout)
    assert m, r.stdout[-2000:] + r.stderr
    score, verdict = float(m.group(1)), m.group(2)
    record_property("systemd_security_exposure", score)
    with capsys.disabled():
        print(f"\nsystemd-analyze security --offline=yes config/uvd.service: {score} {verdict}")
    assert score <= 3.0 and verdict in ("OK", "SAFE")


def test_unit_file_has_the_required_settings():
    text = (ROOT / "config" / "uvd.service").read_text()
    keys = dict(re.findall(r"^(\w+)=(.*)$", text, re.M))
    assert keys["Type"] == "notify" and keys["NotifyAccess"] == "main"
    assert keys["Restart"] == "on-failure" and keys["WatchdogSec"] and keys["TimeoutStopSec"]
    assert "zero-thrust --config" in keys["ExecStopPost"]
    for k in ("NoNewPrivileges", "ProtectHome", "PrivateTmp"):
        assert keys[k] == "yes"
    assert keys["ProtectSystem"] == "strict" and keys["DevicePolicy"] == "closed"
    assert "DeviceAllow" in keys and keys["User"] == "uvd"
    assert "AF_CAN" in keys["RestrictAddressFamilies"]
    # real-time priority is not granted by default (docs/runtime.md has the drop-in)
    assert keys["RestrictRealtime"] == "yes" and keys["LimitRTPRIO"] == "0"
    assert keys["CapabilityBoundingSet"] == ""
