"""The asyncio application: SIGTERM/SIGINT → orderly shutdown and exit 0 within 2 s (as a real
process), SIGHUP reload, failures that still run the shutdown sequence, a raising cycle that
zeroes thrust and latches the failsafe."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest

from uvd.runtime.app import App, ShutdownStep
from uvd.runtime.config import load_config
from uvd.runtime.failsafe import Health
from uvd.runtime.lifecycle import State
from uvd.runtime.notify import SdNotifier

ROOT = Path(__file__).resolve().parents[1]

DAEMON = r'''
import asyncio, json, sys, time
from pathlib import Path
from uvd.runtime.app import App, setup_logging
from uvd.runtime.config import load_config

listener = setup_logging()  # stopped before exit, as `uvd run` does: the queue is flushed
cfg = load_config(sys.argv[1])
out = Path(sys.argv[2])
log = []

def cycle(t, dt):
    app.hub.publish({"t_ns": t, "dt": dt, "cycle": app.loop.cycles})

def zero():
    log.append("zero")

def disable():
    log.append("disable")

class FakeDriver:
    name = "fake-driver"
    async def start(self):
        log.append("start")
    async def run(self):
        await asyncio.Event().wait()
    async def stop(self):
        log.append("stop")

app = App(cfg, cycle, components=[FakeDriver()], realtime=False)
app.set_amplifier_hooks(zero, disable)
rc = asyncio.run(app.run())
out.write_text(json.dumps({"rc": rc, "log": log, "steps": app.shutdown_report["steps"],
                           "duration_s": app.shutdown_report["duration_s"],
                           "telemetry": app.shutdown_report["telemetry"],
                           "cycles": app.loop.cycles}))
listener.stop()
sys.exit(rc)
'''


def sim_config_text(tmp_path: Path, **loop) -> str:
    text = (ROOT / "config" / "sim.toml").read_text()
    text = text.replace("rate_hz = 10.0", f"rate_hz = {loop.get('rate_hz', 100.0)}")
    text = text.replace('[telemetry.jsonl]\nenabled = false\npath = "uvd-telemetry.jsonl"',
                        f'[telemetry.jsonl]\nenabled = true\npath = "{tmp_path / "tel.jsonl"}"')
    assert "enabled = true" in text
    return without_mavlink(text)


def without_mavlink(text: str) -> str:
    """sim.toml's text with the MAVLink link off: the App builds every face a configuration
    enables (uvd.links), and these tests of the App do not test that one (a fixed port, a
    receiver process)."""
    link = 'enabled = true\nlisten = "127.0.0.1:14551"'
    assert link in text
    return text.replace(link, 'enabled = false\nlisten = "127.0.0.1:14551"')


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_gives_orderly_shutdown_and_exit_0_within_2_s(tmp_path, sig):
    cfg = tmp_path / "uvd.toml"
    cfg.write_text(sim_config_text(tmp_path))
    script = tmp_path / "daemon.py"
    script.write_text(DAEMON)
    sock_path = str(tmp_path / "notify.sock")
    rx = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    rx.bind(sock_path)
    rx.settimeout(30.0)
    env = dict(os.environ, NOTIFY_SOCKET=sock_path, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, str(script), str(cfg), str(tmp_path / "out.json")],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        msgs = []
        while not any(m.startswith("READY=1") for m in msgs):
            msgs.append(rx.recv(4096).decode())       # bounded by the socket timeout
        time.sleep(0.3)                                # let it run a few dozen cycles
        t0 = time.monotonic()
        proc.send_signal(sig)
        rc = proc.wait(timeout=10)
        elapsed = time.monotonic() - t0
        _, err = proc.communicate(timeout=5)
        rx.settimeout(0.5)
        try:
            while True:
                msgs.append(rx.recv(4096).decode())
        except TimeoutError:
            pass
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5)
        rx.close()
    print(f"\n{signal.Signals(sig).name} → exit {rc} after {elapsed:.3f} s")
    assert rc == 0, err.decode()[-2000:]
    assert elapsed < 2.0
    assert any(m.startswith("STOPPING=1") for m in msgs)
    res = json.loads((tmp_path / "out.json").read_text())
    assert res["rc"] == 0 and res["cycles"] > 5
    # zero current repeated, amplifiers disabled, driver stopped — in that order
    assert res["log"] == ["start", "zero", "zero", "zero", "disable", "stop"]
    assert res["steps"] == {"zero current": "ok", "disable amplifiers": "ok",
                            "stop fake-driver": "ok"}
    assert res["duration_s"] < 1.5
    stats = res["telemetry"]["jsonl"]
    assert stats["errors"] == 0 and stats["queued"] == 0
    lines = (tmp_path / "tel.jsonl").read_text().splitlines()
    records = [json.loads(line) for line in lines]     # every line complete
    cycles = [r for r in records if "cycle" in r]
    assert len(cycles) == stats["written"] - sum(1 for r in records if "type" in r)
    assert any(r.get("type") == "lifecycle" and r["to"] == "SHUTDOWN" for r in records)
    assert "shutdown complete" in err.decode()


def fast_config(tmp_path, rate=200.0, **daemon):
    cfg = load_config(ROOT / "config" / "sim.toml")
    return replace(cfg, loop=replace(cfg.loop, rate_hz=rate),
                   daemon=replace(cfg.daemon, **daemon),
                   mavlink=replace(cfg.mavlink, enabled=False))  # an App without its link


def run_app(app, timeout=20.0):
    return asyncio.run(asyncio.wait_for(app.run(), timeout))


class Scripted:
    """A component whose run() is a test script."""

    def __init__(self, script, name="script", start=None):
        self.name = name
        self.script = script
        self._start = start
        self.stopped = False

    async def start(self):
        if self._start is not None:
            await self._start()

    async def run(self):
        await self.script()

    async def stop(self):
        self.stopped = True


def test_sighup_reloads_what_may_change_and_names_the_rest(tmp_path, monkeypatch):
    path = tmp_path / "uvd.toml"
    text = without_mavlink((ROOT / "config" / "sim.toml").read_text())
    path.write_text(text)
    cfg = load_config(path)
    seen = []

    async def script():
        await asyncio.sleep(0.1)
        path.write_text(text.replace("kp = 300.0", "kp = 200.0")
                        .replace("rate_hz = 10.0", "rate_hz = 50.0")
                        .replace("overrun_streak = 5", "overrun_streak = 9"))
        os.kill(os.getpid(), signal.SIGHUP)
        for _ in range(500):
            if app.last_reload is not None:
                break
            await asyncio.sleep(0.01)
        seen.append(dict(app.last_reload))
        app.last_reload = None
        path.write_text(text.replace("kp = 300.0", "kp = -3.0"))
        os.kill(os.getpid(), signal.SIGHUP)
        for _ in range(500):
            if app.last_reload is not None:
                break
            await asyncio.sleep(0.01)
        seen.append(dict(app.last_reload))
        app.request_stop("done")

    hooks = []
    app = App(cfg, lambda t, dt: None, components=[Scripted(script)], realtime=False,
              notifier=SdNotifier(env={}))
    app.reload_hooks.append(lambda c, applied: hooks.append((c.control.kp, applied)))
    assert run_app(app) == 0
    first, second = seen
    assert sorted(first["applied"]) == ["control.kp", "loop.overrun_streak"]
    assert first["refused"] == ["loop.rate_hz"]
    assert app.config.control.kp == 200.0 and app.config.loop.rate_hz == 10.0
    assert app.loop.settings.overrun_streak == 9
    assert hooks == [(200.0, first["applied"])]
    assert "control.kp" in second["error"] and "out of range" in second["error"]
    assert app.config.control.kp == 200.0   # an invalid file changes nothing


def test_failing_component_stops_the_daemon_with_exit_1_after_the_shutdown_sequence(tmp_path):
    calls = []

    async def script():
        await asyncio.sleep(0.1)
        raise OSError("serial port vanished")

    comp = Scripted(script, name="ins")
    app = App(fast_config(tmp_path), lambda t, dt: None, components=[comp], realtime=False,
              notifier=SdNotifier(env={}))
    app.set_amplifier_hooks(lambda: calls.append("zero"), lambda: calls.append("disable"))
    assert run_app(app) == 1
    assert "ins failed: OSError: serial port vanished" in app.stop_reason
    assert calls == ["zero"] * 3 + ["disable"] and comp.stopped
    assert app.supervisor.state is State.SHUTDOWN


def test_start_timeout_gives_exit_1_and_still_zeroes(tmp_path):
    calls = []

    async def hang():
        await asyncio.sleep(60)

    comp = Scripted(lambda: asyncio.sleep(0), start=hang)
    app = App(fast_config(tmp_path, start_timeout_s=0.2), lambda t, dt: None,
              components=[comp], realtime=False, notifier=SdNotifier(env={}))
    app.set_amplifier_hooks(lambda: calls.append("zero"))
    t0 = time.monotonic()
    assert run_app(app) == 1
    assert time.monotonic() - t0 < 5.0
    assert "start failed: timed out" in app.stop_reason and calls == ["zero"] * 3
    assert app.loop.cycles == 0 and app.supervisor.state is State.SHUTDOWN


def test_shutdown_steps_are_bounded(tmp_path):
    order = []

    def slow_blocking():
        time.sleep(3.0)          # a driver call that hangs

    async def slow_async():
        await asyncio.sleep(3.0)

    app = App(fast_config(tmp_path, step_timeout_s=0.1), lambda t, dt: None, realtime=False,
              notifier=SdNotifier(env={}))
    app.add_shutdown_step(ShutdownStep("blocking", slow_blocking))
    app.add_shutdown_step(ShutdownStep("async", slow_async))
    app.add_shutdown_step(ShutdownStep("raises", lambda: 1 / 0))
    app.add_shutdown_step(ShutdownStep("last", lambda: order.append("last")))
    app.request_stop("test")
    t0 = time.monotonic()
    assert run_app(app) == 0
    assert time.monotonic() - t0 < 2.0
    steps = app.shutdown_report["steps"]
    assert steps["blocking"] == "timeout" and steps["async"] == "timeout"
    assert steps["raises"].startswith("failed: ZeroDivisionError") and steps["last"] == "ok"
    assert order == ["last"]


def test_a_raising_cycle_zeroes_thrust_and_latches_the_failsafe(tmp_path):
    zeros = []
    n = [0]

    def good(t):
        return Health(t_ns=t, ins_age_s=0.01, dvl_age_s=0.05, depth_age_s=0.05,
                      bottom_lock=True, depth_m=1.0 + 1e-12 * t, amplifiers_enabled=True,
                      feedback_age_s=0.01)

    def cycle(t, dt):
        n[0] += 1
        if n[0] == 8:
            raise FloatingPointError("controller blew up")
        app.supervisor.step(good(t))
        if n[0] == 3:
            assert app.supervisor.request_arm(t).ok
        if n[0] == 20:
            app.request_stop("test done")

    app = App(fast_config(tmp_path), cycle, realtime=False, notifier=SdNotifier(env={}))
    app.set_amplifier_hooks(lambda: zeros.append(app.loop.cycles))
    assert run_app(app) == 0
    assert app.loop.cycle_errors == 1
    assert zeros[0] == 7          # zeroed at once, from the failing cycle itself
    hist = app.supervisor.failsafe_events()
    fired = [h for h in hist if h["type"] == "failsafe" and h["kind"] == "fired"]
    assert fired[0]["trigger"] == "cycle_exception" and fired[0]["action"] == "zero-thrust"
    states = [(h["from"], h["to"]) for h in hist if h["type"] == "lifecycle"]
    assert ("ARMED", "FAILSAFE") in states
    # latched: still in force on the later, healthy cycles
    assert app.supervisor.decision.zero_thrust
    assert "cycle_exception" in {a.name for a in app.supervisor.decision.active}
    summary = app.summary()
    assert summary["loop"]["cycle_errors"] == 1 and summary["lifecycle"] == "SHUTDOWN"
    assert "FloatingPointError: controller blew up" in summary["loop"]["last_error"]
