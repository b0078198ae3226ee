"""The operator's thruster effectiveness through the one supervised cycle (lockstep): the
command sets η, the next cycles allocate with it and give up what the thrusters left cannot
reach, no failsafe follows, clearing restores the healthy allocation; refusals name why."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from uvd.control.ambc import drag_index, mass_index
from uvd.lockstep import of_config
from uvd.runtime import commands as cmd
from uvd.runtime.config import DEFAULT_CONFIG, load_config


def _sim(**control):
    cfg = load_config(DEFAULT_CONFIG)  # the JHU ROV, six thrusters
    if control:
        cfg = replace(cfg, control=replace(cfg.control, **control))
    sim = of_config(cfg, armed=False)
    sim.advance()  # standby: the arming checks need a health snapshot
    assert sim.command(cmd.Arm()).ok
    return sim


def _run(sim, seconds):
    outs = []
    for _ in range(round(seconds / sim.dt_control)):
        outs.append((sim.advance(), sim.last_result.decision.action.label))
    return outs


def test_the_operator_kills_and_restores_a_thruster_through_the_cycle():
    runs = []
    for _ in range(2):
        sim = _sim()
        before = _run(sim, 2.0)
        res = sim.command(cmd.SetThrusterEta(4, 0.0, source="test"))
        assert res.ok and res.reason == "thruster 4 eta 0 (test); given up: pitch"
        fdc_like = sim.command(cmd.SetThrusterEta(3, 0.475901, source="uvd-fdc"))
        assert fdc_like.reason.startswith("thruster 3 eta 0.476 (uvd-fdc)")  # text rounded
        assert sim.command(cmd.SetThrusterEta(3, 1.0)).ok
        during = _run(sim, 3.0)
        assert sim.command(cmd.SetThrusterEta(4, 1.0)).ok
        after = _run(sim, 1.0)
        runs.append([o.thrust_n.copy() for o, _ in before + during + after])
        assert all(o.given_up == () for o, _ in before + after)
        assert all(o.given_up == ("pitch",) and o.thrust_n[3] == 0.0 for o, _ in during)
        assert any(o.thrust_n[3] != 0.0 for o, _ in after)
        # no failsafe: the vehicle keeps flying on five thrusters
        assert {a for _, a in before + during + after} == {before[0][1]}
        assert all(o.status == "ok" and o.mode == "control" for o, _ in during)
    np.testing.assert_array_equal(runs[0], runs[1])  # deterministic: replayable


@pytest.mark.parametrize("c, why", [
    (cmd.SetThrusterEta(7, 0.0), "thruster 7 is not one of 1..6"),
    (cmd.SetThrusterEta(0, 0.0), "thruster 0 is not one of 1..6"),
    (cmd.SetThrusterEta(2, 1.5), "eta 1.5 is not in [0, 1]"),
    (cmd.SetThrusterEta(2, math.nan), "eta nan is not in [0, 1]"),
    (cmd.SetThrusterEta("x", 0.5), "thruster must be an integer and eta a number"),
])
def test_an_effectiveness_that_does_not_fit_is_refused_by_name(c, why):
    sim = _sim()
    res = sim.command(c)
    assert not res.ok and res.reason == why
    assert sim.supervisor.data.thruster_eta is None


def test_the_command_round_trips_through_its_record():
    c = cmd.SetThrusterEta(3, 0.5, source="mavlink")
    rec = {"command": "SetThrusterEta", "args": {"thruster": 3, "eta": 0.5,
                                                 "source": "mavlink"}}
    assert cmd.command_from_record(rec) == c


def test_an_adaptive_controller_does_not_adapt_on_the_dof_given_up():
    """AMBC (single step, from the vehicle file's values) with the bow vertical thruster dead:
    pitch is given up, out of the closed loop — its mass m₅ and drag d₅ stay where they were
    while the other DOFs' parameters keep adapting."""
    sim = _sim(controller="ambc", theta0="vehicle")
    _run(sim, 3.0)
    pitch = [mass_index("decoupled")[4], drag_index("decoupled")[4]]
    others = [mass_index("decoupled")[i] for i in (0, 1, 2, 3, 5)]
    th0 = np.array(sim.state.ctrl.theta)
    assert sim.command(cmd.SetThrusterEta(4, 0.0)).ok
    during = _run(sim, 5.0)
    th1 = np.array(sim.state.ctrl.theta)
    assert all(o.given_up == ("pitch",) for o, _ in during)
    np.testing.assert_array_equal(th1[pitch], th0[pitch])
    assert np.any(th1[others] != th0[others])
