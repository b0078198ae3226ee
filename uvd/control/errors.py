"""SE(3) tracking-error coordinates of §5.2.3."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uvd.control import _kernels
from uvd.model.lie import Ad, inv_H, log_se3


def error_coordinates(H_a: np.ndarray, v_a: np.ndarray, H_d: np.ndarray, v_d: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(ΔH, Δψ, Δv, ᵃv_d) of (5.2)–(5.4).

    ΔH = ʷ_dH⁻¹ ʷₐH (5.2), Δψ = log_SE(3)(ΔH) (5.3), ᵃv_d = Ad_{ΔH⁻¹} ᵈv_d and
    Δv = ᵃvₐ − ᵃv_d (5.4).
    """
    dH = inv_H(H_d) @ H_a
    dpsi = log_se3(dH)
    v_d_a = Ad(inv_H(dH)) @ v_d
    return dH, dpsi, v_a - v_d_a, v_d_a


@dataclass(frozen=True, slots=True)
class ErrorState:
    """Error coordinates and the acceleration term of the MBC regressor.

    Attributes
    ----------
    dpsi : Δψ = log(ʷ_dH⁻¹ ʷₐH) (5.3), [ξ; q] (m, rad).
    dv : Δv = ᵃvₐ − ᵃv_d (5.4), body frame of the actual vehicle.
    v_d : ᵃv_d = Ad_{ΔH⁻¹} ᵈv_d.
    vdot_d : Ad_{ΔH⁻¹} ᵈv̇_d.
    alpha : α = Ad_{ΔH⁻¹} ᵈv̇_d − ad_{Δv} ᵃv_d, so that (5.10) reads Δv̇ = v̇ₐ − α and the
        regressor (5.12) is W_MBC θ = M α − ad_vᵀ(Mv) − D(v) − G(H) with v = ᵃvₐ.
    """

    dpsi: np.ndarray
    dv: np.ndarray
    v_d: np.ndarray
    vdot_d: np.ndarray
    alpha: np.ndarray


def error_state(H_a: np.ndarray, v_a: np.ndarray, H_d: np.ndarray, v_d: np.ndarray,
                vdot_d: np.ndarray) -> ErrorState:
    """:class:`ErrorState` of the actual state (H_a, v_a) and the desired (H_d, v_d, v̇_d)."""
    out = np.empty((5, 6))
    _kernels.error_state(np.ascontiguousarray(H_a, dtype=float), np.asarray(v_a, dtype=float),
                         np.ascontiguousarray(H_d, dtype=float), np.asarray(v_d, dtype=float),
                         np.asarray(vdot_d, dtype=float), out)
    return ErrorState(*out)
