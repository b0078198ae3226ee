"""The pure core of the cycle — what the cycle's update (:func:`uvd.runtime.cycle.update`, run
by the daemon, lockstep simulation and replay) computes around its failsafe arbiter.

    step(config, inputs, state, dt) -> (outputs, state)
         = act(config, sense(config, inputs, state, dt), inputs, state, dt)

:func:`sense` is navigation and estimation; :func:`act` is reference, control in the cycle's
:class:`Mode`, allocation and the output guard. The split lets the failsafe arbiter
(:mod:`uvd.runtime.cycle`) decide the mode from what :func:`sense` found before anything is
commanded: the mode is an *input* of :func:`act`, and what :func:`act` returns is exactly what
the amplifiers get. :func:`step` runs the two back to back without the arbiter (the kernels'
warm-up, tests, benchmarks of the core alone).

**Modes** (docs/architecture.md, "where each failsafe acts"):

==============  ===============================================================================
``CONTROL``     the configured controller (PDC, MBC, AMBC, two-step AMBC); its state advances
``PDC``         PD control (``CoreConfig.pd``) on the reference; the controller is not stepped,
                so its adaptation is frozen (θ̂ held) — the arbiter's FALLBACK, or the operator
``HOLD_DEPTH``  PD on depth, roll and pitch toward the pose held at entry (level, following the
                heading), allocated to the vertical thrusters alone: exactly zero surge, sway
                and yaw thrust; translational velocity feedback only while the DVL is valid
``MANUAL``      the operator's body wrench (``CoreInputs.manual_wrench``), allocated
``ZERO``        zero thrust; the controller is not stepped
==============  ===============================================================================

Disarmed, every mode commands zero. ``CoreInputs.thruster_eta`` — each thruster's
effectiveness η ∈ [0, 1] (1 healthy, 0.5 half thrust, 0 dead) — shapes allocation in every mode
(:func:`uvd.control.allocation.accommodate`): a weak thruster's column scaled, a dead one
removed; when the thrusters left cannot reach every DOF, those of lowest priority
(``CoreConfig.dof_priority``) are given up (``CoreOutputs.given_up``), and a command beyond
a thruster's limit is resolved by that priority too — depth and attitude take the thrust
first, the rest gets what is left (:func:`uvd.control.allocation.allocate_prioritised`;
healthy, the direction-keeping scaling of the thesis experiments). Given-up DOFs are taken
out of the reference's closed loop — so the controller neither commands nor adapts on them
(AMBC's error is masked by the closed loop in (5.28), and its spec's ``hold_dofs`` keeps those
DOFs' parameters, which other rows' Coriolis terms would still move); a horizontal DOF given
up also slides the controller's reference horizontally to the vehicle, along both axes
(:func:`uvd.control.given_up.slide_reference`: drift it cannot correct is not read as depth or
attitude error; ``CoreOutputs.reference`` stays the trajectory's) — and the wrench the
estimators see is B diag(η) f, what the thrusters really give. The estimators (AID) run in
every mode: they identify the vehicle whatever drives it — except on a DOF given up, whose
parameters an estimator's ``hold_dofs`` holds (AID: :func:`uvd.estimation.aid.aid_hold_dofs`,
the reason in its estimates' ``hold_reason``).

navigation → reference → control → estimation → allocation (docs/architecture.md). Pure and
deterministic: no I/O, no clock (time arrives in ``inputs.t_ns``), no logging. Safety is
structural: when navigation is invalid, the vehicle is disarmed, or any number on the way to
the thrusters is not finite, the thrust command is zero and ``outputs.status`` says why — the
cycle never raises for bad data.

Controllers are step functions ``(VehicleState, Reference, params, ctrl_state, dt) ->
(u, ctrl_state)`` (PDC, MBC, AMBC, two-step AMBC of :mod:`uvd.control`). Estimators that
identify the vehicle whatever controls it (AID, :mod:`uvd.estimation`) are step functions
``(VehicleState, u_applied, params, est_state, dt) -> est_state``; they run whether or not
the vehicle is armed. ``u_applied`` is the wrench actually produced during the last cycle —
from measured propeller speeds (f = k ω|ω|, App. A.1) when the amplifiers report them, else
the previous command.

Allocation turns the wrench into per-thruster thrusts. With ``lag_compensation`` on, the
command sent to each thruster is the lead set-point of
:func:`uvd.control.allocation.lag_compensate`: from the propeller speeds measured at the start
of the cycle and the time constants declared in the vehicle file, the command that brings every
propeller to its allocated thrust by the end of the cycle. Missing or non-finite speeds fall
back to plain allocation for that cycle.

With ``ff_preview_s`` = δ > 0 (default 0: off) the reference handed to the controller carries
``preview``, the desired state at t + δ, on which the model-based controllers evaluate their
feed-forward (:func:`uvd.control.ambc.ambc_step`) to offset the actuation chain's delay δ
(:func:`uvd.control.allocation.actuation_delay_s`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any, NamedTuple

import numba
import numpy as np

from drivers.samples import DepthSample, DvlSample, InsSample
from uvd.control.allocation import (
    DEFAULT_DOF_PRIORITY,
    Accommodation,
    Allocator,
    accommodate,
    allocate_kernel,
    allocate_prioritised_kernel,
    dof_priority_indices,
    lag_compensate,
)
from uvd.control.given_up import (
    controlled_dofs,
    measured_acceleration,
    slide_reference,
    world_velocity,
)
from uvd.control.pdc import PDGains, PDState, pdc_step
from uvd.control.types import ControllerSpec, EstimatorSpec, Reference, VehicleState
from uvd.estimation.navigation import NavConfig, NavMemory, NavState, nav_init, nav_step
from uvd.geometry import euler_to_R

__all__ = ["Mode", "CoreConfig", "CoreInputs", "CoreState", "CoreOutputs", "Sensed",
           "ControllerSpec", "EstimatorSpec", "core_init", "sense", "act", "step",
           "HOLD_DEPTH_MASK"]


class Mode(StrEnum):
    """How :func:`act` computes the command (module docstring)."""

    CONTROL = "control"
    PDC = "pdc-fallback"
    HOLD_DEPTH = "hold-depth"
    MANUAL = "manual"
    ZERO = "zero"


_CONTROL, _PDC, _HOLD_DEPTH, _MANUAL, _ZERO_MODE = (Mode.CONTROL, Mode.PDC, Mode.HOLD_DEPTH,
                                                   Mode.MANUAL, Mode.ZERO)

#: closed-loop mask of the hold-depth mode: depth, roll and pitch; no surge, sway, yaw
HOLD_DEPTH_MASK = np.array([False, False, True, True, True, False])


@dataclass(frozen=True)
class CoreConfig:
    """Everything constant about the cycle (Pinocchio's model; :class:`CoreState` is its data)."""

    nav: NavConfig
    controller: ControllerSpec
    reference: Any  # object with .at(t_s) -> Reference: the one a run starts with (core_init)
    allocator: Allocator
    k_thrust: np.ndarray
    estimators: tuple[EstimatorSpec, ...] = ()
    lag_compensation: bool = False  # lead set-points from measured propeller speeds
    ff_preview_s: float = 0.0  # δ of the feed-forward preview (s); 0: off
    pd: PDGains = field(default_factory=PDGains)  # gains of the PDC and HOLD_DEPTH modes
    #: DOFs, highest priority first, kept when the thrusters' effectiveness cannot reach all
    dof_priority: tuple[str, ...] = DEFAULT_DOF_PRIORITY

    def __post_init__(self) -> None:
        if not (math.isfinite(self.ff_preview_s) and self.ff_preview_s >= 0.0):
            raise ValueError(f"ff_preview_s must be finite and >= 0, got {self.ff_preview_s}")
        dof_priority_indices(self.dof_priority)  # a permutation of the six DOFs, or refused
        # constants of the compiled glue, prepared once (not fields): contiguous float64 B,
        # B⁺, thrust limits and per-thruster k of f = k ω|ω|
        alloc = self.allocator
        B = np.ascontiguousarray(alloc.B, dtype=np.float64)
        n = B.shape[1]
        k = np.broadcast_to(np.asarray(self.k_thrust, dtype=np.float64), (n,)).copy()
        object.__setattr__(self, "_glue", (
            B, np.ascontiguousarray(alloc.B_pinv, dtype=np.float64),
            np.ascontiguousarray(alloc.max_thrust_n, dtype=np.float64), k, n))
        object.__setattr__(self, "_vertical", alloc.vertical())
        object.__setattr__(self, "_priority", np.array(dof_priority_indices(self.dof_priority),
                                                       dtype=np.int64))
        object.__setattr__(self, "_restricted", {})  # mask bytes → contiguous B⁺ of the subset
        object.__setattr__(self, "_accommodated", {})  # η bytes → (Accommodation, B diag(η))
        object.__setattr__(self, "_ctrl_params", {})  # η bytes → the controller's params

    def pinv_for(self, mask: np.ndarray | None) -> np.ndarray:
        """B⁺ of the thrusters in ``mask`` (all: None), computed once per mask."""
        if mask is None:
            return self._glue[1]
        key = mask.tobytes()
        p = self._restricted.get(key)
        if p is None:
            p = np.ascontiguousarray(self.allocator.restricted(mask).B_pinv, dtype=np.float64)
            self._restricted[key] = p
        return p


    def accommodation_for(self, eta: np.ndarray) -> tuple[Accommodation, np.ndarray]:
        """The allocation for effectiveness ``eta`` ((N,) float64 in [0, 1]) and B diag(η),
        computed once per η (a fault changes η rarely; each value is kept)."""
        key = eta.tobytes()
        got = self._accommodated.get(key)
        if got is None:
            acc = accommodate(self.allocator, eta, self.dof_priority)
            got = (acc, np.ascontiguousarray(self._glue[0] * eta[None, :]))
            self._accommodated[key] = got
        return got


    def controller_params_for(self, eta: np.ndarray):
        """The controller's params while the allocation is the one for ``eta`` (its spec's
        ``with_allocation``: AMBC's saturation freeze judged on the thrust really commanded),
        computed once per η; its own params when it has no such hook."""
        spec = self.controller
        if spec.with_allocation is None:
            return spec.params
        key = eta.tobytes()
        got = self._ctrl_params.get(key)
        if got is None:
            got = spec.with_allocation(spec.params, self.accommodation_for(eta)[0].B_pinv)
            self._ctrl_params[key] = got
        return got


def _eta_of(eta, n: int) -> np.ndarray | None:
    """``CoreInputs.thruster_eta`` as a float64 (n,) array in [0, 1], or None when every
    thruster is healthy (the allocator's own B⁺, bit for bit as without η). Anything else — a
    wrong length, a non-finite or out-of-range entry — is no thruster: all η = 0, zero thrust
    (doubt ends in zero thrust)."""
    if eta is None:
        return None
    try:
        e = np.array(eta, dtype=np.float64, order="C").reshape(-1)
    except (TypeError, ValueError):
        return np.zeros(n)
    if e.shape != (n,) or not np.isfinite(e).all() or (e < 0.0).any() or (e > 1.0).any():
        return np.zeros(n)
    return None if (e == 1.0).all() else e


class CoreInputs(NamedTuple):
    """What arrived since the previous cycle, stamped on one monotonic clock (ns), and how to
    act on it. Immutable (a named tuple: built every cycle, it costs a fraction of a frozen
    dataclass)."""

    t_ns: int
    ins: InsSample | None = None
    dvl: DvlSample | None = None
    depth: DepthSample | None = None
    propeller_speed_rad_s: np.ndarray | None = None  # amplifier feedback, per thruster
    armed: bool = True
    mode: Mode = Mode.CONTROL
    manual_wrench: np.ndarray | None = None  # (6,) body [f; τ] for Mode.MANUAL (N, N m)
    thruster_eta: np.ndarray | None = None  # (n,) effectiveness η ∈ [0, 1]; None: all 1


@dataclass
class CoreState:
    """What the core carries from one cycle to the next (a new one each cycle)."""

    nav: NavMemory
    ctrl: Any
    est: tuple
    t0_ns: int | None = None
    est_t_ns: int | None = None  # when the estimators last ran (they skip invalid navigation)
    cycles: int = 0
    u_last: np.ndarray = field(default_factory=lambda: np.zeros(6))
    hold: Reference | None = None  # the pose HOLD_DEPTH holds, taken when the mode was entered
    ctrl_t_ns: int | None = None  # when the controller last stepped its state (AMBC's θ̂)
    #: the running reference (``.at(t_s) -> Reference``, t_s from ``t0_ns``): the configured
    #: one from :func:`core_init`; the supervised cycle replaces it (a pose to hold)
    reference: Any = None
    #: (t_ns, world linear velocity) of the last cycle whose controller's reference slid
    #: (surge or sway given up), for the slid reference's acceleration (uvd.control.given_up)
    slid_v: tuple | None = None


class CoreOutputs(NamedTuple):
    """What one cycle commands and why. Immutable (a named tuple, as :class:`CoreInputs`):
    ``thrust_n`` is what the amplifiers get, and nothing downstream changes it."""

    thrust_n: np.ndarray          # per-thruster command (N), always finite
    u_cmd: np.ndarray             # wrench after allocation/saturation (N, N m); with lag
                                  # compensation the wrench the propellers reach by cycle end
    u_applied: np.ndarray         # wrench the estimators saw
    nav: NavState
    reference: Reference | None
    saturated: np.ndarray
    status: str                   # "ok", "disarmed", "nav-invalid", "non-finite"
    lead_fraction: float = float("nan")  # lag compensation's common fraction s (nan: not used)
    mode: str = Mode.CONTROL  # the mode applied (a Mode, a str; "disarmed" when not armed)
    guard: int = 0  # the output guard acted: 1 clamped to ±max thrust, 2 non-finite → zero
    given_up: tuple[str, ...] = ()  # DOFs the thrusters' effectiveness no longer reaches


class Sensed(NamedTuple):
    """What :func:`sense` found: the navigation state and the estimators' new states (a named
    tuple: built every cycle, it costs a third of a frozen dataclass)."""

    nav: NavState
    nav_mem: NavMemory
    nav_ok: bool  # valid and finite
    vs: VehicleState  # the navigation state as the controllers take it
    est: tuple
    est_t_ns: int | None
    u_applied: np.ndarray
    speeds: np.ndarray | None  # the measured propeller speeds as a float64 (n,) array


def core_init(cfg: CoreConfig, *, north_m: float = 0.0, east_m: float = 0.0) -> CoreState:
    return CoreState(nav=nav_init(cfg.nav, north_m=north_m, east_m=east_m),
                     ctrl=cfg.controller.init_state,
                     est=tuple(e.init_state for e in cfg.estimators), reference=cfg.reference)


def _finite(a: np.ndarray) -> bool:
    """All entries finite (no NaN, no ±inf)."""
    return bool(np.isfinite(a).all())


# --------------------------------------------------------------------------- compiled glue
# The cycle's small-vector arithmetic, each a few lines of numpy that cost ~1 µs per call in
# the interpreter, done in three compiled calls. Same formulas as the numpy versions
# (thrust_from_speed, allocate, B @ f); tests/test_core_replay.py holds them to 1e-12.
# Results go into arrays the caller allocates: handing an empty array in costs less than
# boxing a new one on the way out (~0.25 µs against ~0.5 µs per array).

_OK, _NON_FINITE = 0, 1


@numba.njit(cache=True)
def _finite_hv(H, v):
    """Every entry of the pose H (4×4) and the velocity v (6,) is finite."""
    for i in range(H.shape[0]):
        for j in range(H.shape[1]):
            if not np.isfinite(H[i, j]):
                return False
    for i in range(v.shape[0]):
        if not np.isfinite(v[i]):
            return False
    return True


@numba.njit(cache=True)
def _wrench_of(B, f, u):
    """u = B f, written into ``u`` (the same summation order as ``B @ f``'s loop form)."""
    n = f.shape[0]
    for i in range(6):
        x = 0.0
        for j in range(n):
            x += B[i, j] * f[j]
        u[i] = x


@numba.njit(cache=True)
def _applied_wrench(B, k, omega, u):
    """u = B f with f = k ω|ω| (App. A.1), written into ``u``; returns False (u unset) if ω
    has a non-finite entry."""
    n = omega.shape[0]
    for j in range(n):
        if not np.isfinite(omega[j]):
            return False
    f = np.empty(n)
    for j in range(n):
        f[j] = k[j] * omega[j] * np.abs(omega[j])
    _wrench_of(B, f, u)
    return True


@numba.njit(cache=True)
def _command(B, B_pinv, f_max, u_ctrl, ol, use_ol, f_out, sat_out, u_cmd, order, prioritise):
    """Wrench → thrusters, as :func:`uvd.control.allocation.allocate` with the core's checks.

    u = u_ctrl (+ ol): not finite ⇒ u = 0 and status non-finite. f = B⁺u, scaled by the
    largest |fᵢ|/f_max,i when above 1 (flags at the limit) — or, ``prioritise`` (a thruster's
    effectiveness set), saturation resolved by the DOF priority ``order``
    (:func:`uvd.control.allocation.allocate_prioritised_kernel`); f not finite ⇒ f = 0, no
    flags, status non-finite. Writes f, the saturation flags and B f into ``f_out``, ``sat_out``,
    ``u_cmd``; returns the status."""
    status = _OK
    u = np.empty(6)
    for i in range(6):
        u[i] = u_ctrl[i] + ol[i] if use_ol else u_ctrl[i]
    for i in range(6):
        if not np.isfinite(u[i]):
            status = _NON_FINITE
            for m in range(6):
                u[m] = 0.0
            break
    if prioritise:
        f, sat, _fractions = allocate_prioritised_kernel(B_pinv, f_max, u, order)
    else:
        f, sat, _scale = allocate_kernel(B_pinv, f_max, u)
    n = f.shape[0]
    for j in range(n):
        if not np.isfinite(f[j]):
            status = _NON_FINITE
            for m in range(n):
                f[m] = 0.0
                sat[m] = False
            break
    for j in range(n):
        f_out[j] = f[j]
        sat_out[j] = sat[j]
    _wrench_of(B, f, u_cmd)
    return status


# Every array handed to a compiled kernel is a writable, C-contiguous float64 array: numba
# compiles one specialisation per (dtype, layout, read-only) combination, and a new one met in
# the running loop — a read-only zero wrench while disarmed, read-only speeds decoded from a
# CAN frame — would be compiled there, a stall of seconds with an empty cache. The kernels
# never write to their inputs, so the shared zero vector stays zero.
_ZERO6 = np.zeros(6)
_F64 = np.dtype(np.float64)


def _as_vec(a, n: int) -> np.ndarray | None:
    """``a`` as a writable contiguous float64 (n,) array, or None if it cannot be one."""
    if (type(a) is not np.ndarray or a.dtype != _F64 or not a.flags.c_contiguous
            or not a.flags.writeable):
        try:
            a = np.array(a, dtype=np.float64, order="C")  # a copy: writable
        except (TypeError, ValueError):
            return None
    return a if a.shape == (n,) else None


@numba.njit(cache=True)
def _guard(f, f_max):
    """The output guard, in place: a non-finite entry zeroes every command (returns 2); an
    entry beyond ±f_max is clamped (returns 1); else 0."""
    n = f.shape[0]
    for j in range(n):
        if not np.isfinite(f[j]):
            for m in range(n):
                f[m] = 0.0
            return 2
    code = 0
    for j in range(n):
        if f[j] > f_max[j]:
            f[j] = f_max[j]
            code = 1
        elif f[j] < -f_max[j]:
            f[j] = -f_max[j]
            code = 1
    return code


def sense(cfg: CoreConfig, inputs: CoreInputs, state: CoreState, dt: float) -> Sensed:
    """Navigation, the applied wrench and the estimators of one cycle (pure)."""
    B, _, _, k_thr, n_thr = cfg._glue
    eta = _eta_of(inputs.thruster_eta, n_thr)
    actuated = None  # every DOF (the hooks' cheap path: a reduction costs ~2.6 µs)
    if eta is not None:
        acc, B = cfg.accommodation_for(eta)  # the wrench a thrust f really gives: B diag(η) f
        actuated = acc.actuated
    nav, nav_mem = nav_step(cfg.nav, state.nav, inputs.t_ns, inputs.ins, inputs.dvl, inputs.depth)
    nav_ok = nav.valid and _finite_hv(nav.H, nav.v)

    # the wrench applied over the last cycle, for the estimators: from measured propeller
    # speeds when they are there and finite (f = k ω|ω|, u = B f), else the last command
    u_applied = state.u_last
    speeds = inputs.propeller_speed_rad_s
    if speeds is not None:
        speeds = _as_vec(speeds, n_thr)
        if speeds is not None:
            u_meas = np.empty(6)
            if _applied_wrench(B, k_thr, speeds, u_meas):
                u_applied = u_meas

    est = state.est
    est_t_ns = state.est_t_ns
    vs = VehicleState(nav.H, nav.v)
    if nav_ok:
        # the time since the estimators last ran, not one period: after a navigation outage
        # an estimator sees the gap (AID re-synchronises v̂ = v after one, Theorem 4.3.1's t₀)
        dt_est = dt if est_t_ns is None else (inputs.t_ns - est_t_ns) * 1e-9
        stepped = []
        for e, s in zip(cfg.estimators, state.est, strict=True):
            n = e.step(vs, u_applied, e.params, s, dt_est)
            # a DOF no thruster reaches any more: the estimator's parameters of it are held
            stepped.append(n if e.hold_dofs is None else e.hold_dofs(n, s, actuated))
        est = tuple(stepped)
        est_t_ns = inputs.t_ns
    return Sensed(nav, nav_mem, nav_ok, vs, est, est_t_ns, u_applied, speeds)


def _hold_depth(cfg: CoreConfig, nav: NavState, hold: Reference, dt: float) -> np.ndarray:
    """PD on depth, roll and pitch toward ``hold`` (HOLD_DEPTH_MASK), level and following the
    vehicle's heading; horizontal position is not controlled, and without a valid DVL the
    translational velocity is unknown, so only the attitude rates feed the derivative term."""
    H = nav.H.copy()
    H[0, 3], H[1, 3] = hold.H[0, 3], hold.H[1, 3]
    heading = math.atan2(H[1, 0], H[0, 0])
    ref_H = hold.H.copy()
    ref_H[:3, :3] = euler_to_R(0.0, 0.0, heading)
    v = np.array(nav.v, dtype=float)
    if not nav.dvl_valid:
        v[:3] = 0.0
    u, _ = pdc_step(VehicleState(H=H, v=v), replace(hold, H=ref_H), cfg.pd, PDState(), dt)
    return u


def _hold_pose(nav: NavState) -> Reference:
    """The pose HOLD_DEPTH holds: here, level, at rest (taken when the mode is entered)."""
    H = nav.H
    heading = math.atan2(H[1, 0], H[0, 0])
    Hh = np.eye(4)
    Hh[:3, :3] = euler_to_R(0.0, 0.0, heading)
    Hh[:3, 3] = H[:3, 3]
    return Reference(H=Hh, v=np.zeros(6), vdot=np.zeros(6), closed_loop=HOLD_DEPTH_MASK)


# act is long (~105 lines) on purpose: it runs every cycle on the loop's path, and the mode
# decision, allocation and output guard read top to bottom in one place; splitting it would
# add calls to the hot path and spread the one rule of what reaches the amplifiers.
def act(cfg: CoreConfig, sensed: Sensed, inputs: CoreInputs, state: CoreState, dt: float
        ) -> tuple[CoreOutputs, CoreState]:
    """Reference, control in ``inputs.mode``, allocation and the output guard (pure).

    ``state`` is not modified; a new state is returned. The returned ``thrust_n`` is what the
    amplifiers get: finite, within ±max thrust, zero when disarmed or in Mode.ZERO."""
    B, B_pinv, f_max, _, n_thr = cfg._glue
    nav = sensed.nav
    t0 = state.t0_ns if state.t0_ns is not None else inputs.t_ns
    t_s = (inputs.t_ns - t0) * 1e-9
    reference = state.reference
    ref = reference.at(t_s)
    if cfg.ff_preview_s > 0.0:
        # positional (Reference's field order): dataclasses.replace costs ~5 µs a cycle
        ref = Reference(ref.H, ref.v, ref.vdot, ref.open_loop_wrench, ref.closed_loop,
                        reference.at(t_s + cfg.ff_preview_s))

    armed = inputs.armed
    mode = inputs.mode if armed else _ZERO_MODE
    eta = _eta_of(inputs.thruster_eta, n_thr)
    given_up: tuple[str, ...] = ()
    actuated = None
    if eta is not None:
        acc, B = cfg.accommodation_for(eta)
        B_pinv, given_up = acc.B_pinv, acc.given_up
        actuated = acc.actuated
        if given_up:  # no feedback and no adaptation on a DOF no thruster reaches (neither
            # horizontal translation when surge or sway is: horizontal position is given up)
            cl = controlled_dofs(acc.actuated)
            cl = cl if ref.closed_loop is None else (cl & ref.closed_loop)
            ref = replace(ref, closed_loop=cl)
    mask = None  # HOLD_DEPTH's vertical thrusters
    hold = None

    status = "ok"
    slid_v = None
    ctrl = state.ctrl
    ctrl_new = None
    u_ctrl = _ZERO6
    ol = _ZERO6
    if (mode is _CONTROL or mode is _PDC) and armed:
        if sensed.nav_ok:
            # surge or sway given up: the controller's reference slides horizontally to the
            # vehicle, so what cannot be corrected ends as drift, not depth error (the
            # outputs keep the trajectory's reference: what tracking is measured against)
            ref_c = ref
            if given_up:
                slid_v = (inputs.t_ns, world_velocity(sensed.vs))
                ref_c = slide_reference(ref, sensed.vs, actuated,
                                        measured_acceleration(state.slid_v, slid_v, dt))
            if mode is _CONTROL:
                params = cfg.controller.params if eta is None else \
                    cfg.controller_params_for(eta)
                u_new, ctrl_new = cfg.controller.step(sensed.vs, ref_c, params, state.ctrl, dt)
                if given_up and cfg.controller.hold_dofs is not None:
                    # the parameters of a DOF no thruster reaches stay where they were
                    ctrl_new = cfg.controller.hold_dofs(ctrl_new, state.ctrl, actuated)
            else:
                u_new = pdc_step(sensed.vs, ref_c, cfg.pd, PDState(), dt)[0]
            u_ctrl = _as_vec(u_new, 6)
            if ref.open_loop_wrench is not None:
                ol = _as_vec(ref.open_loop_wrench, 6)
            if u_ctrl is None or ol is None:  # not a 6-vector: treated as non-finite
                u_ctrl, ol = _ZERO6, _ZERO6
                status = "non-finite"
                ctrl_new = None
        else:
            status = "nav-invalid"
    elif not armed:
        status = "disarmed"
    elif mode is _MANUAL:
        if inputs.manual_wrench is not None:
            u_ctrl = _as_vec(inputs.manual_wrench, 6)
            if u_ctrl is None:
                u_ctrl, status = _ZERO6, "non-finite"
    elif mode is _HOLD_DEPTH:
        hold = state.hold if state.hold is not None else _hold_pose(nav)
        if nav.ins_valid and nav.depth_valid and _finite_hv(nav.H, nav.v):
            u_ctrl = _hold_depth(cfg, nav, hold, dt)
            mask = cfg._vertical
        else:
            status = "nav-invalid"

    thrust, saturated, u_cmd = np.empty(n_thr), np.empty(n_thr, dtype=np.bool_), np.empty(6)
    if mask is None:
        pinv = B_pinv
    elif eta is None:
        pinv = cfg.pinv_for(mask)
    else:  # the vertical thrusters at their effectiveness
        acc, B = cfg.accommodation_for(np.where(mask, eta, 0.0))
        pinv = acc.B_pinv
    code = _command(B, pinv, f_max, u_ctrl, ol, ol is not _ZERO6, thrust, saturated, u_cmd,
                    cfg._priority, eta is not None)
    if ctrl_new is not None:
        if code == _OK:
            ctrl = ctrl_new  # the controller's new state only with a finite command
        else:
            status = "non-finite"
    elif code != _OK:
        status = "non-finite"
    lead = math.nan
    if (cfg.lag_compensation and status == "ok" and mode is _CONTROL and mask is None
            and eta is None):
        # lead set-points from the speeds measured at the start of the cycle; u_cmd stays the
        # wrench of the allocated thrusts, which the propellers reach by the cycle's end
        f_cmd, s = lag_compensate(cfg.allocator, thrust, sensed.speeds, dt)
        if s == s:
            thrust, lead = np.array(f_cmd, dtype=np.float64), s
    # the output guard: _command's thrust is finite and within ±f_max by construction (zero and
    # status non-finite otherwise); the lead set-points are the one later change, re-checked
    guard = 0
    if lead == lead:
        guard = _guard(thrust, f_max)
        if guard == 2:
            status = "non-finite"
    label = mode if armed else "disarmed"
    out = CoreOutputs(thrust, u_cmd, sensed.u_applied, nav, ref, saturated, status, lead, label,
                      guard, given_up)
    return out, CoreState(sensed.nav_mem, ctrl, sensed.est, t0, sensed.est_t_ns,
                          state.cycles + 1, u_cmd, hold,
                          inputs.t_ns if ctrl is not state.ctrl else state.ctrl_t_ns, reference,
                          slid_v)


def step(cfg: CoreConfig, inputs: CoreInputs, state: CoreState, dt: float
         ) -> tuple[CoreOutputs, CoreState]:
    """The core's step: :func:`act` after :func:`sense`, in ``inputs.mode`` (no arbiter
    between them). ``state`` is not modified."""
    return act(cfg, sense(cfg, inputs, state, dt), inputs, state, dt)
