"""SO(3) and SE(3): operators, exponential/logarithm maps and velocity Jacobians.

Thesis Ch. 2 and App. B. Notation follows the thesis (§2.2.1): ``J`` is the hat map
R³ → so(3) (2.1), ``hat6`` the se(3) hat (2.2), ``ad`` the se(3) adjoint operator (2.4), ``Ad``
the adjoint map (2.5), ``stack`` the column stack (2.8). Velocities are body-frame,
v = [ν; ω] (2.32); poses H ∈ SE(3) map body to world (2.31); ψ = [ξ; q] ∈ R⁶ are se(3)
exponential coordinates (2.29), q ∈ R³ so(3) ones (2.23).

**Sign of the odd term of A⁻¹.** With body velocities, Ṙ = R J(ω) (2.24) and Ḣ = H v̂ (2.30),
the exponential coordinates obey q̇ = (I + ½J(q) + …)ω, and ψ̇ = (I + ½ad_ψ + …)v — the sign that
(B.2) and (B.5) print. The text of (2.26)/(2.28) as extracted prints the opposite sign of the
odd term (−½J(q) in (2.28)), which is the spatial-velocity form and contradicts (B.5), whose
diagonal block must equal (2.28). We use the body-velocity sign throughout (checked against
finite differences in ``tests/test_lie.py``); every identity the thesis uses of these maps —
A(q)A⁻¹(q) = I, A⁻¹(q)q = q, (B.2) = (B.5), (B.6) — holds for it.

Near the singular points (‖q‖ → 0, and ‖q‖ → π for the log) the functions switch to Taylor
series or to a dedicated branch so the results stay accurate. The numeric kernels are compiled
with numba (pure arithmetic, ``cache=True``); the public functions accept any array-like.
"""

from __future__ import annotations

import numba
import numpy as np

from uvd import geometry

_EPS_SMALL = 1e-4  # below this angle, series expansions are used (errors ~ θ⁶ ≪ 1e-16)
_jit = numba.njit(cache=True)


def _f(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


# ---------------------------------------------------------------------------------------------
# scalar coefficient functions, robust near 0
# ---------------------------------------------------------------------------------------------
@_jit
def _sinc(t):
    """sin(t)/t."""
    if t < 1e-4:
        t2 = t * t
        return 1.0 - t2 / 6.0 + t2 * t2 / 120.0
    return np.sin(t) / t


@_jit
def _cosc(t):
    """(1 − cos t)/t²."""
    if t < 1e-4:
        t2 = t * t
        return 0.5 - t2 / 24.0 + t2 * t2 / 720.0
    return (1.0 - np.cos(t)) / (t * t)


@_jit
def _sinc3(t):
    """(t − sin t)/t³."""
    if t < 1e-4:
        t2 = t * t
        return 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0
    return (t - np.sin(t)) / (t * t * t)


@_jit
def _alpha(y):
    """α(y) = (y/2) cot(y/2), App. B."""
    if y < 1e-4:
        y2 = y * y
        return 1.0 - y2 / 12.0 - y2 * y2 / 720.0
    h = 0.5 * y
    return h * np.cos(h) / np.sin(h)


@_jit
def _beta(y):
    """β(y) = (y/2)² / sin²(y/2), App. B."""
    if y < 1e-4:
        y2 = y * y
        return 1.0 + y2 / 12.0 + y2 * y2 / 240.0
    h = 0.5 * y
    s = np.sin(h)
    return h * h / (s * s)


@_jit
def _c2(y):
    """(1 − α(y))/y², the J(q)² coefficient of (2.28)."""
    if y < 0.1:
        y2 = y * y
        return 1.0 / 12.0 + y2 / 720.0 + y2 * y2 / 30240.0 + y2 * y2 * y2 / 1209600.0
    return (1.0 - _alpha(y)) / (y * y)


@_jit
def _B2(y):
    """B₂(y) of (B.4): y⁴B₂ = (1 − α) + ½(α − β)."""
    if y < 0.2:
        y2 = y * y
        return -1.0 / 720.0 - y2 / 15120.0 - y2 * y2 / 403200.0 - y2 * y2 * y2 / 11975040.0
    a = _alpha(y)
    return ((1.0 - a) + 0.5 * (a - _beta(y))) / (y**4)


@_jit
def _B1(y):
    """B₁(y) of (B.3): y²B₁ = 2(1 − α) + ½(α − β), i.e. B₁ = (1 − α)/y² + y²B₂."""
    return _c2(y) + y * y * _B2(y)


# ---------------------------------------------------------------------------------------------
# compiled kernels
# ---------------------------------------------------------------------------------------------
@_jit
def _J(w):
    out = np.zeros((3, 3))
    out[0, 1], out[0, 2] = -w[2], w[1]
    out[1, 0], out[1, 2] = w[2], -w[0]
    out[2, 0], out[2, 1] = -w[1], w[0]
    return out


@_jit
def _mm3(A, B):
    C = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            C[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]
    return C


@_jit
def _mv3(A, x):
    return np.array([A[0, 0] * x[0] + A[0, 1] * x[1] + A[0, 2] * x[2],
                     A[1, 0] * x[0] + A[1, 1] * x[1] + A[1, 2] * x[2],
                     A[2, 0] * x[0] + A[2, 1] * x[1] + A[2, 2] * x[2]])


@_jit
def _poly3(c0, c1, K, c2, K2):
    """c0 I + c1 K + c2 K²."""
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = c1 * K[i, j] + c2 * K2[i, j] + (c0 if i == j else 0.0)
    return out


@_jit
def _norm3(q):
    return np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2])


@_jit
def _exp_so3(q):
    t = _norm3(q)
    K = _J(q)
    return _poly3(1.0, _sinc(t), K, _cosc(t), _mm3(K, K))


@_jit
def _log_so3(R):
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    c = min(max(0.5 * (tr - 1.0), -1.0), 1.0)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])  # 2 sin(t) n
    s = 0.5 * _norm3(w)
    t = np.arctan2(s, c)  # accurate everywhere, unlike acos near 0 and near π
    if c > -0.7:
        if t < 1e-4:
            return 0.5 * w * (1.0 + t * t / 6.0)
        return 0.5 * w * (t / np.sin(t))
    # near π sin t → 0: the axis from the symmetric part, R + Rᵀ = 2 I cos t + 2(1 − cos t) n nᵀ
    B = 0.5 * (R + R.T)
    for i in range(3):
        B[i, i] -= c  # (1 − c) n nᵀ
    k = 0
    for i in range(1, 3):
        if B[i, i] > B[k, k]:
            k = i
    n = B[:, k] / np.sqrt(max(B[k, k] * (1.0 - c), 1e-300))
    n = n / _norm3(n)
    if n[0] * w[0] + n[1] * w[1] + n[2] * w[2] < 0.0:  # the sign of the skew part (2 sin t n)
        n = -n
    return t * n


@_jit
def _A_so3(q):
    t = _norm3(q)
    K = _J(q)
    return _poly3(1.0, -_cosc(t), K, _sinc3(t), _mm3(K, K))


@_jit
def _A_inv_so3(q):
    t = _norm3(q)
    K = _J(q)
    return _poly3(1.0, 0.5, K, _c2(t), _mm3(K, K))


@_jit
def _exp_se3(psi):
    q = psi[3:]
    t = _norm3(q)
    K = _J(q)
    K2 = _mm3(K, K)
    H = np.eye(4)
    H[:3, :3] = _poly3(1.0, _sinc(t), K, _cosc(t), K2)
    H[:3, 3] = _mv3(_poly3(1.0, _cosc(t), K, _sinc3(t), K2), psi[:3])
    return H


@_jit
def _log_se3(H):
    R = np.ascontiguousarray(H[:3, :3])
    q = _log_so3(R)
    t = _norm3(q)
    K = _J(q)
    Vinv = _poly3(1.0, -0.5, K, _c2(t), _mm3(K, K))
    out = np.empty(6)
    out[:3] = _mv3(Vinv, np.ascontiguousarray(H[:3, 3]))
    out[3:] = q
    return out


@_jit
def _ad(v):
    out = np.zeros((6, 6))
    Jw = _J(v[3:])
    out[:3, :3] = Jw
    out[:3, 3:] = _J(v[:3])
    out[3:, 3:] = Jw
    return out


@_jit
def _Ad(H):
    R = np.ascontiguousarray(H[:3, :3])
    out = np.zeros((6, 6))
    out[:3, :3] = R
    out[:3, 3:] = _mm3(_J(np.ascontiguousarray(H[:3, 3])), R)
    out[3:, 3:] = R
    return out


@_jit
def _inv_H(H):
    out = np.eye(4)
    for i in range(3):
        for j in range(3):
            out[i, j] = H[j, i]
        out[i, 3] = -(H[0, i] * H[0, 3] + H[1, i] * H[1, 3] + H[2, i] * H[2, 3])
    return out


@_jit
def _A_inv_se3(psi):
    y = _norm3(psi[3:])
    a = _ad(psi)
    a2 = a @ a
    return np.eye(6) + 0.5 * a + _B1(y) * a2 + _B2(y) * (a2 @ a2)


@_jit
def _A_inv_se3_blocks(psi):
    xi = np.ascontiguousarray(psi[:3])
    q = np.ascontiguousarray(psi[3:])
    y = _norm3(q)
    Jx, Jq = _J(xi), _J(q)
    Jq2 = _mm3(Jq, Jq)
    B4 = _mm3(Jx, Jq) + _mm3(Jq, Jx)
    B3 = _mm3(_mm3(Jq, Jx), Jq2) + _mm3(_mm3(Jq2, Jx), Jq)
    Ai = _poly3(1.0, 0.5, Jq, _c2(y), Jq2)
    out = np.zeros((6, 6))
    out[:3, :3] = Ai
    out[3:, 3:] = Ai
    out[:3, 3:] = 0.5 * Jx + _c2(y) * B4 + _B2(y) * B3
    return out


# ---------------------------------------------------------------------------------------------
# operators (§2.2.1)
# ---------------------------------------------------------------------------------------------
def J(w) -> np.ndarray:
    """Hat map R³ → so(3), eq. (2.1): J(w) x = w × x."""
    return _J(_f(w))


def vee(W: np.ndarray) -> np.ndarray:
    """Inverse of :func:`J` (takes the skew part of W)."""
    return 0.5 * np.array([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]])


def hat6(v) -> np.ndarray:
    """se(3) hat, eq. (2.2): v = [ν; ω] ↦ [[J(ω), ν], [0, 0]] ∈ R⁴ˣ⁴."""
    v = _f(v)
    out = np.zeros((4, 4))
    out[:3, :3] = _J(v[3:])
    out[:3, 3] = v[:3]
    return out


def vee6(X: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat6`."""
    return np.concatenate([X[:3, 3], vee(X[:3, :3])])


def ad(v) -> np.ndarray:
    """se(3) adjoint operator, eq. (2.4): ad_v = [[J(ω), J(ν)], [0, J(ω)]] for v = [ν; ω]."""
    return _ad(_f(v))


def Ad(H) -> np.ndarray:
    """se(3) adjoint map of H = [[R, p], [0, 1]], eq. (2.5): [[R, J(p)R], [0, R]]."""
    return _Ad(_f(H))


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


def inv_H(H) -> np.ndarray:
    """Inverse of a homogeneous transform without a general matrix inverse."""
    return _inv_H(_f(H))


# ---------------------------------------------------------------------------------------------
# SO(3) and SE(3) maps
# ---------------------------------------------------------------------------------------------
def exp_so3(q) -> np.ndarray:
    """SO(3) exponential R = e^{J(q)}, eq. (2.23) (Rodrigues' formula)."""
    return _exp_so3(_f(q))


def log_so3(R) -> np.ndarray:
    """SO(3) logarithm q with R = e^{J(q)}, ‖q‖ ∈ [0, π]; accurate near 0 and near π."""
    return _log_so3(np.ascontiguousarray(R, dtype=np.float64))


def A_so3(q) -> np.ndarray:
    """Angular-velocity Jacobian A(q) of (2.25)–(2.26): ω = A(q) q̇ (body ω, see module note)."""
    return _A_so3(_f(q))


def A_inv_so3(q) -> np.ndarray:
    """Inverse Jacobian A⁻¹(q) of (2.27)–(2.28): q̇ = A⁻¹(q) ω; exists for ‖q‖ < 2π."""
    return _A_inv_so3(_f(q))


def exp_se3(psi) -> np.ndarray:
    """SE(3) exponential H = e^{ψ̂}, eq. (2.29), ψ = [ξ; q]."""
    return _exp_se3(_f(psi))


def log_se3(H) -> np.ndarray:
    """SE(3) logarithm ψ = [ξ; q] with H = e^{ψ̂} and ‖q‖ ≤ π."""
    return _log_se3(_f(H))


def A_inv_se3(psi) -> np.ndarray:
    """Inverse SE(3) velocity Jacobian by (B.2): ψ̇ = A⁻¹(ψ) v.

    A⁻¹(ψ) = I + ½ad_ψ + B₁(‖q‖) ad_ψ² + B₂(‖q‖) ad_ψ⁴ with B₁, B₂ of (B.3)–(B.4).
    """
    return _A_inv_se3(_f(psi))


def A_inv_se3_blocks(psi) -> np.ndarray:
    """Inverse SE(3) velocity Jacobian by the block form (B.5); equal to :func:`A_inv_se3`.

    [[A⁻¹(q), ½J(ξ) + (1−α)/‖q‖² B₄(ξ,q) + B₂(‖q‖) B₃(ξ,q)], [0, A⁻¹(q)]] with
    B₄ = J(ξ)J(q) + J(q)J(ξ) and B₃ = J(q)J(ξ)J(q)² + J(q)²J(ξ)J(q).
    """
    return _A_inv_se3_blocks(_f(psi))


def A_inv_se3_T_psi(psi) -> np.ndarray:
    """A⁻ᵀ(ψ) ψ, the proportional term of the PD law (5.11)."""
    psi = _f(psi)
    return _A_inv_se3_blocks(psi).T @ psi


#: R = Rz(ψ) Ry(θ) Rx(φ) (App. A), compiled for compiled callers: :func:`uvd.geometry.euler_to_R`
euler_R = numba.njit(cache=True)(geometry.euler_to_R)
#: (φ, θ, ψ) of R, compiled for compiled callers: :func:`uvd.geometry.R_to_euler`
R_euler = numba.njit(cache=True)(geometry.R_to_euler)
