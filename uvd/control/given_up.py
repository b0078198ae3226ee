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

:func:`slide_reference` moves the desired position horizontally, along the given-up axis, to
where the vehicle is: the controller's error along that axis becomes zero and its error along
the kept translational axes vanishes only when the vehicle is at the right depth (and on the
right sway line), so what the vehicle cannot correct ends as horizontal drift — depth kept, as
the issue's priority says. The desired velocity slides the same way.
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
    """``ref`` with its desired position and linear velocity moved horizontally, along each
    given-up horizontal DOF (surge, sway: ``actuated`` False), to the vehicle's.

    With R_d the desired attitude and, for each given-up axis i, aᵢ the horizontal direction of
    R_d's column i: the world error e = p − p_d is written e = Σ cᵢ aᵢ + Σ_kept c_j R_d,j
    (unique while each aᵢ is not vertical) and p_d ← p_d + Σ cᵢ aᵢ; the world velocity error
    likewise (the desired body-frame velocity ᵈv_d's linear part, ᵈv_d ← R_dᵀ(ṗ_d + Σ dᵢ aᵢ)).
    The error the controller forms on the kept axes is then zero exactly when the vehicle's
    error is horizontal along the given-up directions. Heave given up, nothing given up, a
    given-up axis near vertical or a non-finite state: ``ref`` unchanged. Attitude, angular
    velocity, acceleration and closed loop are kept; a preview moves by the same offsets.
    """
    act = np.asarray(actuated, dtype=bool).reshape(-1)
    given = ~act[:3]
    if not given[:2].any() or given[2]:
        return ref
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
