"""The reference of a vehicle that has given up a horizontal DOF (issue 33).

A vehicle that loses a thruster may no longer reach surge or sway
(:func:`uvd.control.allocation.accommodate`): that DOF's error is then not corrected and the
vehicle drifts along its body axis. The tracking error is expressed in the desired body frame
(Δψ of (5.3)), so the controller's heave row sees the world error's component along the desired
body z axis. With the vehicle pitched (or rolled) the drift along body x (or y) has a vertical
component — sin θ of it — and driving the body-heave error to zero leaves exactly that in
depth: the JHU ROV with a dead aft thruster (surge given up, RefTraj1's 8.6° of pitch and a
metre of drift) ended with 3–4× its fault-free depth error while its vertical thrusters were
never at their limit (docs/experiments.md, "fault-tolerance").

:func:`slide_reference` moves the desired position horizontally to where the vehicle is: the
controller's error then vanishes only when the vehicle is at the right depth, so what the
vehicle cannot correct ends as horizontal drift — depth kept, as the issue's priority says. The
desired velocity slides the same way.

Both horizontal axes slide, whichever of surge and sway was given up: a vehicle that cannot
move along one of its horizontal body axes cannot hold a horizontal position while its heading
turns — the drift it gathered along that axis becomes error along the other as the heading
changes, and the one thruster left for it chases that error to its limit. Measured (the JHU ROV,
an aft thruster dead, the reference sliding along surge only): the lateral thruster at its limit
in 22–59 % of the cycles after the fault, and the heading missing 2.5–3.6× of its fault-free
error on RefTraj1 and on RefTraj1 with half its heading swing (where the yaw asked stays within
the one aft thruster's reach); sliding both axes, the lateral thruster at its limit in none of
the cycles and heading, roll and pitch within 1.31× on both (docs/experiments.md,
"fault-tolerance"). Horizontal position is given up with surge or sway; the thrusters left keep
depth and attitude.
"""

from __future__ import annotations

import numpy as np

from uvd.control.types import Reference, VehicleState

#: a given-up body axis whose horizontal part is shorter than this (the desired frame pitched
#: or rolled near 90°) has no horizontal direction to slide along: the reference stays
HORIZONTAL_MIN = 0.2


def _slide(e: np.ndarray, R_d: np.ndarray, given: np.ndarray) -> np.ndarray | None:
    """The world vector c·a (a: each given-up axis's horizontal direction) such that e − c·a
    lies in the span of the kept translational axes of R_d; None where it cannot be formed."""
    A = R_d.copy()
    for i in np.flatnonzero(given):
        h = np.array([R_d[0, i], R_d[1, i], 0.0])
        n = float(np.hypot(h[0], h[1]))
        if n < HORIZONTAL_MIN:
            return None
        A[:, i] = h / n
    c = np.linalg.solve(A, e)
    return A[:, given] @ c[given]


def slide_reference(ref: Reference, state: VehicleState, actuated) -> Reference:
    """``ref`` with its desired position and linear velocity moved horizontally to the
    vehicle's when surge or sway is given up (``actuated`` False for either; module docstring:
    both axes slide).

    With R_d the desired attitude and a₁, a₂ the horizontal directions of R_d's surge and sway
    axes: the world error e = p − p_d is written e = c₁a₁ + c₂a₂ + c₃ R_d,z (unique while
    neither axis is near vertical) and p_d ← p_d + c₁a₁ + c₂a₂; the world velocity error
    likewise (the desired body-frame velocity ᵈv_d's linear part, ᵈv_d ← R_dᵀ(ṗ_d + d₁a₁ +
    d₂a₂)). The error the controller forms on the body heave axis is then zero exactly when the
    vehicle is at the desired depth; along body surge and sway it is zero. Nothing horizontal
    given up, heave given up, an axis near vertical or a non-finite state: ``ref`` unchanged.
    Attitude, angular velocity, acceleration and closed loop are kept; a preview moves by the
    same offsets.
    """
    act = np.asarray(actuated, dtype=bool).reshape(-1)
    if act[:2].all() or not act[2]:
        return ref
    given = np.array([True, True, False])
    H_d, H_a = np.asarray(ref.H, dtype=float), np.asarray(state.H, dtype=float)
    if not (np.isfinite(H_a).all() and np.isfinite(state.v).all()):
        return ref
    R_d = H_d[:3, :3]
    dp = _slide(H_a[:3, 3] - H_d[:3, 3], R_d, given)
    if dp is None:
        return ref
    v_d = np.asarray(ref.v, dtype=float)
    dv = _slide(H_a[:3, :3] @ np.asarray(state.v, dtype=float)[:3] - R_d @ v_d[:3], R_d, given)
    preview = ref.preview
    if preview is not None:  # moved alike: the preview's increment stays the trajectory's
        preview = _moved(preview, dp, dv)
    return _moved(Reference(H_d, v_d, ref.vdot, ref.open_loop_wrench, ref.closed_loop, preview),
                  dp, dv)


def _moved(ref: Reference, dp: np.ndarray, dv: np.ndarray) -> Reference:
    """``ref`` with its desired position moved by the world vector ``dp`` and its linear
    velocity by the world vector ``dv`` (ᵈv_d is in the desired body frame)."""
    H = np.array(ref.H, dtype=float)
    v = np.array(ref.v, dtype=float)
    R = H[:3, :3]
    H[:3, 3] += dp
    v[:3] += R.T @ dv
    return Reference(H, v, ref.vdot, ref.open_loop_wrench, ref.closed_loop, ref.preview)
