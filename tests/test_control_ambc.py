"""MBC (Theorem 5.2.1) and AMBC (Theorem 5.2.2): the structured regressor products equal the
kron-built W_UV of (2.49); the control law (5.27) and update law (5.28) computed independently;
fixed parameters (K = 0) stay fixed (§5.2.6); robust projection, dead zone and freezes; MBC
tracking with the true parameters."""

import numpy as np
import pytest
from hypothesis import given, settings

from sim_bridge.plant import Plant, PlantConfig
from sim_bridge.thrusters import ThrusterEffects
from tests.strategies import rotation, theta_uv, vec
from uvd.control import _kernels
from uvd.control.allocation import Allocator, allocate
from uvd.control.ambc import (
    AMBCParams,
    MBCParams,
    MBCState,
    RobustAdaptation,
    adaptation_gains,
    ambc_init,
    ambc_params,
    ambc_step,
    gravity_index,
    mbc_step,
    params_of,
    theta_of,
)
from uvd.control.errors import error_coordinates, error_state
from uvd.control.trajectory import reftraj1, setpoint
from uvd.control.types import Reference, VehicleState
from uvd.io.vehicle import load_vehicle
from uvd.model.lie import A_inv_se3, ad, exp_se3
from uvd.model.params import DECOUPLED_INDEX, UVParams
from uvd.model.regressors import W_UV

ROV = load_vehicle("jhu-rov")
COUPLED = load_vehicle("jhu-rov-coupled")


@settings(max_examples=25, deadline=None)
@given(v=vec(6), alpha=vec(6), R=rotation(), theta=theta_uv(), s=vec(6))
def test_structured_products_equal_the_kron_regressor(v, alpha, R, theta, s):
    W = W_UV(v, alpha, R)
    r = np.ascontiguousarray(R[2])
    scale = 1 + np.abs(W).max() * (1 + np.abs(theta).max())
    np.testing.assert_allclose(_kernels.w_theta(0, theta, v, alpha, r), W @ theta,
                               atol=1e-12 * scale)
    np.testing.assert_allclose(_kernels.wT_s(0, 241, v, alpha, r, s), W.T @ s,
                               atol=1e-12 * (1 + np.abs(W).max()))
    Wd = W[:, DECOUPLED_INDEX]
    th16 = theta[DECOUPLED_INDEX]
    np.testing.assert_allclose(_kernels.w_theta(1, th16, v, alpha, r), Wd @ th16,
                               atol=1e-12 * scale)
    np.testing.assert_allclose(_kernels.wT_s(1, 16, v, alpha, r, s), Wd.T @ s,
                               atol=1e-12 * (1 + np.abs(W).max()))


def _random_case(rng):
    Ha = exp_se3(rng.normal(size=6) * 0.3)
    Hd = exp_se3(rng.normal(size=6) * 0.3)
    va, vd, vdd = rng.normal(size=(3, 6)) * 0.3
    return VehicleState(Ha, va), Reference(H=Hd, v=vd, vdot=vdd)


@pytest.mark.parametrize("model", ["full", "decoupled"])
def test_control_and_update_laws_match_an_independent_computation(model):
    rng = np.random.default_rng(7)
    for _ in range(3):
        vs, ref = _random_case(rng)
        p = ambc_params(model, kp=300.0, kd=100.0, eps=0.2)
        theta = theta_of(COUPLED.params, model) * (1 + 0.1 * rng.normal(size=p.n))
        u, nxt = ambc_step(vs, ref, p, ambc_init(p, theta), 0.01)
        # independent: (5.2)-(5.4), (5.10), (5.12) with the kron regressor
        dH, dpsi, dv, avd = error_coordinates(vs.H, vs.v, ref.H, ref.v)
        from uvd.model.lie import Ad, inv_H
        a_d = Ad(inv_H(dH)) @ ref.vdot - ad(dv) @ avd
        W = W_UV(vs.v, a_d, vs.H[:3, :3])
        if model == "decoupled":
            W = W[:, DECOUPLED_INDEX]
        u_ref = -(300 * A_inv_se3(dpsi).T @ dpsi + 100 * dv) + W @ theta
        np.testing.assert_allclose(u, u_ref, rtol=1e-10, atol=1e-8)
        rate = -p.K * (W.T @ (0.2 * dpsi + dv))
        np.testing.assert_allclose(nxt.theta_dot, rate, rtol=1e-10, atol=1e-8)
        np.testing.assert_allclose(nxt.theta, theta + 0.01 * rate, rtol=1e-12, atol=1e-10)
        np.testing.assert_allclose(nxt.dpsi, dpsi, atol=1e-12)
        es = error_state(vs.H, vs.v, ref.H, ref.v, ref.vdot)
        np.testing.assert_allclose(es.alpha, a_d, atol=1e-12)


def test_zero_gains_keep_parameters_fixed_and_mbc_is_ambc_without_gains():
    rng = np.random.default_rng(3)
    vs, ref = _random_case(rng)
    K = adaptation_gains("decoupled")
    K[gravity_index("decoupled")] = 0.0  # step 2 of §5.2.6: g and b known
    p = AMBCParams(model="decoupled", K=K)
    th0 = ROV.params.decoupled_view()
    _, nxt = ambc_step(vs, ref, p, ambc_init(p, th0), 0.1)
    gi = gravity_index("decoupled")
    np.testing.assert_array_equal(nxt.theta[gi], th0[gi])
    assert np.all(nxt.theta[:12] != th0[:12])
    u_mbc, _ = mbc_step(vs, ref, MBCParams(theta=th0), MBCState(), 0.1)
    p0 = AMBCParams(model="decoupled", K=np.zeros(16))
    u0, s0 = ambc_step(vs, ref, p0, ambc_init(p0, th0), 0.1)
    np.testing.assert_allclose(u_mbc, u0)
    np.testing.assert_array_equal(s0.theta, th0)


def test_open_loop_dofs_get_no_feedback_and_do_not_adapt():
    rng = np.random.default_rng(5)
    vs, ref = _random_case(rng)
    mask = np.array([True, True, True, False, False, True])
    ref = Reference(H=ref.H, v=ref.v, vdot=ref.vdot, closed_loop=mask)
    p = ambc_params("decoupled")
    u, nxt = ambc_step(vs, ref, p, ambc_init(p, ROV.params.decoupled_view()), 0.1)
    assert u[3] == 0.0 and u[4] == 0.0
    # the update law sees s = εΔψ + Δv with the open-loop components removed
    es = error_state(vs.H, vs.v, ref.H, ref.v, ref.vdot)
    s = (p.eps * es.dpsi + es.dv) * mask
    W = W_UV(vs.v, es.alpha, vs.H[:3, :3])[:, DECOUPLED_INDEX]
    np.testing.assert_allclose(nxt.theta_dot, -p.K * (W.T @ s), rtol=1e-10, atol=1e-9)


# ---------------------------------------------------------------------------------------------
# robust adaptation
# ---------------------------------------------------------------------------------------------
def _M_of(theta):
    return params_of(theta, "full").M


@settings(max_examples=40, deadline=None)
@given(theta=theta_uv())
def test_projection_makes_the_model_physical_and_is_idempotent(theta):
    th = theta.copy()
    mf, dc = np.full(6, 10.0), np.full(6, 1.0)
    _kernels.project(0, th, mf, dc)
    p = params_of(th, "full")
    assert p.mass_min_eigenvalue() >= 10.0 - 1e-6
    for Di in p.D:
        assert np.linalg.eigvalsh(0.5 * (Di + Di.T))[-1] <= -1.0 + 1e-6
    assert p.drag_dissipativity_max() < 0.0
    again = th.copy()
    assert _kernels.project(0, again, mf, dc) == 0
    np.testing.assert_array_equal(again, th)


@settings(max_examples=40, deadline=None)
@given(theta=theta_uv())
def test_projection_never_moves_away_from_the_true_parameters(theta):
    """The true coupled parameters lie in the projection set, so the (Frobenius) projection
    brings every block at least as close to them."""
    truth = COUPLED.params
    th = theta.copy()
    _kernels.project(0, th, np.full(6, 10.0), np.full(6, 1.0))
    before, after = params_of(theta, "full"), params_of(th, "full")
    assert (np.linalg.norm(after.M - truth.M) <= np.linalg.norm(before.M - truth.M) + 1e-6)
    for Da, Db, Dt in zip(after.D, before.D, truth.D, strict=True):
        assert np.linalg.norm(Da - Dt) <= np.linalg.norm(Db - Dt) + 1e-6


def test_true_parameters_are_inside_the_projection_set():
    # the coupled D_i have negative definite symmetric parts (largest eigenvalue -30.2)
    for veh, model, ceiling in ((COUPLED, "full", 1.0), (ROV, "decoupled", 1.0),
                                (ROV, "full", 0.0)):
        th = theta_of(veh.params, model)
        moved = _kernels.project(0 if model == "full" else 1, th.copy(), np.full(6, 10.0),
                                 np.full(6, ceiling))
        assert moved == 0
    # a decoupled D_i = d_i e_i e_iᵀ is only semidefinite: outside a strictly negative ceiling
    assert _kernels.project(0, theta_of(ROV.params, "full"), np.full(6, 10.0),
                            np.full(6, 1.0)) == 6


def test_a_non_finite_estimate_passes_the_projection_without_raising():
    """NaN in M̂ or a D̂ᵢ: the block is left as it was, and the projection does not raise
    (numba's eigendecomposition would, mid-cycle)."""
    th = theta_of(COUPLED.params, "full")
    th[3] = np.nan       # an off-diagonal entry of M̂
    th[21 + 7] = np.nan  # an entry of D̂₁
    before = th.copy()
    assert _kernels.project(0, th, np.full(6, 10.0), np.full(6, 1.0)) == 0
    np.testing.assert_array_equal(th, before)  # (NaNs in the same places count as equal)
    # the full-model AMBC cycle with robust projection on and a NaN in the reference:
    # a non-finite command (the core zeroes it), no exception
    alloc = Allocator.from_vehicle(COUPLED)
    p = ambc_params("full", robust=RobustAdaptation(enabled=True), allocator=alloc)
    ref = reftraj1().at(1.0)
    bad = Reference(H=ref.H, v=ref.v, vdot=np.array([np.nan, 0, 0, 0, 0, 0]))
    u, _ = ambc_step(VehicleState(ref.H, ref.v + 0.01), bad, p,
                     ambc_init(p, theta_of(COUPLED.params, "full")), 0.1)
    assert not np.all(np.isfinite(u))


def test_decoupled_projection_clips_masses_and_drags():
    th = ROV.params.decoupled_view()
    th[3] = -5.0
    th[9] = 40.0
    _kernels.project(1, th, np.full(6, 10.0), np.full(6, 1.0))
    assert th[3] == 10.0 and th[9] == -1.0


def test_freeze_on_saturation_and_dead_zone():
    alloc = Allocator.from_vehicle(ROV)
    th0 = ROV.params.decoupled_view()
    rng = np.random.default_rng(11)
    vs, ref = _random_case(rng)
    far = Reference(H=ref.H, v=ref.v * 100, vdot=ref.vdot * 100)  # huge command
    rb = RobustAdaptation(enabled=True, freeze_on_saturation=True)
    p = ambc_params("decoupled", robust=rb, allocator=alloc)
    u, nxt = ambc_step(vs, far, p, ambc_init(p, th0), 0.1)
    assert allocate(alloc, u)[2] < 1.0 and nxt.saturated and nxt.frozen
    np.testing.assert_array_equal(nxt.theta, th0)
    # off: the same cycle adapts
    p_off = ambc_params("decoupled", allocator=alloc)
    _, nxt = ambc_step(vs, far, p_off, ambc_init(p_off, th0), 0.1)
    assert np.any(nxt.theta != th0)
    # dead zone larger than the error: no update; smaller: a scaled update
    ref0 = reftraj1().at(1.0)
    near = VehicleState(ref0.H, ref0.v + 1e-3)
    big = ambc_params("decoupled", robust=RobustAdaptation(enabled=True, dead_zone=1.0))
    _, nxt = ambc_step(near, ref0, big, ambc_init(big, th0), 0.1)
    assert nxt.frozen and np.array_equal(nxt.theta, th0)
    small = ambc_params("decoupled", robust=RobustAdaptation(enabled=True, dead_zone=1e-4))
    plain = ambc_params("decoupled")
    _, a = ambc_step(near, ref0, small, ambc_init(small, th0), 0.1)
    _, b = ambc_step(near, ref0, plain, ambc_init(plain, th0), 0.1)
    s = np.linalg.norm(0.1 * b.dpsi + b.dv)
    np.testing.assert_allclose(a.theta_dot[:12], b.theta_dot[:12] * (1 - 1e-4 / s), rtol=1e-9)


def test_reversal_hold_freezes_after_a_sign_change():
    alloc = Allocator.from_vehicle(ROV)
    th0 = ROV.params.decoupled_view()
    rb = RobustAdaptation(enabled=True, reversal_hold_s=0.5, stiction_band_n=0.0,
                          freeze_on_saturation=False)
    p = ambc_params("decoupled", robust=rb, allocator=alloc)
    st0 = ambc_init(p, th0)
    ref = setpoint((0, 0, 1.5, 0, 0, 0)).at(0.0)  # no feed-forward: u ≈ −k_d Δv
    vs = VehicleState(ref.H, ref.v + 0.3)
    u1, s1 = ambc_step(vs, ref, p, st0, 0.1)
    assert not s1.frozen
    vs2 = VehicleState(ref.H, ref.v - 0.3)  # flips the sign of the commands
    _, s2 = ambc_step(vs2, ref, p, s1, 0.1)
    assert s2.frozen and s2.hold_until == pytest.approx(0.2 + 0.5)
    np.testing.assert_array_equal(s2.theta, s1.theta)


def test_parameters_are_validated():
    with pytest.raises(ValueError):
        AMBCParams(model="coupled", K=np.zeros(16))
    with pytest.raises(ValueError):
        AMBCParams(model="decoupled", K=np.zeros(241))
    with pytest.raises(ValueError):
        ambc_init(ambc_params("decoupled"), np.full(16, np.nan))
    with pytest.raises(ValueError):
        MBCParams(theta=np.zeros(10))


# ---------------------------------------------------------------------------------------------
# MBC with the true parameters (acceptance: ≤ 1e-3 m and rad after transients)
# ---------------------------------------------------------------------------------------------
def _mbc_closed_loop(vehicle, rate_hz, duration_s, params: UVParams | None = None):
    """MBC tracking RefTraj1 from zero initial error on the plant with ideal thrusters (no lag,
    no stiction; saturation on), exact state feedback, no noise; returns (t, Δψ) records."""
    traj = reftraj1()
    r0 = traj.at(0.0)
    plant = Plant(vehicle, PlantConfig(rate_hz=1000.0, thrusters=ThrusterEffects(
        lag=False, stiction=False, saturation=True)), H0=r0.H, v0=r0.v)
    alloc = Allocator.from_vehicle(vehicle)
    p = MBCParams.from_params(params or vehicle.params)
    st_ = MBCState()
    sub = int(round(1000 / rate_hz))
    n = int(duration_s * rate_hz)
    out = np.empty((n, 6))
    for k in range(n):
        ref = traj.at(k / rate_hz)
        u, st_ = mbc_step(VehicleState(plant.H, plant.v), ref, p, st_, 1 / rate_hz)
        f, sat, _ = allocate(alloc, u)
        assert not sat.any()
        for _ in range(sub):
            plant.step(f)
        out[k] = st_.dpsi
    return out


@pytest.mark.parametrize("vehicle", [ROV, COUPLED], ids=["jhu-rov", "jhu-rov-coupled"])
def test_mbc_with_true_parameters_tracks_to_1e_3(vehicle):
    dpsi = _mbc_closed_loop(vehicle, 1000.0, 30.0)
    after = np.abs(dpsi[5000:])  # after 5 s of transient
    assert after[:, :3].max() <= 1e-3  # m
    assert after[:, 3:].max() <= 1e-3  # rad


def test_mbc_with_wrong_parameters_does_not_reach_1e_3():
    """The bound above is a property of the model, not of the PD gains."""
    wrong = UVParams.decoupled(0.5 * ROV.params.decoupled_view()[:6],
                               0.5 * ROV.params.decoupled_view()[6:12], 0.0, (0, 0, 150.0))
    dpsi = _mbc_closed_loop(ROV, 1000.0, 20.0, params=wrong)
    assert np.abs(dpsi[5000:]).max() > 1e-2


def test_mbc_with_noise_and_thruster_dynamics_stays_bounded():
    """The full lockstep loop (10 Hz, Table A.1 noise, propeller lag, stiction): bounded.

    k_d = 1000 (step 2 of §5.3.5): MBC cancels the hydrodynamic damping, and with k_d = 100 the
    surge loop is left with ζ ≈ 0.1, which the 0.15 s propeller lag and the 10 Hz hold turn
    into a ~0.5 m limit cycle."""
    from uvd import core
    from uvd.experiments._control_runner import run_control, tracking_stats

    spec = core.ControllerSpec("mbc", mbc_step, MBCParams.from_params(ROV.params, kd=1000.0),
                               MBCState())
    run = run_control(ROV, spec, reftraj1(), 120.0, seed=3)
    assert run.not_ok == 0
    s = tracking_stats(run, 20.0)
    assert np.abs(run.dpsi_meas[200:]).max() < 0.05
    assert s["position_mne"] < 0.03 and s["velocity_mne"] < 0.03
