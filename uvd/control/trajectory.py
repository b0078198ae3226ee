"""Reference trajectories: per-DOF sums of cosines in world x, y, z, roll, pitch, heading.

Each DOF k is c_k + Σⱼ a_kj cos(w_kj t + φ_kj) with analytic first and second derivatives,
turned into the desired state {ʷ_dH, ᵈv_d, ᵈv̇_d} of §5.2.4.1: R_d = Rz(heading) Ry(pitch) Rx(roll)
(App. A), p_d = [x, y, z]; ν_d = R_dᵀ ṗ, ω_d = E(φ, θ) η̇ (ZYX Euler-rate map), and
ν̇_d = R_dᵀ p̈ − ω_d × ν_d, ω̇_d = E η̈ + Ė η̇.

Built in: RefTraj1 and RefTraj2 of Table 5.1 (:func:`reftraj1`, :func:`reftraj2`; RefTraj2 drives
roll and pitch open loop with cosine torques), :func:`setpoint`, the quasi-static pitch/roll
trajectory of step 1 of two-step AMBC (:func:`quasi_static`, §5.3.5), the pitch-only
trajectories of §5.3.4 (:func:`pitch_only`), and :class:`SequenceTrajectory`, which plays
trajectories one after another with a smooth (quintic) blend between them.

The evaluation is one compiled kernel (a few µs), as every control cycle needs it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from uvd.control.types import Reference
from uvd.model.lie import euler_R

DOFS = ("x", "y", "z", "roll", "pitch", "heading")
WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
_DEG = math.pi / 180.0


@dataclass(frozen=True)
class CosineTerm:
    """a cos(w t + φ): amplitude (m, rad, N or N m), frequency (rad/s), phase (rad)."""

    amplitude: float
    frequency_rad_s: float
    phase_rad: float = 0.0


def _flatten(terms) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    amp, w, ph, idx = [], [], [], []
    for k, per_dof in enumerate(terms):
        for term in per_dof:
            amp.append(float(term.amplitude))
            w.append(float(term.frequency_rad_s))
            ph.append(float(term.phase_rad))
            idx.append(k)
    return (np.array(amp, dtype=float), np.array(w, dtype=float), np.array(ph, dtype=float),
            np.array(idx, dtype=np.int64))


@numba.njit(cache=True)
def _cosines(t, center, amp, w, ph, idx, eta, d1, d2):
    for k in range(6):
        eta[k] = center[k]
        d1[k] = 0.0
        d2[k] = 0.0
    for j in range(amp.shape[0]):
        x = w[j] * t + ph[j]
        c = math.cos(x)
        s = math.sin(x)
        k = idx[j]
        eta[k] += amp[j] * c
        d1[k] -= amp[j] * w[j] * s
        d2[k] -= amp[j] * w[j] * w[j] * c


@numba.njit(cache=True)
def _from_euler(eta, d1, d2, H, v, vdot):
    """Desired (H, v, v̇) from η = [x, y, z, φ, θ, ψ] and its derivatives (module docstring)."""
    phi, th, psi = eta[3], eta[4], eta[5]
    dphi, dth, dpsi = d1[3], d1[4], d1[5]
    R = euler_R(phi, th, psi)
    cr, sr = math.cos(phi), math.sin(phi)
    cp, sp = math.cos(th), math.sin(th)
    for i in range(4):
        for j in range(4):
            H[i, j] = 0.0
    for i in range(3):
        for j in range(3):
            H[i, j] = R[i, j]
        H[i, 3] = eta[i]
    H[3, 3] = 1.0
    # ν = Rᵀ ṗ, ν̇ = Rᵀ p̈ − ω × ν
    nu = np.empty(3)
    acc = np.empty(3)
    for i in range(3):
        nu[i] = R[0, i] * d1[0] + R[1, i] * d1[1] + R[2, i] * d1[2]
        acc[i] = R[0, i] * d2[0] + R[1, i] * d2[1] + R[2, i] * d2[2]
    # ω = E η̇, ω̇ = E η̈ + Ė η̇ (ZYX)
    w0 = dphi - sp * dpsi
    w1 = cr * dth + cp * sr * dpsi
    w2 = -sr * dth + cp * cr * dpsi
    a0 = d2[3] - sp * d2[5] - cp * dth * dpsi
    a1 = (cr * d2[4] + cp * sr * d2[5] - sr * dphi * dth
          + (-sp * dth * sr + cp * cr * dphi) * dpsi)
    a2 = (-sr * d2[4] + cp * cr * d2[5] - cr * dphi * dth
          + (-sp * dth * cr - cp * sr * dphi) * dpsi)
    v[0], v[1], v[2] = nu[0], nu[1], nu[2]
    v[3], v[4], v[5] = w0, w1, w2
    vdot[0] = acc[0] - (w1 * nu[2] - w2 * nu[1])
    vdot[1] = acc[1] - (w2 * nu[0] - w0 * nu[2])
    vdot[2] = acc[2] - (w0 * nu[1] - w1 * nu[0])
    vdot[3], vdot[4], vdot[5] = a0, a1, a2


@numba.njit(cache=True)
def _reference(t, center, amp, w, ph, idx, H, v, vdot):
    """:func:`_cosines` then :func:`_from_euler` in one compiled call (the per-cycle path of
    :meth:`CosineTrajectory.at`)."""
    eta, d1, d2 = np.empty(6), np.empty(6), np.empty(6)
    _cosines(t, center, amp, w, ph, idx, eta, d1, d2)
    _from_euler(eta, d1, d2, H, v, vdot)


def reference_from_euler(eta: np.ndarray, d1: np.ndarray, d2: np.ndarray, *,
                         open_loop_wrench: np.ndarray | None = None,
                         closed_loop: np.ndarray | None = None) -> Reference:
    """Desired state {ʷ_dH, ᵈv_d, ᵈv̇_d} from world position/Euler angles η and η̇, η̈.

    Parameters
    ----------
    eta, d1, d2 : (6,) [x, y, z (m), roll, pitch, heading (rad)] and first/second derivatives.
    """
    H = np.empty((4, 4))
    v = np.empty(6)
    vdot = np.empty(6)
    _from_euler(np.asarray(eta, dtype=float), np.asarray(d1, dtype=float),
                np.asarray(d2, dtype=float), H, v, vdot)
    return Reference(H=H, v=v, vdot=vdot, open_loop_wrench=open_loop_wrench,
                     closed_loop=closed_loop)


@dataclass(frozen=True)
class CosineTrajectory:
    """Sum-of-cosines reference.

    Parameters
    ----------
    center : [x, y, z (m), roll, pitch, heading (rad)], world frame (NED), App. A Euler angles.
    terms : six tuples of :class:`CosineTerm`, one per DOF of ``center``.
    open_loop : optional six tuples of :class:`CosineTerm` for the body wrench [f; τ] (N, N m)
        added open loop (RefTraj2's roll and pitch torques, Table 5.1).
    closed_loop : optional six booleans, per body wrench component, whether feedback acts on it
        (False for the DOFs driven open loop).
    """

    center: tuple[float, float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    terms: tuple[tuple[CosineTerm, ...], ...] = ((),) * 6
    name: str = "trajectory"
    open_loop: tuple[tuple[CosineTerm, ...], ...] | None = None
    closed_loop: tuple[bool, bool, bool, bool, bool, bool] | None = None
    _arrays: tuple = field(default=(), init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if len(self.center) != 6 or len(self.terms) != 6:
            raise ValueError(f"trajectory {self.name!r}: center and terms need six entries")
        if self.open_loop is not None and len(self.open_loop) != 6:
            raise ValueError(f"trajectory {self.name!r}: open_loop needs six entries")
        if self.closed_loop is not None and len(self.closed_loop) != 6:
            raise ValueError(f"trajectory {self.name!r}: closed_loop needs six entries")
        center = np.array(self.center, dtype=float)
        ol = _flatten(self.open_loop) if self.open_loop is not None else None
        mask = (None if self.closed_loop is None
                else np.array([1.0 if c else 0.0 for c in self.closed_loop]))
        object.__setattr__(self, "_arrays", (center, *_flatten(self.terms), ol, mask))

    def dof(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(η, η̇, η̈) of the six DOFs at time t (world x, y, z, roll, pitch, heading)."""
        center, amp, w, ph, idx, _, _ = self._arrays
        eta, d1, d2 = np.empty(6), np.empty(6), np.empty(6)
        _cosines(float(t), center, amp, w, ph, idx, eta, d1, d2)
        return eta, d1, d2

    def open_loop_wrench(self, t: float) -> np.ndarray | None:
        """The open-loop body wrench at time t (None when the trajectory has none)."""
        ol = self._arrays[5]
        if ol is None:
            return None
        u, d1, d2 = np.empty(6), np.empty(6), np.empty(6)
        _cosines(float(t), np.zeros(6), *ol, u, d1, d2)
        return u

    @property
    def closed_loop_mask(self) -> np.ndarray | None:
        return self._arrays[6]

    def at(self, t: float) -> Reference:
        center, amp, w, ph, idx, ol, mask = self._arrays
        H, v, vdot = np.empty((4, 4)), np.empty(6), np.empty(6)
        _reference(float(t), center, amp, w, ph, idx, H, v, vdot)
        return Reference(H, v, vdot, None if ol is None else self.open_loop_wrench(t),
                         None if mask is None else mask > 0.5)


def _smootherstep(x: float) -> tuple[float, float, float]:
    """w(x) = 10x³ − 15x⁴ + 6x⁵ on [0, 1] and its first two derivatives."""
    if x <= 0.0:
        return 0.0, 0.0, 0.0
    if x >= 1.0:
        return 1.0, 0.0, 0.0
    return (x ** 3 * (10.0 - 15.0 * x + 6.0 * x * x), 30.0 * x * x * (1.0 - x) ** 2,
            60.0 * x * (1.0 - x) * (1.0 - 2.0 * x))


@dataclass(frozen=True)
class SequenceTrajectory:
    """Trajectories played one after another, each on its own clock from 0.

    ``segments`` is a tuple of (duration_s, trajectory); the last one lasts for ever. During
    the first ``blend_s`` of each segment after the first, η is blended from the previous
    trajectory (still running) to the new one with a quintic smoothstep w(τ):
    η = (1−w)η_prev + wη_next, whose derivatives follow by the product rule, so the reference
    stays C² (no step in pose, velocity or acceleration).
    """

    segments: tuple[tuple[float, CosineTrajectory], ...]
    blend_s: float = 60.0
    name: str = "sequence"

    def __post_init__(self) -> None:
        if not self.segments:
            raise ValueError("SequenceTrajectory needs at least one segment")
        if self.blend_s < 0:
            raise ValueError("blend_s must be >= 0")

    def _locate(self, t: float) -> tuple[int, float]:
        start = 0.0
        for i, (dur, _) in enumerate(self.segments):
            if i == len(self.segments) - 1 or t < start + dur:
                return i, t - start
            start += dur
        raise AssertionError("unreachable")

    def segment_at(self, t: float) -> int:
        return self._locate(t)[0]

    def dof(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self._dof(*self._locate(t))

    def _dof(self, i: int, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        traj = self.segments[i][1]
        eta, d1, d2 = traj.dof(tau)
        if i == 0 or self.blend_s <= 0.0 or tau >= self.blend_s:
            return eta, d1, d2
        prev_dur, prev = self.segments[i - 1]
        ep, p1, p2 = prev.dof(prev_dur + tau)
        x = tau / self.blend_s
        w, w1, w2 = _smootherstep(x)
        w1 /= self.blend_s
        w2 /= self.blend_s ** 2
        de, dd1 = eta - ep, d1 - p1
        return (ep + w * de, p1 + w * dd1 + w1 * de,
                p2 + w * (d2 - p2) + 2.0 * w1 * dd1 + w2 * de)

    def at(self, t: float) -> Reference:
        i, tau = self._locate(t)
        traj = self.segments[i][1]
        if i == 0 or self.blend_s <= 0.0 or tau >= self.blend_s:
            return traj.at(tau)  # outside a blend: the segment's own, in one compiled call
        eta, d1, d2 = self._dof(i, tau)
        mask = traj.closed_loop_mask
        return reference_from_euler(eta, d1, d2, open_loop_wrench=traj.open_loop_wrench(tau),
                                    closed_loop=None if mask is None else mask > 0.5)


# ---------------------------------------------------------------------------------------------
# built-in trajectories
# ---------------------------------------------------------------------------------------------
DEFAULT_CENTER = (0.0, 0.0, 1.5, 0.0, 0.0, 0.0)
"""[x, y, z, roll, pitch, heading] about which the built-in trajectories run (1.5 m deep)."""


def setpoint(center) -> CosineTrajectory:
    """Hold a constant pose [x, y, z, roll, pitch, heading]."""
    return CosineTrajectory(center=tuple(float(c) for c in center), name="setpoint")


REFTRAJ1_SPEC = ((0.50, 0.242), (0.50, 0.210), (0.30, 0.185), (6.9 * _DEG, 0.5),
                 (8.6 * _DEG, 0.6), (135.0 * _DEG, 0.210))
"""Table 5.1, RefTraj1: (cosine amplitude, frequency rad/s) for x, y, z, roll, pitch, heading."""

REFTRAJ2_SPEC = ((0.50, 0.185), (0.50, 0.286), (0.30, 0.242), None, None,
                 (135.0 * _DEG, 0.0824))
"""Table 5.1, RefTraj2, closed-loop DOFs (roll and pitch are torque inputs: REFTRAJ2_TORQUES)."""

REFTRAJ2_TORQUES = ((35.0, 0.55), (30.0, 0.65))
"""Table 5.1, RefTraj2: open-loop (amplitude N m, frequency rad/s) torques about body x, y."""


def reftraj1(center=DEFAULT_CENTER) -> CosineTrajectory:
    """RefTraj1 of Table 5.1 (trajectory-tracking evaluation), about ``center``.

    x: 0.50 m at 0.242 rad/s; y: 0.50 m at 0.210; z: 0.30 m at 0.185; roll 6.9° at 0.5;
    pitch 8.6° at 0.6; heading 135° at 0.210 rad/s.
    """
    return CosineTrajectory(center=tuple(center),
                            terms=tuple((CosineTerm(a, w),) for a, w in REFTRAJ1_SPEC),
                            name="RefTraj1")


def reftraj2(center=DEFAULT_CENTER) -> CosineTrajectory:
    """RefTraj2 of Table 5.1 (parameter cross-validation), about ``center``.

    Closed loop: x 0.50 m at 0.185 rad/s; y 0.50 m at 0.286; z 0.30 m at 0.242; heading 135° at
    0.0824. Open loop: roll torque 35 N m at 0.55 rad/s and pitch torque 30 N m at 0.65 rad/s;
    the controller gets no feedback on τ_x, τ_y (``closed_loop``) and the reference holds the
    centre's roll and pitch.
    """
    terms = tuple(() if spec is None else (CosineTerm(*spec),) for spec in REFTRAJ2_SPEC)
    (a_r, w_r), (a_p, w_p) = REFTRAJ2_TORQUES
    ol = ((), (), (), (CosineTerm(a_r, w_r),), (CosineTerm(a_p, w_p),), ())
    return CosineTrajectory(center=tuple(center), terms=terms, name="RefTraj2", open_loop=ol,
                            closed_loop=(True, True, True, False, False, True))


QUASI_STATIC_PITCH = (0.2, 34.0)
QUASI_STATIC_ROLL = (0.15, 42.0)


def quasi_static(center=DEFAULT_CENTER, *, pitch=QUASI_STATIC_PITCH,
                 roll=QUASI_STATIC_ROLL) -> CosineTrajectory:
    """Step 1 of two-step AMBC (§5.3.5): constant position and heading, slow pitch and roll.

    Pitch 0.2 rad amplitude, roll 0.15 rad, as in the text. The extracted text gives their
    "frequencies" as 34 Hz and 42 Hz, which cannot be quasi-static (34 Hz is above the control
    rate of 10 Hz); we read them as **periods** of 34 s and 42 s (0.185 and 0.150 rad/s): then
    the inertial torque (≈ I θ̈ ≈ 145 kg m² · 0.2 · 0.185² ≈ 1 N m) and the drag torque
    (≈ 0.7 N m) are ~2 % of the buoyancy torque they are neglected against in (5.37)
    (b₃ sin 0.2 ≈ 60 N m), which is what "quasi-static" requires. ``pitch`` and ``roll`` are
    (amplitude rad, period s).
    """
    (a_p, t_p), (a_r, t_r) = pitch, roll
    terms = ((), (), (), (CosineTerm(a_r, 2 * math.pi / t_r),),
             (CosineTerm(a_p, 2 * math.pi / t_p),), ())
    return CosineTrajectory(center=tuple(center), terms=terms, name="QuasiStatic")


def pitch_only(mean_pitch_rad: float, amplitude_rad: float, frequency_rad_s: float = 0.6,
               center=DEFAULT_CENTER) -> CosineTrajectory:
    """Pitch-only trajectory of §5.3.4: pitch = mean + a cos(w t), every other DOF held."""
    c = list(center)
    c[4] = float(mean_pitch_rad)
    terms = ((), (), (), (), (CosineTerm(amplitude_rad, frequency_rad_s),), ())
    return CosineTrajectory(center=tuple(c), terms=terms, name="PitchOnly")


def named(name: str, center=DEFAULT_CENTER) -> CosineTrajectory | None:
    """The trajectory a configuration names (``[control] reference``): ``reftraj1``,
    ``reftraj2`` (Table 5.1), or None for ``hold`` (the pose held is taken when armed)."""
    if name == "reftraj1":
        return reftraj1(center)
    if name == "reftraj2":
        return reftraj2(center)
    if name == "hold":
        return None
    raise ValueError(f"unknown reference {name!r} (reftraj1, reftraj2 or hold)")


def start_pose(name: str, north_m: float, east_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Where a run of the trajectory ``name`` starts (:func:`named`): depth and attitude of the
    reference at t = 0 (for ``hold`` the centre depth, level, heading north), at the given
    north and east; at rest. Returns (H, v)."""
    traj = named(name)
    H = np.eye(4)
    if traj is not None:
        H = np.array(traj.at(0.0).H, dtype=float)
    else:
        H[2, 3] = DEFAULT_CENTER[2]
    H[0, 3] = north_m
    H[1, 3] = east_m
    return H, np.zeros(6)
