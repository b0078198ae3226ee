"""Proportional-derivative control (PDC): the PD part of (5.11).

    u = −(k_p A⁻ᵀ(Δψ) Δψ + k_d Δv)

on the SE(3) error coordinates of §5.2.3 (Δψ = log(ʷ_dH⁻¹ ʷₐH), Δv = ᵃvₐ − Ad_{ΔH⁻¹} ᵈv_d).
Optionally a *known* gravity/buoyancy wrench G(H) of (2.44) is compensated (u −= G(R)); off for
the thesis comparison (§5.3.5.1 compares plain PD).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from uvd.control import _kernels
from uvd.control.types import Reference, VehicleState
from uvd.model.dynamics import gravity_wrench


def gain_vector(k: float | np.ndarray, name: str = "gain") -> np.ndarray:
    """A scalar gain or six per-DOF gains as a (6,) array; must be finite and ≥ 0."""
    a = np.broadcast_to(np.asarray(k, dtype=float), (6,)).copy()
    if not np.all(np.isfinite(a)) or np.any(a < 0.0):
        raise ValueError(f"{name} must be finite and >= 0, got {k!r}")
    return a


@dataclass(frozen=True)
class PDGains:
    """k_p (N or N m per unit of Δψ) and k_d (N s or N m s per unit of Δv).

    Scalars as in the thesis (k_p = 300, k_d = 100, §5.3.5.1) or (6,) per DOF. With
    ``gravity_compensation`` the known G(R) of (2.44) with ``g`` (N) and ``b`` (N m) is removed.
    """

    kp: float | np.ndarray = 300.0
    kd: float | np.ndarray = 100.0
    gravity_compensation: bool = False
    g: float = 0.0
    b: tuple[float, float, float] = (0.0, 0.0, 0.0)
    _kp: np.ndarray = field(default=None, init=False, repr=False, compare=False)
    _kd: np.ndarray = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_kp", gain_vector(self.kp, "kp"))
        object.__setattr__(self, "_kd", gain_vector(self.kd, "kd"))


@dataclass(frozen=True, slots=True)
class PDState:
    """PDC is memoryless; the state records the last errors for diagnostics."""

    dpsi: np.ndarray = field(default_factory=lambda: np.zeros(6))
    dv: np.ndarray = field(default_factory=lambda: np.zeros(6))


def pdc_step(state: VehicleState, reference: Reference, gains: PDGains, ctrl: PDState,
             dt: float) -> tuple[np.ndarray, PDState]:
    """One PDC cycle; returns (u, new state). u = [f; τ] body wrench (N, N m).

    DOFs that ``reference.closed_loop`` marks open loop get no feedback (Table 5.1, RefTraj2).
    """
    err = np.empty((5, 6))
    _kernels.error_state(state.H, state.v, reference.H, reference.v, reference.vdot, err)
    dpsi, dv = err[0], err[1]
    u = -_kernels.pd_term(dpsi, dv, gains._kp, gains._kd)
    if gains.gravity_compensation:
        u = u - gravity_wrench(gains.g, np.asarray(gains.b, dtype=float), state.H[:3, :3])
    if reference.closed_loop is not None:
        u = np.where(reference.closed_loop, u, 0.0)
    return u, PDState(dpsi=dpsi, dv=dv)
