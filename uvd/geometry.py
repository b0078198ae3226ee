"""Attitude conventions shared by drivers, sim_bridge and uvd: Euler angles ⇄ rotation matrix,
pose → η, and the one angle-wrap convention.

Frames (thesis App. A, Fig. A.2): world x north, y east, z down; body x bow, y starboard,
z keel. Euler sequence heading ψ about z, then pitch θ about the new y, then roll φ about the
new x, so that

    R = Rz(ψ) Ry(θ) Rx(φ)                                       (App. A)

maps body to world, and η = [x, y, z, φ, θ, ψ] (position in the world frame, metres; angles
in radians) is the pose in the coordinates the thesis plots.

One angle-wrap convention: **(−π, π]**. Every wrapped angle — a heading read from an
instrument, the heading of :func:`R_to_euler`, an attitude error in a report — lies in
(−π, π], so an angle has exactly one representative and two wrapped angles compare equal
exactly when they are the same direction. Half-open because a closed interval gives ±π two
names (a wrap that returned either would not be a function of the direction); closed at +π
because that is the range of ``atan2``, from which every heading of a rotation matrix comes
(:func:`R_to_euler` maps its one exception, −π from a negative zero, to +π), and the range
the instrument codecs (PHINS heading, longitude) always used.

:func:`wrap_angle` is exact: it uses IEEE remainder (no rounding, unlike
``(a + π) % 2π − π``, which moves a small angle by up to half an ulp of π), so an angle already
in the range comes back unchanged, bit for bit.

Pure: numpy and math only, importable from every layer (``drivers`` included, see
tests/test_layers.py). The functions are written so that numba can compile them
(:data:`uvd.model.lie.euler_R` is the compiled :func:`euler_to_R`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["euler_to_R", "R_to_euler", "eta_of", "euler_of_rotations", "wrap_angle",
           "wrap_angles", "TWO_PI"]

#: 2π as a float (twice math.pi, exactly)
TWO_PI = 2.0 * math.pi


def euler_to_R(roll, pitch, heading) -> np.ndarray:
    """R = Rz(ψ) Ry(θ) Rx(φ) (App. A): rotation body → world from roll φ, pitch θ, heading ψ.

    Parameters
    ----------
    roll, pitch, heading : float
        Radians.

    Returns
    -------
    ndarray, shape (3, 3)
    """
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    ch, sh = np.cos(heading), np.sin(heading)
    R = np.empty((3, 3))
    R[0, 0] = ch * cp
    R[0, 1] = ch * sp * sr - sh * cr
    R[0, 2] = ch * sp * cr + sh * sr
    R[1, 0] = sh * cp
    R[1, 1] = sh * sp * sr + ch * cr
    R[1, 2] = sh * sp * cr - ch * sr
    R[2, 0] = -sp
    R[2, 1] = cp * sr
    R[2, 2] = cp * cr
    return R


def R_to_euler(R) -> tuple[float, float, float]:
    """(roll φ, pitch θ, heading ψ) of a rotation R (inverse of :func:`euler_to_R`).

    φ and ψ in (−π, π], θ in [−π/2, π/2]. At θ = ±π/2 (gimbal lock) only φ ∓ ψ is defined;
    the split returned is that of ``atan2`` on the rounded entries.

    Parameters
    ----------
    R : array_like, shape (3, 3)
        Rotation body → world.
    """
    s = -R[2, 0]
    pitch = math.asin(min(max(s, -1.0), 1.0))
    roll = math.atan2(R[2, 1], R[2, 2])
    heading = math.atan2(R[1, 0], R[0, 0])
    if roll == -math.pi:
        roll = math.pi
    if heading == -math.pi:
        heading = math.pi
    return roll, pitch, heading


def eta_of(H) -> np.ndarray:
    """η = [x, y, z, φ, θ, ψ] of a pose H (4×4, body → world): position, then
    :func:`R_to_euler` of its rotation."""
    roll, pitch, heading = R_to_euler(H[:3, :3])
    return np.array([H[0, 3], H[1, 3], H[2, 3], roll, pitch, heading])


def euler_of_rotations(R) -> np.ndarray:
    """:func:`R_to_euler` of many rotations at once.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)

    Returns
    -------
    ndarray, shape (..., 3)
        [φ, θ, ψ] of each, in the ranges of :func:`R_to_euler`.
    """
    R = np.asarray(R, dtype=float)
    out = np.empty(R.shape[:-2] + (3,))
    out[..., 0] = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    out[..., 1] = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    out[..., 2] = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    out[..., 0::2][out[..., 0::2] == -np.pi] = np.pi
    return out


def wrap_angle(angle) -> float:
    """The angle in (−π, π] that is ``angle`` modulo 2π (module docstring: the convention).

    Exact (IEEE remainder): an angle already in (−π, π] is returned unchanged. A non-finite
    angle has no direction: NaN.
    """
    a = float(angle)
    if not math.isfinite(a):
        return math.nan
    r = math.remainder(a, TWO_PI)  # in [−π, π], exact
    return math.pi if r == -math.pi else r


def wrap_angles(angles) -> np.ndarray:
    """:func:`wrap_angle` of every entry of an array (a new array; exact, as the scalar)."""
    a = np.array(angles, dtype=float)
    out = a.copy()
    outside = ~(np.abs(a) <= math.pi)  # NaN and ±inf included
    if outside.any():
        out[outside] = [wrap_angle(x) for x in a[outside]]
    out[out == -math.pi] = math.pi
    return out
