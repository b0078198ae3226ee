"""Cross-validation (App. A.2): MAE arithmetic, exact replay of the plant, rotational embedding,
divergence, tables."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from sim_bridge.plant import Plant, PlantConfig
from uvd.estimation.runlog import RunLog
from uvd.estimation.xval import (
    STATES_6DOF,
    STATES_ROT,
    cross_validate,
    embed_rotational,
    format_mae_table,
    mae,
    simulate_run,
    states_of,
)
from uvd.geometry import euler_to_R
from uvd.io.vehicle import load_vehicle
from uvd.model.dynamics import rot_accel
from uvd.model.lie import J
from uvd.model.params import ROTATIONAL_INDEX, RotParams, UVParams

TRUE = load_vehicle("jhu-rov-coupled").params


def test_mae_known_answer():
    """Roll off by exactly 2°, pitch by ±1.5° alternately, u by 0.05 m/s, r by −3 °/s, across
    the ±180° wrap too: the MAEs are those numbers."""
    n = 100
    roll = np.linspace(-0.5, 0.5, n)
    pitch = np.linspace(-0.3, 0.3, n)
    heading = np.linspace(-3.0, 3.0, n)
    R_meas = np.stack([euler_to_R(a, b, c) for a, b, c in zip(roll, pitch, heading, strict=True)])
    sign = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    R_sim = np.stack([euler_to_R(a + math.radians(2.0), b + sign[i] * math.radians(1.5), c)
                      for i, (a, b, c) in enumerate(zip(roll, pitch, heading, strict=True))])
    v_meas = np.zeros((n, 6))
    v_meas[:, 0] = np.linspace(-0.2, 0.2, n)
    v_sim = v_meas.copy()
    v_sim[:, 0] += 0.05
    v_sim[:, 5] -= math.radians(3.0)
    out = mae(states_of(R_meas, v_meas), states_of(R_sim, v_sim), STATES_6DOF)
    assert out["roll_deg"] == pytest.approx(2.0, abs=1e-9)
    assert out["pitch_deg"] == pytest.approx(1.5, abs=1e-9)
    assert out["u_mps"] == pytest.approx(0.05, abs=1e-12)
    assert out["r_degps"] == pytest.approx(3.0, abs=1e-9)
    for s in ("v_mps", "w_mps", "p_degps", "q_degps"):
        assert out[s] == 0.0
    # the wrap: 179° vs −179° is 2° apart, not 358°
    R1 = np.stack([euler_to_R(math.radians(179.0), 0.0, 0.0)])
    R2 = np.stack([euler_to_R(math.radians(-179.0), 0.0, 0.0)])
    z = np.zeros((1, 6))
    assert mae(states_of(R1, z), states_of(R2, z), ("roll_deg",))["roll_deg"] == \
        pytest.approx(2.0, abs=1e-9)


def _ideal_run(seconds, dt=0.1, substeps=10, params=None):
    vehicle = load_vehicle("jhu-rov-coupled")
    plant = Plant(vehicle, PlantConfig(rate_hz=substeps / dt))
    n = int(round(seconds / dt))
    R, p, v, U = np.empty((n, 3, 3)), np.empty((n, 3)), np.empty((n, 6)), np.empty((n, 6))
    u = np.zeros(6)
    for k in range(n):
        t = k * dt
        R[k], p[k], v[k], U[k] = plant.H[:3, :3], plant.H[:3, 3], plant.v, u
        u = np.array([50 * np.cos(0.3 * t), 40 * np.cos(0.4 * t), 60 * np.cos(0.2 * t),
                      30 * np.cos(0.5 * t), 40 * np.cos(0.6 * t), 50 * np.cos(0.25 * t)])
        for _ in range(substeps):
            plant.step_wrench(u)
    return RunLog(t=np.arange(n) * dt, R=R, p=p, v=v, u=U, input_interp="hold")


def test_true_parameters_replay_the_plant_exactly():
    """The plant's own parameters, the same integrator and step: MAE at round-off level."""
    run = _ideal_run(120.0)
    res = cross_validate(TRUE, run, substeps=10)
    assert res.diverged_at_s is None
    assert max(res.mae.values()) < 1e-8
    # and the default (coarser) step is still far below any physical error
    res2 = cross_validate(TRUE, run)
    assert res2.mae["roll_deg"] < 1e-3 and res2.mae["u_mps"] < 1e-5
    # a wrong model is visibly wrong
    wrong = UVParams(M=1.5 * TRUE.M, D=TRUE.D, g=TRUE.g, b=TRUE.b)
    assert cross_validate(wrong, run).mae["u_mps"] > 1e-3


def test_rotational_embedding_is_the_rotational_model():
    """Simulating RotParams through the embedding equals integrating (2.40) directly."""
    p = RotParams.from_theta(TRUE.theta[ROTATIONAL_INDEX])
    n, dt = 300, 0.1
    t = np.arange(n) * dt
    U = np.zeros((n, 6))
    U[:, 3:] = np.column_stack([40 * np.cos(0.5 * t), 55 * np.cos(0.66 * t),
                                70 * np.cos(1.04 * t)])
    run = RunLog(t=t, R=np.tile(np.eye(3), (n, 1, 1)), p=np.zeros((n, 3)),
                 v=np.zeros((n, 6)), u=U, input_interp="hold")
    Rs, vs, k = simulate_run(p, run, substeps=10)
    assert k is None and np.all(vs[:, :3] == 0.0)

    def f(_t, y, tau):
        R = y[:9].reshape(3, 3)
        w = y[9:]
        return np.concatenate([(R @ J(w)).ravel(), rot_accel(p, w, R, tau)])

    y = np.concatenate([np.eye(3).ravel(), np.zeros(3)])
    for j in range(n - 1):
        sol = solve_ivp(f, (0.0, dt), y, args=(U[j + 1, 3:],), rtol=1e-10, atol=1e-12)
        y = sol.y[:, -1]
    assert np.allclose(vs[-1, 3:], y[9:], atol=1e-6)
    assert np.allclose(Rs[-1], y[:9].reshape(3, 3), atol=1e-6)
    assert embed_rotational(p).M[3:, 3:] == pytest.approx(p.I)


def test_divergent_model_is_reported_not_crashed():
    run = _ideal_run(60.0)
    D = np.stack([200.0 * np.eye(6)] * 6)  # drag that feeds energy in
    bad = UVParams(M=TRUE.M, D=D, g=TRUE.g, b=TRUE.b)
    res = cross_validate(bad, run)
    assert res.diverged_at_s is not None and res.diverged_at_s < 60.0
    assert all(math.isinf(x) for x in res.mae.values())
    table = format_mae_table([("BAD", "RUN", res.mae)], STATES_6DOF)
    assert "diverged" in table and "BAD" in table


def test_table_layout():
    rows = [("AIDPM", "CROSS", {s: 1.234 for s in STATES_ROT}),
            ("LSPM", "IDDAT", {s: 0.5 for s in STATES_ROT})]
    text = format_mae_table(rows, STATES_ROT, title="Table 4.3")
    lines = text.splitlines()
    assert lines[0] == "Table 4.3" and "Roll (deg)" in lines[1] and "AngVelZ (deg/s)" in lines[1]
    assert lines[2].split()[:3] == ["AIDPM", "CROSS", "1.23"]
