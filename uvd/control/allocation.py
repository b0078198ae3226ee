"""Thruster allocation: body wrench u → per-thruster thrust f, with direction-keeping saturation.

f = B⁺ u (Moore–Penrose pseudo-inverse of the thruster matrix, u = B f). If any |f_i| exceeds
its limit the whole vector is scaled by the largest ratio, which keeps the wrench's direction;
the thrusters at their limit are reported.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Allocator:
    B: np.ndarray          # 6 × N thruster matrix
    B_pinv: np.ndarray     # N × 6
    max_thrust_n: np.ndarray

    @classmethod
    def from_vehicle(cls, vehicle) -> Allocator:
        B = np.asarray(vehicle.B, dtype=float)
        return cls(B=B, B_pinv=np.linalg.pinv(B), max_thrust_n=vehicle.max_thrust_n)


def allocate(alloc: Allocator, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(f, saturated mask, scale) for the wrench u; scale ≤ 1 is the factor applied."""
    f = alloc.B_pinv @ u
    ratio = np.abs(f) / alloc.max_thrust_n
    worst = float(ratio.max()) if ratio.size else 0.0
    if worst > 1.0:
        f = f / worst
        return f, ratio >= worst * (1.0 - 1e-12), 1.0 / worst
    return f, np.zeros(f.shape, dtype=bool), 1.0
