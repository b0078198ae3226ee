"""SE(3) tracking-error coordinates of §5.2.3."""

from __future__ import annotations

import numpy as np

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
