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

The slid reference's acceleration is the one its velocity has: the model-based controllers
feed M α forward (5.12), α from ᵈv̇_d, and with the drag and Coriolis forces fed forward
exactly (a converged θ̂) little but the gains k_p, k_d is left to damp heave (for the JHU ROV
ω_n = √(300/1043) ≈ 0.54 rad/s, ζ ≈ 0.09). The trajectory's ᵈv̇_d is the derivative of the
trajectory's velocity, not of the slid one: it misses the vehicle's own horizontal acceleration
(its body heave axis, pitched θ, sees sin θ of the surge acceleration) and the turning of the
drift velocity in the desired frame (−ω_d × ᵈv_d). Measured (the JHU ROV, an aft thruster dead,
θ̂ converged, seed 0): with the trajectory's ᵈv̇_d the depth error swung ±45 cm with the surge
drift, 8.0× its fault-free error; with the slid reference's own, 0.45× (docs/experiments.md,
"fault-tolerance"). The vehicle's horizontal acceleration is measured: the difference of two
cycles' velocities (:func:`measured_acceleration`); with none (the first cycle sliding, a
navigation gap) it is taken as zero. Unfiltered, it carries the DVL's noise: within the bound
at 3× the thesis's DVL noise, not with the lateral thruster dead at 10× (z 2.53×;
docs/experiments.md).

With horizontal position given up the controller acts on neither horizontal translation
(:func:`controlled_dofs`): the slid reference leaves the kept one (sway with surge given up) no
error, so all its row would command is the feed-forward that keeps the vehicle drifting as it
drifts — the measured acceleration times the sway mass, which made the JHU ROV's lateral
thruster jump a median 38 N from one cycle to the next (p90 84 N; 4 N fault-free) with θ̂
converged and an aft thruster dead. Out of the loop, the lateral thruster is idle, and depth
and attitude are as good or better (z 0.45×, 0.85×, 0.50× with thrusters 1, 2, 3 dead, seed 0).
"""

from __future__ import annotations

import numpy as np

from uvd.control.types import Reference, VehicleState

#: a given-up body axis whose horizontal part is shorter than this (the desired frame pitched
#: or rolled near 90°) has no horizontal direction to slide along: the reference stays
HORIZONTAL_MIN = 0.2

#: two velocities further apart than this many control periods give no acceleration
ACCEL_MAX_PERIODS = 3.0


def world_velocity(state: VehicleState) -> np.ndarray:
    """The vehicle's linear velocity in the world frame, ʷRₐ ᵃν."""
    H = np.asarray(state.H, dtype=float)
    return H[:3, :3] @ np.asarray(state.v, dtype=float)[:3]


def measured_acceleration(prev, now, dt: float) -> np.ndarray | None:
    """The vehicle's world acceleration from two ``(t_ns, world velocity)`` samples, the
    difference quotient; None when either is missing or not finite, or the two are not 0 <
    Δt ≤ :data:`ACCEL_MAX_PERIODS` control periods ``dt`` apart. (A velocity held between
    slower DVL samples gives 0 and then the whole change: the mean is right, cycle by cycle it
    is noisier.)"""
    if prev is None or now is None:
        return None
    gap = (now[0] - prev[0]) * 1e-9
    if not 0.0 < gap <= ACCEL_MAX_PERIODS * dt:
        return None
    a = (np.asarray(now[1], dtype=float) - np.asarray(prev[1], dtype=float)) / gap
    return a if np.isfinite(a).all() else None


def horizontal_given_up(act: np.ndarray) -> bool:
    """Horizontal position is given up: surge or sway no longer reached, heave still is
    (``act``: 6 booleans, the DOFs the thrusters reach)."""
    return not act[:2].all() and bool(act[2])


def controlled_dofs(actuated) -> np.ndarray:
    """The DOFs the controller acts on when the thrusters reach ``actuated`` (6 booleans): those,
    less both horizontal translations when horizontal position is given up (module
    docstring)."""
    act = np.array(actuated, dtype=bool).reshape(-1)
    if horizontal_given_up(act):
        act[:2] = False
    return act


def _slide(e: np.ndarray, R_d: np.ndarray) -> np.ndarray | None:
    """The world vector c₁a₁ + c₂a₂ (a₁, a₂: the horizontal directions of R_d's surge and sway
    axes) such that e − c₁a₁ − c₂a₂ lies along R_d's heave axis; None where it cannot be formed
    (an axis near vertical)."""
    A = R_d.copy()
    for i in (0, 1):
        n = float(np.hypot(R_d[0, i], R_d[1, i]))
        if n < HORIZONTAL_MIN:
            return None
        A[:, i] = (R_d[0, i] / n, R_d[1, i] / n, 0.0)
    c = np.linalg.solve(A, e)
    return A[:, :2] @ c[:2]


def slide_reference(ref: Reference, state: VehicleState, actuated,
                    accel: np.ndarray | None = None) -> Reference:
    """``ref`` with its desired position and linear velocity moved horizontally to the
    vehicle's when surge or sway is given up (``actuated`` False for either; module docstring:
    both axes slide).

    With R_d the desired attitude and a₁, a₂ the horizontal directions of R_d's surge and sway
    axes: the world error e = p − p_d is written e = c₁a₁ + c₂a₂ + c₃ R_d,z (unique while
    neither axis is near vertical) and p_d ← p_d + c₁a₁ + c₂a₂; the world velocity error
    likewise (the desired body-frame velocity ᵈv_d's linear part, ᵈv_d ← R_dᵀ(ṗ_d + d₁a₁ +
    d₂a₂)). The error the controller forms on the body heave axis is then zero exactly when the
    vehicle is at the desired depth; along body surge and sway it is zero. The acceleration is
    the slid velocity's derivative (module docstring): in the world, the vehicle's horizontal
    acceleration ``accel`` (its x and y; None: zero) and the trajectory's vertical one p̈_d,z,
    so ᵈv̇_d ← R_dᵀ[a_x, a_y, p̈_d,z] − ω_d × ᵈv_d (ν̇ = Rᵀp̈ − ω × ν, as the trajectory's). Nothing
    horizontal given up, heave given up, an axis near vertical or a non-finite state: ``ref``
    unchanged. Attitude, angular velocity, angular acceleration and closed loop are kept; a
    preview moves by the same offsets and takes the same acceleration.
    """
    if not horizontal_given_up(np.asarray(actuated, dtype=bool).reshape(-1)):
        return ref
    H_d, H_a = np.asarray(ref.H, dtype=float), np.asarray(state.H, dtype=float)
    if not (np.isfinite(H_a).all() and np.isfinite(state.v).all()):
        return ref
    R_d = H_d[:3, :3]
    dp = _slide(H_a[:3, 3] - H_d[:3, 3], R_d)
    if dp is None:
        return ref
    v_d = np.asarray(ref.v, dtype=float)
    dv = _slide(world_velocity(state) - R_d @ v_d[:3], R_d)
    a_h = (0.0, 0.0) if accel is None or not np.isfinite(accel).all() else \
        (float(accel[0]), float(accel[1]))
    preview = ref.preview
    if preview is not None:  # moved alike: the preview's increment stays the trajectory's
        preview = _moved(preview, dp, dv, a_h)
    return _moved(Reference(H_d, v_d, ref.vdot, ref.open_loop_wrench, ref.closed_loop, preview),
                  dp, dv, a_h)


def _moved(ref: Reference, dp: np.ndarray, dv: np.ndarray, a_h) -> Reference:
    """``ref`` with its desired position moved by the world vector ``dp``, its linear velocity
    by the world vector ``dv`` (ᵈv_d is in the desired body frame) and its linear acceleration
    that of the moved velocity, horizontally ``a_h`` in the world (:func:`slide_reference`)."""
    H = np.array(ref.H, dtype=float)
    v = np.array(ref.v, dtype=float)
    vdot = np.array(ref.vdot, dtype=float)
    R = H[:3, :3]
    w = v[3:]
    a_z = (R @ (vdot[:3] + np.cross(w, v[:3])))[2]  # the trajectory's p̈_d,z
    H[:3, 3] += dp
    v[:3] += R.T @ dv
    vdot[:3] = R.T @ np.array([a_h[0], a_h[1], a_z]) - np.cross(w, v[:3])
    return Reference(H, v, vdot, ref.open_loop_wrench, ref.closed_loop, ref.preview)
