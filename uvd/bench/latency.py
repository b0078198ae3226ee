"""``uvd bench latency``: end-to-end latency, INS frame on the wire → amplifier command on the bus.

Three real processes, as on the vehicle: ``sim-bridge`` (the INS emulator writes PHINS STDBIN
frames to a pseudo-terminal and stamps the moment each frame's last byte was handed to it),
``uvd run`` (armed, tracking; its telemetry says which INS sample each cycle took and when
that sample was received), and this benchmark, a third node on the CAN bus stamping every
amplifier RPDO it sees. For each INS frame the daemon used:

    latency = (first RPDO of node 1 after the cycle that took the frame) − (frame written)

split into the pty delivery (written → decoded and stamped by the daemon), the wait for the
next cycle, and cycle → RPDO on the bus. Each rate runs twice, the two ``[loop] trigger``
modes one after the other: ``fixed`` (the fixed-rate schedule: the frame waits up to one
period) and ``ins`` (the sensor-synchronous cycle: it runs when the frame is decoded); the
INS sends at the loop's rate in both (``[simulation.instruments] ins_rate_hz``). All stamps
are ``CLOCK_MONOTONIC`` of this one machine. The CAN bus is ``udp_multicast`` on an
interface-local group (never leaves the machine): its per-frame send cost is part of the
figure and is far above a SocketCAN adapter's.
"""

from __future__ import annotations

import bisect
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from uvd.bench import Bench, percentiles, stop_hil
from uvd.cliargs import nonnegative_int, positive_float
from uvd.runtime.process import stop_daemon


def _add(p) -> None:
    p.add_argument("--rate", type=positive_float, nargs="+", default=None,
                   help="control loop rate(s), Hz; the INS sends at the same rate (default: "
                        "the configuration's, 10)")
    p.add_argument("--duration", type=positive_float, default=30.0,
                   help="seconds measured while armed (default 30)")
    p.add_argument("--sched-fifo", type=nonnegative_int, default=50, metavar="PRIO",
                   help="SCHED_FIFO priority of the daemon's loop (default 50, 0 = normal)")
    p.add_argument("--config", type=Path, default=None, help="base configuration")


def _observer(bus_cfg, cob: int, stop_at: float):
    import threading

    from drivers.can.bus import open_bus
    bus = open_bus(bus_cfg)
    seen: list[int] = []
    done = threading.Event()

    def run() -> None:
        try:
            while time.monotonic() < stop_at and not done.is_set():
                msg = bus.recv(timeout=0.05)
                if msg is not None and msg.arbitration_id == cob:
                    seen.append(time.monotonic_ns())
        finally:
            bus.shutdown()
    t = threading.Thread(target=run, daemon=True)
    t.start()
    return seen, done, t


TRIGGERS = ("fixed", "ins")


def measure(duration_s: float = 30.0, *, rate_hz: float | None = None, sched_fifo: int = 50,
            base: Path | None = None, trigger: str = "fixed") -> dict[str, Any]:
    """Run the three processes and return the figures (see the module docstring); the INS
    sends at the loop's rate."""
    from sim_bridge.bridge import BridgeProcess, hil_scheduling, write_local_config
    from uvd.runtime.config import load_config

    run_dir = Path(tempfile.mkdtemp(prefix="uvd-latency-"))
    bridge = daemon = None
    try:
        bridge_args, changes = hil_scheduling()
        changes["loop"]["sched_fifo_priority"] = sched_fifo
        if rate_hz is None:
            rate_hz = load_config(base).loop.rate_hz
        changes["loop"].update(rate_hz=rate_hz, trigger=trigger)
        changes["simulation"] = {"instruments": {"ins_rate_hz": rate_hz}}
        cfg_path = write_local_config(run_dir, base=base, changes=changes)
        cfg = load_config(cfg_path)
        node = cfg.can.amplifiers.node_ids[0]
        bridge = BridgeProcess(cfg_path, duration_s=duration_s + 120.0, hold=True,
                               extra=bridge_args).start(timeout_s=120.0)
        seen, done, th = _observer(cfg.can.bus, 0x200 + node, time.monotonic() + duration_s + 90)
        log = (run_dir / "daemon.log").open("w")
        daemon = subprocess.Popen(
            [sys.executable, "-m", "uvd", "run", "--config", str(cfg_path), "--arm",
             "--stop-with-parent", str(os.getpid()),
             "--duration", str(duration_s + 80.0)], stdout=subprocess.DEVNULL, stderr=log,
            env=dict(os.environ, PYTHONUNBUFFERED="1"))
        t0 = time.monotonic()
        while "→ ARMED" not in (run_dir / "daemon.log").read_text():
            if daemon.poll() is not None or time.monotonic() - t0 > 120.0:
                raise RuntimeError("the daemon did not arm:\n" +
                                   (run_dir / "daemon.log").read_text()[-2000:])
            time.sleep(0.1)
        t_armed = time.monotonic_ns()
        time.sleep(duration_s)
        t_end = time.monotonic_ns()
        writes = bridge.call("writes", name="ins", timeout_s=10.0).get("write_end_ns", [])
        stop_daemon(daemon, 10.0)
        log.close()
        done.set()
        th.join(2.0)
    finally:
        stop_hil(daemon, bridge)

    cycles = []
    for line in (run_dir / "telemetry.jsonl").open(encoding="utf-8"):
        try:
            r = json.loads(line)
        except ValueError:
            continue
        if r.get("type") == "cycle" and r.get("ins_rx_ns") and t_armed <= r["t_ns"] <= t_end:
            cycles.append((r["ins_rx_ns"], r["t_ns"]))
    shutil.rmtree(run_dir, ignore_errors=True)
    writes = sorted(writes)
    seen = sorted(seen)
    total, pty, wait, out = [], [], [], []
    for rx, tc in cycles:
        i = bisect.bisect_right(writes, rx) - 1   # the frame received at rx
        j = bisect.bisect_left(seen, tc)           # the cycle's RPDO
        if i < 0 or j >= len(seen):
            continue
        w, b = writes[i], seen[j]
        if rx - w > 50_000_000:  # no write within 50 ms before: not that frame
            continue
        total.append(b - w)
        pty.append(rx - w)
        wait.append(tc - rx)
        out.append(b - tc)
    s = 1e-9
    return {
        "rate_hz": cfg.loop.rate_hz,
        "trigger": cfg.loop.trigger,
        "ins_rate_hz": cfg.simulation.instruments.ins_rate_hz,
        "sched_fifo_priority": sched_fifo,
        "duration_s": duration_s,
        "frames": len(total),
        "latency_ms": percentiles(np.asarray(total) * s, 1e3),
        "pty_ms": percentiles(np.asarray(pty) * s, 1e3),
        "wait_for_cycle_ms": percentiles(np.asarray(wait) * s, 1e3),
        "cycle_to_bus_ms": percentiles(np.asarray(out) * s, 1e3),
        "can_interface": cfg.can.bus.interface,
        "daemon_cpu_affinity": list(cfg.loop.cpu_affinity),
        "sim_bridge_args": bridge_args,
    }


def _run(args) -> dict:
    load = os.getloadavg()[0]
    runs: dict[str, Any] = {"loadavg_1min_at_start": load}
    for rate in args.rate or [None]:
        for trigger in TRIGGERS:
            f = measure(args.duration, rate_hz=rate, sched_fifo=args.sched_fifo,
                        base=args.config, trigger=trigger)
            runs[f"{f['rate_hz']:g}hz_{trigger}"] = f
            _print(f)
    return runs


def _print(f: dict) -> None:
    lat = f["latency_ms"]
    print(f"uvd bench latency: loop {f['rate_hz']:g} Hz, trigger {f['trigger']} (INS "
          f"{f['ins_rate_hz']:g} Hz, SCHED_FIFO {f['sched_fifo_priority']}), {f['frames']} INS "
          f"frames, load {os.getloadavg()[0]:.2f}")
    if f["frames"]:
        print(f"  INS frame written → RPDO on the bus: median {lat['p50']:.2f} ms, "
              f"p99 {lat['p99']:.2f} ms, max {lat['max']:.2f} ms")
        for k, label in (("pty_ms", "pty → decoded"), ("wait_for_cycle_ms", "wait for cycle"),
                         ("cycle_to_bus_ms", "cycle → bus")):
            print(f"    {label:<16} median {f[k]['p50']:.3f} ms  p99 {f[k]['p99']:.3f} ms")


BENCH = Bench(name="latency", summary="End-to-end latency: INS frame written by the emulator → "
                                      "amplifier RPDO on the bus (sim-bridge + uvd run)",
              run=_run, add_arguments=_add)
