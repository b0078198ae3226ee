"""One scenario of faults through the two ways of running the one cycle: lockstep simulation and
the daemon over ``sim-bridge`` (hardware in the loop).

INS silence, a parameter estimate leaving its bound, a NaN attitude, the depth stuck (latched,
then reset by the operator) and an amplifier fault, injected at the same times after arming.
Both runs must show the same failsafe events in the same order, the same action at every cycle
(but within a few cycles of a transition: the HIL timing tolerance) and the same thrust pattern
for it; the lockstep run is bit-identical when repeated.
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import replace

import numpy as np
import pytest

from tests.hil_daemon import run_scenario, running_bridge
from uvd.lockstep import Lockstep, LockstepConfig
from uvd.runtime import commands as cmd
from uvd.runtime.build import make_cycle, start_pose
from uvd.runtime.config import load_config
from uvd.runtime.leak import leak_sensor_fault_trigger

pytestmark = pytest.mark.slow

#: (seconds after arming, injection) — parameter divergence comes by itself: the bound below
#: is crossed by the adapting d₆ about 5.6 s after arming
SCENARIO = (
    (2.0, ("sensor", "ins", "silence", 0.6)),   # ins_stale → zero thrust, clears
    (8.0, ("sensor", "ins", "nan", 0.5)),       # nonfinite_input → zero thrust, and the INS
                                                # unusable: ins_stale after 0.25 s; both clear
    (11.0, ("sensor", "depth", "stuck", 3.0)),  # depth_stuck (2 s) → zero thrust, latched
    (15.0, ("reset", "depth_stuck")),           # the operator resets it
    (16.5, ("amplifier", 3)),                   # amplifier_fault → disarm, latched
)
END_S = 17.5
THETA_ABS_MAX = 320.0
TOL_CYCLES = 3          # sample arrival (≤ 1 cycle) + injection latency + the age threshold
TOL_DIVERGENCE = 10     # the estimate's path, shaped by each run's own sensor noise


def _config(path):
    cfg = load_config(path)
    return replace(cfg, failsafe=replace(cfg.failsafe, theta_abs_max=THETA_ABS_MAX))


def run_lockstep(cfg) -> list[tuple[str, str, np.ndarray, tuple]]:
    """The scenario in lockstep: (action, mode, thrust, events) per cycle from arming on."""
    vehicle = cfg.load_vehicle()
    H0, v0 = start_pose(cfg)
    cycle = replace(make_cycle(cfg, vehicle), extra_triggers=(leak_sensor_fault_trigger(),))
    sim = Lockstep(vehicle, cycle, LockstepConfig(control_rate_hz=cfg.loop.rate_hz, seed=0),
                   H0=H0, v0=v0, armed=False)
    sim.advance()  # one cycle in standby: the arming checks need a health snapshot
    assert sim.command(cmd.Arm()).ok
    dt = sim.dt_control
    todo = sorted((round(t / dt), what) for t, what in SCENARIO)
    rows = []
    for k in range(round(END_S / dt)):
        while todo and todo[0][0] == k:
            what = todo.pop(0)[1]
            if what[0] == "sensor":
                sim.faults.set(what[1], what[2], what[3])
            elif what[0] == "reset":
                assert sim.command(cmd.ResetFailsafe((what[1],))).ok
            else:
                sim.amplifier_faults = (f"node {what[1]}: overcurrent",)
        out = sim.advance()
        r = sim.last_result
        rows.append((r.decision.action.label, out.mode, out.thrust_n.copy(),
                     tuple((e.kind, e.trigger) for e in r.decision.events)))
    return rows


def run_hil(tmp_path, cfg_changes) -> tuple[list, list]:
    """The scenario against the daemon over sim-bridge: per-cycle rows from arming on and the
    failsafe events."""
    with running_bridge(tmp_path, cfg_changes) as (cfg_path, proc):
        cfg = _config(cfg_path)

        async def scenario(d):
            t_arm = d.armed_at_ns
            for t, what in SCENARIO:
                delay = t_arm * 1e-9 + t - time.monotonic()
                if delay > 0:
                    await asyncio.sleep(delay)
                if what[0] == "sensor":
                    ans = await asyncio.to_thread(proc.call, "sensor", name=what[1],
                                                  mode=what[2], seconds=what[3])
                    assert ans.get("ok"), ans
                elif what[0] == "reset":
                    res = await asyncio.wrap_future(
                        d.app.commands.put(cmd.ResetFailsafe((what[1],))))
                    assert res.ok, res
                else:
                    ans = await asyncio.to_thread(proc.call, "fault", node=what[1],
                                                  name="overcurrent", persistent=True)
                    assert ans.get("ok"), ans
            await asyncio.sleep(t_arm * 1e-9 + END_S - time.monotonic())

        d, cycles = run_scenario(cfg, scenario, tracking_s=0.0)
        t_arm = d.armed_at_ns
        rows = [(r["action"], r["mode"], np.asarray(r["thrust"], dtype=float), ())
                for r in cycles if r["t_ns"] >= t_arm]
        events = [(e["kind"], e["trigger"]) for e in d.supervisor.failsafe_events()
                  if e["type"] == "failsafe" and e["t_ns"] >= t_arm
                  and e["kind"] in ("fired", "cleared", "reset")]
        return rows, events


def _transitions(actions: list[str]) -> list[int]:
    return [k for k in range(1, len(actions)) if actions[k] != actions[k - 1]]


def _pattern(thrust: np.ndarray) -> str:
    return "zero" if not np.any(thrust) else "thrust"


def test_lockstep_runs_the_failsafes_bit_for_bit():
    cfg = _config("config/sim.toml")
    a, b = run_lockstep(cfg), run_lockstep(cfg)
    assert len(a) == len(b)
    for ra, rb in zip(a, b, strict=True):
        assert ra[0] == rb[0] and ra[1] == rb[1] and ra[3] == rb[3]
        assert np.array_equal(ra[2], rb[2])  # bit for bit
    fired = [e for r in a for e in r[3] if e[0] == "fired"]
    assert [t for _, t in fired] == ["ins_stale", "parameter_divergence", "nonfinite_input",
                                     "ins_stale", "depth_stuck", "amplifier_fault"], fired
    modes = {r[1] for r in a}
    assert {"control", "zero", "pdc-fallback", "disarmed"} <= modes


def test_lockstep_and_hil_take_the_same_failsafe_actions(tmp_path):
    base = _config("config/sim.toml")
    lock = run_lockstep(base)
    hil, hil_events = run_hil(tmp_path, {"failsafe": {"theta_abs_max": THETA_ABS_MAX}})
    lock_events = [e for r in lock for e in r[3] if e[0] in ("fired", "cleared", "reset")]
    print("lockstep events:", lock_events)
    print("HIL events:     ", hil_events)
    assert [e for e in hil_events if e[0] == "fired"] == \
        [e for e in lock_events if e[0] == "fired"]
    n = min(len(lock), len(hil))
    assert n >= round(END_S / 0.1) - 3
    la, ha = [r[0] for r in lock[:n]], [r[0] for r in hil[:n]]
    near = set()
    div = next(k for k, r in enumerate(lock) if ("fired", "parameter_divergence") in r[3])
    for k in _transitions(la) + _transitions(ha):
        tol = TOL_DIVERGENCE if abs(k - div) <= TOL_DIVERGENCE else TOL_CYCLES
        near.update(range(k - tol, k + tol + 1))
    compared = [k for k in range(n) if k not in near]
    disagree = [(k, la[k], ha[k]) for k in compared if la[k] != ha[k]]
    pattern = [(k, la[k]) for k in compared if la[k] == ha[k]
               and _pattern(lock[k][2]) != _pattern(hil[k][2])]
    # while both control, the commands themselves: the same law on each run's own noisy data
    both = [k for k in compared if la[k] == ha[k] and _pattern(lock[k][2]) == "thrust"]
    diff = np.array([lock[k][2] - hil[k][2] for k in both])
    ref = np.array([lock[k][2] for k in both])
    rel = float(np.sqrt(np.mean(diff ** 2)) / np.sqrt(np.mean(ref ** 2)))
    print(f"{len(compared)} of {n} cycles compared (the others within the timing tolerance "
          f"of a transition); actions disagree on {len(disagree)}, thrust pattern on "
          f"{len(pattern)}; RMS command difference while controlling {rel:.1%} of the RMS "
          "command")
    assert not disagree, disagree[:10]
    assert not pattern, pattern[:10]
    assert len(compared) >= n // 2
    assert rel < 0.25
