"""One control cycle — the pure core that the daemon, lockstep simulation and replay all drive.

    step(config, inputs, state, dt) -> (outputs, state)

navigation → reference → control → estimation → allocation (DESIGN.md). Pure and
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
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.samples import DepthSample, DvlSample, InsSample
from uvd.control.allocation import Allocator, allocate
from uvd.control.types import Reference, VehicleState
from uvd.estimation.navigation import NavConfig, NavMemory, NavState, nav_init, nav_step
from uvd.model.thrusters import thrust_from_speed


@dataclass(frozen=True)
class ControllerSpec:
    name: str
    step: Callable[..., tuple[np.ndarray, Any]]
    params: Any
    init_state: Any


@dataclass(frozen=True)
class EstimatorSpec:
    name: str
    step: Callable[..., Any]
    params: Any
    init_state: Any


@dataclass(frozen=True)
class CoreConfig:
    """Everything constant about the cycle."""

    nav: NavConfig
    controller: ControllerSpec
    reference: Any  # object with .at(t_s) -> Reference
    allocator: Allocator
    k_thrust: np.ndarray
    estimators: tuple[EstimatorSpec, ...] = ()


@dataclass(frozen=True)
class CoreInputs:
    """What arrived since the previous cycle, stamped on one monotonic clock (ns)."""

    t_ns: int
    ins: InsSample | None = None
    dvl: DvlSample | None = None
    depth: DepthSample | None = None
    propeller_speed_rad_s: np.ndarray | None = None  # amplifier feedback, per thruster
    armed: bool = True


@dataclass
class CoreState:
    nav: NavMemory
    ctrl: Any
    est: tuple
    t0_ns: int | None = None
    est_t_ns: int | None = None  # when the estimators last ran (they skip invalid navigation)
    cycles: int = 0
    u_last: np.ndarray = field(default_factory=lambda: np.zeros(6))


@dataclass(frozen=True)
class CoreOutputs:
    thrust_n: np.ndarray          # per-thruster command (N), always finite
    u_cmd: np.ndarray             # wrench after allocation/saturation (N, N m)
    u_applied: np.ndarray         # wrench the estimators saw
    nav: NavState
    reference: Reference | None
    saturated: np.ndarray
    status: str                   # "ok", "disarmed", "nav-invalid", "non-finite"


def core_init(cfg: CoreConfig, *, north_m: float = 0.0, east_m: float = 0.0) -> CoreState:
    return CoreState(nav=nav_init(cfg.nav, north_m=north_m, east_m=east_m),
                     ctrl=cfg.controller.init_state,
                     est=tuple(e.init_state for e in cfg.estimators))


def _finite(a: np.ndarray) -> bool:
    """All entries finite (no NaN, no ±inf)."""
    return bool(np.isfinite(a).all())


def step(cfg: CoreConfig, inputs: CoreInputs, state: CoreState, dt: float
         ) -> tuple[CoreOutputs, CoreState]:
    """One control cycle. ``state`` is not modified; a new state is returned."""
    nav, nav_mem = nav_step(cfg.nav, state.nav, inputs.t_ns, inputs.ins, inputs.dvl, inputs.depth)
    t0 = state.t0_ns if state.t0_ns is not None else inputs.t_ns
    t_s = (inputs.t_ns - t0) * 1e-9
    ref = cfg.reference.at(t_s)
    vs = VehicleState(H=nav.H, v=nav.v)
    nav_ok = nav.valid and _finite(nav.H) and _finite(nav.v)

    # the wrench applied over the last cycle, for the estimators
    if inputs.propeller_speed_rad_s is not None and _finite(inputs.propeller_speed_rad_s):
        u_applied = cfg.allocator.B @ thrust_from_speed(inputs.propeller_speed_rad_s, cfg.k_thrust)
    else:
        u_applied = state.u_last

    est = state.est
    est_t_ns = state.est_t_ns
    if nav_ok:
        # the time since the estimators last ran, not one period: after a navigation outage
        # an estimator sees the gap (AID re-synchronises v̂ = v after one, Theorem 4.3.1's t₀)
        dt_est = dt if est_t_ns is None else (inputs.t_ns - est_t_ns) * 1e-9
        est = tuple(e.step(vs, u_applied, e.params, s, dt_est)
                    for e, s in zip(cfg.estimators, state.est, strict=True))
        est_t_ns = inputs.t_ns

    status = "ok"
    ctrl = state.ctrl
    u = np.zeros(6)
    if not inputs.armed:
        status = "disarmed"
    elif not nav_ok:
        status = "nav-invalid"
    else:
        u_new, ctrl_new = cfg.controller.step(vs, ref, cfg.controller.params, state.ctrl, dt)
        if ref.open_loop_wrench is not None:
            u_new = u_new + ref.open_loop_wrench
        if _finite(u_new):
            u, ctrl = u_new, ctrl_new
        else:
            status = "non-finite"

    thrust, saturated, _scale = allocate(cfg.allocator, u)
    if not _finite(thrust):
        thrust = np.zeros_like(thrust)
        saturated = np.zeros(thrust.shape, dtype=bool)
        status = "non-finite"
    u_cmd = cfg.allocator.B @ thrust
    out = CoreOutputs(thrust_n=thrust, u_cmd=u_cmd, u_applied=u_applied, nav=nav,
                      reference=ref, saturated=saturated, status=status)
    new_state = CoreState(nav=nav_mem, ctrl=ctrl, est=est, t0_ns=t0, est_t_ns=est_t_ns,
                          cycles=state.cycles + 1, u_last=u_cmd)
    return out, new_state
