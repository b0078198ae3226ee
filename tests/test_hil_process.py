"""The real daemon process against the real sim-bridge process.

Under a fake ``NOTIFY_SOCKET`` (an AF_UNIX datagram socket standing in for systemd) the
daemon sends READY=1 once its drivers are up, WATCHDOG=1 periodically from the loop, STATUS=
with the lifecycle state, and STOPPING=1 on SIGTERM; after SIGTERM during an armed run,
zero-current RPDOs are on the bus (observed by a third CAN node, this test) within 100 ms and
the process exits 0 within 2 s.
"""

from __future__ import annotations

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


def test_notify_and_sigterm_with_the_real_processes(tmp_path):
    bridge_args, changes = hil_scheduling()  # scheduled as in the demo
    cfg_path = write_local_config(tmp_path, changes=changes)
    cfg = load_config(cfg_path)
    nodes = cfg.can.amplifiers.node_ids
    bridge = BridgeProcess(cfg_path, duration_s=90.0, hold=True,
                           extra=bridge_args).start(timeout_s=90.0)
    notify = NotifyReceiver(str(tmp_path / "notify.sock"))
    observer = BusObserver(cfg.can.bus, nodes)
    env = dict(os.environ, NOTIFY_SOCKET=str(tmp_path / "notify.sock"),
               WATCHDOG_USEC="400000", PYTHONUNBUFFERED="1")
    env.pop("WATCHDOG_PID", None)
    log = (tmp_path / "daemon.log").open("w")
    daemon = subprocess.Popen([sys.executable, "-m", "uvd", "run", "--config", str(cfg_path),
                               "--arm", "--duration", "80"], env=env,
                              stdout=subprocess.DEVNULL, stderr=log)
    try:
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
        if daemon.poll() is None:
            daemon.kill()
            daemon.wait(timeout=5.0)
        log.close()
        observer.close()
        notify.close()
        bridge.stop(timeout_s=5.0)
        bridge.kill()

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
