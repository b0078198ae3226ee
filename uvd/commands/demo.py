"""``uvd demo``: the hardware-in-the-loop demo on the embedded default configuration.

Two processes, as on the vehicle: ``sim-bridge`` (the simulated JHU ROV in real time — plant,
INS/DVL/Digiquartz on pseudo-terminals, six CiA 402 amplifiers and a CiA 404 pressure
transmitter on a ``udp_multicast`` CAN bus that never leaves this machine) and ``uvd run``
(the daemon, connecting to them exactly as to hardware). The daemon arms as soon as its
arming checks pass and tracks RefTraj1 (Table 5.1) with two-step AMBC, robust adaptation on
(``config/sim.toml``). Afterwards the demo prints the tracking error per DOF (true state vs
reference), the loop statistics, the failsafe events and the memory of both processes, and
compares the tracking error with a lockstep simulation of the same configuration (the same
core, no I/O, simulated clock) and the same seed: both draw each instrument's noise per frame
from the seed (frame f after arming carries the same noise in both,
:mod:`sim_bridge.instruments.models`, "Noise streams"), so the ratio measures the daemon's
timing, not two draws of dead reckoning's random walk — and with the spread of
``SPREAD_SEEDS`` lockstep runs of other seeds, how wide that walk is.
``--config config/sim-bluerov2.toml`` runs the BlueROV2 Heavy. ``--fault thruster:4:0.5@30``
weakens a thruster during the run, uvd-fdc detects it over Zenoh and the daemon accommodates
it; the demo prints the times fault → detection → reallocation (:mod:`uvd.commands.demo_fault`;
no lockstep comparison then).

Every process is bounded in time and killed in all cases. ``--record DIR`` keeps the run:
configuration, telemetry, truth log, CAN log, both processes' logs and the figures.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import queue
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from uvd import _jitcache
from uvd.cliargs import nonnegative_int, output_file, output_folder, positive_float_upto
from uvd.jsonio import write_json
from uvd.runtime.process import stop_daemon

#: lockstep runs (seeds seed … seed + SPREAD_SEEDS − 1) whose spread the HIL run is set against
SPREAD_SEEDS = 5
#: the longest --duration: its lockstep twins (SPREAD_SEEDS of them, computed before the run,
#: ~5 s a simulated hour each on a 2-core VM) and their logs in memory grow with it; 1e9 s
#: asked numpy for 75 GiB and ended in a traceback (session 33)
MAX_DURATION_S = 86400.0


def register(sub) -> None:
    p = sub.add_parser("demo", help="hardware-in-the-loop demo: sim-bridge + uvd run, "
                                    "RefTraj1 with two-step AMBC",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--duration", type=positive_float_upto(MAX_DURATION_S), default=60.0,
                   metavar="S", help=f"seconds of armed tracking (default 60, at most "
                                     f"{MAX_DURATION_S:g}: a day; the lockstep twin of the "
                                     "run is computed first)")
    p.add_argument("--json", type=output_file, metavar="OUT", help="write the figures to this file")
    p.add_argument("--record", type=output_folder, metavar="DIR",
                   help="keep the run's files (config, telemetry, truth, CAN log, logs) in "
                        "DIR, which must not hold another run's")
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="base configuration (default: the embedded config/sim.toml)")
    p.add_argument("--seed", type=nonnegative_int, default=0,
                   help="seed of the simulated instruments")
    p.add_argument("--fault", metavar="thruster:I:ETA@T",
                   help="T s after arming thruster I keeps ETA of its thrust (sim-bridge); "
                        "uvd-fdc detects it over Zenoh, the daemon confirms and reallocates "
                        "(uvd.commands.demo_fault)")
    p.add_argument("--accept", choices=("confirm", "advisory", "auto"), default=None,
                   help="with --fault: [faults.fdc] accept (default confirm)")
    p.add_argument("--false-alarm", action="store_true",
                   help="with --fault: also put a fault sample naming a healthy thruster 5 s "
                        "before the fault, as a false alarm of uvd-fdc would")
    p.set_defaults(handler=_run)


# ----------------------------------------------------------------------------- helpers

def _rss_mb(pid: int | None) -> tuple[float, float]:
    """(VmRSS, VmHWM) of a process in MB (NaN when gone)."""
    if pid is None:
        return math.nan, math.nan
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return math.nan, math.nan
    vals = {}
    for line in text.splitlines():
        if line.startswith(("VmRSS:", "VmHWM:")):
            k, v = line.split(":", 1)
            vals[k] = int(v.split()[0]) / 1024.0
    return vals.get("VmRSS", math.nan), vals.get("VmHWM", math.nan)


def lockstep_sim(cfg, seed: int):
    """The same configuration in lockstep simulation: the daemon's very cycle
    (:func:`uvd.runtime.build.make_cycle`: the same core, failsafes and lifecycle), armed from
    the start."""
    from uvd.lockstep import lockstep_config, of_config
    return of_config(cfg, lockstep_config(cfg, seed))


def lockstep_run(cfg, duration_s: float, seed: int):
    """:func:`lockstep_sim` run for ``duration_s``; the log (its ``supervisor`` keeps the
    failsafe events)."""
    from uvd.lockstep import run

    sim = lockstep_sim(cfg, seed)
    log = run(sim, duration_s)
    log.failsafe_events = sim.supervisor.failsafe_events()
    return log


def lockstep_tracking(log, end_s: float | None = None) -> dict[str, Any]:
    """Tracking errors of a lockstep log over [0, end_s) (the HIL run's armed span)."""
    from uvd.lockstep import tracking_errors
    out = tracking_errors(log, 0.0, end_s)
    out["wall_s"] = log.wall_s
    out["cycles_not_ok"] = int(sum(s != "ok" for s in log.status))
    return out


def _memory(samples: list[tuple[float, float, float]], duration_s: float) -> dict[str, Any]:
    """Growth of the daemon's RSS: over the last 8 minutes of a run of ≥ 10 minutes, else over
    the last 80 % of the run; each end is the median of the samples within 5 s of it."""
    if not samples:
        return {}
    a = np.asarray(samples, dtype=float)
    t_end = a[-1, 0]
    if duration_s >= 600.0:
        window, note = 480.0, "growth over the last 8 minutes"
    else:
        window = 0.8 * duration_s
        note = "run shorter than 10 min: growth over the last 80 % of it"
    t0 = t_end - window

    def around(t: float, col: int) -> float:
        sel = np.abs(a[:, 0] - t) <= 5.0
        vals = a[sel, col]
        vals = vals[np.isfinite(vals)]
        return float(np.median(vals)) if vals.size else math.nan

    return {"daemon_rss_growth_mb": around(t_end, 1) - around(t0, 1),
            "bridge_rss_growth_mb": around(t_end, 2) - around(t0, 2),
            "growth_window_s": window, "growth_note": note,
            "daemon_rss_end_mb": around(t_end, 1)}


class _LineTail:
    """Collects a child's stderr lines into a file and a queue (a daemon thread)."""

    def __init__(self, stream, path: Path) -> None:
        self.q: queue.Queue[str] = queue.Queue()
        self.lines: list[str] = []
        self._fh = path.open("w", encoding="utf-8")
        self._t = threading.Thread(target=self._run, args=(stream,), daemon=True)
        self._t.start()

    def _run(self, stream) -> None:
        for raw in stream:
            line = raw.rstrip("\n")
            self._fh.write(line + "\n")
            self._fh.flush()
            self.lines.append(line)
            del self.lines[:-200]
            self.q.put(line)
        self._fh.close()

    def tail(self, n: int = 15) -> str:
        return "\n".join(self.lines[-n:])


# ----------------------------------------------------------------------------- the demo

def _fmt_table(hil: dict, lock: dict) -> str:
    from uvd.lockstep import DOF_NAMES, VEL_NAMES
    lines = [f"{'DOF':>8} {'position MAE':>14} {'lockstep':>12} {'ratio':>6}   "
             f"{'velocity MAE':>14}"]
    for i, (pn, vn) in enumerate(zip(DOF_NAMES, VEL_NAMES, strict=True)):
        pe, le = hil["position_mae"][pn], lock["position_mae"][pn]
        ve = hil["velocity_mae"][vn]
        ratio = pe / le if le > 0 else math.nan
        if i < 3:
            lines.append(f"{pn:>8} {pe:>11.4f} m  {le:>9.4f} m  {ratio:>5.2f}   "
                         f"{ve:>9.4f} m/s")
        else:
            lines.append(f"{pn:>8} {math.degrees(pe):>9.3f} deg  {math.degrees(le):>7.3f} deg  "
                         f"{ratio:>5.2f}   {math.degrees(ve):>7.3f} deg/s")
    return "\n".join(lines)


def _figures(cfg, duration_s: float, seed: int, run_dir: Path, truth_path: Path,
             summary_path: Path, lock_log, watch: dict[str, Any], code: int, stop_s: float,
             bridge_stats: dict, prio, ready: dict, start_s: float,
             spread_logs: tuple = ()) -> dict[str, Any]:
    """The demo's figures from what the run left behind (summary, telemetry, truth);
    ``spread_logs``: lockstep runs of the same configuration with other seeds."""
    from sim_bridge.bridge import read_truth
    from uvd.lockstep import hil_tracking
    c = cfg.control
    samples, loads, steal = watch["samples"], watch["loads"], watch["steal"]
    daemon_hwm, bridge_hwm = watch["daemon_hwm"], watch["bridge_hwm"]
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else {}
    loop = summary.get("loop", {})
    fs_events = [e for e in summary.get("failsafe_events", []) if e.get("type") == "failsafe"]
    lifecycle = [e for e in summary.get("failsafe_events", [])
                 if e.get("type") == "lifecycle"]
    hil = hil_tracking(run_dir / "telemetry.jsonl", read_truth(truth_path)) \
        if truth_path.is_file() and (run_dir / "telemetry.jsonl").is_file() \
        else {"samples": 0}
    ended = watch.get("ended")
    mem = _memory(samples, duration_s if ended is None else ended["after_s"])
    mem["daemon_peak_rss_mb"] = daemon_hwm
    mem["bridge_peak_rss_mb"] = bridge_hwm
    figures: dict[str, Any] = {
        "duration_s": duration_s,
        "config": {"controller": c.controller, "model": c.model,
                   "robust_adaptation": c.robust_adaptation, "reference": c.reference,
                   "rate_hz": cfg.loop.rate_hz, "vehicle": cfg.vehicle.name, "seed": seed},
        "loop": {k: loop.get(k) for k in ("rate_hz", "cycles", "overruns", "skipped",
                                           "max_overrun_streak", "cycle_errors",
                                           "lateness_us", "compute_us", "timer")},
        "tracking": hil,
        "failsafe_events": fs_events,
        "lifecycle": lifecycle,
        "memory": mem,
        "ended_during_run": ended,
        "daemon": {"exit_code": code, "stop_s": stop_s,
                   "shutdown": summary.get("shutdown", {}).get("steps"),
                   "counters": summary.get("daemon"),
                   "warm_up_and_start_s": start_s},
        "sim_bridge": {"counters": bridge_stats.get("counters"),
                       "ports": bridge_stats.get("ports")},
        # scheduling of every thread of both processes (uvd.rtthreads)
        "realtime": {"daemon": summary.get("realtime"),
                     "sim_bridge": {"sched_fifo_priority": prio,
                                    "threads": ready.get("threads"),
                                    "messages": ready.get("thread_messages")}},
        "load_average_1min": {"min": min(loads), "max": max(loads),
                              "mean": sum(loads) / len(loads)} if loads else None,
        "host_steal": _steal_summary(steal),
    }
    if hil.get("samples") and lock_log is not None:
        # the same span of tracking: a run cut short by a failsafe disarm compares with
        # the lockstep run's same first seconds (dead-reckoning drift grows with time)
        lock = lockstep_tracking(lock_log, hil["duration_s"] + 1.0 / cfg.loop.rate_hz)
        ratio = {k: hil["position_mae"][k] / v if v > 0 else math.nan
                 for k, v in lock["position_mae"].items()}
        figures["lockstep"] = {"span_s": hil["duration_s"],
                               "position_mae": lock["position_mae"],
                               "velocity_mae": lock["velocity_mae"],
                               "position_mne": lock["position_mne"],
                               "velocity_mne": lock["velocity_mne"],
                               "ratio": ratio,
                               "within_25pct": {k: bool(abs(r - 1.0) <= 0.25)
                                                for k, r in ratio.items()},
                               # the same supervised cycle: its failsafes, as the HIL run's
                               "failsafe_events": [e for e in lock_log.failsafe_events
                                                   if e.get("type") == "failsafe"],
                               "cycles_not_ok": lock["cycles_not_ok"]}
        if spread_logs:
            figures["lockstep"]["seed_spread"] = _seed_spread(
                [lock_log, *spread_logs], hil, hil["duration_s"] + 1.0 / cfg.loop.rate_hz)
    return figures


def _seed_spread(logs, hil: dict, end_s: float) -> dict[str, Any]:
    """Position MAE per DOF over lockstep runs with different seeds (the instruments' noise
    and DVLNAV scale error differ): min and max, and whether the HIL figure lies within
    [0.75 min, 1.25 max] — where dead reckoning's random walk dominates (x, y of a vehicle
    that tracks to millimetres), one seed's lockstep run is not a prediction of another's."""
    maes = [lockstep_tracking(log, end_s)["position_mae"] for log in logs]
    out: dict[str, Any] = {"seeds": len(logs), "min": {}, "max": {}, "within_25pct": {}}
    for k in maes[0]:
        lo, hi = min(m[k] for m in maes), max(m[k] for m in maes)
        out["min"][k], out["max"][k] = lo, hi
        out["within_25pct"][k] = bool(0.75 * lo <= hil["position_mae"][k] <= 1.25 * hi)
    return out


def _watch(daemon, bridge, armed_at: float, duration_s: float, events: list[str], pump,
           tail, progress) -> dict[str, Any]:
    """Follow the run for ``duration_s`` after arming: the daemon's log lines, both processes'
    memory, the load average and the host's steal, a progress line every 10 s. Ctrl-C ends
    the watch early (``interrupted_s``: seconds since arming): the run is then stopped and
    reported over the seconds it ran (in a terminal the daemon had the SIGINT too and is
    stopping in order; sim-bridge, in a session of its own, runs until stopped). SIGTERM and
    SIGHUP unwind at once, as in every command.

    Meanwhile SIGINT only sets a flag, read within a second: a KeyboardInterrupt raised in
    the wait for the daemon's next log line can leave that queue's lock broken, and the demo
    then ended in "RuntimeError: release unlocked lock" (once in a fresh clone's tests). A
    SIGINT ignored when the demo started (a background job) stays ignored."""
    samples: list[tuple[float, float, float]] = []
    loads: list[float] = []  # 1-minute load average, once a second
    steal: list[tuple[float, float]] = []  # (monotonic s, cumulative steal s), ~1 Hz
    ctrl_c = threading.Event()
    own = threading.current_thread() is threading.main_thread() \
        and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    before = signal.signal(signal.SIGINT, lambda *_: ctrl_c.set()) if own else None
    try:
        ended = _follow(daemon, bridge, armed_at, duration_s, events, pump, tail, progress,
                        samples, loads, steal, ctrl_c)
    finally:
        if own:
            signal.signal(signal.SIGINT, before)
    interrupted_s = time.monotonic() - armed_at if ctrl_c.is_set() else None
    if interrupted_s is not None:
        progress(f"uvd demo: interrupted {interrupted_s:.0f} s into the run: stopping both "
                 "processes, then the figures of the seconds run (Ctrl-C again to quit "
                 "without them)")
    # the kernel's peak; of a process already gone (the daemon ends at a Ctrl-C too) the
    # largest sample
    peaks = [_rss_mb(daemon.pid)[1], _rss_mb(bridge.pid)[1]]
    for i, peak in enumerate(peaks):
        seen = [x[i + 1] for x in samples if math.isfinite(x[i + 1])]
        if math.isnan(peak) and seen:
            peaks[i] = max(seen)
    return {"samples": samples, "loads": loads, "steal": steal, "daemon_hwm": peaks[0],
            "bridge_hwm": peaks[1], "interrupted_s": interrupted_s, "ended": ended}


def _follow(daemon, bridge, armed_at: float, duration_s: float, events: list[str], pump,
            tail, progress, samples: list, loads: list, steal: list,
            ctrl_c: threading.Event) -> dict[str, Any] | None:
    """:func:`_watch`'s loop: appends a sample a second until ``duration_s`` after arming,
    the exit of either process or ``ctrl_c``. Returns which process was seen to have ended
    by itself, when (seconds after arming) and its exit code; None if neither did."""
    from uvd.bench import host_steal_s
    next_report = 10.0
    while True:
        el = time.monotonic() - armed_at
        if el >= duration_s:
            break
        pump(min(1.0, duration_s - el))
        if ctrl_c.is_set():  # the daemon had it too: its exit is no news
            break
        rd, _ = _rss_mb(daemon.pid)
        rb, _ = _rss_mb(bridge.pid)
        samples.append((time.monotonic() - armed_at, rd, rb))
        with contextlib.suppress(OSError, ValueError):
            loads.append(float(Path("/proc/loadavg").read_text().split()[0]))
        st = host_steal_s()
        if st is not None:
            steal.append((time.monotonic(), st))
        if daemon.poll() is not None:
            progress("uvd demo: the daemon exited during the run:\n" + tail.tail())
            return {"process": "daemon", "after_s": el, "exit_code": daemon.returncode}
        if bridge.proc.poll() is not None:  # the vehicle is gone: nothing more to measure
            code = bridge.proc.returncode
            progress(f"uvd demo: sim-bridge, the simulated vehicle, exited during the run "
                     f"({_exit_words(code)}): stopping the daemon"
                     + (f"; its last words:\n{bridge.stderr_tail().rstrip()}"
                        if bridge.stderr_tail().strip() else ""))
            return {"process": "sim-bridge", "after_s": el, "exit_code": code}
        if el >= next_report:
            next_report += 10.0
            n_fs = sum("failsafe fired" in e for e in events)
            progress(f"  {el:5.0f} / {duration_s:g} s   daemon RSS {rd:6.1f} MB   sim-bridge "
                     f"RSS {rb:6.1f} MB   failsafe events {n_fs}")
    return None


def _stop(daemon, bridge, pump) -> tuple[int, float, dict]:
    """SIGTERM to the daemon as systemd would (killed after 5 s), then the bridge; returns
    the daemon's exit code, how long it took to stop and the bridge's statistics."""
    t_sig = time.monotonic()
    code = stop_daemon(daemon)
    stop_s = time.monotonic() - t_sig
    pump(0.5)
    bridge_stats = bridge.stop(timeout_s=10.0) or {}
    bridge.kill()

    return code, stop_s, bridge_stats


def _listener_moves(cfg) -> tuple[dict[str, Any], list[str]]:
    """The configuration's listeners (Zenoh, MAVLink) whose port another process holds now —
    a second demo, a daemon, another program — moved to a free port of the same host, and
    the lines that say so. Free ones stay where ``uvd watch`` and MAVProxy look by default:
    before, a second demo ran without both links ("sink … did not open")."""
    from uvd.netports import free_port, port_taken
    from uvd.zenoh_names import endpoint_address
    changes: dict[str, Any] = {}
    said: list[str] = []
    z = cfg.telemetry.zenoh
    if z.enabled:
        listen = list(z.listen)
        for i, ep in enumerate(listen):
            a = endpoint_address(ep)
            if a and a[0] in ("tcp", "udp") and port_taken(a[0], a[1].strip("[]"), a[2]):
                listen[i] = f"{a[0]}/{a[1]}:{free_port(a[0], a[1].strip('[]'))}"
                said.append(f"  Zenoh: {ep} is taken (another daemon or demo?): this run "
                            f"listens on {listen[i]}")
        if said:
            changes["telemetry"] = {"zenoh": {"listen": listen}}
    mav = cfg.mavlink
    host, _, port = (mav.listen or "").rpartition(":")
    if mav.enabled and port.isdigit() and int(port) and port_taken("udp", host.strip("[]"),
                                                                   int(port)):
        moved = f"{host}:{free_port('udp', host.strip('[]'))}"
        changes["mavlink"] = {"listen": moved}
        said.append(f"  MAVLink: udp {mav.listen} is taken (another daemon or demo?): this "
                    f"run listens on udp {moved}")
    return changes, said


def _local_config(run_dir: Path, base, changes: dict[str, Any]):
    """The run's configuration (``sim_bridge.bridge.write_local_config``), with its taken
    listeners moved (:func:`_listener_moves`): its path, the loaded one and what to say."""
    from sim_bridge.bridge import merge_tables, write_local_config
    from uvd.runtime.config import load_config
    cfg_path = write_local_config(run_dir, base=base, changes=changes)
    cfg = load_config(cfg_path)
    moves, said = _listener_moves(cfg)
    if moves:
        merge_tables(changes, moves)
        cfg_path = write_local_config(run_dir, base=base, changes=changes)
        cfg = load_config(cfg_path)
    return cfg_path, cfg, said


# run_demo is long (~110 lines) because it owns two processes (sim-bridge and the daemon)
# for its whole duration: start, arm, watch and stop share one try/finally that kills both.
def run_demo(duration_s: float = 60.0, *, record: Path | None = None, base: Path | None = None,
             seed: int = 0, progress=print, fault=None, accept: str = "confirm",
             false_alarm: bool = False) -> tuple[dict[str, Any], int]:
    """Run the demo; returns (figures, exit code). See the module docstring; ``fault`` a
    :class:`~uvd.commands.demo_fault.FaultSpec` (exit code 1 unless it was accommodated)."""
    from sim_bridge.bridge import BridgeProcess, hil_scheduling, write_local_config
    from uvd.runtime.config import load_config

    tmp = None
    if record is not None:
        run_dir = Path(record).absolute()  # the configuration names files in it
        run_dir.mkdir(parents=True, exist_ok=True)
    else:
        tmp = tempfile.mkdtemp(prefix="uvd-demo-")
        run_dir = Path(tmp)
    bridge = daemon = fault_run = None
    try:
        # Real-time priority as on the vehicle (config/jhu-rov.toml): on a shared machine a
        # normally scheduled loop is sometimes descheduled for tens of ms. The simulated
        # devices run above the daemon (sim_bridge.bridge.hil_scheduling): real ones are
        # separate hardware. Neither is pinned to a CPU (measured: pinned, the loop was later).
        # Refused without the privilege: both processes say so and run normally scheduled.
        bridge_args, changes = hil_scheduling()
        if record:
            changes["can"] = {"log": {"path": str(run_dir / "can.log")}}
            changes["recording"] = {"enabled": True, "dir": str(run_dir)}
        if fault is not None:
            from uvd.commands import demo_fault
            vehicle = load_config(write_local_config(run_dir, base=base)).load_vehicle()
            changes.update(demo_fault.config_changes(fault, run_dir, vehicle, accept))
        cfg_path, cfg, moved = _local_config(run_dir, base, changes)
        c = cfg.control
        progress(f"uvd demo: {c.controller} ({c.model}, robust adaptation "
                 f"{'on' if c.robust_adaptation else 'off'}) tracking {c.reference} on "
                 f"'{cfg.vehicle.name}' at {cfg.loop.rate_hz:g} Hz for {duration_s:g} s, "
                 "hardware in the loop")
        for line in moved:
            progress(line)
        if _jitcache.cache_is_empty():
            progress("  compiling the numeric kernels first (once after an install or upgrade: "
                     "about a minute)")
        t0 = time.monotonic()
        lock_log, spread_logs = None, ()
        if fault is None:  # a faulty run is not the lockstep run's twin
            if duration_s > 600.0:  # 5 s a simulated hour and seed on a 2-core VM
                progress(f"  lockstep simulation of the same configuration first: "
                         f"{SPREAD_SEEDS} seeds × {duration_s:g} s simulated")
            lock_log = lockstep_run(cfg, duration_s, seed)
            spread_logs = tuple(lockstep_run(cfg, duration_s, seed + k)
                                for k in range(1, SPREAD_SEEDS))
            progress(f"  lockstep simulation of the same configuration: {lock_log.wall_s:.1f} "
                     f"s wall ({time.monotonic() - t0:.1f} s with compiling and "
                     f"{SPREAD_SEEDS - 1} more seeds)")

        # -- the two processes --
        truth_path = run_dir / "truth.bin"
        bound = duration_s + 300.0  # a loaded machine takes minutes to arm (compiling)
        bridge = BridgeProcess(cfg_path, duration_s=bound, seed=seed, hold=True,
                               truth_log=truth_path, extra=bridge_args)
        bridge.start(timeout_s=120.0)
        prio = (bridge.ready or {}).get("realtime")
        rt = f"SCHED_FIFO {prio}" if prio else "normal scheduling"
        progress(f"  sim-bridge up (pid {bridge.pid}, {rt}): ptys in {run_dir}, CAN "
                 f"{cfg.can.bus.interface} {cfg.can.bus.channel} port {cfg.can.bus.port}")
        summary_path = run_dir / "daemon-summary.json"
        daemon = subprocess.Popen(
            [sys.executable, "-m", "uvd", "run", "--config", str(cfg_path), "--arm",
             "--stop-with-parent", str(os.getpid()),
             "--duration", str(bound), "--summary-json", str(summary_path)],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            text=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        tail = _LineTail(daemon.stderr, run_dir / "daemon.log")
        events: list[str] = []

        def pump(wait_s: float = 0.0) -> None:
            deadline = time.monotonic() + wait_s
            while True:
                try:
                    line = tail.q.get(timeout=max(0.0, deadline - time.monotonic()))
                except queue.Empty:
                    return
                if "failsafe fired" in line or "lifecycle" in line or "ERROR" in line \
                        or "SCHED_FIFO" in line or "recording: " in line \
                        or "telemetry: sink" in line:  # a full disk, told by spells
                    events.append(line)
                    progress(f"  daemon: {line.split(': ', 1)[-1]}")

        t_start = time.monotonic()
        armed_at = None
        while armed_at is None:
            pump(0.2)
            if any("→ ARMED" in e for e in events):
                armed_at = time.monotonic()
            elif daemon.poll() is not None or time.monotonic() - t_start > 180.0:
                progress("uvd demo: the daemon did not arm:\n" + tail.tail()
                         + "\nsim-bridge's last words:\n" + bridge.stderr_tail())
                return {"error": "the daemon did not arm", "daemon_log": tail.tail(40),
                        "sim_bridge_log": bridge.stderr_tail()}, 1
        progress(f"  armed {armed_at - t_start:.1f} s after start; tracking for "
                 f"{duration_s:g} s")
        watched = pump
        if fault is not None:
            fault_run = demo_fault.FaultRun(fault, cfg, run_dir, progress, false_alarm)
            fault_run.start(bridge, armed_at)

            def watched(wait_s: float = 0.0) -> None:
                pump(wait_s)
                fault_run.poll(bridge)

        watch = _watch(daemon, bridge, armed_at, duration_s, events, watched, tail, progress)
        interrupted_s = watch["interrupted_s"]
        # -- stop: SIGTERM as systemd would --
        code, stop_s, bridge_stats = _stop(daemon, bridge, pump)
        # -- figures --
        ran_s = duration_s if interrupted_s is None else interrupted_s
        figures = _figures(cfg, ran_s, seed, run_dir, truth_path,
                           summary_path, lock_log, watch, code, stop_s, bridge_stats, prio,
                           bridge.ready or {}, armed_at - t_start, spread_logs)
        if interrupted_s is not None:
            figures["interrupted"] = {"after_s": interrupted_s, "of_s": duration_s}
        hil = figures["tracking"]
        fs_events = figures["failsafe_events"]
        _report(figures, progress)
        ok = code == 0 and bool(hil.get("samples")) and not fs_events \
            and figures["ended_during_run"] is None
        if fault_run is not None:
            figures["fault"] = f = fault_run.finish()
            fault_run = None
            if summary_path.is_file():  # the daemon's count of samples by outcome
                f["daemon_counts"] = json.loads(summary_path.read_text()).get("fault_samples")
            if interrupted_s is not None:
                f["interrupted_after_s"] = interrupted_s
            demo_fault.report(f, progress)
            ok = ok and (f.get("reallocated") is not None or accept == "advisory")
        if interrupted_s is not None:  # as any uvd command stopped by Ctrl-C
            return figures, 130
        return figures, 0 if ok else 1
    finally:
        if fault_run is not None:
            fault_run.finish()
        if daemon is not None and daemon.poll() is None:
            with contextlib.suppress(subprocess.TimeoutExpired):
                stop_daemon(daemon)
        if bridge is not None:
            bridge.kill()
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


def _steal_summary(steal: list[tuple[float, float]]) -> dict[str, float] | None:
    """Total steal over the run and its largest share of one sampling interval (per CPU)."""
    if len(steal) < 2:
        return None
    n_cpu = os.cpu_count() or 1
    shares = [(s1 - s0) / n_cpu / (t1 - t0)
              for (t0, s0), (t1, s1) in zip(steal, steal[1:], strict=False) if t1 > t0]
    return {"total_s": steal[-1][1] - steal[0][1], "max_share_per_interval": max(shares),
            "interval_s": (steal[-1][0] - steal[0][0]) / (len(steal) - 1)}


def _disp(dof: str, value: float) -> str:
    return f"{value:.4f} m" if dof in ("x", "y", "z") else f"{math.degrees(value):.3f}°"


def _report(f: dict, progress) -> None:
    hil = f["tracking"]
    if "interrupted" in f:
        progress(f"Interrupted after {f['interrupted']['after_s']:.0f} of "
                 f"{f['interrupted']['of_s']:g} s: the figures of the seconds run")
    if hil.get("samples") and "lockstep" not in f:  # a fault run: no lockstep twin
        progress(f"Tracking error, true state vs reference ({hil['samples']} cycles, "
                 f"{hil['duration_s']:.0f} s): " + ", ".join(
                     f"{k} {_disp(k, v)}" for k, v in hil["position_mae"].items()))
    elif hil.get("samples"):
        progress(f"Tracking error, true state vs reference ({hil['samples']} cycles, "
                 f"{hil['duration_s']:.0f} s), against lockstep simulation of the same "
                 "configuration:")
        progress(_fmt_table(hil, {"position_mae": f["lockstep"]["position_mae"]}))
        sp = f["lockstep"].get("seed_spread")
        if sp:
            rng = ", ".join(
                f"{k} {_disp(k, sp['min'][k])}–{_disp(k, sp['max'][k])}"
                f"{'' if sp['within_25pct'][k] else ' (HIL outside ±25 %)'}" for k in sp["min"])
            progress(f"lockstep over {sp['seeds']} seeds: {rng}")
        progress(f"MNE: position {hil['position_mne']:.4f} (lockstep "
                 f"{f['lockstep']['position_mne']:.4f}), velocity {hil['velocity_mne']:.4f} "
                 f"(lockstep {f['lockstep']['velocity_mne']:.4f})")
    else:
        progress("no armed cycles recorded: no tracking figures")
    lp = f["loop"]
    lat, comp = lp.get("lateness_us") or {}, lp.get("compute_us") or {}
    if lat:
        progress(f"Loop {lp['rate_hz']:g} Hz: {lp['cycles']} cycles, {lp['overruns']} overruns; "
                 f"lateness µs p50 {lat['p50']:.1f} p99 {lat['p99']:.1f} max {lat['max']:.1f}; "
                 f"compute µs p50 {comp['p50']:.0f} p99 {comp['p99']:.0f} (core + CAN sends)")
    rt = f.get("realtime") or {}
    for who, threads in (("daemon", (((rt.get("daemon") or {}).get("threads") or {}).get(
            "booted"))), ("sim-bridge", (rt.get("sim_bridge") or {}).get("threads"))):
        if threads:
            pols = sorted({f"{t['policy']} {t['priority']}" for t in threads})
            progress(f"Threads of the {who}: {len(threads)} ({', '.join(pols)})")
    la = f.get("load_average_1min")
    if la:
        progress(f"Load average (1 min) during the run: {la['min']:.2f}–{la['max']:.2f}")
    hs = f.get("host_steal")
    if hs:
        progress(f"CPU time taken by the VM host (steal): {hs['total_s']:.2f} s over the run, "
                 f"at most {100 * hs['max_share_per_interval']:.0f} % of a "
                 f"{hs['interval_s']:.1f} s interval")
    fs = f["failsafe_events"]
    progress(f"Failsafe events: {len(fs)}" + "".join(
        f"\n  {e['kind']}: {e['trigger']} → {e['action']} ({e['reason']})" for e in fs))
    m = f["memory"]
    progress(f"Memory: daemon peak RSS {m.get('daemon_peak_rss_mb', math.nan):.1f} MB, growth "
             f"{m.get('daemon_rss_growth_mb', math.nan):+.2f} MB ({m.get('growth_note', '')}); "
             f"sim-bridge peak RSS {m.get('bridge_peak_rss_mb', math.nan):.1f} MB")
    d, e = f["daemon"], f.get("ended_during_run")
    if e is None or e["process"] != "daemon":  # a SIGTERM of the demo's ended it
        how = "Ctrl-C, then SIGTERM" if "interrupted" in f else "SIGTERM"
        progress(f"{how} → daemon exit code {d['exit_code']} in {d['stop_s']:.2f} s")
    if e is not None:
        who = "The daemon" if e["process"] == "daemon" else "sim-bridge, the simulated vehicle,"
        progress(f"{who} ended by itself {e['after_s']:.0f} s after arming: "
                 f"{_exit_words(e['exit_code'])}")


def _exit_words(code: int | None) -> str:
    """A process's exit code said: "exit code 1", "exit code -9 (killed by SIGKILL)"."""
    if code is not None and code < 0 and -code in signal.valid_signals():
        return f"exit code {code} (killed by {signal.Signals(-code).name})"
    return f"exit code {code}"


#: what a recorded demo leaves in its folder (the black box's files are uvd-*.mcap)
RUN_FILES = ("demo.json", "uvd.toml", "telemetry.jsonl", "truth.bin", "can.log", "daemon.log")


def _a_run_in(folder: Path) -> str | None:
    """The files of an earlier recorded run in ``folder`` (a few, named), or None."""
    p = Path(folder)
    if not p.is_dir():
        return None
    found = [n for n in RUN_FILES if (p / n).exists()] + sorted(
        x.name for x in p.glob("uvd-*.mcap"))
    return ", ".join(found[:3]) + (", …" if len(found) > 3 else "") if found else None


def _run(args) -> int:
    fault = None
    if not args.fault and (args.accept or args.false_alarm):
        print("uvd demo: --accept and --false-alarm need --fault", file=sys.stderr)
        return 2
    if args.fault:
        from uvd.commands.demo_fault import FaultSpec
        try:
            fault = FaultSpec.parse(args.fault)
        except ValueError as exc:
            print(f"uvd demo: {exc}", file=sys.stderr)
            return 2
        if fault.at_s >= args.duration:  # it ran the whole demo and ended "no reallocation"
            print(f"uvd demo: --fault {args.fault!r}: T {fault.at_s:g} s is not within the "
                  f"run's {args.duration:g} s of armed tracking (--duration)", file=sys.stderr)
            return 2
    if args.config is not None:   # the user's file judged before anything starts
        from uvd.commands import checked_config
        if checked_config(args.config, "demo", "nothing started") is None:
            return 2
    held = _a_run_in(args.record) if args.record else None
    if held:  # a second run there overwrote the first's figures, telemetry and truth
        print(f"uvd demo: --record {args.record}: it holds a run already ({held}); give "
              "another folder, or remove that one: nothing started", file=sys.stderr)
        return 2
    figures, code = run_demo(args.duration, record=args.record, base=args.config,
                             seed=args.seed, fault=fault, accept=args.accept or "confirm",
                             false_alarm=args.false_alarm)
    if args.json:
        write_json(args.json, figures)
    if args.record:
        write_json(Path(args.record) / "demo.json", figures)
    return code
