"""The failsafe arbiter: every built-in trigger fires within its threshold + one cycle, and
clears (after ``clear_after_s``) or latches (until an operator reset) as documented."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from uvd.runtime.failsafe import (
    BUILTIN_NAMES,
    NAV_HEALTH_FIELDS,
    Action,
    Health,
    Thresholds,
    TriggerDef,
    arbiter_init,
    builtin_triggers,
    evaluate,
    make_registry,
    nav_health,
    nonfinite_names,
    reset,
)

DT = 0.1                      # a 10 Hz cycle, as the thesis
NS = 1_000_000_000


def healthy(t_s: float, **kw) -> Health:
    """Every signal fresh and sane; the depth changes a little every cycle."""
    base = dict(t_ns=int(round(t_s * NS)), ins_age_s=0.01, dvl_age_s=0.05, depth_age_s=0.05,
                bottom_lock=True, depth_m=2.0 + 1e-4 * math.sin(7 * t_s),
                amplifiers_enabled=True, feedback_age_s=0.01, m_hat_min_eig=10.0,
                theta_hat=np.ones(241), leak=False)
    base.update(kw)
    return Health(**base)


class Sim:
    """Steps the arbiter at 10 Hz with a health function of time."""

    def __init__(self, th: Thresholds | None = None, extra=()):
        self.th = th or Thresholds()
        self.reg = make_registry(self.th, extra)
        self.state = arbiter_init(self.reg)
        self.t = 0.0
        self.events = []

    def step(self, **kw):
        self.t = round(self.t + DT, 9)
        d, self.state = evaluate(self.reg, self.th, self.state, healthy(self.t, **kw))
        self.events += list(d.events)
        return d

    def run_until(self, t_end, health_fn):
        """Step until t_end; health_fn(t) -> kwargs. Returns the list of decisions."""
        out = []
        while self.t < t_end - 1e-9:
            out.append((round(self.t + DT, 9), self.step(**health_fn(round(self.t + DT, 9)))))
        return out


def first_fire(decisions, name):
    for t, d in decisions:
        if any(a.name == name for a in d.active):
            return t
    return None


def active_names(d):
    return {a.name for a in d.active}


# one entry per built-in trigger: kwargs that break it from t = 1 s, the expected action, the
# threshold (s) after which it must fire (measured from the break), latching or not,
# and kwargs that repair it.
CASES = {
    "ins_stale": (lambda t0, t: {"ins_age_s": 0.01 + (t - t0)}, Action.ZERO_THRUST, 0.1, False),
    "ins_rates_degraded": (lambda t0, t: {"rates_degraded": True}, Action.WARN, 0.0, False),
    "dvl_stale": (lambda t0, t: {"dvl_age_s": 0.05 + (t - t0)}, Action.HOLD_DEPTH, 1.0, False),
    "dvl_bottom_lock_lost": (lambda t0, t: {"bottom_lock": False}, Action.HOLD_DEPTH, 0.0,
                             False),
    "depth_stale": (lambda t0, t: {"depth_age_s": 0.05 + (t - t0)}, Action.ZERO_THRUST, 0.5,
                    False),
    "depth_stuck": (lambda t0, t: {"depth_m": 3.25}, Action.ZERO_THRUST, 2.0, True),
    "nonfinite_input": (lambda t0, t: {"nonfinite_inputs": ("ins.roll",)}, Action.ZERO_THRUST,
                        0.0, False),
    "nonfinite_output": (lambda t0, t: {"nonfinite_outputs": ("thrust",)},
                         Action.ZERO_THRUST, 0.0, True),
    "parameter_divergence": (lambda t0, t: {"m_hat_min_eig": -0.5}, Action.FALLBACK, 0.0,
                             True),
    "amplifier_fault": (lambda t0, t: {"amplifier_faults": ("node 3: over-current",)},
                        Action.DISARM, 0.0, True),
    "feedback_missing": (lambda t0, t: {"feedback_age_s": 0.01 + (t - t0)},
                         Action.ZERO_THRUST, 0.5, False),
    "bus_off": (lambda t0, t: {"bus_off": True}, Action.DISARM, 0.0, True),
    "loop_overrun_streak": (lambda t0, t: {"overrun_streak": 5, "overrun_streak_exceeded": True},
                            Action.ZERO_THRUST, 0.0, False),
    "cycle_exception": (lambda t0, t: {"cycle_failed": True}, Action.ZERO_THRUST, 0.0, True),
    "leak": (lambda t0, t: {"leak": True}, Action.DISARM, 0.0, True),
}


def test_every_builtin_trigger_has_a_case():
    assert set(CASES) == set(BUILTIN_NAMES) == {d.name for d in builtin_triggers()}


@pytest.mark.parametrize("name", sorted(CASES))
def test_trigger_fires_within_threshold_plus_one_cycle_then_clears_or_latches(name):
    breaker, action, threshold, latch = CASES[name]
    t_break, t_fix = 1.0, 5.0
    sim = Sim()

    def health(t):
        return breaker(t_break, t) if t_break <= t < t_fix else {}

    decisions = sim.run_until(8.0, health)
    fired = first_fire(decisions, name)
    assert fired is not None, f"{name} never fired"
    assert fired >= t_break + threshold - 1e-9, f"{name} fired early at {fired}"
    assert fired <= t_break + threshold + DT + 1e-9, f"{name} fired late at {fired}"
    # while broken, its action is in force (nothing else is active in these scenarios)
    during = dict(decisions)[round(t_fix - DT, 9)]
    assert active_names(during) == {name} and during.action == action
    fired_ev = [e for e in sim.events if e.kind == "fired" and e.trigger == name]
    assert len(fired_ev) == 1 and fired_ev[0].action == action and fired_ev[0].reason
    after = dict(decisions)
    th = sim.th
    if latch:
        # still active long after the condition went away, until an operator reset
        assert name in active_names(after[8.0])
        assert after[8.0].action == action
        st, evs, refused = reset(sim.reg, th, sim.state, healthy(8.1), [name])
        assert refused == () and [e.kind for e in evs] == ["reset"]
        d, _ = evaluate(sim.reg, th, st, healthy(8.2))
        assert d.action == Action.NONE and not d.active
    else:
        cleared = [t for t, d in decisions if t >= t_fix and name not in active_names(d)]
        assert cleared, f"{name} never cleared"
        # clears once the condition has been false for clear_after_s (+ one cycle)
        assert t_fix + th.clear_after_s - 1e-9 <= cleared[0] <= t_fix + th.clear_after_s + DT \
            + 1e-9
        assert any(e.kind == "cleared" and e.trigger == name for e in sim.events)
        assert after[8.0].action == Action.NONE


def test_latched_trigger_cannot_be_reset_while_its_condition_holds():
    sim = Sim()
    sim.step(leak=True)
    st, evs, refused = reset(sim.reg, sim.th, sim.state, healthy(sim.t + DT, leak=True))
    assert evs == () and refused[0][0] == "leak" and "condition still true" in refused[0][1]
    _, _, refused = reset(sim.reg, sim.th, sim.state, healthy(sim.t), ["no_such"])
    assert refused == (("no_such", "unknown trigger"),)


def test_a_reset_of_all_refuses_latched_holds_leaves_clearing_ones_and_clears_the_rest():
    """The operator's reset of every trigger (names None: MAVLink 31011, uvd
    reset-failsafe): a latched one whose condition holds is refused by name; one that clears
    by itself and still holds is left to clear, not refused (an INS without rates would
    otherwise refuse every reset); one whose condition has just gone is cleared now, not
    ``clear_after_s`` later; a latched one whose condition has gone is reset."""
    sim = Sim()
    sim.step(leak=True, feedback_age_s=5.0, ins_age_s=5.0)
    assert {"leak", "feedback_missing", "ins_stale"} == \
        active_names(evaluate(sim.reg, sim.th, sim.state, healthy(sim.t))[0])
    # still wet, the INS still stale; the feedback back
    h = healthy(sim.t + DT, leak=True, ins_age_s=5.0)
    st, evs, refused = reset(sim.reg, sim.th, sim.state, h)
    assert [n for n, _ in refused] == ["leak"] and "condition still true" in refused[0][1]
    assert [e.trigger for e in evs] == ["feedback_missing"]
    d, _ = evaluate(sim.reg, sim.th, st, h)
    assert active_names(d) == {"leak", "ins_stale"}
    # dry: the leak is reset, the stale INS still left to clear by itself
    h = healthy(sim.t + 2 * DT, ins_age_s=5.0)
    st, evs, refused = reset(sim.reg, sim.th, st, h)
    assert refused == () and [e.trigger for e in evs] == ["leak"]


def test_most_severe_action_wins_and_events_name_the_causes():
    sim = Sim()
    d = sim.step(rates_degraded=True)
    assert d.action == Action.WARN and not d.freeze_adaptation
    d = sim.step(rates_degraded=True, m_hat_min_eig=0.0)
    assert d.action == Action.FALLBACK and d.freeze_adaptation and not d.zero_horizontal
    d = sim.step(rates_degraded=True, m_hat_min_eig=0.0, dvl_age_s=3.0)
    assert d.action == Action.HOLD_DEPTH and d.zero_horizontal and not d.zero_thrust
    d = sim.step(rates_degraded=True, m_hat_min_eig=0.0, dvl_age_s=3.0, ins_age_s=1.0)
    assert d.action == Action.ZERO_THRUST and d.zero_thrust and not d.disarm
    d = sim.step(rates_degraded=True, m_hat_min_eig=0.0, dvl_age_s=3.0, ins_age_s=1.0, leak=True)
    assert d.action == Action.DISARM and d.disarm
    assert active_names(d) == {"ins_rates_degraded", "parameter_divergence", "dvl_stale",
                               "ins_stale", "leak"}
    assert "leak: leak detected" in d.causes
    actions = [e.action for e in sim.events if e.kind == "action"]
    assert actions == [Action.WARN, Action.FALLBACK, Action.HOLD_DEPTH, Action.ZERO_THRUST,
                       Action.DISARM]


def test_default_health_is_not_healthy():
    th = Thresholds()
    reg = make_registry(th)
    d, _ = evaluate(reg, th, arbiter_init(reg), Health(t_ns=0))
    assert {"ins_stale", "dvl_stale", "depth_stale", "feedback_missing",
            "dvl_bottom_lock_lost"} <= active_names(d)
    assert d.zero_thrust


NEVER_HEARD = {"ins_age_s": math.inf, "dvl_age_s": math.inf, "depth_age_s": math.inf,
               "bottom_lock": False, "depth_m": math.nan}
SOURCE_TRIGGERS = ["ins_stale", "dvl_stale", "dvl_bottom_lock_lost", "depth_stale"]


def test_sources_never_heard_from_wait_while_disarmed_and_block_arming():
    from uvd.runtime.lifecycle import builtin_checks, run_checks
    sim = Sim()
    for _ in range(20):  # 2 s of a boot whose sensors are still starting
        d = sim.step(armed=False, **NEVER_HEARD)
        assert d.action == Action.NONE and not d.active
        assert list(d.waiting) == SOURCE_TRIGGERS
    assert sim.events == []
    checks = {r.name: r for r in run_checks(builtin_checks(sim.th),
                                            healthy(sim.t, armed=False, **NEVER_HEARD), d)}
    assert not checks["failsafe_clear"].ok
    assert checks["failsafe_clear"].reason == (
        "waiting for a first sample: ins_stale, dvl_stale, dvl_bottom_lock_lost, depth_stale")
    # the DVL still silent, the others heard: only the DVL's triggers wait
    d = sim.step(armed=False, dvl_age_s=math.inf, bottom_lock=False)
    assert list(d.waiting) == ["dvl_stale", "dvl_bottom_lock_lost"] and sim.events == []
    # every source heard: nothing waits, nothing to clear — arming may follow at once
    d = sim.step(armed=False)
    assert d.waiting == () and d.action == Action.NONE and sim.events == []
    assert all(r.ok for r in run_checks(builtin_checks(sim.th), healthy(sim.t), d))


def test_armed_a_source_never_heard_from_fires_as_before():
    strict, armed = Sim(), Sim()
    d_default = strict.step(**NEVER_HEARD)  # Health's default is the strict reading
    d_armed = armed.step(armed=True, **NEVER_HEARD)
    for d in (d_default, d_armed):
        assert active_names(d) == set(SOURCE_TRIGGERS) and d.waiting == ()
        assert d.action == Action.ZERO_THRUST
        assert {a.name: a.reason for a in d.active}["dvl_stale"] == "DVL age inf s > 1 s"
    assert [e.trigger for e in armed.events if e.kind == "fired"] == SOURCE_TRIGGERS


def test_disarmed_a_source_heard_once_then_silent_is_stale():
    sim = Sim()
    sim.step(armed=False)
    d = sim.run_until(3.0, lambda t: {"armed": False, "dvl_age_s": 0.05 + t})[-1][1]
    assert "dvl_stale" in active_names(d) and d.waiting == ()
    assert [e.trigger for e in sim.events if e.kind == "fired"] == ["dvl_stale"]


def test_a_trigger_active_when_disarmed_is_not_turned_into_waiting():
    sim = Sim()
    sim.step(armed=True, **NEVER_HEARD)  # fired while armed
    d = sim.step(armed=False, **NEVER_HEARD)  # then disarmed, still never heard
    assert active_names(d) == set(SOURCE_TRIGGERS) and d.waiting == ()
    assert not [e for e in sim.events if e.kind == "cleared"]


def test_flicker_does_not_clear_before_the_hysteresis():
    sim = Sim()
    sim.step(ins_age_s=0.5)
    for k in range(20):  # condition false every other cycle: must stay active
        d = sim.step(ins_age_s=0.5 if k % 2 else 0.01)
        assert "ins_stale" in active_names(d)
    assert [e.kind for e in sim.events if e.trigger == "ins_stale" and e.kind != "action"] \
        == ["fired"]


def test_stale_depth_does_not_count_as_stuck():
    sim = Sim()
    # the sensor goes silent: the held value does not change, but that is staleness only
    for _ in range(40):
        d = sim.step(depth_m=2.5, depth_age_s=1.0)
    assert "depth_stale" in active_names(d) and "depth_stuck" not in active_names(d)


def test_theta_out_of_bounds_and_non_finite():
    sim = Sim(Thresholds(theta_abs_max=100.0))
    theta = np.ones(241)
    theta[17] = 250.0
    d = sim.step(theta_hat=theta)
    assert d.action == Action.FALLBACK and "θ̂[17]" in d.causes
    sim2 = Sim()
    theta[17] = np.nan
    assert "not finite" in sim2.step(theta_hat=theta).causes


def test_disabled_triggers_and_unknown_names():
    th = Thresholds(disabled=("dvl_bottom_lock_lost",))
    sim = Sim(th)
    assert sim.step(bottom_lock=False).action == Action.NONE
    errs = Thresholds(disabled=("no_such",))._check(None)
    assert errs and "unknown trigger" in errs[0][1]


def test_new_triggers_plug_in_as_data():
    def operator_lost(h, th, mem):
        age = (h.extra or {}).get("operator_heartbeat_age_s")
        if age is not None and age > 3.0:
            return f"no operator heartbeat for {age:.1f} s", mem
        return None, mem

    hb = TriggerDef("operator_heartbeat", Action.HOLD_DEPTH, operator_lost)
    sim = Sim(extra=[hb])
    assert sim.step(extra={"operator_heartbeat_age_s": 1.0}).action == Action.NONE
    d = sim.step(extra={"operator_heartbeat_age_s": 3.5})
    assert d.action == Action.HOLD_DEPTH and "operator_heartbeat" in active_names(d)
    with pytest.raises(ValueError, match="duplicate"):
        make_registry(Thresholds(), [hb, hb])


def test_a_broken_condition_is_itself_a_trigger():
    def broken(h, th, mem):
        raise ZeroDivisionError("oops")

    sim = Sim(extra=[TriggerDef("broken", Action.ZERO_THRUST, broken)])
    d = sim.step()
    assert d.action == Action.ZERO_THRUST and "could not be evaluated" in d.causes


def test_evaluate_is_pure():
    th = Thresholds()
    reg = make_registry(th)
    s0 = arbiter_init(reg)
    snapshot = dict(s0.triggers)
    h = healthy(1.0, ins_age_s=1.0)
    d1, s1 = evaluate(reg, th, s0, h)
    d2, s2 = evaluate(reg, th, s0, h)
    assert dict(s0.triggers) == snapshot           # input state untouched
    assert d1.action == d2.action and s1.triggers == s2.triggers
    # an unchanged cycle reuses the decision object (no allocation at 1 kHz)
    d3, s3 = evaluate(reg, th, s1, healthy(1.1, ins_age_s=1.0))
    d4, _ = evaluate(reg, th, s3, healthy(1.2, ins_age_s=1.0))
    assert d4 is d3 and d4.events == ()


def test_helpers():
    assert nonfinite_names(a=np.array([1.0, np.inf]), b=np.zeros(3), c=None, d=float("nan"),
                           e="text") == ("a", "d", "e")
    nav = dataclasses.make_dataclass("Nav", ["ins_age_s", "dvl_age_s", "depth_age_s",
                                             "rates_degraded", "bottom_lock", "H"])
    H = np.eye(4)
    H[2, 3] = 4.5
    fields = nav_health(nav(0.01, 0.2, 0.1, False, True, H))
    assert fields["depth_m"] == 4.5 and fields["bottom_lock"] is True
    Health(t_ns=1, **fields)  # they are Health fields
    # the cycle builds Health positionally (uvd.runtime.cycle.update): the fields in this order
    assert [f.name for f in dataclasses.fields(Health)] == [
        "t_ns", *NAV_HEALTH_FIELDS, "nonfinite_inputs", "nonfinite_outputs", "m_hat_min_eig",
        "theta_hat", "amplifiers_enabled", "amplifier_faults", "feedback_age_s", "bus_off",
        "overrun_streak", "overrun_streak_exceeded", "cycle_failed", "leak", "extra", "armed"]
