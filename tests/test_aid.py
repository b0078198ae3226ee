"""Adaptive identification (Theorems 4.2.1, 4.3.1): update laws, symmetry, freezing, convergence."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_bridge.plant import Plant, PlantConfig
from tests.strategies import rotation, spd, vec
from uvd.control.types import VehicleState
from uvd.estimation.aid import (
    INITP_6DOF,
    INITP_ROT,
    AID3Gains,
    AID3Params,
    AID6Gains,
    AID6Params,
    aid3_init,
    aid3_params,
    aid3_step,
    aid6_estimator,
    aid6_init,
    aid6_params,
    aid6_step,
    aid_unfreeze,
)
from uvd.io.vehicle import load_vehicle
from uvd.model.lie import J, ad, exp_so3, make_H
from uvd.model.params import ROTATIONAL_INDEX, RotParams, UVParams, theta_M_from

TRUE = load_vehicle("jhu-rov-coupled").params


def _vs(R, v):
    return VehicleState(H=make_H(R, np.zeros(3)), v=np.asarray(v, dtype=float))


def _reference_step6(theta, vhat, v, r, u, dt, g, v_prev, v_now=None):
    """(4.23)–(4.27) written with dense matrices, straight from the theorem, with the model and
    regressor terms at the signals (v, r = Rᵀe₃, u); v̂ propagates with ∆v = v̂ − v_prev; the
    parameter laws use that ∆v or, with ``v_now``, the fresh error v̂⁺ − v_now."""
    p = UVParams.from_theta(theta)
    M, D, gg, b = p.M, p.D, p.g, p.b
    G = np.concatenate([gg * r, np.cross(b, r)])
    rhs = ad(v).T @ (M @ v) + np.tensordot(np.abs(v), D, axes=1) @ v + G + u
    psi2 = np.linalg.solve(M, rhs)
    dv = vhat - v_prev
    vhat_new = vhat + dt * (psi2 - g.a * dv)
    if v_now is not None:
        dv = vhat_new - v_now
    psi1 = ad(v) @ dv
    s = np.asarray(g.dof_scale)  # the diagonal gain per DOF (ones: the theorem's scalar γ's)
    Mdot = 0.5 * g.gamma1 * np.sqrt(np.outer(s, s)) * (
        -np.outer(psi1, v) - np.outer(v, psi1) + np.outer(dv, psi2) + np.outer(psi2, dv))
    Ddot = np.stack([-g.gamma2 * abs(v[i]) * np.outer(s * dv, v) for i in range(6)])
    gdot = -g.gamma3 * np.mean(s[:3]) * dv[:3] @ r
    bdot = g.gamma4 * s[3:] * (J(dv[3:]) @ r)
    new = UVParams(M=M + dt * Mdot, D=D + dt * Ddot, g=gg + dt * gdot, b=b + dt * bdot)
    if g.entry_scale:  # one more multiplier per entry of θ_UV: the most general diagonal Γ
        return theta + np.asarray(g.entry_scale) * (new.theta - theta), vhat_new
    return new.theta, vhat_new


@settings(max_examples=60, deadline=None)
@given(M=spd(6, floor=50.0), R=rotation(), v=vec(6, 0.3), vhat=vec(6, 0.3), u=vec(6, 50.0),
       dseed=st.integers(0, 2**31 - 1), per_dof=st.booleans(), per_entry=st.booleans())
def test_aid6_step_is_the_theorem(M, R, v, vhat, u, dseed, per_dof, per_entry):
    """One compiled step equals the dense (4.23)–(4.27) — with the scalar γ's, with a
    diagonal gain per DOF and with one more multiplier per entry (``entry_scale``); M̂ stays
    exactly symmetric."""
    rng = np.random.default_rng(dseed)
    D = rng.normal(size=(6, 6, 6)) * 100.0
    theta0 = UVParams(M=M, D=D, g=rng.normal() * 10, b=rng.normal(size=3) * 50).theta
    gains = AID6Gains(dof_scale=tuple(np.exp(rng.normal(size=6))) if per_dof else (1.0,) * 6,
                      entry_scale=tuple(np.exp(rng.normal(size=241))) if per_entry else ())
    prm = AID6Params(gains=gains, input_interp="hold", sampling="euler")
    st0 = replace(aid6_init(theta0), v_hat=vhat, v_prev=v, r_prev=R[2].copy(),
                  u_prev=np.zeros(6))
    dt = 1e-3
    st1 = aid6_step(_vs(R, v), u, prm, st0, dt)
    th_ref, vhat_ref = _reference_step6(theta0, vhat, v, R[2], u, dt, gains, v_prev=v)
    assert np.allclose(st1.v_hat, vhat_ref, rtol=1e-9, atol=1e-12)
    lam = np.linalg.eigvalsh(UVParams.from_theta(th_ref).M)
    if lam[0] <= prm.pd_floor * lam[-1]:  # the step would break M̂ > 0: freeze, keep θ̂
        assert st1.frozen and np.array_equal(st1.theta, st0.theta)
        return
    assert not st1.frozen
    assert np.allclose(st1.theta, th_ref, rtol=1e-9, atol=1e-9 * np.abs(th_ref).max())
    Mh = aid6_params(st1).M
    assert np.array_equal(Mh, Mh.T)
    assert np.allclose(st1.dv, st1.v_hat - v)


@settings(max_examples=40, deadline=None)
@given(M=spd(6, floor=200.0), R0=rotation(), R1=rotation(), v0=vec(6, 0.3), v1=vec(6, 0.3),
       vhat=vec(6, 0.3), u0=vec(6, 50.0), u1=vec(6, 50.0))
def test_aid6_midpoint_sampling_is_the_theorem_at_interval_signals(M, R0, R1, v0, v1, vhat,
                                                                   u0, u1):
    """Default discretisation: the theorem's right-hand sides at the interval's mid signals
    (½(v₀+v₁), ½(r₀+r₁), ½(u₀+u₁)) and the parameter laws driven by the fresh error."""
    theta0 = UVParams(M=M, D=INITP_6DOF.D, g=-20.0, b=np.array([5.0, -1.0, 300.0])).theta
    gains = AID6Gains()
    prm = AID6Params(gains=gains)
    assert prm.sampling == "midpoint" and prm.input_interp == "linear"
    st0 = replace(aid6_init(theta0), v_hat=vhat, v_prev=v0, r_prev=R0[2].copy(), u_prev=u0)
    dt = 1e-3
    st1 = aid6_step(_vs(R1, v1), u1, prm, st0, dt)
    th_ref, vhat_ref = _reference_step6(theta0, vhat, 0.5 * (v0 + v1), 0.5 * (R0[2] + R1[2]),
                                        0.5 * (u0 + u1), dt, gains, v_prev=v0, v_now=v1)
    assert np.allclose(st1.v_hat, vhat_ref, rtol=1e-9, atol=1e-12)
    lam = np.linalg.eigvalsh(UVParams.from_theta(th_ref).M)
    if lam[0] <= prm.pd_floor * lam[-1]:
        assert st1.frozen and np.array_equal(st1.theta, st0.theta)
        return
    assert np.allclose(st1.theta, th_ref, rtol=1e-9, atol=1e-9 * np.abs(th_ref).max())
    assert np.allclose(st1.dv, st1.v_hat - v1)


def _reference_step3(theta, what, w, R, tau, dt, g):
    p = RotParams.from_theta(theta)
    I, C, b = p.I, p.C, p.b
    r = R.T @ np.array([0.0, 0.0, 1.0])
    rhs = J(I @ w) @ w + np.tensordot(np.abs(w), C, axes=1) @ w + J(b) @ r + tau
    psi3 = np.linalg.solve(I, rhs)
    dw = what - w
    psi4 = J(w) @ dw
    Idot = -0.5 * g.gamma1 * (np.outer(psi4, w) + np.outer(w, psi4) - np.outer(dw, psi3)
                              - np.outer(psi3, dw))
    Cdot = np.stack([-g.gamma2 * abs(w[i]) * np.outer(dw, w) for i in range(3)])
    bdot = -g.gamma3 * J(r) @ dw
    new = RotParams(I=I + dt * Idot, C=C + dt * Cdot, b=b + dt * bdot)
    return new.theta, what + dt * (psi3 - g.a * dw)


@settings(max_examples=60, deadline=None)
@given(I=spd(3, floor=20.0), R=rotation(), w=vec(3, 0.3), what=vec(3, 0.3), tau=vec(3, 30.0),
       dseed=st.integers(0, 2**31 - 1))
def test_aid3_step_is_the_theorem(I, R, w, what, tau, dseed):
    rng = np.random.default_rng(dseed)
    theta0 = RotParams(I=I, C=rng.normal(size=(3, 3, 3)) * 100, b=rng.normal(size=3) * 50).theta
    gains = AID3Gains()
    st0 = replace(aid3_init(theta0), v_hat=what, v_prev=w, r_prev=R[2].copy(),
                  u_prev=np.zeros(3))
    v6 = np.concatenate([np.zeros(3), w])
    u6 = np.concatenate([np.zeros(3), tau])
    prm = AID3Params(gains=gains, input_interp="hold", sampling="euler")
    st1 = aid3_step(_vs(R, v6), u6, prm, st0, 1e-3)
    th_ref, what_ref = _reference_step3(theta0, what, w, R, tau, 1e-3, gains)
    assert np.allclose(st1.v_hat, what_ref, rtol=1e-9, atol=1e-12)
    lam = np.linalg.eigvalsh(RotParams.from_theta(th_ref).I)
    if lam[0] <= prm.pd_floor * lam[-1]:
        assert st1.frozen and np.array_equal(st1.theta, st0.theta)
        return
    assert np.allclose(st1.theta, th_ref, rtol=1e-9, atol=1e-9 * np.abs(th_ref).max())
    Ih = aid3_params(st1).I
    assert np.array_equal(Ih, Ih.T)


def _excite(t):
    return np.array([60 * np.cos(0.3 * t) + 20 * np.sin(1.1 * t), 50 * np.cos(0.41 * t + 1),
                     70 * np.cos(0.23 * t) + 20 * np.cos(0.9 * t),
                     40 * np.cos(0.26 * t) + 10 * np.cos(1.3 * t), 55 * np.cos(0.45 * t),
                     60 * np.cos(0.21 * t + 0.5) + 15 * np.cos(0.77 * t)])


def _ideal_run(minutes, st, gains=None, dt=0.1, substeps=10):
    """Noise-free plant with ideal actuators; AID sees the true (R, v) and the held wrench."""
    plant = Plant(load_vehicle("jhu-rov-coupled"), PlantConfig(rate_hz=substeps / dt))
    prm = AID6Params(gains=gains or AID6Gains(), input_interp="hold")
    n = int(round(minutes * 60 / dt))
    dv = np.empty((n, 6))
    v = np.empty((n, 6))
    u = np.zeros(6)
    for k in range(n):
        st = aid6_step(VehicleState(plant.H, plant.v), u, prm, st, dt)  # u held over last dt
        dv[k], v[k] = st.dv, plant.v
        u = _excite(k * dt)
        for _ in range(substeps):
            plant.step_wrench(u)
    return st, dv, v


def _minute_rms(dv):
    return np.array([np.sqrt(np.mean(np.sum(dv[s:s + 600] ** 2, axis=1)))
                     for s in range(1, len(dv), 600)])


def test_velocity_estimate_converges_noise_free():
    """Theorem 4.3.1: ∆v → 0 through adaptation. From INITP (M̂ = 100 I, far outside (4.29)),
    on a noise-free run: the per-minute RMS of ∆v falls steadily, ends an order of magnitude
    below the same estimator with adaptation switched off, and M̂ stays positive definite."""
    st, dv, v = _ideal_run(6.0, aid6_init(INITP_6DOF))
    _, dv_off, _ = _ideal_run(6.0, replace(aid6_init(INITP_6DOF), frozen=True))
    w, w_off = _minute_rms(dv), _minute_rms(dv_off)
    assert not st.frozen and st.m_min_eig > 0
    assert np.all(w[3:] < 0.5 * w[0])
    assert w[-1] < 0.1 * w_off[-1]
    # the parameter error decreased too (Lyapunov function (4.31) dominated by ∆M)
    err0 = np.linalg.norm(INITP_6DOF.M - TRUE.M)
    assert np.linalg.norm(aid6_params(st).M - TRUE.M) < 0.7 * err0


def test_true_parameters_are_nearly_an_equilibrium():
    """Started at the true θ, θ̂ barely moves and ∆v stays near zero: with the default
    mid-interval sampling the 10 Hz discretisation is accurate to O(dt²)."""
    st, dv, v = _ideal_run(2.0, aid6_init(TRUE.theta))
    rel = np.linalg.norm(st.theta - TRUE.theta) / np.linalg.norm(TRUE.theta)
    assert rel < 0.01
    assert np.sqrt(np.mean(np.sum(dv ** 2, axis=1))) < 1e-3 * np.sqrt(np.mean(np.sum(v ** 2,
                                                                                 axis=1)))


@pytest.mark.parametrize("scale", [(1.0,) * 6, (0.3, 2.0, 1.0, 5.0, 0.5, 3.0)])
def test_lyapunov_function_non_increasing_small_step(scale):
    """V of (4.31) along a fine-step noise-free run: V̇ = −a∆vᵀM∆v ≤ 0 (4.33), so V may not grow
    beyond the O(dt²) of Euler — also with a diagonal gain per DOF, V's parameter terms then
    weighted by the inverse of each entry's gain."""
    gains = AID6Gains(dof_scale=scale)
    sc = np.array(scale)
    dt = 0.002
    plant = Plant(load_vehicle("jhu-rov-coupled"), PlantConfig(rate_hz=1.0 / dt))
    prm = AID6Params(gains=gains, input_interp="hold")
    st = aid6_init(TRUE.theta + 0.02 * np.abs(TRUE.theta) * np.sign(np.sin(np.arange(241))))
    th0 = TRUE.theta

    def V(s):
        d = s.theta - th0
        dM = UVParams.from_theta(s.theta).M - TRUE.M
        dv = s.dv
        dD = d[21:237].reshape(6, 6, 6)  # [i, column, row]: row r of every D̂ᵢ at γ₂s_r
        return (0.5 * dv @ TRUE.M @ dv
                + np.sum(dM * dM / np.sqrt(np.outer(sc, sc))) / (2 * gains.gamma1)
                + np.sum(dD ** 2 / sc) / (2 * gains.gamma2)
                + d[237] ** 2 / (2 * gains.gamma3 * np.mean(sc[:3]))
                + np.sum(d[238:] ** 2 / sc[3:]) / (2 * gains.gamma4))

    u = np.zeros(6)
    vals = []
    for k in range(3000):
        st = aid6_step(VehicleState(plant.H, plant.v), u, prm, st, dt)
        vals.append(V(st))
        u = _excite(k * dt) + 30.0 * np.sin(7.0 * k * dt)
        plant.step_wrench(u)
    vals = np.array(vals[1:])
    assert vals[-1] < vals[0]
    assert np.max(np.diff(vals)) <= 1e-6 * vals[0]


def test_freezes_when_mass_estimate_loses_definiteness():
    M = np.diag([100.0, 100.0, 100.0, 100.0, 100.0, 1e-3])
    theta = UVParams(M=M, D=INITP_6DOF.D, g=0.0, b=np.array([0.0, 0.0, 100.0])).theta
    st = aid6_init(theta)
    prm = AID6Params(gains=AID6Gains(gamma1=1e7))
    R = np.eye(3)
    st = aid6_step(_vs(R, np.zeros(6)), np.zeros(6), prm, st, 0.1)
    v = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.5])
    st = aid6_step(_vs(R, v), np.array([0, 0, 0, 0, 0, 200.0]), prm, st, 0.1)
    for _ in range(5):
        st = aid6_step(_vs(R, v), np.array([0, 0, 0, 0, 0, -200.0]), prm, st, 0.1)
        if st.frozen:
            break
    assert st.frozen and "positive definiteness" in st.freeze_reason
    frozen_theta = st.theta.copy()
    assert np.linalg.eigvalsh(UVParams.from_theta(frozen_theta).M)[0] > 0
    # frozen: θ̂ no longer moves, v̂ is still propagated, nothing non-finite
    for s in range(5):
        st = aid6_step(_vs(R, v * (s + 1)), np.full(6, 50.0), prm, st, 0.1)
        assert np.array_equal(st.theta, frozen_theta)
        assert np.all(np.isfinite(st.v_hat))
    resumed = aid_unfreeze(st)
    assert not resumed.frozen and resumed.freeze_reason == ""
    assert np.array_equal(resumed.theta, frozen_theta)
    # the same call resumes a frozen 3-DOF estimator, which then adapts again
    st3 = replace(aid3_init(INITP_ROT), frozen=True, freeze_reason="test")
    w = np.array([0.0, 0.0, 0.0, 0.2, -0.1, 0.3])

    def two_steps(s3):
        s3 = aid3_step(_vs(R, w), np.zeros(6), AID3Params(), s3, 0.1)
        return aid3_step(_vs(R, 2 * w), np.full(6, 20.0), AID3Params(), s3, 0.1)

    still = two_steps(st3)
    assert still.frozen and np.array_equal(still.theta, INITP_ROT.theta)
    moved = two_steps(aid_unfreeze(st3))
    assert not moved.frozen and not np.array_equal(moved.theta, INITP_ROT.theta)


def test_init_rejects_indefinite_mass_and_bad_input_is_skipped():
    bad = UVParams(M=-np.eye(6), D=INITP_6DOF.D, g=0.0, b=np.zeros(3))
    with pytest.raises(ValueError, match="positive definite"):
        aid6_init(bad.theta)
    with pytest.raises(ValueError, match="241"):
        aid6_init(np.zeros(10))
    st = aid6_init(INITP_6DOF)
    prm = AID6Params()
    st = aid6_step(_vs(np.eye(3), np.zeros(6)), np.zeros(6), prm, st, 0.1)
    st2 = aid6_step(_vs(np.eye(3), np.full(6, np.nan)), np.zeros(6), prm, st, 0.1)
    assert st2.skipped == 1 and np.array_equal(st2.theta, st.theta)
    st3 = aid6_step(_vs(np.eye(3), np.ones(6) * 0.1), np.zeros(6), prm, st, 5.0)  # a gap
    assert st3.resyncs == 1 and np.array_equal(st3.v_hat, np.ones(6) * 0.1)
    assert np.array_equal(st3.theta, st.theta)


@pytest.mark.parametrize("step, init, theta0",
                         [(aid6_step, aid6_init, INITP_6DOF.theta),
                          (aid3_step, aid3_init, INITP_ROT.theta)])
@pytest.mark.parametrize("big", [1e3, 1e150, 1e200, 1e300])
def test_finite_but_huge_inputs_never_raise(step, init, theta0, big):
    """Finite inputs so large that the update overflows to inf or NaN: the step rejects the
    update (θ̂ kept, M̂ still positive definite) instead of raising mid-cycle. Before M̂'s
    eigenvalues were guarded, 1e200 raised LinAlgError."""
    prm = AID6Params() if step is aid6_step else AID3Params()
    st = init(theta0)
    for k in range(4):
        v = np.full(6, big) * (-1) ** k
        st = step(_vs(np.eye(3), v), np.full(6, big), prm, st, 0.1)
        assert np.all(np.isfinite(st.theta)) and np.all(np.isfinite(st.v_hat))
    kept = UVParams.from_theta(st.theta).M if step is aid6_step else \
        RotParams.from_theta(st.theta).I
    assert np.linalg.eigvalsh(kept)[0] > 0
    # frozen, with the cause named: indefinite M̂ (1e3, 1e150) or an overflow (1e200 and up)
    cause = "update was not finite" if big >= 1e200 else "lost positive definiteness"
    assert st.frozen and cause in st.freeze_reason


def test_first_step_sets_vhat_to_v():
    v0 = np.array([0.1, -0.2, 0.05, 0.01, 0.02, -0.03])
    st = aid6_step(_vs(exp_so3(np.array([0.1, 0.2, 0.3])), v0), np.ones(6), AID6Params(),
                   aid6_init(INITP_6DOF), 0.1)
    assert np.array_equal(st.v_hat, v0) and np.array_equal(st.dv, np.zeros(6))
    assert np.array_equal(st.theta, INITP_6DOF.theta)


def test_rotational_aid_converges_noise_free():
    """Theorem 4.2.1 on a pure rotational plant (2.40): ∆ω → 0 from INITP."""
    true_rot = RotParams.from_theta(TRUE.theta[ROTATIONAL_INDEX])
    from uvd.estimation.xval import embed_rotational

    p6 = embed_rotational(true_rot)
    from uvd.model.dynamics import UVModel
    from uvd.model.integrate import rk4_step

    model = UVModel.from_params(p6)
    H, v = np.eye(4), np.zeros(6)
    st = aid3_init(INITP_ROT)
    prm = AID3Params(input_interp="hold")
    u = np.zeros(6)
    dw = []
    for k in range(3000):
        st = aid3_step(VehicleState(H, v), u, prm, st, 0.1)
        dw.append(np.linalg.norm(st.dv))
        t = 0.1 * k
        u = np.array([0, 0, 0, 40 * np.cos(0.503 * t) + 10 * np.cos(1.7 * t),
                      55 * np.cos(0.663 * t), 70 * np.cos(1.043 * t)])
        for _ in range(5):
            H, v = rk4_step(model, H, v, u, 0.02)
    dw = np.array(dw)
    assert not st.frozen
    assert np.sqrt(np.mean(dw[-300:] ** 2)) < 0.2 * np.sqrt(np.mean(dw[1:300] ** 2))
    Ih = aid3_params(st).I
    assert np.linalg.norm(Ih - true_rot.I) < 0.5 * np.linalg.norm(INITP_ROT.I - true_rot.I)


def test_estimator_spec_in_the_core_cycle():
    """AID plugs into the core as an EstimatorSpec and only sees (R, v, u_applied)."""
    from uvd.experiments.identification import dataset_6dof, record

    spec = aid6_estimator()
    assert spec.name == "aid6" and np.array_equal(spec.init_state.theta, INITP_6DOF.theta)
    rec = record(dataset_6dof("IDDAT"), kind="6dof", seed=3, minutes=0.5, estimator=spec)
    assert rec.cycles_not_ok == 0
    assert rec.hist["steps"] == len(rec.run.t) - 1
    assert np.all(rec.hist["min_eig"] > 0) and not np.any(rec.hist["frozen"])
    assert np.all(np.isfinite(rec.aid_theta))
    assert not np.array_equal(rec.aid_theta, INITP_6DOF.theta)
    # M̂ is read through θ_M: symmetric by construction
    Mh = UVParams.from_theta(rec.aid_theta).M
    assert np.array_equal(Mh, Mh.T)
    assert theta_M_from(Mh).shape == (21,)


def test_exact_dvl_diagnostic_measures_the_true_velocity():
    """aid-6dof's diagnostic re-run: the DVL error-free and sampled every cycle, the INS still
    noisy (Table A.1) — so navigation's ν is the plant's and ω is not."""
    from uvd.experiments.identification import EXACT_DVL, dataset_6dof, record

    exact = record(dataset_6dof("IDDAT"), kind="6dof", seed=0, minutes=0.5,
                   instruments=EXACT_DVL).run
    assert np.array_equal(exact.v[:, :3], exact.v_true[:, :3])
    assert np.any(exact.v[:, 3:] != exact.v_true[:, 3:])
    normal = record(dataset_6dof("IDDAT"), kind="6dof", seed=0, minutes=0.5).run
    assert np.abs(normal.v[:, :3] - normal.v_true[:, :3]).max() > 0.003


def test_aid_hover_measures_drift_from_the_true_parameters():
    """``aid-hover`` (6 simulated minutes): AID from the true θ through station keeping stays
    near it; the DVL's noise is what moves M̂ (the exact-DVL run drifts less)."""
    from uvd.experiments import ExperimentOptions
    from uvd.experiments.aid_hover import run_aid_hover

    res = run_aid_hover(ExperimentOptions(hours=0.1, progress=lambda m: None))
    noisy, exact = res["table_a1"], res["exact_dvl"]
    for r in (noisy, exact):
        assert not r["frozen"] and r["cycles_not_ok"] == 0 and r["steps"] == 3599
        assert r["M_min_eigenvalue"]["min"] > 0.9 * r["M_min_eigenvalue"]["start"]
        assert 0 < r["relative_error_final"]["M"] < 0.01
        assert r["rms_velocity"]["translational_mps"] < 0.05  # station keeping, no excitation
        assert len(r["relative_error"]["t_s"]) == 6 and set(r["rate_per_hour"]) == {
            "theta", "M", "D", "g", "b"}
    assert exact["relative_error_final"]["M"] < noisy["relative_error_final"]["M"]
    assert "per hour" in res["summary"]
