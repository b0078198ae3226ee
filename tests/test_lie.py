"""SO(3)/SE(3) identities used by the thesis (Ch. 2, App. B), each as a property test."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.strategies import finite, rotation, rotvec_inside_pi, vec
from uvd.model import lie

PROP = settings(max_examples=200, deadline=None)


@PROP
@given(rotvec_inside_pi())
def test_so3_exp_log_round_trip(q):
    np.testing.assert_allclose(lie.log_so3(lie.exp_so3(q)), q, atol=1e-9)


@PROP
@given(rotation())
def test_so3_log_exp_round_trip_any_rotation(R):
    np.testing.assert_allclose(lie.exp_so3(lie.log_so3(R)), R, atol=1e-9)


@PROP
@given(st.floats(min_value=0.0, max_value=1e-6), vec(3))
def test_so3_log_near_pi(eps, axis):
    """Rotations within 1e-6 rad of π: the log still reproduces the rotation."""
    n = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 1e-3 else np.array([0.0, 0.0, 1.0])
    R = lie.exp_so3((np.pi - eps) * n)
    q = lie.log_so3(R)
    assert np.linalg.norm(q) <= np.pi + 1e-12
    np.testing.assert_allclose(lie.exp_so3(q), R, atol=1e-9)


@PROP
@given(vec(3), st.sampled_from([1e-12, 1e-8, 1e-5, 1e-3]))
def test_so3_exp_log_near_zero(d, scale):
    q = scale * d
    np.testing.assert_allclose(lie.log_so3(lie.exp_so3(q)), q, atol=1e-15, rtol=1e-9)


@PROP
@given(vec(3), rotvec_inside_pi())
def test_se3_exp_log_round_trip(xi, q):
    psi = np.concatenate([xi, q])
    np.testing.assert_allclose(lie.log_se3(lie.exp_se3(psi)), psi, atol=1e-8)
    H = lie.exp_se3(psi)
    np.testing.assert_allclose(lie.exp_se3(lie.log_se3(H)), H, atol=1e-9)


@PROP
@given(rotvec_inside_pi())
def test_A_times_A_inv_is_identity(q):
    """A(q)A⁻¹(q) = I for ‖q‖ < π, (2.26) and (2.28)."""
    np.testing.assert_allclose(lie.A_so3(q) @ lie.A_inv_so3(q), np.eye(3), atol=1e-9)


@PROP
@given(vec(3), rotvec_inside_pi())
def test_B2_equals_B5(xi, q):
    """The two closed forms of the inverse SE(3) velocity Jacobian, (B.2) and (B.5), agree."""
    psi = np.concatenate([xi, q])
    np.testing.assert_allclose(lie.A_inv_se3(psi), lie.A_inv_se3_blocks(psi), atol=1e-9)


@PROP
@given(vec(3), rotvec_inside_pi())
def test_bilinear_identity_B1(xi, q):
    """App. B.1: ½ψᵀ(A⁻ᵀ(ψ) + A⁻¹(ψ))ψ = ψᵀψ, i.e. ψᵀ(A⁻ᵀ + A⁻¹)ψ = 2ψᵀψ.

    (B.6) as printed omits the ½ that its own derivation in App. B.1 carries; the derivation's
    form is the one checked, together with A⁻¹(ψ)ψ = ψ on which it rests.
    """
    psi = np.concatenate([xi, q])
    Ai = lie.A_inv_se3(psi)
    assert np.isclose(0.5 * psi @ (Ai.T + Ai) @ psi, psi @ psi, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(Ai @ psi, psi, atol=1e-9)


@PROP
@given(st.lists(finite, min_size=9, max_size=9), vec(3))
def test_theorem_2_3_3(a, x):
    """Theorem 2.3.3: Aᵀ J(Ax) A = det(A) J(x) for every A ∈ R³ˣ³."""
    A = np.array(a).reshape(3, 3)
    np.testing.assert_allclose(A.T @ lie.J(A @ x) @ A, np.linalg.det(A) * lie.J(x), atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(vec(6, 0.5), vec(3), rotvec_inside_pi())
def test_A_inv_is_the_body_velocity_jacobian(v, xi, q):
    """ψ̇ = A⁻¹(ψ) v (2.33) for Ḣ = H v̂ (2.30), by central differences of log(H e^{±hv̂})."""
    if np.linalg.norm(q) > np.pi - 0.05:  # keep the ±h perturbation inside the log's domain
        q = q * (np.pi - 0.05) / np.linalg.norm(q)
    psi = np.concatenate([xi, q])
    H = lie.exp_se3(psi)
    h = 1e-6
    d = (lie.log_se3(H @ lie.exp_se3(h * v)) - lie.log_se3(H @ lie.exp_se3(-h * v))) / (2 * h)
    np.testing.assert_allclose(d, lie.A_inv_se3(psi) @ v, atol=2e-6 * (1 + np.abs(v).max()))


@PROP
@given(vec(6), rotation(), vec(3))
def test_adjoint_map_transports_velocities(v, R, p):
    """H v̂ H⁻¹ = (Ad_H v)^ (used in (5.7))."""
    H = lie.make_H(R, p)
    np.testing.assert_allclose(H @ lie.hat6(v) @ lie.inv_H(H), lie.hat6(lie.Ad(H) @ v),
                               atol=1e-9)


def test_stack_and_kron_identity():
    """stack(A X B) = (Bᵀ ⊗ A) stack(X), the identity every regressor is built on."""
    rng = np.random.default_rng(0)
    A, X, B = rng.normal(size=(3, 4)), rng.normal(size=(4, 5)), rng.normal(size=(5, 2))
    np.testing.assert_allclose(lie.stack(A @ X @ B), lie.kron(B.T, A) @ lie.stack(X))
    np.testing.assert_array_equal(lie.unstack(lie.stack(X), 4, 5), X)


@given(st.floats(-np.pi, np.pi), st.floats(-1.5, 1.5), st.floats(-np.pi, np.pi))
@settings(max_examples=200, deadline=None)
def test_compiled_euler_R_is_the_drivers_formula(roll, pitch, heading):
    from uvd.geometry import euler_to_R
    np.testing.assert_allclose(lie.euler_R(roll, pitch, heading),
                               euler_to_R(roll, pitch, heading), rtol=0, atol=1e-15)
