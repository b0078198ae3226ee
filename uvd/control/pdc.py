"""Proportional-derivative control (PDC): the PD part of (5.11).

    u = −(k_p A⁻ᵀ(Δψ) Δψ + k_d Δv)

on the SE(3) error coordinates of §5.2.3. Optionally a *known* gravity/buoyancy wrench G(H) is
compensated (u −= G(R)); off for the thesis comparison (§5.3.5.1 compares plain PD).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from uvd.control.errors import error_coordinates
from uvd.control.types import Reference, VehicleState
from uvd.model.dynamics import gravity_wrench
from uvd.model.lie import A_inv_se3_blocks


@dataclass(frozen=True)
class PDGains:
    """k_p (N per unit of Δψ) and k_d (N s per unit of Δv); scalars as in the thesis or (6,)."""

    kp: float | np.ndarray = 300.0
    kd: float | np.ndarray = 100.0
    gravity_compensation: bool = False
    g: float = 0.0
    b: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class PDState:
    """PDC is memoryless; the state records the last errors for diagnostics."""

    dpsi: np.ndarray = field(default_factory=lambda: np.zeros(6))
    dv: np.ndarray = field(default_factory=lambda: np.zeros(6))


def pdc_step(state: VehicleState, reference: Reference, gains: PDGains, ctrl: PDState,
             dt: float) -> tuple[np.ndarray, PDState]:
    """One PDC cycle; returns (u, new state). u = [f; τ] body wrench (N, N m)."""
    _, dpsi, dv, _ = error_coordinates(state.H, state.v, reference.H, reference.v)
    u = -(gains.kp * (A_inv_se3_blocks(dpsi).T @ dpsi) + gains.kd * dv)
    if gains.gravity_compensation:
        u = u - gravity_wrench(gains.g, np.asarray(gains.b), state.H[:3, :3])
    if reference.closed_loop is not None:  # DOFs driven open loop get no feedback (Table 5.1)
        u = np.where(reference.closed_loop, u, 0.0)
    return u, PDState(dpsi=dpsi, dv=dv)
