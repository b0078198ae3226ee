"""The real daemon process against the real sim-bridge process.

Under a fake ``NOTIFY_SOCKET`` (an AF_UNIX datagram socket standing in for systemd) the
daemon sends READY=1 once its drivers are up, WATCHDOG=1 periodically from the loop, STATUS=
with the lifecycle state, and STOPPING=1 on SIGTERM; after SIGTERM during an armed run,
zero-current RPDOs are on the bus (observed by a third CAN node, this test) within 100 ms and
the process exits 0 within 2 s.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

import pytest

from drivers.can.bus import open_bus
from sim_bridge.bridge import BridgeProcess, hil_scheduling, write_local_config
from uvd.runtime.config import load_config

pytestmark = pytest.mark.timeout(150)


class NotifyReceiver:
    """systemd's side of sd_notify: a bound datagram socket, (monotonic ns, message) pairs."""

    def __init__(self, path: str) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(path)
        self.sock.settimeout(0.05)
        self.msgs: list[tuple[int, str]] = []
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self) -> None:
        end = time.monotonic() + 120.0
        while not self._stop.is_set() and time.monotonic() < end:
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            self.msgs.append((time.monotonic_ns(), data.decode()))

    def first(self, text: str) -> int | None:
        return next((t for t, m in self.msgs if text in m), None)

    def wait(self, text: str, timeout_s: float) -> int | None:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            t = self.first(text)
            if t is not None:
                return t
            time.sleep(0.01)
        return None

    def close(self) -> None:
        self._stop.set()
        self._t.join(2.0)
        self.sock.close()


class BusObserver:
    """A third node on the bus recording every RPDO (COB-ID 0x201…) with its receive time."""

    def __init__(self, bus_cfg, node_ids) -> None:
        self.bus = open_bus(bus_cfg)
        self.cob = {0x200 + n: n for n in node_ids}
        self.rpdos: list[tuple[int, int, int]] = []  # (t_ns, node, target permille)
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self) -> None:
        end = time.monotonic() + 120.0
        while not self._stop.is_set() and time.monotonic() < end:
            msg = self.bus.recv(timeout=0.05)
            if msg is None or msg.arbitration_id not in self.cob or len(msg.data) < 4:
                continue
            _cw, target = struct.unpack_from("<Hh", bytes(msg.data))
            self.rpdos.append((time.monotonic_ns(), self.cob[msg.arbitration_id], target))

    def close(self) -> None:
        self._stop.set()
        self._t.join(2.0)
        self.bus.shutdown()


@contextlib.contextmanager
def _daemon_on_bridge(tmp_path, *run_args: str, env: dict | None = None):
    """sim-bridge (scheduled as in the demo), a third node watching the bus, and ``uvd run
    --config … --arm RUN_ARGS`` with its stderr in ``tmp_path/daemon.log``: ``(config, daemon,
    observer)``. All of them ended after, whatever happened."""
    bridge_args, changes = hil_scheduling()
    cfg_path = write_local_config(tmp_path, changes=changes)
    cfg = load_config(cfg_path)
    bridge = BridgeProcess(cfg_path, duration_s=90.0, hold=True,
                           extra=bridge_args).start(timeout_s=90.0)
    observer = BusObserver(cfg.can.bus, cfg.can.amplifiers.node_ids)
    log = (tmp_path / "daemon.log").open("w")
    daemon = None
    try:
        daemon = subprocess.Popen(
            [sys.executable, "-m", "uvd", "run", "--config", str(cfg_path), "--arm", *run_args],
            env=env or dict(os.environ, PYTHONUNBUFFERED="1"), stdout=subprocess.DEVNULL,
            stderr=log)
        yield cfg, daemon, observer
    finally:
        if daemon is not None and daemon.poll() is None:
            daemon.kill()
            daemon.wait(timeout=5.0)
        log.close()
        observer.close()
        bridge.stop(timeout_s=5.0)
        bridge.kill()


def test_notify_and_sigterm_with_the_real_processes(tmp_path):
    notify = NotifyReceiver(str(tmp_path / "notify.sock"))
    env = dict(os.environ, NOTIFY_SOCKET=str(tmp_path / "notify.sock"),
               WATCHDOG_USEC="400000", PYTHONUNBUFFERED="1")
    env.pop("WATCHDOG_PID", None)
    try:
        with _daemon_on_bridge(tmp_path, "--duration", "80", env=env) as (cfg, daemon, observer):
            nodes = cfg.can.amplifiers.node_ids
            t_ready = notify.wait("READY=1", 60.0)
            assert t_ready is not None, (tmp_path / "daemon.log").read_text()[-2000:]
            t_armed = notify.wait("STATUS=ARMED", 20.0)
            assert t_armed is not None, (tmp_path / "daemon.log").read_text()[-2000:]
            time.sleep(1.5)  # tracking RefTraj1
            t_sig = time.monotonic_ns()
            daemon.send_signal(signal.SIGTERM)
            code = daemon.wait(timeout=10.0)
            t_exit = time.monotonic_ns()
            time.sleep(0.3)
    finally:
        notify.close()

    # -- exit --
    assert code == 0
    exit_s = (t_exit - t_sig) * 1e-9
    assert exit_s <= 2.0
    # -- notifications --
    msgs = [m for _, m in notify.msgs]
    ready = next(i for i, m in enumerate(msgs) if "READY=1" in m)
    assert "STATUS=STANDBY" in msgs[ready]
    wd = [t for t, m in notify.msgs if "WATCHDOG=1" in m]
    assert min(wd) > t_ready and len([t for t in wd if t < t_sig]) >= 5  # every ~200 ms
    t_stopping = notify.first("STOPPING=1")
    assert t_stopping is not None and t_sig < t_stopping < t_exit
    assert not [t for t in wd if t > t_stopping]
    # -- the bus: tracking before the signal, zero current within 100 ms after it --
    before = [r for r in observer.rpdos if t_armed < r[0] < t_sig]
    assert any(target != 0 for _, _, target in before)
    after = [r for r in observer.rpdos if r[0] > t_sig]
    last_nonzero = max((t for t, _, target in after if target != 0), default=t_sig)
    zeros = [r for r in after if r[0] > last_nonzero]
    assert {n for _, n, _ in zeros} == set(nodes)  # every amplifier got zero, and kept it
    t_zero = max(min(t for t, n, _ in zeros if n == node) for node in nodes)
    zero_ms = (t_zero - t_sig) * 1e-6
    print(f"SIGTERM: zero-current RPDOs on every node {zero_ms:.1f} ms after the signal, "
          f"exit 0 after {exit_s * 1e3:.0f} ms")
    assert zero_ms <= 100.0


def test_a_missed_deadline_does_not_fault_the_drives(tmp_path):
    """The daemon process stopped for 150 ms (SIGSTOP, SIGCONT: a VM paused, a kernel stall)
    just before a command is due, three times, at the shipped 10 Hz: each time the drives go
    about 250 ms without a command — one missed deadline — and the shipped
    ``command_timeout_ms`` (300: three cycles) rides it out: no drive times out, no failsafe,
    still armed, tracking after. Before (session 32) the shipped 200 ms faulted every drive at
    the first stall (measured with ``uvd demo``: amplifier_fault → disarm)."""
    log_path, summary = tmp_path / "daemon.log", tmp_path / "summary.json"
    stalls = []
    with _daemon_on_bridge(tmp_path, "--duration", "80", "--summary-json",
                           str(summary)) as (cfg, daemon, observer):
        assert cfg.loop.rate_hz == 10.0 and cfg.can.amplifiers.command_timeout_ms == 300
        nodes = cfg.can.amplifiers.node_ids
        deadline = time.monotonic() + 60.0
        while "→ ARMED" not in log_path.read_text():
            assert daemon.poll() is None and time.monotonic() < deadline, \
                log_path.read_text()[-2000:]
            time.sleep(0.05)
        time.sleep(1.5)
        for _ in range(3):
            n = len(observer.rpdos)
            while len(observer.rpdos) == n:  # a command has just gone out
                time.sleep(0.001)
            time.sleep(0.085)  # the next is due in ~15 ms
            t0 = time.monotonic_ns()
            os.kill(daemon.pid, signal.SIGSTOP)
            time.sleep(0.15)
            os.kill(daemon.pid, signal.SIGCONT)
            stalls.append(t0)
            time.sleep(1.5)
        t_end = time.monotonic_ns()
        daemon.send_signal(signal.SIGTERM)
        assert daemon.wait(timeout=10.0) == 0
    text = log_path.read_text()
    # each stall left the drives ~250 ms without a command: past the 200 ms shipped before
    t1 = [t for t, node, _ in observer.rpdos if node == nodes[0] and t < t_end]
    for t0 in stalls:
        gap = max((b - a) / 1e6 for a, b in zip(t1, t1[1:], strict=False) if a <= t0 < b)
        print(f"stall at {t0}: {gap:.0f} ms without a command")
        assert gap > 200.0, gap
    assert "command_timeout" not in text and "failsafe fired" not in text, text[-3000:]
    res = json.loads(summary.read_text())
    assert not [e for e in res["failsafe_events"] if e.get("type") == "failsafe"]
    assert res["loop"]["overruns"] >= 1
    after = [target for t, _, target in observer.rpdos if stalls[-1] + 1_000_000_000 < t < t_end]
    assert any(target != 0 for target in after), "not tracking after the stalls"
