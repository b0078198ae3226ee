"""Regressor forms of the UV models: u = W_UV(v, v̇, R) θ_UV (2.49), τ = W_UVR(ω, ω̇, R) θ_UVR (2.42).

Derived from the model equations with stack(A X B) = (Bᵀ ⊗ A) stack(X) (the extracted thesis
text lost some transposes and signs; ``tests/test_regressors.py`` proves each form equals its
model for random arguments):

* M v̇ = (v̇ᵀ ⊗ I₆) Mˢ and −ad_vᵀ(Mv) = (vᵀ ⊗ (−ad_vᵀ)) Mˢ, so
  W_M(v, v̇) = (v̇ᵀ ⊗ I₆ − vᵀ ⊗ ad_vᵀ) P_M                                       (6 × 21)
* −|vᵢ| Dᵢ v = (−|vᵢ| vᵀ ⊗ I₆) Dᵢˢ, so W_Dᵢ(v) = −|vᵢ| vᵀ ⊗ I₆                   (6 × 36 each)
* −G(R) = [−Rᵀe₃ g; J(Rᵀe₃) b], so W_gb(R) = [[−Rᵀe₃, 0], [0, J(Rᵀe₃)]]         (6 × 4)
* rotational: W_I(ω, ω̇) = (ω̇ᵀ ⊗ I₃ + ωᵀ ⊗ J(ω)) P_I (2.39), since −J(Iω)ω = J(ω)Iω;
  W_Cᵢ = −|ωᵢ| ωᵀ ⊗ I₃; the b block is J(Rᵀe₃).
"""

from __future__ import annotations

import numpy as np

from uvd.model.lie import J, ad
from uvd.model.params import P_I, P_M

_I6 = np.eye(6)
_I3 = np.eye(3)


def W_M(v: np.ndarray, vdot: np.ndarray) -> np.ndarray:
    """Mass regressor (6 × 21): W_M θ_M = M v̇ − ad_vᵀ(Mv)."""
    return (np.kron(vdot[None, :], _I6) - np.kron(v[None, :], ad(v).T)) @ P_M


def W_D(v: np.ndarray) -> np.ndarray:
    """Drag regressor (6 × 216): W_D [D₁ˢ; …; D₆ˢ] = −(Σᵢ|vᵢ|Dᵢ) v."""
    base = np.kron(v[None, :], _I6)  # vᵀ ⊗ I₆, 6 × 36
    return np.hstack([-abs(vi) * base for vi in v])


def W_gb(R: np.ndarray) -> np.ndarray:
    """Gravity/buoyancy regressor (6 × 4): W_gb [g; b] = −G(R)."""
    r = R[2]  # Rᵀe₃
    out = np.zeros((6, 4))
    out[:3, 0] = -r
    out[3:, 1:] = J(r)
    return out


def W_UV(v: np.ndarray, vdot: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Full regressor (6 × 241) of (2.49): u = W_UV(v, v̇, R) θ_UV."""
    return np.hstack([W_M(v, vdot), W_D(v), W_gb(R)])


def W_I(w: np.ndarray, wdot: np.ndarray) -> np.ndarray:
    """Inertia regressor (3 × 6) of (2.39): W_I θ_I = Iω̇ − J(Iω)ω."""
    return (np.kron(wdot[None, :], _I3) + np.kron(w[None, :], J(w))) @ P_I


def W_UVR(w: np.ndarray, wdot: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Rotational regressor (3 × 36) of (2.42)–(2.43): τ = W_UVR(ω, ω̇, R) θ_UVR."""
    base = np.kron(w[None, :], _I3)
    return np.hstack([W_I(w, wdot)] + [-abs(wi) * base for wi in w] + [J(R[2])])
