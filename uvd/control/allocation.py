"""Thruster allocation: body wrench u → per-thruster thrust f, with direction-keeping saturation,
and the thruster law both ways (App. A.1).

* f = B_W⁺ u, the weighted pseudo-inverse of the thruster matrix (u = B f): the f of least
  Σ wᵢ fᵢ² that produces u exactly, B_W⁺ = W⁻¹Bᵀ(B W⁻¹ Bᵀ)⁻¹ (with unit weights the
  Moore–Penrose B⁺). Weights let a weak or worn thruster be spared.
* If any |fᵢ| exceeds its limit the *whole* vector is scaled by the largest ratio, which keeps
  the wrench's direction (u_applied = s u, 0 < s ≤ 1); the thrusters at their limit are reported.
  With a thruster's effectiveness set (a fault, :func:`accommodate`), saturation is resolved by
  DOF priority instead (:func:`allocate_prioritised`): depth and attitude take the thrust first,
  the lower-priority DOFs what is left.
* Thrust → amplifier command through the thruster model: the propeller-speed set-point
  ω* = sign(f)√(|f|/k) of the steady-state law f = k ω|ω| (App. A.1).
* The inverse, which the thesis uses as the applied input: thrust estimated from measured
  propeller speed, f = k ω|ω|, and the wrench u = B f it produces.
* Thruster effectiveness η ∈ [0, 1] per thruster (:func:`accommodate`): thruster i delivers
  ηᵢ of the thrust it is commanded, so allocation inverts B diag(η) — a weak thruster's column
  scaled, a dead one (η = 0) removed — and, when the thrusters left no longer span every DOF,
  keeps the DOFs of highest priority and says which it gave up.
* Optional compensation of the propeller lag (:func:`lag_compensate`): with the measured
  propeller speeds and each thruster's declared time constant τ, the command that brings every
  propeller to its allocated thrust by the end of the control period.
"""

from __future__ import annotations

import math
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
    time_constant_s : (N,) first-order time constant τ of each propeller's speed (s), as the
        vehicle file declares it; used only by :func:`lag_compensate`.
    """

    B: np.ndarray
    B_pinv: np.ndarray
    max_thrust_n: np.ndarray
    k_thrust: np.ndarray | None = None
    weights: np.ndarray | None = None
    time_constant_s: np.ndarray | None = None

    @classmethod
    def from_vehicle(cls, vehicle, weights: np.ndarray | None = None) -> Allocator:
        B = np.ascontiguousarray(vehicle.B, dtype=float)
        return cls(B=B, B_pinv=weighted_pinv(B, weights),
                   max_thrust_n=np.asarray(vehicle.max_thrust_n, dtype=float),
                   k_thrust=np.asarray(vehicle.k_thrust, dtype=float),
                   weights=None if weights is None else np.asarray(weights, dtype=float),
                   time_constant_s=np.array([float(t.time_constant_s)
                                             for t in vehicle.thrusters]))

    @property
    def n_thrusters(self) -> int:
        return self.B.shape[1]

    def restricted(self, mask: np.ndarray) -> Allocator:
        """The same allocator using only the thrusters where ``mask`` is True.

        B⁺ becomes the (weighted) least-norm, least-squares inverse of B's columns in
        ``mask`` — f = W^{-1/2} (B_m W^{-1/2})⁺ u on those thrusters, exactly zero on the
        others — so a wrench the subset cannot produce is met as closely as it can be (a
        failed thruster, or the hold-depth failsafe's vertical thrusters alone). Limits and
        thruster data are unchanged.
        """
        m = np.asarray(mask, dtype=bool).reshape(-1)
        if m.shape != (self.n_thrusters,):
            raise ValueError(f"mask must have {self.n_thrusters} entries, got {m.shape[0]}")
        w = np.ones(self.n_thrusters) if self.weights is None else self.weights
        s = 1.0 / np.sqrt(w[m])
        pinv = np.zeros((self.n_thrusters, 6))
        if m.any():
            pinv[m] = s[:, None] * np.linalg.pinv(self.B[:, m] * s[None, :])
        return Allocator(B=self.B, B_pinv=np.ascontiguousarray(pinv),
                         max_thrust_n=self.max_thrust_n, k_thrust=self.k_thrust,
                         weights=self.weights, time_constant_s=self.time_constant_s)

    def vertical(self, tol: float = 1e-9) -> np.ndarray:
        """Mask of the thrusters that produce no surge, sway or yaw (|B| ≤ tol in those
        rows): the ones the hold-depth failsafe may use."""
        return np.all(np.abs(self.B[[0, 1, 5], :]) <= tol, axis=0)


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


#: the body DOFs in the order of u = [f; τ] (thesis App. A: x bow, y starboard, z keel)
DOF_NAMES = ("surge", "sway", "heave", "roll", "pitch", "yaw")

#: default priority of the DOFs, highest first: depth and attitude before the horizontal
#: translation (the vehicle neither sinks nor rolls over; it may drift)
DEFAULT_DOF_PRIORITY = ("heave", "roll", "pitch", "yaw", "surge", "sway")

#: an η at or below this is a dead thruster (removed, not scaled)
ETA_DEAD = 1e-6


@dataclass(frozen=True)
class Accommodation:
    """Allocation with per-thruster effectiveness (:func:`accommodate`).

    Attributes
    ----------
    eta : (N,) effectiveness ηᵢ ∈ [0, 1] it was built for.
    B_pinv : (N, 6) the inverse to use in place of B⁺: f = B_pinv u gives
        B diag(η) f = u on the actuated DOFs (exactly, unsaturated); rows of dead thrusters and
        columns of given-up DOFs are zero.
    actuated : (6,) bool, the DOFs (:data:`DOF_NAMES` order) still reached.
    given_up : names of the DOFs no longer actuated, in priority order.
    """

    eta: np.ndarray
    B_pinv: np.ndarray
    actuated: np.ndarray
    given_up: tuple[str, ...]


def dof_priority_indices(priority) -> tuple[int, ...]:
    """The DOF indices (0–5 of u) of ``priority`` — a permutation of :data:`DOF_NAMES` —
    highest first; anything else is refused with a ValueError naming it."""
    names = tuple(priority)
    if sorted(names) != sorted(DOF_NAMES):
        raise ValueError(f"DOF priority must name each of {DOF_NAMES} once, got {names}")
    return tuple(DOF_NAMES.index(n) for n in names)


def accommodate(alloc: Allocator, eta, priority=DEFAULT_DOF_PRIORITY,
                min_authority: float = 0.2) -> Accommodation:
    """The allocation for thruster effectiveness η (a thruster commanded fᵢ delivers ηᵢ fᵢ).

    B_η = B diag(η) with the dead thrusters' columns (η ≤ :data:`ETA_DEAD`) dropped. The DOFs
    kept are chosen greedily in ``priority`` order: a DOF is kept when the rows kept with it
    still have authority — the smallest singular value of B_η,S W^{-1/2} at least
    ``min_authority`` times that of the healthy B W^{-1/2} (the wrench per unit of weighted
    thrust in the healthy vehicle's weakest direction). Merely independent rows are not enough:
    the JHU ROV without an aft vertical thruster could still reach pitch through the lateral
    thruster's 5 cm lever in roll, at 300 N of sway for 15 N m. So the kept set has at most
    rank(B_η) DOFs, and each DOF given up is one the higher-priority ones leave too little
    authority for. f = W^{-1/2} (B_η,S W^{-1/2})⁺ u_S
    (S: kept rows, W: the allocator's weights) meets the kept DOFs exactly with the least
    weighted thrust; what it produces on a given-up DOF is a side effect (none is asked).
    Saturation stays :func:`allocate_kernel`'s: limits are on the command, which a weak
    thruster still obeys.

    With η all 1 this is the allocator's own B_W⁺ (to rounding).

    Parameters
    ----------
    alloc : the vehicle's allocator (B, weights).
    eta : (N,) effectiveness, each in [0, 1] (a non-finite or out-of-range value is refused).
    priority : the six DOF names, highest priority first.
    """
    n = alloc.n_thrusters
    e = np.asarray(eta, dtype=float).reshape(-1)
    if e.shape != (n,) or not np.all(np.isfinite(e)) or np.any(e < 0.0) or np.any(e > 1.0):
        raise ValueError(f"eta must be {n} numbers in [0, 1], got {np.asarray(eta).tolist()}")
    order = dof_priority_indices(priority)
    live = e > ETA_DEAD
    w = np.ones(n) if alloc.weights is None else alloc.weights
    s = 1.0 / np.sqrt(w[live])
    Bl = alloc.B[:, live] * e[live][None, :] * s[None, :]  # B_η W^{-1/2} on the live ones
    healthy = np.linalg.svd(alloc.B / np.sqrt(w)[None, :], compute_uv=False)[-1]
    floor = max(float(min_authority), 1e-9) * float(healthy)
    kept: list[int] = []
    for d in order:
        rows = Bl[kept + [d], :]
        if rows.shape[1] > len(kept):  # as many live thrusters as DOFs, at least
            if np.linalg.svd(rows, compute_uv=False)[-1] >= floor:
                kept.append(d)
    S = sorted(kept)
    pinv = np.zeros((n, 6))
    if S:
        pinv[np.ix_(live, S)] = s[:, None] * np.linalg.pinv(Bl[S, :])
    actuated = np.zeros(6, dtype=bool)
    actuated[S] = True
    given_up = tuple(DOF_NAMES[d] for d in order if not actuated[d])
    return Accommodation(eta=e.copy(), B_pinv=np.ascontiguousarray(pinv), actuated=actuated,
                         given_up=given_up)


@numba.njit(cache=True)
def allocate_kernel(B_pinv, f_max, u):
    """Compiled body of :func:`allocate` (B⁺ and limits as arrays), for compiled callers
    such as the core's command kernel."""
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
            # clamped: x·(1/worst) can round one ulp past the limit for the thruster at it
            f[j] = min(max(f[j] * scale, -f_max[j]), f_max[j])
            sat[j] = ratio[j] >= worst * (1.0 - 1e-12)
    return f, sat, scale


#: :func:`allocate_prioritised_kernel`: two allocations whose wrench on a DOF differs by less
#: than this times the largest |uᵢ| give that DOF the same (rounding)
PRIORITY_TIE = 1e-9


@numba.njit(cache=True)
def allocate_prioritised_kernel(B_pinv, f_max, u, order):
    """Allocation that spends the thrust left, under saturation, on the DOFs in priority order.

    ``order``: the DOF indices (0–5 of u) highest priority first (:func:`dof_priority_indices`).
    When f = B⁺u is within every limit it is returned exactly as :func:`allocate_kernel` does
    (nothing saturates, nothing is given). Otherwise the wrench is built up one DOF at a time in
    ``order``: f ← f + s_d B⁺[:, d] u_d with s_d ∈ [0, 1] the largest that keeps every thruster
    within ±f_max — depth and attitude take the thrust first, a lower-priority DOF gets what they
    leave — and a second pass in the same order raises each s_d as far as the thrust a later DOF
    freed on a shared thruster allows. Because B B⁺ is the identity on the DOFs B⁺ reaches, DOF
    d then gets s_d u_d; plain scaling gives every DOF the common fraction
    c = 1/max_i(|fᵢ|/f_max,i). In a geometry where a lower-priority DOF's thrust would relieve a
    higher one's thruster, the fill can leave a DOF of higher priority below c: so the two are
    compared in ``order`` on the DOFs asked for (u_d ≠ 0 and reached by B⁺), and the one that
    gives the first DOF where they differ (by more than :data:`PRIORITY_TIE` × max|uᵢ| in
    wrench) the larger fraction is returned — never worse than plain scaling for the DOF of
    highest priority where they differ (lexicographically, in ``order``).

    Returns (f, saturated, s): the thrusts (within ±f_max), the thrusters at their limit, and the
    fraction s_d ∈ [0, 1] of each DOF's wrench produced (1 for a DOF not asked for, u_d = 0;
    0 for one B⁺ does not reach, a DOF given up).
    """
    n = B_pinv.shape[0]
    f0, sat0, c = allocate_kernel(B_pinv, f_max, u)
    s = np.ones(6)
    if c == 1.0:
        return f0, sat0, s
    asked = np.zeros(6, dtype=np.bool_)
    for d in range(6):
        for j in range(n):
            if u[d] != 0.0 and B_pinv[j, d] != 0.0:
                asked[d] = True
        if u[d] != 0.0 and not asked[d]:
            s[d] = 0.0  # a DOF B⁺ does not reach (given up): none of it is asked
    f = np.zeros(n)
    for d in range(6):
        if asked[d]:
            s[d] = 0.0
    for _ in range(2):  # the second pass: what a later DOF's thrust freed on a shared thruster
        for d in order:
            if not asked[d] or s[d] >= 1.0:
                continue
            t = 1.0 - s[d]
            for j in range(n):
                g = B_pinv[j, d] * u[d]
                if g > 0.0:
                    t = min(t, (f_max[j] - f[j]) / g)
                elif g < 0.0:
                    t = min(t, (-f_max[j] - f[j]) / g)
            if t > 0.0:
                s[d] += t
                for j in range(n):
                    f[j] = min(max(f[j] + t * B_pinv[j, d] * u[d], -f_max[j]), f_max[j])
    tie = 0.0  # a difference in wrench below PRIORITY_TIE × max|u| is none (rounding)
    for d in range(6):
        tie = max(tie, abs(u[d]))
    tie *= PRIORITY_TIE
    for d in order:  # the first DOF asked for where fill and plain scaling differ decides
        if asked[d] and abs(u[d]) * abs(s[d] - c) > tie:
            if s[d] < c:
                for i in range(6):
                    if asked[i]:
                        s[i] = c
                return f0, sat0, s
            break
    sat = np.zeros(n, dtype=np.bool_)
    for j in range(n):
        sat[j] = abs(f[j]) >= f_max[j] * (1.0 - 1e-12)
    return f, sat, s


def allocate_prioritised(alloc: Allocator, u: np.ndarray, priority=DEFAULT_DOF_PRIORITY,
                         B_pinv: np.ndarray | None = None
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(f, saturated mask, per-DOF fraction s) for the wrench u, saturation resolved by DOF
    priority (:func:`allocate_prioritised_kernel`); ``B_pinv`` replaces the allocator's (an
    :class:`Accommodation`'s). A non-finite u gives a non-finite f, as :func:`allocate`."""
    P = np.ascontiguousarray(alloc.B_pinv if B_pinv is None else B_pinv, dtype=float)
    u = np.asarray(u, dtype=float)
    if not np.isfinite(u).all():
        f = P @ u
        return f, np.zeros(f.shape, dtype=bool), np.ones(6)
    order = np.asarray(dof_priority_indices(priority), dtype=np.int64)
    return allocate_prioritised_kernel(P, np.asarray(alloc.max_thrust_n, dtype=float),
                                       np.ascontiguousarray(u), order)


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
    return allocate_kernel(alloc.B_pinv, alloc.max_thrust_n, u)


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


# ---------------------------------------------------------------------------------------------
# propeller-lag compensation
# ---------------------------------------------------------------------------------------------
@numba.njit(cache=True)
def _lag_compensate(f_des, omega_meas, k, f_max, tau, dt, f_out):
    """Kernel of :func:`lag_compensate`; writes f_out, returns the common fraction s ∈ [α, 1]
    (1: full compensation), or -1.0 when an input is unusable (f_out untouched)."""
    n = f_des.shape[0]
    if not (dt > 0.0) or not np.isfinite(dt):
        return -1.0
    for j in range(n):
        if (not np.isfinite(f_des[j]) or not np.isfinite(omega_meas[j])
                or not (k[j] > 0.0) or not (f_max[j] > 0.0) or not (tau[j] >= 0.0)):
            return -1.0
    # per thruster: the measured speed (clamped to the speed limit), the increment of the
    # compensated set-point over it, and the largest fraction of that increment within limits
    s = 1.0
    w0 = np.empty(n)
    dw = np.empty(n)
    for j in range(n):
        w_max = math.sqrt(f_max[j] / k[j])
        w0[j] = min(max(omega_meas[j], -w_max), w_max)
        w_des = math.copysign(math.sqrt(abs(f_des[j]) / k[j]), f_des[j])
        a = 1.0 if tau[j] == 0.0 else -math.expm1(-dt / tau[j])
        if not (a > 0.0):  # τ so long that nothing moves in one period: do not compensate
            return -1.0
        dw[j] = (w_des - w0[j]) / a
        lim = w_max - w0[j] if dw[j] > 0.0 else -w_max - w0[j]
        if dw[j] != 0.0 and abs(dw[j]) > abs(lim):
            s = min(s, lim / dw[j])
    for j in range(n):
        w = w0[j] + s * dw[j]
        f_out[j] = min(max(k[j] * w * abs(w), -f_max[j]), f_max[j])
    return s


def lag_compensate(alloc: Allocator, f_des: np.ndarray, omega_meas_rad_s: np.ndarray | None,
                   dt: float) -> tuple[np.ndarray, float]:
    """Thrust commands that bring the propellers to ``f_des`` at the end of one control period.

    The thrusters' first-order lag acts on propeller speed: with the command c held over the
    period, the set-point is ω*(c) = sign(c)√(|c|/k) and the speed obeys τ ω̇ = ω* − ω, so
    (exact discretisation over dt)

        ω(t+dt) = ω_m + α (ω* − ω_m),   α = 1 − e^{−dt/τ},

    from the measured speed ω_m at the start of the period; thrust is f = k ω|ω| (App. A.1).
    Asking ω(t+dt) = ω_d = sign(f_des)√(|f_des|/k) gives the lead set-point

        ω* = ω_m + (ω_d − ω_m)/α,   command c = k ω*|ω*|

    (for τ = 0, α = 1 and c = f_des). In thrust terms this is the first-order compensation
    f_cmd = f_m + (f_des − f_m)/α written in the speed the lag really acts on, so it is exact
    for the f = k ω|ω| law rather than only to first order.

    Saturation: |ω*| ≤ ω_max = √(f_max/k). When a set-point would exceed it, every thruster's
    increment (ω* − ω_m) is scaled by one common fraction s so that all stay within limits —
    each propeller then covers the same share s of the way to its target, as allocation's
    direction-keeping scale does for the wrench. s ≥ α always: s = α is plain allocation
    (ω* = ω_d, because f_des is itself within limits), so the compensated command never asks
    less than the uncompensated one. Measured speeds beyond ±ω_max are clamped first.

    Safety: when the speeds are missing, of the wrong shape or not finite, when f_des is not
    finite, or the allocator lacks k or τ, the result is ``f_des`` unchanged with s = nan —
    plain allocation, never an exception (the core's non-finite check still guards f_des).

    Parameters
    ----------
    alloc : allocator with ``k_thrust``, ``max_thrust_n`` and ``time_constant_s``.
    f_des : (N,) allocated thrust (N), within the limits.
    omega_meas_rad_s : (N,) propeller speeds measured at the start of the period (rad/s).
    dt : the control period over which the command is held (s).

    Returns
    -------
    (f_cmd, s) : (N,) thrust command (N) and the common fraction s ∈ [α, 1] (nan: not
    compensated).
    """
    f_des = np.asarray(f_des, dtype=float)
    if (omega_meas_rad_s is None or alloc.k_thrust is None or alloc.time_constant_s is None):
        return f_des, math.nan
    w = np.asarray(omega_meas_rad_s, dtype=float)
    if w.shape != f_des.shape or f_des.ndim != 1:
        return f_des, math.nan
    out = np.empty_like(f_des)
    s = _lag_compensate(f_des, w, alloc.k_thrust, alloc.max_thrust_n, alloc.time_constant_s,
                        float(dt), out)
    if s < 0.0:
        return f_des, math.nan
    return out, s


def actuation_delay_s(dt: float, tau_s: float, *, compensated: bool) -> float:
    """Low-frequency delay δ (s) of the actuation chain, from the wrench the controller computes
    at t_k to the thrust the propellers produce: the cycle's zero-order hold followed by the
    first-order propeller lag τ ω̇ = ω* − ω (App. A.1), with or without
    :func:`lag_compensate`. Small-signal (speed and thrust delays agree to first order).

    * Hold alone (τ = 0): the held sample of a ramp lags it by s ∈ [0, dt), δ = dt/2.
    * Hold + uncompensated lag: the lag's group delay at ω → 0 is τ, δ = dt/2 + τ.
    * Hold + compensated lag: the lead set-point makes the speed leave ω_{k−1} (reached at t_k)
      and reach ω_k = ω_d(t_k) at t_k + dt along ω(t_k + s) = ω_{k−1} + (ω_k − ω_{k−1}) φ(s),
      φ(s) = (1 − e^{−s/τ})/α, α = 1 − e^{−dt/τ}. For a ramp ω_d = r t the delay at t_k + s is
      dt + s − dt φ(s); its mean over the cycle, with (1/dt)∫₀^dt φ = 1/α − τ/dt, is

          δ = 3dt/2 + τ − dt/α  =  dt/2 (hold)  +  (dt + τ − dt/α) (compensated propeller).

      τ → 0 gives dt/2 (no lag), τ → ∞ gives dt (linear interpolation one cycle late). For
      dt = 0.1 s, τ = 0.15 s: 50 + 44.5 = 94.5 ms — the delay measured on the plant model
      (docs/experiments.md, "What biases the masses and drags").
    """
    dt = float(dt)
    tau = float(tau_s)
    if not (math.isfinite(dt) and dt > 0.0 and math.isfinite(tau) and tau >= 0.0):
        raise ValueError(f"need dt > 0 and tau >= 0 (finite), got dt={dt}, tau={tau}")
    if tau == 0.0:
        return 0.5 * dt
    if not compensated:
        return 0.5 * dt + tau
    a = -math.expm1(-dt / tau)
    return 1.5 * dt + tau - dt / a
