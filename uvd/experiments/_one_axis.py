"""One axis of the decoupled model under a PD law: what Table 5.6's PDC row asks of the gains.

Each DOF of RefTraj1 alone (Table 5.1: A cos ωt), on its decoupled row of (2.44):

    m ẍ = τ + d |ẋ| ẋ + r(x),   τ = k_p (x_r − x) + k_d (ẋ_r − ẋ)

with r(x) = −b₃ sin x for roll and pitch (the righting moment of G(R)), g for heave, 0 else;
τ held over the 0.1 s cycle (§5.3.1), RK4 at 100 Hz, the plant started on the reference, MAE
of position and velocity sampled at the cycle over ``seconds`` (PDC's 10 minutes, §5.3.5.1).
No thruster dynamics, no noise, no coupling: an idealisation that isolates what the gains and
the identified m_i, d_i (Table 5.5) imply for each column of Table 5.6.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from uvd.control.trajectory import REFTRAJ1_SPEC

AXES = ("x", "y", "z", "roll", "pitch", "heading")


@numba.njit(cache=True)
def _rhs(x, xd, tau, m, d, b3, g, angular):
    r = -b3 * math.sin(x) if angular else g
    return xd, (tau + d * abs(xd) * xd + r) / m


@numba.njit(cache=True)
def _one_axis(m, d, b3, g, angular, amp, w, kp, kd, seconds):
    dt, sub = 0.01, 10
    n = int(round(seconds / (dt * sub)))
    out = np.empty((kp.shape[0], 2))
    for j in range(kp.shape[0]):
        x, xd = amp, 0.0
        ep = ev = 0.0
        for k in range(n):
            t = k * dt * sub
            xr, xrd = amp * math.cos(w * t), -amp * w * math.sin(w * t)
            ep += abs(xr - x)
            ev += abs(xrd - xd)
            tau = kp[j] * (xr - x) + kd * (xrd - xd)
            for _ in range(sub):
                k1x, k1v = _rhs(x, xd, tau, m, d, b3, g, angular)
                k2x, k2v = _rhs(x + 0.5 * dt * k1x, xd + 0.5 * dt * k1v, tau, m, d, b3, g,
                                angular)
                k3x, k3v = _rhs(x + 0.5 * dt * k2x, xd + 0.5 * dt * k2v, tau, m, d, b3, g,
                                angular)
                k4x, k4v = _rhs(x + dt * k3x, xd + dt * k3v, tau, m, d, b3, g, angular)
                x += dt / 6.0 * (k1x + 2 * k2x + 2 * k3x + k4x)
                xd += dt / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
        out[j, 0] = ep / n
        out[j, 1] = ev / n
    return out


def one_axis_pd(params, axis: str, kp, kd: float, seconds: float = 600.0) -> np.ndarray:
    """(position MAE, velocity MAE) of one RefTraj1 axis under PD for each k_p in ``kp``
    (m, m/s or rad, rad/s); ``params`` the decoupled view of (2.44) (:class:`UVParams`)."""
    i = AXES.index(axis)
    m = float(params.M[i, i])
    d = float(params.D[i][i, i])
    amp, w = REFTRAJ1_SPEC[i]
    return _one_axis(m, d, float(params.b[2]), float(params.g), i in (3, 4), float(amp),
                     float(w), np.atleast_1d(np.asarray(kp, dtype=float)), float(kd),
                     float(seconds))


#: the k_p searched by :func:`fit_gain`: 100 to 10 000, 121 steps of 3.9 %
KP_GRID = np.geomspace(100.0, 10000.0, 121)


def fit_gain(params, axis: str, target: tuple[float, float], kd: float,
             kp_grid: np.ndarray = KP_GRID, seconds: float = 600.0) -> dict:
    """The k_p of ``kp_grid`` whose (position, velocity) MAE pair is nearest ``target`` in
    log-ratio (Σ log²(ours/target)); with the pair it gives."""
    mae = one_axis_pd(params, axis, kp_grid, kd, seconds)
    cost = np.sum(np.log(mae / np.asarray(target)) ** 2, axis=1)
    j = int(np.argmin(cost))
    return {"axis": axis, "kd": kd, "kp": float(kp_grid[j]), "position_mae": float(mae[j, 0]),
            "velocity_mae": float(mae[j, 1]), "target": list(target),
            "rms_log_ratio": float(np.sqrt(cost[j] / 2.0)),
            "grid": [float(kp_grid[0]), float(kp_grid[-1]), int(len(kp_grid))]}
