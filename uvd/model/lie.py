"""SO(3) and SE(3): operators, exponential/logarithm maps and velocity Jacobians (thesis Ch. 2, App. B).

Notation follows the thesis (§2.2.1): ``J`` is the hat map R³ → so(3) (2.1), ``hat6`` the se(3)
hat (2.2), ``ad`` the se(3) adjoint operator (2.4), ``Ad`` the adjoint map (2.5), ``stack`` the
column stack (2.8). Velocities are body-frame, v = [ν; ω] (2.32); poses H ∈ SE(3) map body to
world (2.31); ψ = [ξ; q] ∈ R⁶ are se(3) exponential coordinates (2.29), q ∈ R³ so(3) ones (2.23).

**Sign of the odd term of A⁻¹.** With body velocities, Ṙ = R J(ω) (2.24) and Ḣ = H v̂ (2.30),
the exponential coordinates obey q̇ = (I + ½J(q) + …)ω, and ψ̇ = (I + ½ad_ψ + …)v — the sign that
(B.2) and (B.5) print. The text of (2.26)/(2.28) as extracted prints the opposite sign of the
odd term (−½J(q) in (2.28)), which is the spatial-velocity form and contradicts (B.5), whose
diagonal block must equal (2.28). We use the body-velocity sign throughout (checked against
finite differences in ``tests/test_lie.py``); every identity the thesis uses of these maps —
A(q)A⁻¹(q) = I, A⁻¹(q)q = q, (B.2) = (B.5), (B.6) — holds for it.

All functions are pure numpy; near the singular points (‖q‖ → 0, and ‖q‖ → π for the log) they
switch to Taylor series or to the dedicated branch so the results stay accurate.
"""

from __future__ import annotations

import numpy as np

_EPS_SMALL = 1e-4  # below this angle, series expansions are used (errors ~ θ⁶ ≪ 1e-16)


# ---------------------------------------------------------------------------------------------
# operators (§2.2.1)
# ---------------------------------------------------------------------------------------------
def J(w: np.ndarray) -> np.ndarray:
    """Hat map R³ → so(3), eq. (2.1): J(w) x = w × x."""
    w1, w2, w3 = w
    return np.array([[0.0, -w3, w2], [w3, 0.0, -w1], [-w2, w1, 0.0]])


def vee(W: np.ndarray) -> np.ndarray:
    """Inverse of :func:`J` (takes the skew part of W)."""
    return 0.5 * np.array([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]])


def hat6(v: np.ndarray) -> np.ndarray:
    """se(3) hat, eq. (2.2): v = [ν; ω] ↦ [[J(ω), ν], [0, 0]] ∈ R⁴ˣ⁴."""
    out = np.zeros((4, 4))
    out[:3, :3] = J(v[3:])
    out[:3, 3] = v[:3]
    return out


def vee6(X: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat6`."""
    return np.concatenate([X[:3, 3], vee(X[:3, :3])])


def ad(v: np.ndarray) -> np.ndarray:
    """se(3) adjoint operator, eq. (2.4): ad_v = [[J(ω), J(ν)], [0, J(ω)]] for v = [ν; ω]."""
    out = np.zeros((6, 6))
    Jw = J(v[3:])
    out[:3, :3] = Jw
    out[:3, 3:] = J(v[:3])
    out[3:, 3:] = Jw
    return out


def Ad(H: np.ndarray) -> np.ndarray:
    """se(3) adjoint map of H = [[R, p], [0, 1]], eq. (2.5): [[R, J(p)R], [0, R]]."""
    R = H[:3, :3]
    out = np.zeros((6, 6))
    out[:3, :3] = R
    out[:3, 3:] = J(H[:3, 3]) @ R
    out[3:, 3:] = R
    return out


def stack(A: np.ndarray) -> np.ndarray:
    """Column stack operator ·^S, eq. (2.8) (Fortran-order flatten)."""
    return np.asarray(A).reshape(-1, order="F")


def unstack(a: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Inverse of :func:`stack`."""
    return np.asarray(a).reshape((rows, cols), order="F")


def kron(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Kronecker product ⊗, eq. (2.7); with it stack(A X B) = (Bᵀ ⊗ A) stack(X)."""
    return np.kron(A, B)


def make_H(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Homogeneous transform (2.31) from rotation R and position p."""
    H = np.eye(4)
    H[:3, :3] = R
    H[:3, 3] = p
    return H


def inv_H(H: np.ndarray) -> np.ndarray:
    """Inverse of a homogeneous transform without a general matrix inverse."""
    R = H[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ H[:3, 3]
    return out


# ---------------------------------------------------------------------------------------------
# scalar coefficient functions, robust near 0
# ---------------------------------------------------------------------------------------------
def _sinc(t: float) -> float:
    """sin(t)/t."""
    if t < _EPS_SMALL:
        t2 = t * t
        return 1.0 - t2 / 6.0 + t2 * t2 / 120.0
    return np.sin(t) / t


def _cosc(t: float) -> float:
    """(1 − cos t)/t²."""
    if t < _EPS_SMALL:
        t2 = t * t
        return 0.5 - t2 / 24.0 + t2 * t2 / 720.0
    return (1.0 - np.cos(t)) / (t * t)


def _sinc3(t: float) -> float:
    """(t − sin t)/t³."""
    if t < _EPS_SMALL:
        t2 = t * t
        return 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0
    return (t - np.sin(t)) / (t * t * t)


def _alpha(y: float) -> float:
    """α(y) = (y/2) cot(y/2), App. B."""
    if y < _EPS_SMALL:
        y2 = y * y
        return 1.0 - y2 / 12.0 - y2 * y2 / 720.0
    h = 0.5 * y
    return h * np.cos(h) / np.sin(h)


def _beta(y: float) -> float:
    """β(y) = (y/2)² / sin²(y/2), App. B."""
    if y < _EPS_SMALL:
        y2 = y * y
        return 1.0 + y2 / 12.0 + y2 * y2 / 240.0
    h = 0.5 * y
    s = np.sin(h)
    return h * h / (s * s)


def _c2(y: float) -> float:
    """(1 − α(y))/y², the J(q)² coefficient of (2.28)."""
    if y < 0.1:
        y2 = y * y
        return 1.0 / 12.0 + y2 / 720.0 + y2 * y2 / 30240.0 + y2 * y2 * y2 / 1209600.0
    return (1.0 - _alpha(y)) / (y * y)


def _B2(y: float) -> float:
    """B₂(y) of (B.4): y⁴B₂ = (1 − α) + ½(α − β)."""
    if y < 0.2:
        y2 = y * y
        return -1.0 / 720.0 - y2 / 15120.0 - y2 * y2 / 403200.0 - y2 * y2 * y2 / 11975040.0
    a = _alpha(y)
    return ((1.0 - a) + 0.5 * (a - _beta(y))) / (y**4)


def _B1(y: float) -> float:
    """B₁(y) of (B.3): y²B₁ = 2(1 − α) + ½(α − β), i.e. B₁ = (1 − α)/y² + y²B₂."""
    return _c2(y) + y * y * _B2(y)


# ---------------------------------------------------------------------------------------------
# SO(3)
# ---------------------------------------------------------------------------------------------
def exp_so3(q: np.ndarray) -> np.ndarray:
    """SO(3) exponential R = e^{J(q)}, eq. (2.23) (Rodrigues' formula)."""
    t = float(np.linalg.norm(q))
    K = J(q)
    return np.eye(3) + _sinc(t) * K + _cosc(t) * (K @ K)


def log_so3(R: np.ndarray) -> np.ndarray:
    """SO(3) logarithm q with R = e^{J(q)}, ‖q‖ ∈ [0, π]; accurate near 0 and near π."""
    tr = float(np.trace(R))
    c = np.clip(0.5 * (tr - 1.0), -1.0, 1.0)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])  # 2 sin(t) n
    if c > 0.0:
        # sin(t) from the skew part is accurate here; t = atan2 avoids acos' loss near 0
        s = 0.5 * float(np.linalg.norm(w))
        t = np.arctan2(s, c)
        if t < _EPS_SMALL:
            return 0.5 * w * (1.0 + t * t / 6.0)
        return 0.5 * w * (t / np.sin(t))
    # near π: take the axis from the symmetric part, R + Rᵀ = 2 I cos t + 2 (1 − cos t) n nᵀ
    t = np.arccos(c)
    B = 0.5 * (R + R.T) - c * np.eye(3)  # (1 − c) n nᵀ
    k = int(np.argmax(np.diag(B)))
    n = B[:, k] / np.sqrt(max(B[k, k] * (1.0 - c), 1e-300))
    n = n / np.linalg.norm(n)
    if np.dot(n, w) < 0.0:  # choose the sign that matches the skew part (2 sin t n)
        n = -n
    return t * n


def A_so3(q: np.ndarray) -> np.ndarray:
    """Angular-velocity Jacobian A(q) of (2.25)–(2.26): ω = A(q) q̇ (body ω, see module note)."""
    t = float(np.linalg.norm(q))
    K = J(q)
    return np.eye(3) - _cosc(t) * K + _sinc3(t) * (K @ K)


def A_inv_so3(q: np.ndarray) -> np.ndarray:
    """Inverse Jacobian A⁻¹(q) of (2.27)–(2.28): q̇ = A⁻¹(q) ω; exists for ‖q‖ < 2π."""
    t = float(np.linalg.norm(q))
    K = J(q)
    return np.eye(3) + 0.5 * K + _c2(t) * (K @ K)


# ---------------------------------------------------------------------------------------------
# SE(3)
# ---------------------------------------------------------------------------------------------
def _V_so3(q: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3), the translation part of the SE(3) exponential."""
    t = float(np.linalg.norm(q))
    K = J(q)
    return np.eye(3) + _cosc(t) * K + _sinc3(t) * (K @ K)


def exp_se3(psi: np.ndarray) -> np.ndarray:
    """SE(3) exponential H = e^{ψ̂}, eq. (2.29), ψ = [ξ; q]."""
    xi, q = psi[:3], psi[3:]
    return make_H(exp_so3(q), _V_so3(q) @ xi)


def log_se3(H: np.ndarray) -> np.ndarray:
    """SE(3) logarithm ψ = [ξ; q] with H = e^{ψ̂} and ‖q‖ ≤ π."""
    q = log_so3(H[:3, :3])
    t = float(np.linalg.norm(q))
    K = J(q)
    V_inv = np.eye(3) - 0.5 * K + _c2(t) * (K @ K)
    return np.concatenate([V_inv @ H[:3, 3], q])


def A_inv_se3(psi: np.ndarray) -> np.ndarray:
    """Inverse SE(3) velocity Jacobian by (B.2): ψ̇ = A⁻¹(ψ) v.

    A⁻¹(ψ) = I + ½ad_ψ + B₁(‖q‖) ad_ψ² + B₂(‖q‖) ad_ψ⁴ with B₁, B₂ of (B.3)–(B.4).
    """
    y = float(np.linalg.norm(psi[3:]))
    a = ad(psi)
    a2 = a @ a
    return np.eye(6) + 0.5 * a + _B1(y) * a2 + _B2(y) * (a2 @ a2)


def A_inv_se3_blocks(psi: np.ndarray) -> np.ndarray:
    """Inverse SE(3) velocity Jacobian by the block form (B.5); equal to :func:`A_inv_se3`.

    [[A⁻¹(q), ½J(ξ) + (1−α)/‖q‖² B₄(ξ,q) + B₂(‖q‖) B₃(ξ,q)], [0, A⁻¹(q)]] with
    B₄ = J(ξ)J(q) + J(q)J(ξ) and B₃ = J(q)J(ξ)J(q)² + J(q)²J(ξ)J(q).
    """
    xi, q = psi[:3], psi[3:]
    y = float(np.linalg.norm(q))
    Jx, Jq = J(xi), J(q)
    Jq2 = Jq @ Jq
    B4 = Jx @ Jq + Jq @ Jx
    B3 = Jq @ Jx @ Jq2 + Jq2 @ Jx @ Jq
    Ai = A_inv_so3(q)
    out = np.zeros((6, 6))
    out[:3, :3] = Ai
    out[3:, 3:] = Ai
    out[:3, 3:] = 0.5 * Jx + _c2(y) * B4 + _B2(y) * B3
    return out


def A_inv_se3_T_psi(psi: np.ndarray) -> np.ndarray:
    """A⁻ᵀ(ψ) ψ, the proportional term of the PD law (5.11); cheap closed form use of (B.5)."""
    return A_inv_se3_blocks(psi).T @ psi
