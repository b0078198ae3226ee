"""Regressor forms equal their models: u = W_UV θ_UV (2.49), τ = W_UVR θ_UVR (2.42)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.strategies import finite, rotation, theta_uv, vec
from uvd.model import regressors as W
from uvd.model.dynamics import rot_inverse_dynamics, uv_inverse_dynamics
from uvd.model.params import N_THETA_UVR, RotParams, UVParams

PROP = settings(max_examples=200, deadline=None)


def model_rhs(p: UVParams, v, vdot, R):
    """M v̇ − adᵀ_v(Mv) − Σ|v_i|D_i v − G(R), written out independently of uvd.model."""
    e3 = np.array([0.0, 0.0, 1.0])
    nu, om = v[:3], v[3:]
    Mv = p.M @ v
    adT = np.concatenate([np.cross(Mv[:3], om), np.cross(Mv[:3], nu) + np.cross(Mv[3:], om)])
    D = sum(abs(v[i]) * p.D[i] for i in range(6))
    G = np.concatenate([p.g * R.T @ e3, np.cross(p.b, R.T @ e3)])
    return p.M @ vdot - adT - D @ v - G


@PROP
@given(vec(6), vec(6), rotation(), theta_uv())
def test_uv_regressor_identity(v, vdot, R, theta):
    p = UVParams.from_theta(theta)
    lhs = W.W_UV(v, vdot, R) @ theta
    rhs = model_rhs(p, v, vdot, R)
    np.testing.assert_allclose(lhs, rhs, rtol=1e-9, atol=1e-9 * (1 + np.abs(rhs).max()))
    np.testing.assert_allclose(uv_inverse_dynamics(p, v, vdot, R), rhs, rtol=1e-9,
                               atol=1e-9 * (1 + np.abs(rhs).max()))


@PROP
@given(vec(3), vec(3), rotation(),
       st.lists(finite, min_size=N_THETA_UVR, max_size=N_THETA_UVR))
def test_rotational_regressor_identity(w, wdot, R, th):
    theta = 100.0 * np.array(th)
    p = RotParams.from_theta(theta)
    e3 = np.array([0.0, 0.0, 1.0])
    C = sum(abs(w[i]) * p.C[i] for i in range(3))
    rhs = p.I @ wdot - np.cross(p.I @ w, w) - C @ w - np.cross(p.b, R.T @ e3)
    np.testing.assert_allclose(W.W_UVR(w, wdot, R) @ theta, rhs, rtol=1e-9,
                               atol=1e-9 * (1 + np.abs(rhs).max()))
    np.testing.assert_allclose(rot_inverse_dynamics(p, w, wdot, R), rhs, rtol=1e-9,
                               atol=1e-9 * (1 + np.abs(rhs).max()))


def test_a_wrong_sign_in_a_regressor_fails_the_identity():
    """The identity test has teeth: flip the sign of any one block of W_UV and it fails."""
    rng = np.random.default_rng(1)
    theta = 100.0 * rng.normal(size=241)
    p = UVParams.from_theta(theta)
    v, vdot, R = rng.normal(size=6), rng.normal(size=6), np.eye(3)
    good = W.W_UV(v, vdot, R)
    rhs = model_rhs(p, v, vdot, R)
    assert np.allclose(good @ theta, rhs)
    for block in (slice(0, 21), slice(21, 237), slice(237, 241)):
        bad = good.copy()
        bad[:, block] *= -1.0
        assert not np.allclose(bad @ theta, rhs, rtol=1e-6), f"sign flip of {block} undetected"
