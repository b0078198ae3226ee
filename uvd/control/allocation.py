"""Thruster allocation: body wrench u → per-thruster thrust f, with direction-keeping saturation,
and the thruster law both ways (App. A.1).

* f = B_W⁺ u, the weighted pseudo-inverse of the thruster matrix (u = B f): the f of least
  Σ wᵢ fᵢ² that produces u exactly, B_W⁺ = W⁻¹Bᵀ(B W⁻¹ Bᵀ)⁻¹ (with unit weights the
  Moore–Penrose B⁺). Weights let a weak or worn thruster be spared.
* If any |fᵢ| exceeds its limit the *whole* vector is scaled by the largest ratio, which keeps
  the wrench's direction (u_applied = s u, 0 < s ≤ 1); the thrusters at their limit are reported.
* Thrust → amplifier command through the thruster model: the propeller-speed set-point
  ω* = sign(f)√(|f|/k) of the steady-state law f = k ω|ω| (App. A.1).
* The inverse, which the thesis uses as the applied input: thrust estimated from measured
  propeller speed, f = k ω|ω|, and the wrench u = B f it produces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from uvd.model.thrusters import speed_from_thrust, thrust_from_speed


@dataclass(frozen=True)
class Allocator:
    """Constant allocation data.

    Attributes
    ----------
    B : (6, N) thruster matrix, u = B f.
    B_pinv : (N, 6) (weighted) pseudo-inverse.
    max_thrust_n : (N,) per-thruster thrust limit (N).
    k_thrust : (N,) f = k ω|ω| constants (N/(rad/s)²), for the amplifier command.
    weights : (N,) allocation weights (larger: used less).
    """

    B: np.ndarray
    B_pinv: np.ndarray
    max_thrust_n: np.ndarray
    k_thrust: np.ndarray | None = None
    weights: np.ndarray | None = None

    @classmethod
    def from_vehicle(cls, vehicle, weights: np.ndarray | None = None) -> Allocator:
        B = np.ascontiguousarray(vehicle.B, dtype=float)
        return cls(B=B, B_pinv=weighted_pinv(B, weights),
                   max_thrust_n=np.asarray(vehicle.max_thrust_n, dtype=float),
                   k_thrust=np.asarray(vehicle.k_thrust, dtype=float),
                   weights=None if weights is None else np.asarray(weights, dtype=float))

    @property
    def n_thrusters(self) -> int:
        return self.B.shape[1]


def weighted_pinv(B: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """B_W⁺ = W⁻¹Bᵀ(BW⁻¹Bᵀ)⁻¹ (W = diag(weights) > 0; None: Moore–Penrose B⁺).

    B must have full row rank 6 (a fully actuated vehicle)."""
    B = np.asarray(B, dtype=float)
    if weights is None:
        return np.ascontiguousarray(np.linalg.pinv(B))
    w = np.asarray(weights, dtype=float).reshape(-1)
    if w.shape != (B.shape[1],) or not np.all(w > 0) or not np.all(np.isfinite(w)):
        raise ValueError(f"weights must be {B.shape[1]} finite positive numbers")
    Wi = np.diag(1.0 / w)
    return np.ascontiguousarray(Wi @ B.T @ np.linalg.inv(B @ Wi @ B.T))


@numba.njit(cache=True)
def _allocate(B_pinv, f_max, u):
    n = B_pinv.shape[0]
    f = np.empty(n)
    ratio = np.empty(n)
    worst = 0.0
    for j in range(n):
        x = 0.0
        for i in range(6):
            x += B_pinv[j, i] * u[i]
        f[j] = x
        ratio[j] = abs(x) / f_max[j]
        worst = max(worst, ratio[j])
    sat = np.zeros(n, dtype=np.bool_)
    scale = 1.0
    if worst > 1.0:
        scale = 1.0 / worst
        for j in range(n):
            f[j] *= scale
            sat[j] = ratio[j] >= worst * (1.0 - 1e-12)
    return f, sat, scale


def allocate(alloc: Allocator, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(f, saturated mask, scale) for the wrench u; scale ≤ 1 is the factor applied.

    Unsaturated: B f = u exactly. Saturated: f = B⁺u / max_i(|fᵢ|/f_max,i), so B f = scale·u
    (same direction) and the thrusters at their limit are flagged. A non-finite u gives a
    non-finite f (the core then commands zero thrust).
    """
    u = np.asarray(u, dtype=float)
    if not np.isfinite(u).all():
        f = alloc.B_pinv @ u
        return f, np.zeros(f.shape, dtype=bool), 1.0
    return _allocate(alloc.B_pinv, alloc.max_thrust_n, u)


def speed_command(alloc: Allocator, f: np.ndarray) -> np.ndarray:
    """Amplifier command: the propeller-speed set-point ω* = sign(f)√(|f|/k) (rad/s) that
    yields thrust f in steady state (App. A.1)."""
    if alloc.k_thrust is None:
        raise ValueError("allocator has no k_thrust (build it with Allocator.from_vehicle)")
    return speed_from_thrust(f, alloc.k_thrust)


def thrust_from_measured_speed(alloc: Allocator, omega_rad_s: np.ndarray) -> np.ndarray:
    """Thrust estimated from measured propeller speed, f = k ω|ω| (App. A.1)."""
    if alloc.k_thrust is None:
        raise ValueError("allocator has no k_thrust (build it with Allocator.from_vehicle)")
    return thrust_from_speed(omega_rad_s, alloc.k_thrust)


def applied_wrench(alloc: Allocator, omega_rad_s: np.ndarray) -> np.ndarray:
    """The wrench u = B f with f estimated from measured propeller speed — the thesis's
    applied input (App. A.1, Fig. 5.2)."""
    return alloc.B @ thrust_from_measured_speed(alloc, omega_rad_s)
