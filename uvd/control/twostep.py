"""Two-step AMBC (§5.2.6, experiment §5.3.5).

Step 1 adapts only the gravity/buoyancy parameters g and b, with the inertial and drag terms
taken as zero — the quasi-static model 0 = G(H) + u of (5.37) — while the vehicle tracks a slow
pitch/roll trajectory (:func:`uvd.control.trajectory.quasi_static`). Step 2 fixes g and b at
their step-1 values and adapts M and D, from zero, while tracking any trajectory (RefTraj1 in
the thesis). Both steps are the AMBC of Theorem 5.2.2 with a diagonal K_θ whose entries are zero
for the parameters held fixed (§5.2.6): step 1 has K = diag(0, …, 0, γ_g, γ_b), step 2 has
K = diag(γ_m, γ_d, 0, 0, 0, 0).

:func:`two_step_step` is one controller that runs step 1 for ``step1_duration_s`` seconds of
control and then switches to step 2 on its own (θ̂'s g and b frozen, M and D reset to the
step-2 initial values); :func:`two_step_reference` is the matching reference (quasi-static,
then the step-2 trajectory after a smooth blend).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from uvd.control.ambc import (
    AMBCParams,
    AMBCState,
    RobustAdaptation,
    adaptation_gains,
    ambc_hold_dofs,
    ambc_init,
    ambc_params,
    ambc_step,
    ambc_with_allocation,
    gravity_index,
    m_hat_min_eig,
)
from uvd.control.trajectory import (
    DEFAULT_CENTER,
    CosineTrajectory,
    SequenceTrajectory,
    quasi_static,
    reftraj1,
)
from uvd.control.types import ControllerSpec, Diagnostics, Reference, VehicleState

STEP1_DURATION_S = 90 * 60.0
"""Step 1 lasts 90 minutes in §5.3.5."""

STEP2_DURATION_S = 4.5 * 3600.0
"""Step 2 lasts four and a half hours in §5.3.5."""


@dataclass(frozen=True)
class TwoStepParams:
    """Constant configuration of :func:`two_step_step`.

    Attributes
    ----------
    step1, step2 : :class:`AMBCParams` of each step (same model); their K must be zero on the
        parameters the step holds fixed (use :func:`two_step_params`).
    theta0 : θ̂ at the start of step 1 (M, D zero as (5.37) assumes; g, b an initial guess).
    step2_theta0 : θ̂ at the start of step 2 except g and b, which come from step 1
        (default: θ0, i.e. zero mass and drag as in §5.3.5).
    step1_duration_s : length of step 1 in seconds of control.
    """

    step1: AMBCParams
    step2: AMBCParams
    theta0: np.ndarray
    step2_theta0: np.ndarray | None = None
    step1_duration_s: float = STEP1_DURATION_S

    def __post_init__(self) -> None:
        if self.step1.model != self.step2.model:
            raise ValueError("step 1 and step 2 must use the same model")
        n = self.step1.n
        th = np.asarray(self.theta0, dtype=float).reshape(-1)
        if th.shape != (n,):
            raise ValueError(f"theta0 must have {n} entries")
        object.__setattr__(self, "theta0", th)
        if self.step2_theta0 is not None:
            th2 = np.asarray(self.step2_theta0, dtype=float).reshape(-1)
            if th2.shape != (n,):
                raise ValueError(f"step2_theta0 must have {n} entries")
            object.__setattr__(self, "step2_theta0", th2)


@dataclass(frozen=True, slots=True)
class TwoStepState:
    """phase 1 or 2; ``ambc`` the inner AMBC state; ``gb_step1`` the g, b handed to step 2."""

    phase: int
    ambc: AMBCState
    t: float = 0.0
    gb_step1: np.ndarray | None = None
    switched_at_s: float | None = None


def two_step_init(params: TwoStepParams) -> TwoStepState:
    return TwoStepState(phase=1, ambc=ambc_init(params.step1, params.theta0))


def _enter_step2(params: TwoStepParams, ctrl: TwoStepState) -> TwoStepState:
    gi = gravity_index(params.step1.model)
    gb = ctrl.ambc.theta[gi].copy()
    base = params.step2_theta0 if params.step2_theta0 is not None else params.theta0
    theta = np.array(base, dtype=float)
    theta[gi] = gb
    inner = ambc_init(params.step2, theta)
    inner = replace(inner, t=ctrl.ambc.t)
    return TwoStepState(phase=2, ambc=inner, t=ctrl.t, gb_step1=gb, switched_at_s=ctrl.t)


def two_step_step(state: VehicleState, reference: Reference, params: TwoStepParams,
                  ctrl: TwoStepState, dt: float) -> tuple[np.ndarray, TwoStepState]:
    """One cycle of two-step AMBC: the AMBC of the current step, switching to step 2 once
    ``step1_duration_s`` seconds of control have passed."""
    if ctrl.phase == 1 and ctrl.t >= params.step1_duration_s - 1e-9:
        ctrl = _enter_step2(params, ctrl)
    step = params.step1 if ctrl.phase == 1 else params.step2
    u, inner = ambc_step(state, reference, step, ctrl.ambc, dt)
    return u, TwoStepState(phase=ctrl.phase, ambc=inner, t=ctrl.t + dt, gb_step1=ctrl.gb_step1,
                           switched_at_s=ctrl.switched_at_s)


def two_step_params(model: str = "decoupled", *, kp: float | np.ndarray = 300.0,
                    kd: float | np.ndarray = 100.0,
                    eps: float = 0.1, kd1: float | None = None, kd2: float | None = None,
                    eps1: float | None = None, eps2: float | None = None,
                    gamma_m: float | np.ndarray = 1000.0, gamma_d: float | np.ndarray = 5000.0,
                    gamma_g: float = 0.5, gamma_b=(0.5, 0.5, 10.0),
                    theta0: np.ndarray | None = None, step2_theta0: np.ndarray | None = None,
                    step1_duration_s: float = STEP1_DURATION_S,
                    robust: RobustAdaptation | None = None, allocator=None) -> TwoStepParams:
    """Two-step AMBC with the thesis's gains (§5.3.5): k_p = 300, γ_g = γ_b1 = γ_b2 = 0.5,
    γ_b3 = 10 in step 1; γ_mi = 1000, γ_di = 5000 in step 2. θ̂ starts at zero (or ``theta0``).

    ``kd``/``eps`` apply to both steps unless ``kd1``/``eps1`` (step 1) or ``kd2``/``eps2``
    (step 2) say otherwise — the thesis ran the steps as two trials, with k_d = 100 in step 1
    and (in the text) k_d = 1000 in step 2.
    """
    K = adaptation_gains(model, gamma_m=gamma_m, gamma_d=gamma_d, gamma_g=gamma_g,
                         gamma_b=gamma_b)
    gi = gravity_index(model)
    K1 = np.zeros_like(K)
    K1[gi] = K[gi]
    K2 = K.copy()
    K2[gi] = 0.0
    common = {"kp": kp, "robust": robust, "allocator": allocator}
    p1 = ambc_params(model, K=K1, kd=kd if kd1 is None else kd1,
                     eps=eps if eps1 is None else eps1, **common)
    p2 = ambc_params(model, K=K2, kd=kd if kd2 is None else kd2,
                     eps=eps if eps2 is None else eps2, **common)
    th0 = np.zeros(p1.n) if theta0 is None else theta0
    return TwoStepParams(step1=p1, step2=p2, theta0=th0, step2_theta0=step2_theta0,
                         step1_duration_s=step1_duration_s)


def two_step_reference(step2: CosineTrajectory | None = None, *,
                       step1_duration_s: float = STEP1_DURATION_S, blend_s: float = 60.0,
                       center=DEFAULT_CENTER) -> SequenceTrajectory:
    """Quasi-static pitch/roll for ``step1_duration_s`` (:func:`quasi_static`), then ``step2``
    (RefTraj1 by default) after a ``blend_s`` smooth transition."""
    step2 = reftraj1(center) if step2 is None else step2
    return SequenceTrajectory(segments=((step1_duration_s, quasi_static(center)),
                                        (float("inf"), step2)),
                              blend_s=blend_s, name=f"two-step ({step2.name})")


def two_step_diagnostics(ctrl: TwoStepState) -> Diagnostics:
    """The diagnostics hook of two-step AMBC's spec: the inner AMBC's, with the phase; step 1
    holds M̂ = 0 by design (the quasi-static model (5.37)), so no M̂ eigenvalue there."""
    theta = np.array(ctrl.ambc.theta, dtype=float)
    m = m_hat_min_eig(theta) if ctrl.phase == 2 else None
    return Diagnostics(theta=theta, m_min_eig=m, frozen=bool(ctrl.ambc.frozen), phase=ctrl.phase)


def two_step_spec(params: TwoStepParams, name: str = "two-step-ambc") -> ControllerSpec:
    """Two-step AMBC (§5.2.6) as the core runs it."""
    return ControllerSpec(name, two_step_step, params, two_step_init(params),
                          two_step_diagnostics, two_step_hold_dofs, two_step_with_allocation)


def two_step_with_allocation(params: TwoStepParams, B_pinv) -> TwoStepParams:
    """``with_allocation`` of two-step AMBC: both steps' (:func:`ambc_with_allocation`)."""
    return replace(params, step1=ambc_with_allocation(params.step1, B_pinv),
                   step2=ambc_with_allocation(params.step2, B_pinv))


def two_step_hold_dofs(new: TwoStepState, old: TwoStepState, actuated) -> TwoStepState:
    """``hold_dofs`` of two-step AMBC: its inner AMBC's (:func:`ambc_hold_dofs`); across the
    switch to step 2 (a new θ̂) nothing is held."""
    if new.phase != old.phase:
        return new
    inner = ambc_hold_dofs(new.ambc, old.ambc, actuated)
    return new if inner is new.ambc else replace(new, ambc=inner)
