"""Thruster geometry and the steady-state thruster law (App. A.1) — pure math.

A thruster at body position r with unit thrust direction d contributes the body wrench
[d; r × d] per newton, so u = B f with B = [[d₁ … d_N], [r₁×d₁ … r_N×d_N]] ∈ R⁶ˣᴺ.
Steady state, thrust and propeller speed obey f = k ω|ω| (App. A.1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uvd.errors import ParameterError


@dataclass(frozen=True)
class ThrusterSpec:
    """One thruster: geometry (body frame, m), f = k ω|ω| constant, limits and dynamics."""

    name: str
    position_m: tuple[float, float, float]
    direction: tuple[float, float, float]
    k_thrust: float = 0.0048
    max_thrust_n: float = 300.0
    time_constant_s: float = 0.15
    stiction_n: float = 5.0

    def __post_init__(self) -> None:
        d = np.asarray(self.direction, dtype=float)
        n = float(np.linalg.norm(d))
        if len(self.position_m) != 3 or d.shape != (3,):
            raise ParameterError(f"thruster {self.name!r}: position_m and direction need 3 entries")
        if not n > 0.0:
            raise ParameterError(f"thruster {self.name!r}: direction must be non-zero")
        object.__setattr__(self, "direction", tuple(float(x) for x in d / n))
        object.__setattr__(self, "position_m", tuple(float(x) for x in self.position_m))
        if self.k_thrust <= 0 or self.max_thrust_n <= 0 or self.time_constant_s < 0:
            raise ParameterError(
                f"thruster {self.name!r}: k_thrust and max_thrust_n must be > 0, "
                "time_constant_s >= 0")


def thruster_matrix(specs: tuple[ThrusterSpec, ...] | list[ThrusterSpec]) -> np.ndarray:
    """B ∈ R⁶ˣᴺ with u = [f; τ] = B f_thrusters."""
    B = np.zeros((6, len(specs)))
    for j, s in enumerate(specs):
        d = np.asarray(s.direction)
        r = np.asarray(s.position_m)
        B[:3, j] = d
        B[3:, j] = np.cross(r, d)
    return B


def thrust_from_speed(omega: np.ndarray, k: np.ndarray | float) -> np.ndarray:
    """Steady-state thrust f = k ω|ω| (App. A.1); ω in rad/s, f in N."""
    omega = np.asarray(omega, dtype=float)
    return k * omega * np.abs(omega)


def speed_from_thrust(f: np.ndarray, k: np.ndarray | float) -> np.ndarray:
    """Inverse of :func:`thrust_from_speed`: ω = sign(f) √(|f|/k)."""
    f = np.asarray(f, dtype=float)
    return np.sign(f) * np.sqrt(np.abs(f) / k)
