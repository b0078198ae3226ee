"""Reference trajectories: per-DOF sums of cosines in world x, y, z, roll, pitch, heading.

Each DOF k is c_k + Σⱼ a_kj cos(w_kj t + φ_kj) with analytic first and second derivatives,
turned into the desired state {ʷ_dH, ᵈv_d, ᵈv̇_d} of §5.2.4.1: R_d = Rz(heading) Ry(pitch) Rx(roll)
(App. A), p_d = [x, y, z]; ν_d = R_dᵀ ṗ, ω_d = E(φ, θ) η̇ (ZYX Euler-rate map), and
ν̇_d = R_dᵀ p̈ − ω_d × ν_d, ω̇_d = E η̈ + Ė η̇.

RefTraj1 of Table 5.1 is built in (:func:`reftraj1`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivers.samples import euler_to_R
from uvd.control.types import Reference
from uvd.model.lie import make_H

DOFS = ("x", "y", "z", "roll", "pitch", "heading")
_DEG = math.pi / 180.0


@dataclass(frozen=True)
class CosineTerm:
    amplitude: float
    frequency_rad_s: float
    phase_rad: float = 0.0


@dataclass(frozen=True)
class CosineTrajectory:
    """Sum-of-cosines reference; ``center`` is [x, y, z (m), roll, pitch, heading (rad)]."""

    center: tuple[float, float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    terms: tuple[tuple[CosineTerm, ...], ...] = ((),) * 6
    name: str = "trajectory"

    def dof(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(η, η̇, η̈) of the six DOFs at time t (world x, y, z, roll, pitch, heading)."""
        eta = np.array(self.center, dtype=float)
        d1 = np.zeros(6)
        d2 = np.zeros(6)
        for k, terms in enumerate(self.terms):
            for term in terms:
                a, w, ph = term.amplitude, term.frequency_rad_s, term.phase_rad
                c, s = math.cos(w * t + ph), math.sin(w * t + ph)
                eta[k] += a * c
                d1[k] -= a * w * s
                d2[k] -= a * w * w * c
        return eta, d1, d2

    def at(self, t: float) -> Reference:
        eta, d1, d2 = self.dof(t)
        return reference_from_euler(eta, d1, d2)


def reference_from_euler(eta: np.ndarray, d1: np.ndarray, d2: np.ndarray) -> Reference:
    """Desired state from world position/Euler angles and their first two derivatives."""
    phi, th, psi = eta[3], eta[4], eta[5]
    dphi, dth, dpsi = d1[3], d1[4], d1[5]
    R = euler_to_R(phi, th, psi)
    sphi, cphi = math.sin(phi), math.cos(phi)
    sth, cth = math.sin(th), math.cos(th)
    E = np.array([[1.0, 0.0, -sth], [0.0, cphi, cth * sphi], [0.0, -sphi, cth * cphi]])
    Edot = np.array([
        [0.0, 0.0, -cth * dth],
        [0.0, -sphi * dphi, -sth * dth * sphi + cth * cphi * dphi],
        [0.0, -cphi * dphi, -sth * dth * cphi - cth * sphi * dphi],
    ])
    nu = R.T @ d1[:3]
    om = E @ d1[3:]
    nudot = R.T @ d2[:3] - np.cross(om, nu)
    omdot = E @ d2[3:] + Edot @ d1[3:]
    return Reference(H=make_H(R, eta[:3]), v=np.concatenate([nu, om]),
                     vdot=np.concatenate([nudot, omdot]))


def setpoint(center) -> CosineTrajectory:
    """Hold a constant pose [x, y, z, roll, pitch, heading]."""
    return CosineTrajectory(center=tuple(float(c) for c in center), name="setpoint")


def reftraj1(center=(0.0, 0.0, 1.5, 0.0, 0.0, 0.0)) -> CosineTrajectory:
    """RefTraj1 of Table 5.1 (trajectory-tracking evaluation), about ``center``.

    x: 0.50 m at 0.242 rad/s; y: 0.50 m at 0.210; z: 0.30 m at 0.185; roll 6.9° at 0.5;
    pitch 8.6° at 0.6; heading 135° at 0.210 rad/s.
    """
    spec = [(0.50, 0.242), (0.50, 0.210), (0.30, 0.185), (6.9 * _DEG, 0.5), (8.6 * _DEG, 0.6),
            (135.0 * _DEG, 0.210)]
    return CosineTrajectory(center=tuple(center),
                            terms=tuple((CosineTerm(a, w),) for a, w in spec), name="RefTraj1")
