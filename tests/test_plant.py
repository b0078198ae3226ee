"""The simulated plant (2.44) on SE(3): energy, equilibria, steady state, order of accuracy."""

import math

import numpy as np
import pytest

from sim_bridge.plant import Plant, PlantConfig
from sim_bridge.thrusters import ThrusterEffects
from uvd.io.vehicle import load_vehicle
from uvd.model.dynamics import UVModel, kinetic_energy, uv_accel
from uvd.model.integrate import kernel_accel, simulate
from uvd.model.lie import exp_so3, inv_H, log_se3, make_H
from uvd.model.params import UVParams
from uvd.model.vehicle import Vehicle


def _with(vehicle: Vehicle, **changes) -> Vehicle:
    p = vehicle.params
    params = UVParams(M=changes.get("M", p.M), D=changes.get("D", p.D), g=changes.get("g", p.g),
                      b=changes.get("b", p.b))
    return Vehicle(vehicle.name, vehicle.description, params, vehicle.thrusters)


@pytest.fixture(scope="module")
def coupled():
    return load_vehicle("jhu-rov-coupled")


def test_compiled_dynamics_equal_the_reference_formula(coupled):
    model = UVModel.from_params(coupled.params)
    rng = np.random.default_rng(0)
    for _ in range(50):
        v, u = rng.normal(size=6), 100 * rng.normal(size=6)
        R = exp_so3(rng.normal(size=3))
        np.testing.assert_allclose(kernel_accel(model, v, R, u), uv_accel(model, v, R, u),
                                   rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", ["jhu-rov", "jhu-rov-coupled"])
def test_kinetic_energy_never_increases_without_input_or_gravity(name):
    """u = 0, g = 0, b = 0: d/dt ½vᵀMv = vᵀ(Σ|v_i|D_i)v ≤ 0 (adᵀ does no work)."""
    vehicle = _with(load_vehicle(name), g=0.0, b=np.zeros(3))
    rng = np.random.default_rng(1)
    for _trial in range(3):
        plant = Plant(vehicle, PlantConfig(rate_hz=100.0),
                      H0=make_H(exp_so3(rng.normal(size=3)), rng.normal(size=3)),
                      v0=rng.normal(size=6) * [0.5, 0.5, 0.5, 0.6, 0.6, 0.6])
        e_prev = kinetic_energy(plant.model, plant.v)
        e0 = e_prev
        for _ in range(2000):
            plant.step_wrench(np.zeros(6))
            e = kinetic_energy(plant.model, plant.v)
            assert e <= e_prev * (1 + 1e-12) + 1e-15, f"energy rose at t={plant.t}"
            e_prev = e
        assert e < 0.5 * e0  # and drag actually removed energy


def _tilt_from_equilibrium(plant, b):
    """Angle between the body-frame gravity direction Rᵀe₃ and b (zero at equilibrium, where
    J(b)Rᵀe₃ = 0: centre of buoyancy straight above the centre of gravity)."""
    r = plant.R.T @ np.array([0.0, 0.0, 1.0])
    return math.acos(min(1.0, float(r @ b) / np.linalg.norm(b)))


def test_buoyancy_torque_returns_roll_and_pitch_to_equilibrium(coupled):
    """Released at 27° of tilt, roll and pitch oscillate back to the equilibrium of b.

    Drag is purely quadratic (2.44), so the oscillation decays like 1/t, not exponentially:
    the test checks a steady decay of the peak tilt and a small final tilt.
    """
    vehicle = _with(coupled, g=0.0)
    b = vehicle.params.b
    plant = Plant(vehicle, PlantConfig(), H0=make_H(exp_so3([0.35, -0.3, 0.2]), np.zeros(3)))
    peaks = []
    for _window in range(6):  # six windows of 20 s
        peak = 0.0
        for _ in range(20 * 100):
            plant.step_wrench(np.zeros(6))
            peak = max(peak, _tilt_from_equilibrium(plant, b))
        peaks.append(peak)
    assert peaks[0] > 0.1
    assert all(later < earlier for earlier, later in zip(peaks, peaks[1:], strict=False))
    assert peaks[-1] < 0.1 * peaks[0]


def test_constant_surge_force_settles_where_thrust_balances_drag():
    """Decoupled jhu-rov (Table 5.5): steady surge speed u with d₁u|u| + F = 0 → u = √(F/|d₁|),
    thrust produced by the two aft thrusters through their full model (lag, stiction, limits).

    b = g = 0 and a level start keep the motion in pure surge (an invariant subspace): with
    m₂ > m₁ the Munk moment (m₁ − m₂)uv makes straight-line surge directionally unstable, so
    any tilt from b would let the vehicle turn away — physics, which a heading controller
    handles in closed loop.
    """
    vehicle = _with(load_vehicle("jhu-rov"), g=0.0, b=np.zeros(3))
    plant = Plant(vehicle, PlantConfig())
    F = 120.0
    cmd = np.zeros(6)
    cmd[:2] = F / 2  # aft-port, aft-starboard thrust along +x; their yaw moments cancel
    for _ in range(120 * 100):
        plant.step(cmd)
    d1 = vehicle.params.D[0, 0, 0]
    assert plant.v[0] == pytest.approx(math.sqrt(F / -d1), rel=1e-3)
    np.testing.assert_allclose(plant.v[1:], 0.0, atol=1e-9)


def test_rk4_is_fourth_order_on_a_smooth_trajectory(coupled):
    """Halving h divides the error by ≈ 16. Smooth: no drag (|v_i| is not differentiable at 0)."""
    vehicle = _with(coupled, D=np.zeros((6, 6, 6)))
    model = UVModel.from_params(vehicle.params)
    H0 = make_H(exp_so3([0.1, 0.2, 0.3]), np.zeros(3))
    v0 = np.array([0.5, 0.4, 0.3, 0.3, 0.35, 0.4])
    u = np.array([200.0, 100.0, 100.0, 50.0, 60.0, 40.0])
    finals = {}
    for h in (0.1, 0.05, 0.025, 0.0125, 0.00625):
        _, Hs, vs = simulate(model, H0, v0, lambda t: u, 2.0, h)
        finals[h] = (Hs[-1], vs[-1])
    ref_H, ref_v = finals[0.00625]

    def err(h):
        H, v = finals[h]
        return np.linalg.norm(log_se3(inv_H(ref_H) @ H)) + np.linalg.norm(v - ref_v)

    orders = [math.log2(err(h) / err(h / 2)) for h in (0.1, 0.05)]
    assert all(3.7 < o < 4.5 for o in orders), orders


def test_pose_stays_on_se3(coupled):
    plant = Plant(coupled, PlantConfig(), v0=np.array([0.3, -0.2, 0.1, 0.5, -0.4, 0.8]))
    rng = np.random.default_rng(2)
    for _ in range(5000):
        plant.step(rng.normal(size=6) * 80.0)
    R = plant.R
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_array_equal(plant.H[3], [0, 0, 0, 1])


def test_non_finite_wrench_is_no_wrench(coupled):
    plant = Plant(coupled, PlantConfig())
    plant.step_wrench(np.array([np.nan, 0, 0, 0, 0, 0]))
    assert np.all(np.isfinite(plant.H)) and np.all(np.isfinite(plant.v))
    plant.step(np.array([np.inf, 0, 0, 0, 0, 0]))
    assert np.all(np.isfinite(plant.v))


def test_effects_can_be_switched_off(coupled):
    """With every thruster effect off the plant applies exactly u = B f."""
    off = ThrusterEffects(lag=False, stiction=False, saturation=False)
    a = Plant(coupled, PlantConfig(thrusters=off))
    b = Plant(coupled, PlantConfig())
    f = np.array([400.0, -400.0, 10.0, -3.0, 3.0, 50.0])
    a.step(f)
    np.testing.assert_allclose(a.u, coupled.B @ f, rtol=1e-12)
    b.step(f)
    assert not np.allclose(b.u, coupled.B @ f)


def test_an_entanglement_fault_raises_drag_so_the_same_thrust_settles_slower():
    """PlantFault(drag_scale=1.5) mid-run: the steady surge speed of the test above falls by
    √1.5 (d₁u|u| + F = 0 with 1.5·d₁); clearing the fault restores it."""
    from sim_bridge.plant import PlantFault

    vehicle = _with(load_vehicle("jhu-rov"), g=0.0, b=np.zeros(3))
    plant = Plant(vehicle, PlantConfig())
    F = 120.0
    cmd = np.zeros(6)
    cmd[:2] = F / 2
    d1 = vehicle.params.D[0, 0, 0]
    for fault, scale in ((PlantFault(drag_scale=1.5), 1.5), (None, 1.0)):
        plant.set_fault(fault)
        for _ in range(120 * 100):
            plant.step(cmd)
        assert plant.v[0] == pytest.approx(math.sqrt(F / -(scale * d1)), rel=1e-3)
    with pytest.raises(ValueError, match="PlantFault"):
        PlantFault(mass_scale=0.0)


@pytest.mark.parametrize("tank", [False, True])
def test_steps_held_traces_the_state_of_every_step_as_single_steps_make_it(tank):
    """``steps_held(cmd, n, trace)``: one call, the state after each step in the trace — bit
    for bit what n calls of ``step`` pass through (the lockstep's instruments sample it), the
    tank's plant (its own step) included; the trace's shorter than n: only its rows."""
    from sim_bridge.tank import TankEffects, TankPlant

    def plant():
        p = Plant(load_vehicle("jhu-rov"), H0=make_H(np.eye(3), np.array([0.0, 0.0, 2.0])),
                  v0=np.array([0.3, 0.0, 0.05, 0.0, 0.01, 0.1]))
        return TankPlant(p, TankEffects(tether_n=5.0)) if tank else p

    cmd = np.array([20.0, -15.0, 5.0, 3.0, -8.0, 1.0])
    a, b = plant(), plant()
    trace = (np.full((7, 4, 4), np.nan), np.full((7, 6), np.nan))
    for n in (7, 3):
        a.steps_held(cmd, n, trace)
        for i in range(n):
            b.step(cmd)
            assert trace[0][i].tobytes() == b.H.tobytes()
            assert trace[1][i].tobytes() == b.v.tobytes()
        assert a.H.tobytes() == b.H.tobytes() and a.v.tobytes() == b.v.tobytes()
    short = (np.empty((2, 4, 4)), np.empty((2, 6)))
    a.steps_held(cmd, 4, short)
    b.steps_held(cmd, 4)
    assert a.H.tobytes() == b.H.tobytes() and short[0][1].tobytes() != a.H.tobytes()
