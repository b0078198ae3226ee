"""``uvd bench chaos``: the daemon soaked in every fault sim-bridge can make, with an operator.

Three real processes, as on the vehicle: ``sim-bridge`` (its control channel makes the
faults), ``uvd run`` (armed at its start, recording its black box) and this benchmark, which
is also the ground station (pymavlink over UDP loopback, the daemon's MAVLink link). For
``--minutes``, every 0.5–3 s one action drawn with ``--seed``: an instrument's fault
(silence, garbage, NaN, stuck; 0.2–4 s), one drive's CAN silence (0.1–1.5 s: it misses its
commands and faults), a drive's EMCY, a thruster's health, a bus-off (0.1–0.5 s), a leak
(0.2–2 s), a full disk under the daemon (0.2–3 s: ``prlimit`` RLIMIT_FSIZE 1 byte on its
pid, every write to a file fails as on a full disk), the operator's arm, disarm, mode, manual
control or failsafe reset, a SIGHUP reload. Every ``--check-every`` seconds a **recovery
check**: sim-bridge's faults cleared (its ``reset``: the drives reboot, the instruments are
well again), 2 s, the operator's failsafe reset (MAVLink 31011), then arm; it passes when the
vehicle reports armed within 10 s.

Figures: recovery checks passed of those run; the actions by kind; station calls that got no
answer; the daemon's exit code, its cycles and overruns and its memory (RSS) at the first and
last sample; and from its recording: cycles with thrust where there must be none (a
zero-thrust or disarm action, or disarmed — hold-depth's vertical thrust is allowed),
non-finite commands, ``uvd replay --lockstep``'s mismatches over the whole run (every
command, reset and recovery included), the recording's failures told to the operator
(``/uvd/sink``: failing and working again, by sink) and, after the soak and one telling hold,
whether the last told of each was "writes again" and the station's SYS_STATUS says logging
healthy.
"""

from __future__ import annotations

import contextlib
import glob
import json
import os
import random
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from uvd.bench import Bench, stop_hil
from uvd.cliargs import nonnegative_int, positive_float
from uvd.links.mavlink.station import GroundStation
from uvd.runtime.process import stop_daemon

#: MAVLink custom mode numbers the operator picks from (docs/mavlink.md)
_MODES = (1, 2, 3, 4, 5, 6, 7)


def _add(p) -> None:
    p.add_argument("--minutes", type=positive_float, default=4.0,
                   help="minutes of faults (default 4)")
    p.add_argument("--seed", type=nonnegative_int, default=2,
                   help="seed of the drawn actions (default 2)")
    p.add_argument("--check-every", type=positive_float, default=25.0, metavar="S",
                   help="seconds between recovery checks (default 25)")
    p.add_argument("--config", default=None, metavar="FILE",
                   help="base configuration: a file or a shipped one's name, e.g. "
                        "sim-bluerov2 (default: the embedded config/sim.toml)")


def _ack(st: GroundStation, cmd: int, *params: float) -> int | None:
    """COMMAND_LONG ``cmd``'s MAV_RESULT, or None: no COMMAND_ACK within 15 s."""
    ack = st.command(cmd, *params, timeout_s=15.0)
    return None if ack is None else int(ack.result)


def _manual(st: GroundStation, rng: random.Random) -> None:
    """One MANUAL_CONTROL of random sticks (x, y, r: ±1000; z: 0–1000), buttons none."""
    st.send("manual_control", st.target[0], rng.randint(-1000, 1000),
            rng.randint(-1000, 1000), rng.randint(0, 1000), rng.randint(-1000, 1000), 0)


def _armed(st: GroundStation, timeout_s: float) -> bool:
    """Whether the vehicle's HEARTBEAT says armed within ``timeout_s``."""
    st.drain()  # a heartbeat from before the arm would answer for it
    return st.wait("HEARTBEAT", lambda m: m.get_srcSystem() == st.target[0]
                   and bool(m.base_mode & st.mav.MAV_MODE_FLAG_SAFETY_ARMED),
                   timeout_s) is not None


def _rss_kb(pid: int) -> int | None:
    with contextlib.suppress(OSError, StopIteration):
        with open(f"/proc/{pid}/status") as fh:
            return next(int(x.split()[1]) for x in fh if x.startswith("VmRSS"))
    return None


def _act(rng: random.Random, bridge, st: GroundStation, daemon, nodes: list[int]
         ) -> tuple[str, Any]:
    """One drawn action (``nodes``: the amplifiers' node ids): its kind and what answered
    it."""
    mav = st.mav
    kind = rng.choice(["sensor", "sensor", "can_silence", "can_fault", "can_health", "bus_off",
                       "leak", "disk_full", "arm", "disarm", "mode", "manual", "reload",
                       "reset"])
    if kind == "sensor":
        name = rng.choice(["ins", "dvl", "depth"])
        modes = ["silence", "garbage", "stuck"] + ([] if name == "depth" else ["nan"])
        return kind, bridge.call("sensor", name=name, mode=rng.choice(modes),
                                 seconds=round(rng.uniform(0.2, 4.0), 2)).get("ok")
    if kind == "can_silence":
        return kind, bridge.call("silence", node=rng.choice(nodes),
                                 seconds=round(rng.uniform(0.1, 1.5), 2)).get("ok")
    if kind == "can_fault":
        return kind, bridge.call("fault", node=rng.choice(nodes)).get("ok")
    if kind == "can_health":
        return kind, bridge.call("health", node=rng.choice(nodes),
                                 value=round(rng.uniform(0.2, 1.0), 2)).get("ok")
    if kind == "bus_off":
        return kind, bridge.call("bus_off", seconds=round(rng.uniform(0.1, 0.5), 2)).get("ok")
    if kind == "leak":
        bridge.call("leak", wet=True)
        time.sleep(rng.uniform(0.2, 2.0))
        return kind, bridge.call("leak", wet=False).get("ok")
    if kind == "disk_full":
        soft, hard = resource.prlimit(daemon.pid, resource.RLIMIT_FSIZE)
        resource.prlimit(daemon.pid, resource.RLIMIT_FSIZE, (1, hard))
        try:
            time.sleep(rng.uniform(0.2, 3.0))
        finally:
            resource.prlimit(daemon.pid, resource.RLIMIT_FSIZE, (soft, hard))
        return kind, True
    if kind in ("arm", "disarm"):
        return kind, _ack(st, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if kind == "arm" else 0.0)
    if kind == "mode":
        return kind, _ack(st, mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                          rng.choice(_MODES))
    if kind == "manual":
        for _ in range(10):
            _manual(st, rng)
            time.sleep(0.05)
        return kind, True
    if kind == "reload":
        os.kill(daemon.pid, signal.SIGHUP)
        return kind, True
    return kind, _ack(st, 31011, 0)


def _recording_figures(run_dir: Path) -> dict[str, Any]:
    from uvd.runtime.replay.lockstep import replay_lockstep
    from uvd.telemetry.recording import read_messages
    files = sorted(glob.glob(str(run_dir / "rec" / "*.mcap")))
    if len(files) != 1:
        return {"recording_files": len(files)}
    n = must_be_zero = nonfinite = 0
    for _, _, m in read_messages(files[0], ["/uvd/cycle"]):
        n += 1
        th = np.asarray(m["thrust"], dtype=float)
        nonfinite += not bool(np.all(np.isfinite(th)))
        if (m["action"] in ("zero-thrust", "disarm") or m["state"] != "ARMED"
                and m["action"] != "hold-depth") and bool(np.any(th != 0.0)):
            must_be_zero += 1
    told: dict[str, dict[str, Any]] = {}
    for _, _, m in read_messages(files[0], ["/uvd/sink"]):
        t = told.setdefault(m["sink"], {"failing": 0, "writes_again": 0})
        t["failing" if not m["ok"] else "writes_again"] += 1
        t["last_told_ok"] = bool(m["ok"])
    rep = replay_lockstep(files[0])
    return {"recorded_cycles": n, "cycles_with_thrust_where_none_allowed": must_be_zero,
            "nonfinite_commands": nonfinite, "recording_failures_told": told,
            "replay": {"cycles": rep.cycles, "mismatches": rep.mismatches,
                       "stopped": rep.stopped}}


def _logging_healthy(st: GroundStation) -> bool | None:
    """Whether the vehicle's next SYS_STATUS says its recording (MAV_SYS_STATUS_LOGGING)
    healthy; None: no SYS_STATUS within 5 s."""
    st.drain()
    m = st.wait("SYS_STATUS", None, 5.0)
    return None if m is None else bool(m.onboard_control_sensors_health
                                       & st.mav.MAV_SYS_STATUS_LOGGING)


def _link_port(log_path: Path, proc: subprocess.Popen, timeout_s: float) -> int:
    """The UDP port the daemon's MAVLink link bound (``listen`` port 0: the kernel's pick),
    from its log line "MAVLink link on udp HOST:PORT"."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end and proc.poll() is None:
        found = re.search(r"MAVLink link on udp \S+:(\d+) ", log_path.read_text(errors="replace"))
        if found:
            return int(found.group(1))
        time.sleep(0.1)
    raise RuntimeError(f"the daemon's MAVLink link did not bind within {timeout_s:g} s "
                       f"(exit code {proc.poll()}; its log {log_path})")


def _recovery_check(bridge, st: GroundStation) -> dict[str, Any]:
    """sim-bridge's faults cleared (its drives reboot), 2 s, the failsafe reset, arm: the
    answers, and whether the vehicle reported armed within 10 s (then back to auto)."""
    bridge.call("reset")
    time.sleep(2.0)
    reset = _ack(st, 31011, 0)
    time.sleep(0.3)
    arm = _ack(st, st.mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    armed = _armed(st, 10.0)
    _ack(st, st.mav.MAV_CMD_DO_SET_MODE, st.mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 1)
    return {"reset": reset, "arm": arm, "armed": armed}


def measure(minutes: float = 4.0, seed: int = 2, check_every_s: float = 25.0,
            base: str | None = None, progress=print) -> dict[str, Any]:
    """Run the soak (the module docstring) on configuration ``base`` and return its
    figures."""
    from sim_bridge.bridge import BridgeProcess, hil_scheduling, write_local_config
    from uvd.runtime.config import load_config
    from uvd.telemetry.sink import TELL_HOLD_S

    rng = random.Random(seed)
    run_dir = Path(tempfile.mkdtemp(prefix="uvd-chaos-"))
    bridge_args, changes = hil_scheduling()
    changes.update(
        # the disk's real room is not this soak's (a machine low on it would be told so)
        recording={"enabled": True, "dir": str(run_dir / "rec"), "min_free_mb": 0},
        telemetry={"jsonl": {"enabled": False}, "zenoh": {"enabled": False}},
        mavlink={"enabled": True, "listen": "127.0.0.1:0", "params_file": "",
                 "operator_timeout_s": 0.0,
                 "signing_timestamp_file": str(run_dir / "signing.ts")})
    cfg_path = write_local_config(run_dir, base=base, changes=changes)
    nodes = list(load_config(cfg_path).can.amplifiers.node_ids)
    soak_s = minutes * 60.0
    actions: dict[str, dict[str, int]] = {}
    checks: list[dict[str, Any]] = []
    rss: list[int] = []
    unanswered = 0
    bridge = daemon = st = None
    try:
        bridge = BridgeProcess(cfg_path, duration_s=soak_s + 180.0, hold=True,
                               extra=bridge_args).start(timeout_s=120.0)
        log = (run_dir / "daemon.log").open("w")
        daemon = subprocess.Popen(
            [sys.executable, "-m", "uvd", "run", "--config", str(cfg_path), "--arm",
             "--stop-with-parent", str(os.getpid()), "--duration", str(soak_s + 120.0),
             "--summary-json", str(run_dir / "summary.json")],
            stdout=subprocess.DEVNULL, stderr=log)
        st = GroundStation("127.0.0.1", _link_port(run_dir / "daemon.log", daemon, 120.0))
        if st.vehicle(120.0) is None:
            raise RuntimeError("no heartbeat from the daemon within 120 s")
        t0 = time.monotonic()
        next_check = check_every_s
        while (el := time.monotonic() - t0) < soak_s:
            if daemon.poll() is not None:
                raise RuntimeError(f"the daemon ended ({daemon.returncode}) {el:.0f} s in")
            if (kb := _rss_kb(daemon.pid)) is not None:
                rss.append(kb)
            if el >= next_check:
                next_check = el + check_every_s
                c = _recovery_check(bridge, st)
                unanswered += (c["reset"] is None) + (c["arm"] is None)
                checks.append({"t_s": round(el, 1), **c})
                progress(f"  {el:5.0f} s of {soak_s:.0f}: recovery check "
                         f"{'passed' if c['armed'] else 'FAILED'} (reset {c['reset']}, arm "
                         f"{c['arm']}); {sum(a['n'] for a in actions.values())} actions so far")
                continue
            kind, ans = _act(rng, bridge, st, daemon, nodes)
            a = actions.setdefault(kind, {"n": 0, "unanswered": 0})
            a["n"] += 1
            if ans is None:
                a["unanswered"] += 1
                unanswered += 1
                progress(f"  {el:5.0f} s of {soak_s:.0f}: {kind}: no answer (t_ns "
                         f"{time.monotonic_ns()})")
            time.sleep(rng.uniform(0.5, 3.0))
        time.sleep(TELL_HOLD_S + 2.0)  # a full disk's last change is told after one hold
        logging_healthy = _logging_healthy(st)
        st.close()
        st = None
        code = stop_daemon(daemon, 30.0)
        log.close()
    finally:
        if st is not None:
            st.close()
        stop_hil(daemon, bridge)
    summary = json.loads((run_dir / "summary.json").read_text())
    figures = {"minutes": minutes, "seed": seed, "config": base or "sim",
               "recovery_checks": {"passed": sum(c["armed"] for c in checks),
                                   "run": len(checks)},
               "actions": actions, "station_calls_unanswered": unanswered,
               "logging_healthy_at_end": logging_healthy,
               "daemon": {"exit_code": code, "cycles": summary["loop"].get("cycles"),
                          "overruns": summary["loop"].get("overruns"),
                          "amplifier_recoveries": summary["daemon"].get(
                              "amplifier_recoveries"),
                          "rss_mb_first_last": [round(rss[0] / 1024, 1),
                                                round(rss[-1] / 1024, 1)] if rss else None},
               **_recording_figures(run_dir)}
    ok = figures["recovery_checks"]["passed"] == len(checks) and code == 0 \
        and unanswered == 0 \
        and figures.get("cycles_with_thrust_where_none_allowed") == 0 \
        and (figures.get("replay") or {}).get("mismatches") == 0 \
        and logging_healthy is True \
        and all(t["last_told_ok"] for t in figures.get("recording_failures_told", {}).values())
    if ok:
        shutil.rmtree(run_dir, ignore_errors=True)
    else:  # what to read: the daemon's log, its summary and its black box
        figures["kept"] = str(run_dir)
    return figures


BENCH = Bench(name="chaos", summary="A soak of the daemon under every fault sim-bridge makes, "
                                    "with an operator: recovery checks, thrust where none is "
                                    "allowed, replay mismatches",
              run=lambda a: measure(a.minutes, a.seed, a.check_every, a.config),
              add_arguments=_add)
