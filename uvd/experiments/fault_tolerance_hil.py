"""``uvd experiment fault-tolerance-hil``: the BlueROV2-heavy's dead thruster in hardware in the
loop (issue 33) — the lockstep case of ``fault-tolerance`` on real buses and the real clock.

Two runs, as ``uvd demo --config config/sim-bluerov2.toml`` runs them (``sim-bridge`` and
``uvd run`` as separate processes: instruments on pseudo-terminals, CiA 402 drives on a
``udp_multicast`` CAN bus), both with ``[failsafe] amplifier_fault = "reallocate"``: one
fault-free, and one where the bridge faults thruster ``k``'s drive (EMCY overcurrent,
persistent: its output zero) ``T`` seconds after the vehicle left its cradle
(the bridge's scheduler, ``at_s``: what ``sim-bridge --at`` does). The daemon's amplifier
source sets η 0 and reallocates inside the cycle that reads the fault. Per run: the per-DOF
MAE of the true state (the bridge's truth log) against the daemon's reference before ``T``
and from ``T + settle`` to the end; the ratio of the faulted run's to the fault-free run's
over the same span; the accommodation event and its latency after the fault. The two runs
draw the same instrument noise (the same seed); what differs between them besides the fault
is the machine's timing.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from uvd.experiments import Experiment, ExperimentOptions
from uvd.experiments.fault_tolerance import DOFS, SETTLE_S, _config_dir, _fmt, run_duration
from uvd.runtime.process import stop_daemon

CONFIG = "sim-bluerov2.toml"
THRUSTER = 4
T_FAULT_S = 40.0
DURATION_S = 120.0


def run_hil(config_name: str, k: int, *, fault: bool, t_fault_s: float = T_FAULT_S,
            duration_s: float = DURATION_S, seed: int = 0, progress=print) -> dict[str, Any]:
    """One HIL run (module docstring); ``fault``: thruster ``k``'s drive faults at
    ``t_fault_s`` after the release."""
    from sim_bridge.bridge import BridgeProcess, hil_scheduling, read_truth, write_local_config
    from uvd.lockstep import hil_tracking
    from uvd.runtime.config import load_config

    with tempfile.TemporaryDirectory(prefix="uvd-ft-hil-") as tmp:
        run_dir = Path(tmp)
        bridge_args, changes = hil_scheduling()
        changes["failsafe"] = {"amplifier_fault": "reallocate"}
        cfg_path = write_local_config(run_dir, base=_config_dir() / config_name,
                                      changes=changes)
        node = load_config(cfg_path).can.amplifiers.node_ids[k - 1]
        truth_path = run_dir / "truth.bin"
        bound = duration_s + 120.0
        bridge = BridgeProcess(cfg_path, duration_s=bound, seed=seed, hold=True,
                               truth_log=truth_path, extra=bridge_args)
        bridge.start(timeout_s=120.0)
        daemon = None
        try:
            with (run_dir / "daemon.log").open("w") as err:
                daemon = subprocess.Popen(
                    [sys.executable, "-m", "uvd", "run", "--config", str(cfg_path), "--arm",
                     "--stop-with-parent", str(os.getpid()),
                     "--duration", str(bound)], stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL, stderr=err)
            released = _released(bridge, daemon, run_dir)
            fault_ns = released + int(t_fault_s * 1e9)
            if fault:
                ans = bridge.call("fault", node=node, name="overcurrent", persistent=True,
                                  at_s=max(0.0, (fault_ns - time.monotonic_ns()) * 1e-9))
                if not ans.get("ok"):
                    raise RuntimeError(f"sim-bridge refused the fault: {ans}")
            progress(f"  {'fault' if fault else 'fault-free'}: released; tracking "
                     f"{duration_s:g} s")
            time.sleep(max(0.0, (released + int(duration_s * 1e9) - time.monotonic_ns()) * 1e-9))
            stop_ns = time.monotonic_ns()
            code = stop_daemon(daemon, 60.0)
            bridge.stop(timeout_s=10.0)
        finally:
            if daemon is not None and daemon.poll() is None:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    stop_daemon(daemon)
            bridge.kill()
        truth = read_truth(truth_path)
        tel = run_dir / "telemetry.jsonl"
        before = hil_tracking(tel, truth, until_ns=fault_ns)
        after = hil_tracking(tel, truth, since_ns=fault_ns + int(SETTLE_S * 1e9))
        events = _events(tel)
    acc = [e for e in events if e.get("kind") == "accommodated"]
    fired = [e for e in events if e.get("kind") == "fired"]
    return {"before": before["position_mae"], "after": after["position_mae"],
            "samples_after": after["samples"], "daemon_exit": code,
            "accommodated": [e["reason"] for e in acc],
            "accommodated_after_fault_ms": (acc[0]["t_ns"] - fault_ns) * 1e-6 if acc else None,
            "failsafe_fired": [f"{e['trigger']} at {(e['t_ns'] - fault_ns) * 1e-9:+.2f} s from "
                               f"the fault: {e['reason']}" for e in fired],
            "stopped_after_fault_s": (stop_ns - fault_ns) * 1e-9}


def _released(bridge, daemon, run_dir: Path, timeout_s: float = 180.0) -> int:
    """When the vehicle left its cradle (the daemon armed and commanded thrust)."""
    deadline = time.monotonic() + timeout_s
    while True:
        released = bridge.call("stats").get("released_at_ns")
        if released is not None:
            return int(released)
        if daemon.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError("the daemon did not arm: "
                               + (run_dir / "daemon.log").read_text()[-2000:])
        time.sleep(0.2)


def _events(telemetry: Path) -> list[dict]:
    out = []
    with contextlib.suppress(FileNotFoundError), telemetry.open(encoding="utf-8") as fh:
        for line in fh:
            if '"failsafe"' in line:
                with contextlib.suppress(ValueError):
                    r = json.loads(line)
                    if r.get("type") == "failsafe":
                        out.append(r)
    return out


def _run(opts: ExperimentOptions) -> dict[str, Any]:
    duration = run_duration("fault-tolerance-hil", opts, DURATION_S, T_FAULT_S)
    opts.progress(f"fault-tolerance-hil: {CONFIG}, thruster {THRUSTER} dead at "
                  f"{T_FAULT_S:g} s, {duration:g} s, HIL")
    free = run_hil(CONFIG, THRUSTER, fault=False, duration_s=duration, seed=opts.seed,
                   progress=opts.progress)
    dead = run_hil(CONFIG, THRUSTER, fault=True, duration_s=duration, seed=opts.seed,
                   progress=opts.progress)
    from uvd.experiments.fault_tolerance import run_arm
    # the same configuration's fault-free lockstep run over the same span: a baseline the
    # machine's load cannot disturb (a HIL run under load may see a stale INS, zero thrust)
    lock = run_arm(CONFIG, THRUSTER, 1.0, "fault-free", t_fault_s=T_FAULT_S,
                   duration_s=duration, seed=opts.seed)
    ratio = {d: dead["after"][d] / free["after"][d] for d in DOFS}
    ratio_lock = {d: dead["after"][d] / lock["after"][d] for d in DOFS}
    worst = max(ratio, key=ratio.get)
    worst_lock = max(ratio_lock, key=ratio_lock.get)
    lat = dead["accommodated_after_fault_ms"]
    lines = [f"fault-tolerance-hil: bluerov2-heavy (sim-bridge, real buses), thruster "
             f"{THRUSTER}'s drive faults at {T_FAULT_S:g} s, {duration:g} s; position MAE "
             f"from {T_FAULT_S + SETTLE_S:g} s to the end",
             "fault-free  " + "  ".join(f"{d} {_fmt(d, free['after'][d])}" for d in DOFS),
             "dead        " + "  ".join(f"{d} {_fmt(d, dead['after'][d])}" for d in DOFS),
             "ratio       " + "  ".join(f"{d} {ratio[d]:.2f}x" for d in DOFS)
             + f"  (largest: {worst} {ratio[worst]:.2f}x; target 1.5x)",
             "lockstep    " + "  ".join(f"{d} {_fmt(d, lock['after'][d])}" for d in DOFS)
             + "  (fault-free, same configuration and span)",
             "dead/lockst " + "  ".join(f"{d} {ratio_lock[d]:.2f}x" for d in DOFS)
             + f"  (largest: {worst_lock} {ratio_lock[worst_lock]:.2f}x)",
             "accommodated: " + ("; ".join(dead["accommodated"]) or "no")
             + (f", {lat:.0f} ms after the fault" if lat is not None else "")
             + f"; failsafes fired: {len(dead['failsafe_fired'])} (fault run: "
             f"{'; '.join(dead['failsafe_fired']) or 'none'}), "
             f"{len(free['failsafe_fired'])} (fault-free: "
             f"{'; '.join(free['failsafe_fired']) or 'none'})"]
    if free["failsafe_fired"]:
        lines.append("the fault-free HIL run is not a clean baseline (a failsafe fired in it): "
                     "read the ratio to the lockstep run")
    return {"fault_free": free, "dead": dead, "lockstep_fault_free": lock,
            "ratio_after": ratio, "ratio_after_to_lockstep": ratio_lock, "thruster": THRUSTER,
            "t_fault_s": T_FAULT_S, "duration_s": duration, "settle_s": SETTLE_S,
            "summary": "\n".join(lines), "thesis_reference": THESIS_REFERENCE}


THESIS_REFERENCE = (
    "beyond the thesis (issue 33's acceptance: BlueROV2-class, one thruster dead, position "
    "and attitude MAE within 1.5x of the fault-free run in HIL): `config/sim-bluerov2.toml` "
    "with `[failsafe] amplifier_fault = \"reallocate\"` in sim-bridge, thruster 4's drive "
    "faulted (EMCY, persistent) 40 s after the release; MAE of the truth against the "
    "daemon's reference from 50 s to the end, faulted run / fault-free run.")


EXPERIMENTS = [Experiment(
    "fault-tolerance-hil",
    "the BlueROV2-heavy's dead thruster in hardware in the loop (sim-bridge, real buses): "
    "the drive's fault accommodated by the daemon's amplifier source, tracking MAE against a "
    "fault-free HIL run",
    _run)]


def note(result: dict) -> str | None:
    """The page's reading of the HIL figures (docs/RESULTS.md), from the JSON only."""
    try:
        r, rl = result["ratio_after"], result["ratio_after_to_lockstep"]
        dead, free = result["dead"], result["fault_free"]
    except (KeyError, TypeError):
        return None
    w = max(r, key=r.get)
    wl = max(rl, key=rl.get)
    clean = not free["failsafe_fired"] and not dead["failsafe_fired"]
    lat = dead["accommodated_after_fault_ms"]
    return (
        "**Reading.** In HIL the drive's fault was accommodated "
        + (f"{lat:.0f} ms after the bridge faulted it" if lat is not None else "— not at all")
        + f"; after it every DOF's MAE is within {r[w]:.2f}× of the fault-free HIL run "
        f"({w}) and {rl[wl]:.2f}× of the fault-free lockstep run ({wl}); target 1.5×. "
        + ("No failsafe fired in either run." if clean else
           "A failsafe fired in the "
           + " and the ".join(n for n, r in (("fault-free run", free), ("fault run", dead))
                              if r["failsafe_fired"])
           + " (above): its MAE carries it.")
        + " Two HIL runs differ by the machine's timing as well as by the fault.")
