"""The daemon's lifecycle: BOOT → STANDBY → ARMED → FAILSAFE → SHUTDOWN. Pure.

========  =================================================================================
state     meaning
========  =================================================================================
BOOT      drivers starting; no command is sent
STANDBY   disarmed: sensors and estimators run (AID identifies whoever drives the vehicle),
          thrust is zero
ARMED     closed-loop control (possibly degraded: WARN / FALLBACK failsafes keep ARMED)
FAILSAFE  armed, but a failsafe of HOLD_DEPTH or ZERO_THRUST overrides control
SHUTDOWN  terminal: the shutdown sequence runs
========  =================================================================================

Transitions (each returns :class:`Transition` records with their cause; requests that are not
allowed return a ``refused`` reason instead and change nothing):

* BOOT → STANDBY: :meth:`Lifecycle.boot_complete` (drivers up).
* STANDBY → ARMED: :meth:`Lifecycle.request_arm` with the results of the arming checks
  (:func:`run_checks`); refused, naming every failed check, unless all pass.
* ARMED → FAILSAFE when the arbiter's action is HOLD_DEPTH or ZERO_THRUST; FAILSAFE → ARMED
  when it drops below HOLD_DEPTH (the triggers cleared or were reset);
  ARMED/FAILSAFE → STANDBY on DISARM (via FAILSAFE) — re-arming runs the checks again
  (:meth:`Lifecycle.on_failsafe`).
* ARMED/FAILSAFE → STANDBY: :meth:`Lifecycle.request_disarm` (operator).
* any → SHUTDOWN: :meth:`Lifecycle.request_shutdown`.

Arming checks are data (:class:`ArmingCheck`): a name and a function of the failsafe
:class:`~uvd.runtime.failsafe.Health` snapshot and the current
:class:`~uvd.runtime.failsafe.Decision` returning ``(ok, reason)``. :func:`builtin_checks`
gives INS valid, depth valid, amplifiers enabled and fault-free, parameters valid (M̂
positive definite, θ̂ in bounds) and no failsafe at HOLD_DEPTH or above.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from uvd.runtime.failsafe import Action, Decision, Health, Thresholds

__all__ = ["State", "Transition", "CheckResult", "ArmingCheck", "Lifecycle", "LifecycleStep",
           "builtin_checks", "run_checks"]


class State(StrEnum):
    BOOT = "BOOT"
    STANDBY = "STANDBY"
    ARMED = "ARMED"
    FAILSAFE = "FAILSAFE"
    SHUTDOWN = "SHUTDOWN"


@dataclass(frozen=True, slots=True)
class Transition:
    """One state change and why it happened."""

    t_ns: int
    source: State
    target: State
    event: str
    cause: str

    def __str__(self) -> str:
        return f"{self.source.value} → {self.target.value} ({self.event}: {self.cause})"

    def as_dict(self) -> dict:
        return {"t_ns": self.t_ns, "from": self.source.value, "to": self.target.value,
                "event": self.event, "cause": self.cause}


@dataclass(frozen=True, slots=True)
class CheckResult:
    name: str
    ok: bool
    reason: str


@dataclass(frozen=True)
class ArmingCheck:
    """An arming precondition: ``fn(health, decision) -> (ok, reason)``."""

    name: str
    fn: Callable[[Health, Decision | None], tuple[bool, str]]
    doc: str = ""


def run_checks(checks: Sequence[ArmingCheck], health: Health,
               decision: Decision | None = None) -> tuple[CheckResult, ...]:
    """Evaluate every check; a check that raises fails with the exception as its reason."""
    out = []
    for c in checks:
        try:
            ok, reason = c.fn(health, decision)
        except Exception as exc:  # a broken check refuses arming, it does not crash
            ok, reason = False, f"check could not be evaluated ({type(exc).__name__}: {exc})"
        out.append(CheckResult(c.name, bool(ok), str(reason)))
    return tuple(out)


def builtin_checks(th: Thresholds) -> tuple[ArmingCheck, ...]:
    """INS valid, depth valid, amplifiers ready, parameters valid, no failsafe ≥ HOLD_DEPTH
    and no trigger waiting for its source's first sample."""

    def ins_valid(h: Health, d: Decision | None) -> tuple[bool, str]:
        ok = h.ins_age_s <= th.ins_stale_s
        return ok, (f"INS age {h.ins_age_s:.3g} s" if ok else
                    f"INS not valid: age {h.ins_age_s:.3g} s > {th.ins_stale_s:g} s")

    def depth_valid(h: Health, d: Decision | None) -> tuple[bool, str]:
        ok = h.depth_age_s <= th.depth_stale_s and math.isfinite(h.depth_m)
        return ok, (f"depth {h.depth_m:.3f} m, age {h.depth_age_s:.3g} s" if ok else
                    f"depth not valid: age {h.depth_age_s:.3g} s (limit {th.depth_stale_s:g} "
                    f"s), value {h.depth_m}")

    def amplifiers_ready(h: Health, d: Decision | None) -> tuple[bool, str]:
        if h.bus_off:
            return False, "CAN bus-off"
        if h.amplifier_faults:
            return False, "amplifier fault: " + "; ".join(h.amplifier_faults)
        if not h.amplifiers_enabled:
            return False, "amplifiers not enabled (not every node in operation enabled)"
        if h.feedback_age_s is not None and not (h.feedback_age_s <= th.feedback_stale_s):
            return False, f"amplifier feedback age {h.feedback_age_s:.3g} s"
        return True, "every amplifier enabled, no fault"

    def parameters_valid(h: Health, d: Decision | None) -> tuple[bool, str]:
        e = h.m_hat_min_eig
        if e is not None and not (e > th.m_hat_min_eig):
            return False, f"M̂ not positive definite (smallest eigenvalue {e:.3g})"
        if h.theta_hat is not None:
            a = np.abs(np.asarray(h.theta_hat, dtype=float))
            if a.size and not (float(a.max()) <= th.theta_abs_max):
                return False, f"θ̂ out of bounds or not finite (max |θ̂ᵢ| = {float(a.max()):.3g})"
        return True, ("M̂ positive definite" if e is not None else
                      "no estimate running (nominal parameters)")

    def failsafe_clear(h: Health, d: Decision | None) -> tuple[bool, str]:
        if d is not None and d.action >= Action.HOLD_DEPTH:
            latched = [a.name for a in d.active if a.latched and a.action >= Action.HOLD_DEPTH]
            hint = f" ({', '.join(latched)} latched: reset it once its cause is gone, " \
                "uvd reset-failsafe or MAVLink command 31011)" if latched else ""
            return False, f"failsafe {d.action.label} active: {d.causes}{hint}"
        if d is not None and d.waiting:  # a source never heard from would fire once armed
            return False, f"waiting for a first sample: {', '.join(d.waiting)}"
        return True, "no failsafe at hold-depth or above, no source waited for"

    return (ArmingCheck("ins_valid", ins_valid, "INS sample fresh"),
            ArmingCheck("depth_valid", depth_valid, "depth sample fresh and finite"),
            ArmingCheck("amplifiers_ready", amplifiers_ready,
                        "amplifiers enabled, fault-free, feedback fresh, bus not off"),
            ArmingCheck("parameters_valid", parameters_valid,
                        "M̂ positive definite, θ̂ within bounds"),
            ArmingCheck("failsafe_clear", failsafe_clear,
                        "no failsafe ≥ hold-depth, no source not yet heard from"))


@dataclass(frozen=True, slots=True)
class LifecycleStep:
    """Result of a request: the new lifecycle, what changed, or why nothing did."""

    lifecycle: Lifecycle
    transitions: tuple[Transition, ...] = ()
    refused: str | None = None

    @property
    def ok(self) -> bool:
        return self.refused is None


@dataclass(frozen=True, slots=True)
class Lifecycle:
    """Current state and since when (monotonic ns). Immutable; requests return a new one."""

    state: State = State.BOOT
    since_ns: int = 0

    @property
    def armed(self) -> bool:
        """Commands may reach the amplifiers (ARMED or FAILSAFE; the failsafe shapes them)."""
        return self.state in (State.ARMED, State.FAILSAFE)

    def _go(self, t_ns: int, target: State, event: str, cause: str,
            prior: tuple[Transition, ...] = ()) -> LifecycleStep:
        tr = Transition(t_ns, self.state, target, event, cause)
        return LifecycleStep(Lifecycle(target, t_ns), prior + (tr,))

    def _refuse(self, reason: str) -> LifecycleStep:
        return LifecycleStep(self, (), reason)

    def boot_complete(self, t_ns: int, cause: str = "drivers up") -> LifecycleStep:
        if self.state is not State.BOOT:
            return self._refuse(f"boot already complete (state {self.state.value})")
        return self._go(t_ns, State.STANDBY, "boot-complete", cause)

    def request_arm(self, t_ns: int, results: Sequence[CheckResult],
                    cause: str = "operator request") -> LifecycleStep:
        if self.state is not State.STANDBY:
            return self._refuse(f"cannot arm from {self.state.value} (only from STANDBY)")
        failed = [r for r in results if not r.ok]
        if not results:
            return self._refuse("arming refused: no arming check was run")
        if failed:
            return self._refuse("arming refused: " +
                                "; ".join(f"{r.name}: {r.reason}" for r in failed))
        return self._go(t_ns, State.ARMED, "arm",
                        f"{cause}; checks passed: {', '.join(r.name for r in results)}")

    def request_disarm(self, t_ns: int, cause: str = "operator request") -> LifecycleStep:
        if self.state in (State.ARMED, State.FAILSAFE):
            return self._go(t_ns, State.STANDBY, "disarm", cause)
        if self.state is State.STANDBY:
            return LifecycleStep(self)
        return self._refuse(f"cannot disarm in {self.state.value}")

    def on_failsafe(self, t_ns: int, decision: Decision) -> LifecycleStep:
        """Follow the arbiter: enter/leave FAILSAFE, or disarm. No-op when not armed."""
        a = decision.action
        s = self.state
        if s not in (State.ARMED, State.FAILSAFE):
            return LifecycleStep(self)
        if a >= Action.DISARM:
            cause = f"{a.label}: {decision.causes}"
            if s is State.ARMED:
                first = self._go(t_ns, State.FAILSAFE, "failsafe", cause)
                return first.lifecycle._go(t_ns, State.STANDBY, "failsafe-disarm", cause,
                                           first.transitions)
            return self._go(t_ns, State.STANDBY, "failsafe-disarm", cause)
        if a >= Action.HOLD_DEPTH:
            if s is State.ARMED:
                return self._go(t_ns, State.FAILSAFE, "failsafe", f"{a.label}: {decision.causes}")
            return LifecycleStep(self)
        if s is State.FAILSAFE:
            return self._go(t_ns, State.ARMED, "failsafe-cleared",
                            f"failsafe action now {a.label}")
        return LifecycleStep(self)

    def request_shutdown(self, t_ns: int, cause: str) -> LifecycleStep:
        if self.state is State.SHUTDOWN:
            return LifecycleStep(self)
        return self._go(t_ns, State.SHUTDOWN, "shutdown", cause)

    def status_text(self, decision: Decision | None = None) -> str:
        """One line for systemd's STATUS=."""
        if decision is not None and decision.action > Action.NONE:
            return f"{self.state.value} ({decision.action.label}: {decision.causes})"[:200]
        return self.state.value
