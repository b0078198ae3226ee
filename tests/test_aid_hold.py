"""AID on a DOF given up (issue 33): when a thruster's effectiveness leaves a DOF unreached,
the online estimator's parameters of that DOF's rows are held while the others adapt, and the
estimates say so. The JHU ROV through the one supervised cycle (lockstep) with 6-DOF AID, the
bow vertical thruster (4) killed by the operator: pitch is given up."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from uvd.estimation.aid import INITP_6DOF, aid6_init, aid_hold_dofs, held_indices
from uvd.lockstep import of_config
from uvd.runtime import commands as cmd
from uvd.runtime.config import DEFAULT_CONFIG, load_config
from uvd.telemetry.records import estimate_records

pytestmark = pytest.mark.timeout(300)


def test_the_rows_of_a_dof_are_its_entries_of_m_d_g_b():
    pitch = held_indices(6, (4,))
    # M̂: row/column 4 of a symmetric 6×6 → 6 of the 21 unique entries; D̂ᵢ: row 4 of each of
    # the six 6×6 → 36 entries; b̂ (rotational row): 3; ĝ not (it enters the translational rows)
    assert pitch.size == 6 + 36 + 3
    assert 237 not in pitch and {238, 239, 240} <= set(pitch.tolist())
    heave = held_indices(6, (2,))
    assert 237 in heave and 238 not in heave
    assert held_indices(3, (0,)).size == 0  # 3-DOF AID has no surge row
    assert held_indices(3, (4,)).size == 3 + 9 + 3


def test_every_dof_actuated_holds_nothing():
    st = aid6_init(INITP_6DOF)
    assert aid_hold_dofs(st, st, np.ones(6, dtype=bool)) is st


def test_aid_holds_the_pitch_rows_while_the_others_adapt():
    cfg = load_config(DEFAULT_CONFIG)  # the JHU ROV, six thrusters
    cfg = replace(cfg, estimation=replace(cfg.estimation, aid=True))
    sim = of_config(cfg, armed=False)
    sim.advance()
    assert sim.command(cmd.Arm()).ok
    for _ in range(20):
        sim.advance()
    assert sim.command(cmd.SetThrusterEta(4, 0.0, source="test")).ok
    theta0 = np.array(sim.state.est[0].theta)
    thetas, reasons = [], []
    for _ in range(150):  # 15 s
        out = sim.advance()
        assert out.given_up == ("pitch",)
        thetas.append(np.array(sim.state.est[0].theta))
        reasons.append(estimate_records(sim.core_cfg, sim.state, sim.t_ns)[0]["hold_reason"])
    held = held_indices(6, (4,))
    free = np.setdiff1d(np.arange(241), held)
    th = np.array(thetas)
    assert sim.state.est[0].steps > 100 and not sim.state.est[0].frozen
    np.testing.assert_array_equal(th[:, held], np.broadcast_to(theta0[held], th[:, held].shape))
    moved = np.abs(th[-1, free] - theta0[free]) > 0
    print(f"held {held.size} parameters constant; {int(moved.sum())} of {free.size} others moved")
    assert moved.sum() > 100
    assert set(reasons) == {"pitch given up (no thruster reaches it): rows held, 45 of 241 "
                            "parameters of θ̂"}
    # back: the rows adapt again and the reason clears
    assert sim.command(cmd.SetThrusterEta(4, 1.0)).ok
    for _ in range(20):
        sim.advance()
    assert estimate_records(sim.core_cfg, sim.state, sim.t_ns)[0]["hold_reason"] == ""
    assert np.any(np.array(sim.state.est[0].theta)[held] != theta0[held])
