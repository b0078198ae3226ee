"""Lifecycle: BOOT → STANDBY → ARMED → FAILSAFE → SHUTDOWN, arming checks as data, a reason on
every refusal and a cause on every transition; the supervisor that steps it with the arbiter."""

from __future__ import annotations

import numpy as np
import pytest

from uvd.runtime.cycle import CycleConfig
from uvd.runtime.failsafe import Action, ActiveTrigger, Decision, Health, Thresholds
from uvd.runtime.lifecycle import (
    ArmingCheck,
    Lifecycle,
    State,
    builtin_checks,
    run_checks,
)
from uvd.runtime.supervisor import Supervisor

NS = 1_000_000_000


def good(t_ns=0, **kw) -> Health:
    base = dict(t_ns=t_ns, ins_age_s=0.02, dvl_age_s=0.1, depth_age_s=0.1, bottom_lock=True,
                depth_m=1.5 + 1e-12 * t_ns, amplifiers_enabled=True, feedback_age_s=0.02,
                m_hat_min_eig=3.0)
    base.update(kw)
    return Health(**base)


def decision(action: Action, name="t") -> Decision:
    active = () if action == Action.NONE else (ActiveTrigger(name, action, "why", 0, False),)
    return Decision(action, active, ())


def standby() -> Lifecycle:
    return Lifecycle().boot_complete(1, "drivers up").lifecycle


def test_boot_to_standby_once():
    s = Lifecycle().boot_complete(5, "drivers up")
    assert s.ok and s.lifecycle.state is State.STANDBY and s.lifecycle.since_ns == 5
    (tr,) = s.transitions
    assert (tr.source, tr.target, tr.event, tr.cause) == (State.BOOT, State.STANDBY,
                                                          "boot-complete", "drivers up")
    assert "BOOT → STANDBY" in str(tr)
    again = s.lifecycle.boot_complete(6)
    assert not again.ok and "already" in again.refused and again.lifecycle is s.lifecycle


def test_arming_passes_only_when_every_check_does():
    checks = builtin_checks(Thresholds())
    lc = standby()
    step = lc.request_arm(10, run_checks(checks, good()))
    assert step.ok and step.lifecycle.state is State.ARMED and step.lifecycle.armed
    assert "checks passed: ins_valid, depth_valid, amplifiers_ready, parameters_valid, " \
           "failsafe_clear" in step.transitions[0].cause


def test_every_refusal_names_each_failed_check():
    checks = builtin_checks(Thresholds())
    lc = standby()
    bad = good(ins_age_s=0.5, depth_age_s=float("inf"), amplifiers_enabled=False,
               m_hat_min_eig=-1.0)
    step = lc.request_arm(10, run_checks(checks, bad))
    assert not step.ok and step.lifecycle is lc and step.transitions == ()
    r = step.refused
    assert r.startswith("arming refused:")
    for part in ("ins_valid: INS not valid: age 0.5 s > 0.1 s", "depth_valid: depth not valid",
                 "amplifiers_ready: amplifiers not enabled",
                 "parameters_valid: M̂ not positive definite"):
        assert part in r, part
    assert "failsafe_clear" not in r  # that one passed


def test_amplifier_and_parameter_checks():
    checks = builtin_checks(Thresholds(theta_abs_max=10.0))
    res = {c.name: c for c in run_checks(checks, good(amplifier_faults=("node 2: EMCY 0x2310",)))}
    assert not res["amplifiers_ready"].ok and "node 2" in res["amplifiers_ready"].reason
    res = {c.name: c for c in run_checks(checks, good(bus_off=True))}
    assert res["amplifiers_ready"].reason == "CAN bus-off"
    res = {c.name: c for c in run_checks(checks, good(feedback_age_s=2.0))}
    assert not res["amplifiers_ready"].ok
    theta = np.ones(241)
    theta[3] = 11.0
    res = {c.name: c for c in run_checks(checks, good(theta_hat=theta))}
    assert not res["parameters_valid"].ok
    res = {c.name: c for c in run_checks(checks, good(m_hat_min_eig=None))}
    assert res["parameters_valid"].ok and "nominal" in res["parameters_valid"].reason
    res = {c.name: c for c in run_checks(checks, good(), decision(Action.HOLD_DEPTH))}
    assert not res["failsafe_clear"].ok and "hold-depth" in res["failsafe_clear"].reason
    res = {c.name: c for c in run_checks(checks, good(), decision(Action.FALLBACK))}
    assert res["failsafe_clear"].ok


def test_checks_are_data_and_a_broken_check_refuses():
    def crash(h, d):
        raise RuntimeError("sensor table missing")

    checks = (ArmingCheck("always", lambda h, d: (True, "fine")), ArmingCheck("crash", crash))
    step = standby().request_arm(3, run_checks(checks, good()))
    assert not step.ok and "crash: check could not be evaluated" in step.refused
    assert not standby().request_arm(3, ()).ok  # no check run: no arming


def test_cannot_arm_outside_standby():
    checks = builtin_checks(Thresholds())
    r = Lifecycle().request_arm(1, run_checks(checks, good()))
    assert not r.ok and "only from STANDBY" in r.refused


def test_failsafe_transitions_follow_the_arbiter():
    armed = standby().request_arm(2, run_checks(builtin_checks(Thresholds()), good())).lifecycle
    # WARN and FALLBACK keep ARMED
    for a in (Action.WARN, Action.FALLBACK):
        s = armed.on_failsafe(3, decision(a))
        assert s.lifecycle is armed and s.transitions == ()
    s = armed.on_failsafe(4, decision(Action.HOLD_DEPTH, "dvl_stale"))
    assert s.lifecycle.state is State.FAILSAFE and s.lifecycle.armed
    assert "hold-depth: dvl_stale: why" in s.transitions[0].cause
    fs = s.lifecycle
    assert fs.on_failsafe(5, decision(Action.ZERO_THRUST)).transitions == ()
    back = fs.on_failsafe(6, decision(Action.WARN))
    assert back.lifecycle.state is State.ARMED and back.transitions[0].event == "failsafe-cleared"
    # DISARM from ARMED goes through FAILSAFE to STANDBY, both recorded
    d = armed.on_failsafe(7, decision(Action.DISARM, "leak"))
    assert [(t.source, t.target) for t in d.transitions] == [(State.ARMED, State.FAILSAFE),
                                                             (State.FAILSAFE, State.STANDBY)]
    assert not d.lifecycle.armed
    assert fs.on_failsafe(8, decision(Action.DISARM)).lifecycle.state is State.STANDBY
    # in STANDBY the failsafe changes nothing (thrust is already zero)
    sb = standby()
    assert sb.on_failsafe(9, decision(Action.DISARM)).lifecycle is sb


def test_disarm_and_shutdown():
    armed = standby().request_arm(2, run_checks(builtin_checks(Thresholds()), good())).lifecycle
    d = armed.request_disarm(3, "operator")
    assert d.lifecycle.state is State.STANDBY and d.transitions[0].cause == "operator"
    assert d.lifecycle.request_disarm(4).transitions == ()
    assert not Lifecycle().request_disarm(1).ok
    sd = armed.request_shutdown(5, "SIGTERM")
    assert sd.lifecycle.state is State.SHUTDOWN and sd.transitions[0].cause == "SIGTERM"
    assert sd.lifecycle.request_shutdown(6, "again").transitions == ()
    assert not sd.lifecycle.request_arm(7, run_checks(builtin_checks(Thresholds()), good())).ok
    assert sd.lifecycle.on_failsafe(8, decision(Action.DISARM)).transitions == ()


def test_status_text():
    lc = standby()
    assert lc.status_text() == "STANDBY"
    assert lc.status_text(decision(Action.ZERO_THRUST, "ins_stale")) == \
        "STANDBY (zero-thrust: ins_stale: why)"


def test_supervisor_steps_arbiter_and_lifecycle_with_records():
    events, transitions = [], []
    sup = Supervisor(CycleConfig(None, Thresholds()), on_event=events.append,
                     on_transition=lambda tr, d: transitions.append(tr))
    sup.boot_complete(0)
    t = 0
    for _ in range(3):
        t += NS // 10
        sup.step(good(t))
    assert sup.request_arm(t).ok and sup.state is State.ARMED
    t += NS // 10
    d = sup.step(good(t, ins_age_s=0.5))          # INS stale → zero thrust → FAILSAFE
    assert d.zero_thrust and sup.state is State.FAILSAFE
    refused = sup.request_disarm(t + 1)
    assert refused.ok and sup.state is State.STANDBY
    # re-arming is refused while the failsafe holds, with the reason
    r = sup.request_arm(t + 2)
    assert not r.ok and "failsafe_clear" in r.refused and "ins_valid" in r.refused
    assert [e.kind for e in events] == ["fired", "action"]
    assert [(tr.source.value, tr.target.value) for tr in transitions] == [
        ("BOOT", "STANDBY"), ("STANDBY", "ARMED"), ("ARMED", "FAILSAFE"),
        ("FAILSAFE", "STANDBY")]
    hist = sup.failsafe_events()
    assert {h["type"] for h in hist} == {"failsafe", "lifecycle"} and len(hist) == 6


def test_supervisor_reset_and_listener_failures():
    def bad_listener(*a):
        raise RuntimeError("listener")

    sup = Supervisor(CycleConfig(None, Thresholds()), on_event=bad_listener,
                     on_transition=bad_listener)
    sup.boot_complete(0)
    sup.step(good(NS, leak=True))
    assert sup.listener_errors >= 2
    assert sup.reset_failsafe(NS + 1, ["leak"])[0][0] == "leak"   # still leaking
    sup.step(good(2 * NS, leak=False))
    assert "leak" in {a.name for a in sup.decision.active}         # latched
    assert sup.reset_failsafe(2 * NS + 1, ["leak"]) == ()
    assert not sup.step(good(3 * NS)).active
    sup.set_thresholds(Thresholds(disabled=("leak",)))
    assert "leak" not in {d.name for d in sup.config.registry}
    assert not sup.step(good(4 * NS, leak=True)).active


def test_the_cycle_waits_for_a_dvl_still_starting_at_boot_and_fires_on_its_silence_armed():
    """The boot of the sensor-synchronous BlueROV2 (docs/runtime.md, "not yet available"):
    the first cycles run before the DVL's first frame. No failsafe event while disarmed, arming
    refused until the DVL is heard, then at once; armed, the DVL's silence is stale as before."""
    from drivers.samples import DepthSample, DvlSample, InsSample
    from uvd.runtime import commands as cmd
    from uvd.runtime.build import make_cycle
    from uvd.runtime.config import load_config
    from uvd.runtime.cycle import ActuatorStatus, CycleInputs

    cfg = load_config("config/sim-bluerov2.toml")
    sup = Supervisor(make_cycle(cfg, cfg.load_vehicle()), north_m=0.5, east_m=0.5)
    sup.boot_complete(0, "test")
    dt_ns = 20_000_000  # 50 Hz

    def step(k: int, dvl: bool):
        t = (k + 1) * dt_ns
        inp = CycleInputs(t, InsSample(t, 0.0, 0.0, 0.0, np.zeros(3)),
                          DvlSample(t, np.zeros(3), True, 2.0) if dvl else None,
                          DepthSample(t, 1.8 + 1e-4 * (k % 3)),
                          ActuatorStatus(np.zeros(8), True, (), t))
        return sup.update(inp, 0.02), t

    for k in range(10):  # 0.2 s of a DVL still starting
        r, t = step(k, dvl=False)
        assert r.decision.waiting == ("dvl_stale", "dvl_bottom_lock_lost")
        assert r.decision.action == Action.NONE
    res = sup.apply(cmd.Arm(), t)
    assert not res.ok and "failsafe_clear: waiting for a first sample: dvl_stale" in res.reason
    r, t = step(10, dvl=True)  # the DVL's first frame
    assert r.decision.waiting == ()
    assert sup.apply(cmd.Arm(), t).ok  # no clear_after_s to sit out: nothing had fired
    assert not [e for e in sup.failsafe_events() if e["type"] == "failsafe"]
    fired = None
    for k in range(11, 11 + 60):  # armed, the DVL silent for 1.2 s > dvl_stale_s = 1 s
        r, t = step(k, dvl=False)
        if "dvl_stale" in {a.name for a in r.decision.active}:
            fired = t
            break
    assert fired is not None and r.decision.action == Action.HOLD_DEPTH
    assert (fired - 11 * dt_ns) * 1e-9 == pytest.approx(cfg.failsafe.dvl_stale_s, abs=0.021)
