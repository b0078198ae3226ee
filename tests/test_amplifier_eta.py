"""The amplifier's own fault as a source of thruster effectiveness η (issue 33).

``[failsafe] amplifier_fault = "reallocate"``: a thruster whose amplifier reports a fault gets
η = 0 inside the cycle (:func:`uvd.runtime.cycle.amplifier_source`) and the vehicle flies on
the rest while heave, roll, pitch and yaw stay actuated; otherwise — and always under the
default ``"disarm"`` — the failsafe disarms as before. The pure cycle first, then the daemon
against a live ``sim-bridge`` (its emulated CiA 402 drives on the ``udp_multicast`` CAN bus),
the fault injected by the bridge's own scheduler (``at_s``, what ``sim-bridge --at`` does).
"""

from __future__ import annotations

import asyncio
from dataclasses import replace

import numpy as np
import pytest

from uvd.runtime import commands as cmd
from uvd.runtime import cycle as C
from uvd.runtime.build import make_cycle
from uvd.runtime.config import DEFAULT_CONFIG, load_config
from uvd.runtime.cycle import ActuatorStatus

pytestmark = pytest.mark.timeout(180)


def _cycle(rule: str):
    cfg = load_config(DEFAULT_CONFIG)  # the JHU ROV: 1, 2 aft, 3 lateral, 4-6 vertical
    c = make_cycle(cfg)
    return replace(c, thresholds=replace(c.thresholds, amplifier_fault=rule))


def _status(*faulted: int) -> ActuatorStatus:
    return ActuatorStatus(np.zeros(6), not faulted,
                          tuple(f"node {k}: overcurrent" for k in faulted), 5, False,
                          faulted, 7)


def test_disarm_is_the_default_and_leaves_eta_alone():
    assert load_config(DEFAULT_CONFIG).failsafe.amplifier_fault == "disarm"
    c = _cycle("disarm")
    v = C.amplifier_source(c, C.cycle_init(c, armed=True), _status(1), 10)
    assert v.eta is None and v.faults == ("node 1: overcurrent",) and v.effects == ()
    assert v.feedback_t_ns == 5


def test_reallocate_kills_the_thruster_and_hides_its_fault_from_the_arbiter():
    c = _cycle("reallocate")
    st = C.cycle_init(c, armed=True)
    bus = _status(1)._replace(faults=("node 1: overcurrent", "bus: send_failed"))
    v = C.amplifier_source(c, st, bus, 10)
    np.testing.assert_array_equal(v.eta, [0, 1, 1, 1, 1, 1])
    assert v.faults == ("bus: send_failed",) and v.feedback_t_ns == 7
    (ev,) = v.effects
    assert (ev.kind, ev.trigger, ev.action.label) == ("accommodated", "amplifier_fault", "warn")
    assert ev.reason == "thruster 1 eta 0 (amplifier); given up: surge"
    # latched in the state: the next cycle tells nothing new
    again = C.amplifier_source(c, st._replace(thruster_eta=v.eta), bus, 20)
    assert again.effects == () and again.eta is v.eta


def test_a_fault_that_would_lose_depth_or_attitude_is_left_to_the_failsafe():
    c = _cycle("reallocate")
    v = C.amplifier_source(c, C.cycle_init(c, armed=True), _status(4), 10)  # a vertical: pitch
    assert v.eta is None and v.faults == ("node 4: overcurrent",) and v.effects == ()


def test_the_operator_cannot_clear_eta_while_the_amplifier_still_reports():
    c = _cycle("reallocate")
    st = C.cycle_init(c, armed=True)
    v = C.amplifier_source(c, st, _status(2), 10)
    st = st._replace(thruster_eta=v.eta)
    res, st, _ = C.apply(c, st, cmd.SetThrusterEta(2, 1.0), 11)
    assert res.ok and st.thruster_eta is None
    v = C.amplifier_source(c, st, _status(2), 12)
    assert v.eta[1] == 0.0 and len(v.effects) == 1  # set again, and told again
    assert C.amplifier_source(c, st, _status(), 13).eta is None  # the fault gone: η 1 stays


def test_the_status_round_trips_through_the_cycle_record():
    a = _status(3)
    inp = C.CycleInputs(100, actuators=a)
    rec = C.inputs_record(inp, np.array([1, 1, 0, 1, 1, 1.0]))
    back = C.inputs_from_record(100, rec)
    assert back.actuators.faulted == (3,) and back.actuators.healthy_feedback_t_ns == 7
    assert rec["thruster_eta"].tolist() == [1, 1, 0, 1, 1, 1]


# ----------------------------------------------------------------------------- HIL

def _events(d, kind, trigger="amplifier_fault"):
    return [e for e in d.supervisor.failsafe_events() if e["type"] == "failsafe"
            and e["kind"] == kind and e["trigger"] == trigger]


@pytest.fixture(scope="module")
def reallocating_bridge(tmp_path_factory):
    from tests.hil_daemon import running_bridge
    with running_bridge(tmp_path_factory.mktemp("hil"),
                        {"failsafe": {"amplifier_fault": "reallocate"}}) as b:
        yield b


def test_hil_an_aft_amplifier_fault_is_accommodated_and_the_vehicle_flies_on(
        reallocating_bridge):
    from tests.hil_daemon import run_scenario, until
    from uvd.runtime.lifecycle import State
    cfg_path, proc = reallocating_bridge
    assert proc.call("reset")["ok"] and proc.call("place", hold=True)["ok"]
    cfg = load_config(cfg_path)
    info = {}

    async def scenario(d):
        ans = await asyncio.to_thread(proc.call, "fault", node=1, name="overcurrent",
                                      persistent=True, at_s=0.3)
        assert ans.get("ok") and ans.get("scheduled_ns"), ans
        info["at"] = ans["scheduled_ns"]
        await until(lambda: _events(d, "accommodated"), 3.0, "the accommodation")
        await asyncio.sleep(2.0)
        info["state"] = d.supervisor.state

    d, cycles = run_scenario(cfg, scenario, timeout_s=150.0)
    (ev,) = _events(d, "accommodated")
    assert ev["reason"] == "thruster 1 eta 0 (amplifier); given up: surge"
    assert not _events(d, "fired") and info["state"] is State.ARMED
    after = [r for r in cycles if r["t_ns"] >= ev["t_ns"]]
    assert len(after) >= 10
    for r in after:
        assert r["state"] == "ARMED" and r["mode"] == "control"
        assert r["thrust"][0] == 0.0
        assert r["inputs"]["thruster_eta"].tolist() == [0, 1, 1, 1, 1, 1]
    assert any(np.any(np.asarray(r["thrust"])[1:] != 0.0) for r in after)
    before = [r for r in cycles if r["t_ns"] < ev["t_ns"]]
    assert all(r["inputs"]["thruster_eta"] is None for r in before)
    print(f"accommodated {(ev['t_ns'] - info['at']) / 1e6:.0f} ms after the bridge's fault")


def test_hil_a_vertical_amplifier_fault_still_disarms(reallocating_bridge):
    from tests.hil_daemon import run_scenario, until
    cfg_path, proc = reallocating_bridge
    assert proc.call("reset")["ok"] and proc.call("place", hold=True)["ok"]
    cfg = load_config(cfg_path)

    async def scenario(d):
        ans = await asyncio.to_thread(proc.call, "fault", node=4, name="overcurrent",
                                      persistent=True, at_s=0.3)
        assert ans.get("ok"), ans
        await until(lambda: _events(d, "fired"), 3.0, "amplifier_fault")
        await asyncio.sleep(0.5)

    d, cycles = run_scenario(cfg, scenario, timeout_s=150.0)
    ev = _events(d, "fired")[0]
    assert ev["action"] == "disarm" and "node 4" in ev["reason"]
    assert not _events(d, "accommodated")
    assert all(np.all(np.asarray(r["thrust"]) == 0.0) for r in cycles if r["t_ns"] > ev["t_ns"])
