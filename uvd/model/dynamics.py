"""UV dynamics: the 6-DOF model (2.44) and the 3-DOF rotational model (2.40).

    Ḣ = H v̂,   M v̇ = ad_vᵀ(Mv) + (Σᵢ|vᵢ|Dᵢ) v + G(R) + u,   G(R) = [g Rᵀe₃; J(b) Rᵀe₃]   (2.44)
    Ṙ = R J(ω), I ω̇ = J(Iω)ω + (Σᵢ|ωᵢ|Cᵢ) ω + J(b) Rᵀe₃ + τ                            (2.40)

:class:`UVModel` is the constant model description (Pinocchio style): M⁻¹ and the drag
matrices laid side by side are precomputed once, so the forward dynamics is a handful of small
numpy operations. Functions are pure; nothing here keeps state between calls.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uvd.model.lie import J
from uvd.model.params import RotParams, UVParams


def ad_T(v: np.ndarray, x: np.ndarray) -> np.ndarray:
    """ad_vᵀ x for v = [ν; ω], x = [p; h]: [p × ω; p × ν + h × ω]  (transpose of (2.4))."""
    return np.array(_ad_T_list(v.tolist(), x.tolist()))


def _ad_T_list(v: list[float], x: list[float]) -> list[float]:
    n1, n2, n3, w1, w2, w3 = v
    p1, p2, p3, h1, h2, h3 = x
    return [
        p2 * w3 - p3 * w2,
        p3 * w1 - p1 * w3,
        p1 * w2 - p2 * w1,
        p2 * n3 - p3 * n2 + h2 * w3 - h3 * w2,
        p3 * n1 - p1 * n3 + h3 * w1 - h1 * w3,
        p1 * n2 - p2 * n1 + h1 * w2 - h2 * w1,
    ]


def gravity_wrench(g: float, b: np.ndarray, R: np.ndarray) -> np.ndarray:
    """G(R) = [g Rᵀe₃; J(b) Rᵀe₃] of (2.44); Rᵀe₃ is the third row of R."""
    return np.array(_gravity_list(float(g), b.tolist(), R[2].tolist()))


def _gravity_list(g: float, b: list[float], r: list[float]) -> list[float]:
    r1, r2, r3 = r
    b1, b2, b3 = b
    return [g * r1, g * r2, g * r3, b2 * r3 - b3 * r2, b3 * r1 - b1 * r3, b1 * r2 - b2 * r1]


def drag_wrench(D_flat: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(Σᵢ|vᵢ|Dᵢ) v with D_flat = [D₁ … D₆] (6 × 36): D_flat · (|v| ⊗ v)."""
    return D_flat @ np.multiply.outer(np.abs(v), v).ravel()


@dataclass(frozen=True)
class UVModel:
    """Precomputed, immutable description of a 6-DOF UV for fast forward dynamics."""

    params: UVParams
    M: np.ndarray
    M_inv: np.ndarray
    D_flat: np.ndarray
    g: float
    b: np.ndarray
    b_list: list

    @classmethod
    def from_params(cls, p: UVParams) -> UVModel:
        M = 0.5 * (p.M + p.M.T)
        # b is copied: UVParams' arrays are read-only, and a read-only array is another type
        # to the compiled kernels — a copy of the model (copy.deepcopy makes arrays writable)
        # would compile them a second time, seconds, at its first step
        return cls(params=p, M=M, M_inv=np.linalg.inv(M), D_flat=np.hstack(list(p.D)),
                   g=float(p.g), b=np.array(p.b, dtype=float),
                   b_list=[float(x) for x in p.b])


def uv_accel(model: UVModel, v: np.ndarray, R: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Forward dynamics of (2.44): v̇ = M⁻¹(ad_vᵀ(Mv) + Σ|vᵢ|Dᵢ v + G(R) + u).

    Parameters
    ----------
    v : (6,) body velocity [ν; ω] (m/s, rad/s). R : (3, 3) body→world rotation.
    u : (6,) body wrench [f; τ] (N, N m).
    """
    vl = v.tolist()
    a = _ad_T_list(vl, (model.M @ v).tolist())
    gr = _gravity_list(model.g, model.b_list, R[2].tolist())
    rhs = np.array([a[i] + gr[i] for i in range(6)])
    rhs += model.D_flat @ np.multiply.outer(np.abs(v), v).ravel()
    rhs += u
    return model.M_inv @ rhs


def uv_inverse_dynamics(p: UVParams, v: np.ndarray, vdot: np.ndarray, R: np.ndarray) -> np.ndarray:
    """u = M v̇ − ad_vᵀ(Mv) − (Σᵢ|vᵢ|Dᵢ) v − G(R): the input that produces v̇ (2.44)."""
    M = 0.5 * (p.M + p.M.T)
    D_sum = np.tensordot(np.abs(v), p.D, axes=1)
    return M @ vdot - ad_T(v, M @ v) - D_sum @ v - gravity_wrench(p.g, p.b, R)


def kinetic_energy(model: UVModel, v: np.ndarray) -> float:
    """½ vᵀ M v."""
    return 0.5 * float(v @ model.M @ v)


# ---------------------------------------------------------------------------------------------
# 3-DOF rotational model (2.40)
# ---------------------------------------------------------------------------------------------
def rot_accel(p: RotParams, w: np.ndarray, R: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """ω̇ = I⁻¹(J(Iω)ω + Σ|ωᵢ|Cᵢ ω + J(b)Rᵀe₃ + τ), eq. (2.40)."""
    I = np.asarray(p.I)
    C_sum = np.tensordot(np.abs(w), np.asarray(p.C), axes=1)
    rhs = J(I @ w) @ w + C_sum @ w + J(np.asarray(p.b)) @ R[2] + tau
    return np.linalg.solve(I, rhs)


def rot_inverse_dynamics(p: RotParams, w: np.ndarray, wdot: np.ndarray,
                         R: np.ndarray) -> np.ndarray:
    """τ = Iω̇ − J(Iω)ω − Σ|ωᵢ|Cᵢ ω − J(b)Rᵀe₃ (2.40)."""
    I = np.asarray(p.I)
    C_sum = np.tensordot(np.abs(w), np.asarray(p.C), axes=1)
    return I @ wdot - J(I @ w) @ w - C_sum @ w - J(np.asarray(p.b)) @ R[2]
