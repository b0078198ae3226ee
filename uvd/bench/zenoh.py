"""``uvd bench zenoh --vehicles N --duration S``: a fleet publishing to one ``uvd-fdc``.

N simulated vehicles, each the daemon's own Zenoh sink (:class:`~uvd.links.zenoh.
ZenohSink`, peer mode, listening on a loopback port of its own), fed as the daemon's hub feeds
it: a cycle record every control cycle (``--rate``, 100 Hz), batched every
``flush_interval_s`` (50 ms), state published at ``--state-hz`` (20) and an AID estimate
(θ ∈ R²⁴¹) at ``--estimate-hz`` (10). One ``uvd-fdc`` process connects to every vehicle and
counts what arrives (``--stats``: per key received and lost by the gaps in ``seq``, latency
from each payload's ``wall_time`` to its receipt — one machine, one clock).

Figures: samples published and received, sample loss, end-to-end latency p50/p99, and the
daemon-side cost per control cycle — building the cycle record (on the loop's critical path
in the daemon), the sink's ``write`` (payloads, on the event loop's thread, off the critical
path) and the puts (in the sink's worker thread) — CPU time of the thread doing each.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from uvd.bench import Bench
from uvd.cliargs import positive_float, positive_int
from uvd.netports import free_port


def _add(p) -> None:
    p.add_argument("--vehicles", type=positive_int, default=20,
                   help="simulated vehicles (default 20)")
    p.add_argument("--duration", type=positive_float, default=10.0,
                   help="seconds of publishing (default 10)")
    p.add_argument("--rate", type=positive_float, default=100.0,
                   help="control cycles a second (100)")
    p.add_argument("--state-hz", type=positive_float, default=20.0, help="state rate (20 Hz)")
    p.add_argument("--estimate-hz", type=positive_float, default=10.0, help="estimate rate (10 Hz)")


class FdcProcess:
    """A ``uvd-fdc`` process connected to ``endpoints`` that counts what it receives
    (``--stats``). Its output goes to a file, never to a pipe nobody reads (a full pipe
    would stop its callbacks, and then its session's close).

    Parameters
    ----------
    endpoints : list of str
        What it connects to.
    seconds : float, optional
        It ends by itself this long after it subscribed; else :meth:`finish` interrupts it.
    """

    def __init__(self, endpoints: list[str], seconds: float | None = None) -> None:
        self.dir = Path(tempfile.mkdtemp(prefix="uvd-fdc-"))
        self.stats_path, self.log_path = self.dir / "stats.json", self.dir / "output.txt"
        cmd = [sys.executable, "-m", "uvd.fdc.client", "--stats", str(self.stats_path)]
        if seconds is not None:
            cmd += ["--seconds", str(seconds)]
        for ep in endpoints:
            cmd += ["--connect", ep]
        with self.log_path.open("w") as log:
            self.proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)

    def output(self) -> str:
        return self.log_path.read_text(errors="replace")

    async def subscribed(self, timeout_s: float = 60.0) -> None:
        """Wait for its "watching" line (its subscriptions declared)."""
        deadline = time.monotonic() + timeout_s
        while "watching" not in self.output():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"uvd-fdc did not start: {self.output()[-500:]!r}")
            await asyncio.sleep(0.1)

    def finish(self, timeout_s: float = 60.0) -> dict:
        """Wait for it to end (interrupt it first if it was given no ``seconds``); its
        counts (:class:`uvd.fdc.client.LinkStats`)."""
        try:
            if "--seconds" not in self.proc.args:
                self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.send_signal(signal.SIGINT)
                try:
                    self.proc.wait(10.0)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait()
            text = self.stats_path.read_text() if self.stats_path.exists() else ""
            if not text:
                raise RuntimeError(f"uvd-fdc (exit code {self.proc.returncode}) wrote no "
                                   f"counts; its output ends: {self.output()[-500:]!r}")
            return json.loads(text)
        finally:
            self.out = self.output()
            shutil.rmtree(self.dir, ignore_errors=True)


def _fmt(x) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.2f}"


def _thread_cpu(fn):
    """``fn`` with the CPU time of its calls (thread time, ns) summed in ``.ns``."""
    def timed(*args):
        t0 = time.thread_time_ns()
        try:
            return fn(*args)
        finally:
            timed.ns += time.thread_time_ns() - t0
    timed.ns = 0
    return timed


async def _publish(sinks, theta, args) -> dict:
    from uvd.bench.loop import bench_cycle_record

    period_ns = int(1e9 / args.rate)
    flush_ns = 50_000_000
    every_estimate = max(1, int(round(args.rate / args.estimate_hz)))
    batches: list[list[dict]] = [[] for _ in sinks]
    record_ns = write_ns = 0
    cycles = 0
    t0 = time.monotonic_ns()
    end = t0 + int(args.duration * 1e9)
    next_flush = t0 + flush_ns
    k = 0
    while True:
        now = time.monotonic_ns()
        if now >= end:
            break
        t_cycle = t0 + k * period_ns  # cycles due since the last flush, on their own stamps
        while t_cycle <= now:
            for i, batch in enumerate(batches):
                c0 = time.thread_time_ns()
                batch.append(bench_cycle_record(t_cycle, 1.0 / args.rate))
                if k % every_estimate == 0:
                    batch.append({"type": "estimate", "t_ns": t_cycle, "estimator": "aid6",
                                  "theta": theta, "m_min_eig": 90.0, "m_max_eig": 1100.0,
                                  "frozen": False, "freeze_reason": "", "steps": k,
                                  "velocity_error": 0.01})
                record_ns += time.thread_time_ns() - c0
                cycles += i == 0
            k += 1
            t_cycle = t0 + k * period_ns
        if now >= next_flush:
            next_flush += flush_ns
            for sink, batch in zip(sinks, batches, strict=True):
                if batch:
                    # CPU time only: waiting for the worker's puts costs this thread none
                    c0 = time.thread_time_ns()
                    await sink.write(batch)
                    write_ns += time.thread_time_ns() - c0
                    batch.clear()
        await asyncio.sleep(max(0.0, (min(next_flush, end) - time.monotonic_ns()) * 1e-9))
    return {"cycles_per_vehicle": cycles, "record_ns": record_ns, "write_ns": write_ns}


def _run(args) -> dict:
    import zenoh  # noqa: F401 - fail here, with its message, if the package is missing

    from uvd.io.vehicle import load_vehicle
    from uvd.links.zenoh import ZenohSink, zenoh_config

    theta = np.asarray(load_vehicle("jhu-rov").params.theta, dtype=float)
    endpoints = [f"tcp/127.0.0.1:{free_port()}" for _ in range(args.vehicles)]
    sinks = [ZenohSink(f"bench{i:02d}", zenoh_config(listen=[ep]), state_hz=args.state_hz,
                       health_hz=0.0)
             for i, ep in enumerate(endpoints)]
    for s in sinks:
        s._put_all = _thread_cpu(s._put_all)
    fdc = None

    async def main() -> dict:
        nonlocal fdc
        for s in sinks:
            await s.open()
        fdc = FdcProcess(endpoints, seconds=args.duration + 8.0)  # ends ~6 s after the last
        await fdc.subscribed()
        await asyncio.sleep(2.0)  # its subscriptions reach every vehicle
        try:
            return await _publish(sinks, theta, args)
        finally:
            for s in sinks:
                await s.aclose()

    wall0 = time.monotonic()
    try:
        pub = asyncio.run(main())
    finally:
        stats = fdc.finish() if fdc is not None else {}
    published = {k: n for s in sinks for k, n in s._seq.items()}  # key → samples sent
    received = stats.get("received", {})
    per_kind = {}
    for kind in ("state", "estimate"):
        keys = [k for k in published if k.split("/")[2] == kind]
        sent = sum(published[k] for k in keys)
        got = sum(received.get(k, 0) for k in keys)
        per_kind[kind] = {"published": sent, "received": got, "lost": sent - got,
                          "rate_hz_per_vehicle": sent / args.vehicles / args.duration}
    cycles = pub["cycles_per_vehicle"] * args.vehicles
    put_ns = sum(s._put_all.ns for s in sinks)
    lat = stats.get("latency_ms", {})
    figures = {
        "vehicles": args.vehicles, "duration_s": args.duration, "rate_hz": args.rate,
        "state_hz": args.state_hz, "estimate_hz": args.estimate_hz,
        "samples": per_kind,
        "sample_loss": sum(v["lost"] for v in per_kind.values()),
        "gaps_in_seq": sum(stats.get("lost", {}).values()),
        "latency_ms": lat,
        "publish_cost_us_per_cycle": {
            "record": pub["record_ns"] / cycles * 1e-3,
            "sink_write": pub["write_ns"] / cycles * 1e-3,
            "puts_worker": put_ns / cycles * 1e-3,
        },
        "cycles": cycles,
        "loadavg_1min": os.getloadavg()[0],
        "wall_s": time.monotonic() - wall0,
        "fdc_exit_code": fdc.proc.returncode,
        "fdc_output_tail": fdc.out.strip().splitlines()[-3:],
    }
    c = figures["publish_cost_us_per_cycle"]
    print(f"uvd bench zenoh: {args.vehicles} vehicles × {args.duration:g} s, state "
          f"{args.state_hz:g} Hz, estimates {args.estimate_hz:g} Hz → one uvd-fdc; load "
          f"{figures['loadavg_1min']:.2f}")
    for kind, v in per_kind.items():
        print(f"  {kind:<8}: published {v['published']}, received {v['received']}, lost "
              f"{v['lost']} ({v['rate_hz_per_vehicle']:.1f} Hz a vehicle)")
    print(f"  end-to-end latency ms: p50 {_fmt(lat.get('p50'))}  p99 {_fmt(lat.get('p99'))}  "
          f"max {_fmt(lat.get('max'))}  (n {lat.get('n', 0)})")
    print(f"  daemon-side cost µs a cycle: record {c['record']:.1f} (critical path), sink "
          f"write {c['sink_write']:.1f} (event loop), puts {c['puts_worker']:.1f} (worker)")
    return figures


BENCH = Bench(name="zenoh", summary="N simulated vehicles' Zenoh sinks publishing to one "
                                    "uvd-fdc: sample loss, end-to-end latency, publish cost",
              run=_run, add_arguments=_add)
