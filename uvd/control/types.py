"""Small value types shared by controllers, estimators and the core."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np


@dataclass(frozen=True, slots=True)
class VehicleState:
    """Actual state: pose ʷₐH (4×4, body→world) and body velocity ᵃvₐ = [ν; ω] (5.1)."""

    H: np.ndarray
    v: np.ndarray


@dataclass(frozen=True, slots=True)
class Reference:
    """Desired state {ʷ_dH, ᵈv_d, ᵈv̇_d} (§5.2.4.1), velocities in the desired body frame.

    ``open_loop_wrench`` is added to the controller's output for DOFs driven open loop
    (RefTraj2's roll and pitch torques, Table 5.1); ``closed_loop`` masks which DOFs the
    controller acts on (all six by default). ``preview`` is the desired state δ seconds later,
    set by the core only when the feed-forward preview is on (``CoreConfig.ff_preview_s``);
    the model-based controllers then evaluate their feed-forward on it
    (:func:`uvd.control.ambc.ambc_step`).
    """

    H: np.ndarray
    v: np.ndarray
    vdot: np.ndarray
    open_loop_wrench: np.ndarray | None = None
    closed_loop: np.ndarray | None = None
    preview: Reference | None = None


class Diagnostics(NamedTuple):
    """What a controller's or an estimator's state says about its health — the one hook
    (``ControllerSpec.diagnostics``, ``EstimatorSpec.diagnostics``) through which the cycle,
    the failsafe arbiter and telemetry read it. ``None``: not applicable. Immutable (a named
    tuple: the cycle reads the controller's every cycle, and a frozen dataclass of eleven
    fields costs ~2 µs more to build).

    Attributes
    ----------
    theta : ndarray or None
        θ̂ (the controller's model parameters, or the estimator's θ_UV of (2.48)).
    m_min_eig, m_max_eig : float or None
        Extreme eigenvalues of M̂ (None where M̂ is not adapted, e.g. step 1 of two-step AMBC,
        whose quasi-static model (5.37) holds M̂ = 0).
    frozen : bool
        An estimator's adaptation stopped for good (AID: M̂ would have lost positive
        definiteness); ``freeze_reason`` says why. An adaptive controller's: its last update
        was skipped (AMBC: saturation, the reversal hold, the dead zone), no reason given.
    phase : int or None
        Two-step AMBC's step (1 or 2).
    steps, skipped, resyncs : int or None
        Estimator counters (adaptation steps, ignored calls, v̂ re-synchronisations).
    velocity_error : float or None
        ‖v̂ − v‖ of an observer-based estimator (AID's (4.23)).
    hold_reason : str
        The DOFs whose parameters are held while the others adapt, and why ("" : none).
    """

    theta: np.ndarray | None = None
    m_min_eig: float | None = None
    m_max_eig: float | None = None
    frozen: bool = False
    freeze_reason: str = ""
    phase: int | None = None
    steps: int | None = None
    skipped: int | None = None
    resyncs: int | None = None
    velocity_error: float | None = None
    hold_reason: str = ""


NO_DIAGNOSTICS = Diagnostics()


def no_diagnostics(state) -> Diagnostics:
    """The diagnostics of a memoryless controller (PDC): nothing to report."""
    return NO_DIAGNOSTICS


@dataclass(frozen=True)
class ControllerSpec:
    """A controller as the core runs it: ``step(VehicleState, Reference, params, state, dt)
    -> (u, state)``, its constant ``params``, its initial state, its ``diagnostics(state)``
    hook and, for an adaptive one, ``hold_dofs(new, old, actuated) -> state``: the new state
    with the parameters of the DOFs not ``actuated`` ((6,) bool) kept at the old state's
    (the core calls it when a thruster's effectiveness leaves DOFs unreached; None: nothing
    adapts) and, for one that watches the thrusters (AMBC's freeze on saturation),
    ``with_allocation(params, B_pinv) -> params``: its params for the allocation the core uses
    while a thruster's effectiveness is set (None: the controller does not look at it)."""

    name: str
    step: Callable[..., tuple[np.ndarray, Any]]
    params: Any
    init_state: Any
    diagnostics: Callable[[Any], Diagnostics] = no_diagnostics
    hold_dofs: Callable[[Any, Any, np.ndarray], Any] | None = None
    with_allocation: Callable[[Any, np.ndarray], Any] | None = None


@dataclass(frozen=True)
class EstimatorSpec:
    """An estimator as the core runs it: ``step(VehicleState, u_applied, params, state, dt)
    -> state``, with its ``diagnostics(state)`` hook and, when it adapts per DOF,
    ``hold_dofs(new, old, actuated) -> state``: the new state with the parameters of the DOFs
    not ``actuated`` ((6,) bool; None: every DOF, the healthy path) kept at the old state's
    and the reason in its diagnostics' ``hold_reason`` (the core calls it after every step;
    None: nothing held)."""

    name: str
    step: Callable[..., Any]
    params: Any
    init_state: Any
    diagnostics: Callable[[Any], Diagnostics] = no_diagnostics
    hold_dofs: Callable[[Any, Any, np.ndarray], Any] | None = None
