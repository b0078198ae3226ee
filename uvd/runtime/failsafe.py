"""The failsafe arbiter: health signals in, the most severe required action out. Pure.

Every cycle the application fills a :class:`Health` snapshot (ages, flags, counters — plain
values any subsystem can produce) and calls :func:`evaluate` with the trigger registry, the
thresholds and the arbiter's previous :class:`ArbiterState`. It returns a :class:`Decision`
(the action to apply, the active triggers, the events of this cycle) and the next state.
Nothing here reads a clock, logs or raises for bad data; logging of the returned events happens
at the edge.

Actions are ordered; the most severe active one wins, and a more severe action implies the
milder ones (holding depth also freezes adaptation):

=====  ==================  ===============================================================
level  action              what the application does
=====  ==================  ===============================================================
0      ``NONE``            normal operation
1      ``WARN``            report only
2      ``FALLBACK``        freeze adaptation (θ̂ held) and control with PDC
3      ``HOLD_DEPTH``      zero horizontal thrust (surge, sway, yaw); hold depth
4      ``ZERO_THRUST``     command zero thrust to every amplifier (still armed)
5      ``DISARM``          zero thrust and leave ARMED (re-arming runs the arming checks)
=====  ==================  ===============================================================

Triggers are data: a :class:`TriggerDef` names a condition ``(health, thresholds, memory) ->
(reason or None, memory)``, its action and its rule. **Clear rule**: a non-latching trigger
clears once its condition has been false for ``Thresholds.clear_after_s`` (hysteresis, so a
flickering signal does not chatter). **Latch rule**: a latching trigger stays active until
:func:`reset` (an operator command) is called *and* its condition is false. Conditions are
evaluated every cycle, so a trigger fires within its threshold plus one cycle.

Built-in triggers (:func:`builtin_triggers`; thresholds in :class:`Thresholds`, the
``[failsafe]`` configuration section):

======================  ==========================================  ============  ========
trigger                 condition                                   action        rule
======================  ==========================================  ============  ========
ins_stale               INS sample older than ``ins_stale_s``       ZERO_THRUST   clear
ins_rates_degraded      ω derived from attitude, not measured       WARN          clear
dvl_stale               DVL sample older than ``dvl_stale_s``       HOLD_DEPTH    clear
dvl_bottom_lock_lost    no bottom lock for ``dvl_lock_lost_s``      HOLD_DEPTH    clear
depth_stale             depth older than ``depth_stale_s``          ZERO_THRUST   clear
depth_stuck             depth value unchanged ``depth_stuck_s``     ZERO_THRUST   latch
nonfinite_input         NaN/inf in a sensor input                   ZERO_THRUST   clear
nonfinite_output        NaN/inf in a command or estimate            ZERO_THRUST   latch
parameter_divergence    M̂ not PD or θ̂ out of bounds / not finite    FALLBACK      latch
amplifier_fault         an amplifier reports a fault (below)        DISARM        latch
feedback_missing        amplifier feedback older than threshold     ZERO_THRUST   clear
bus_off                 CAN bus-off                                 DISARM        latch
loop_overrun_streak     overrun streak reached ``[loop]`` limit     ZERO_THRUST   clear
cycle_exception         the cycle callback raised                   ZERO_THRUST   latch
leak                    leak input asserted                         DISARM        latch
======================  ==========================================  ============  ========

**An amplifier's fault as a source of η.** With ``amplifier_fault = "reallocate"`` a faulted
amplifier's thruster gets effectiveness η = 0 inside the cycle
(:func:`uvd.runtime.cycle.amplifier_source`) when the rest still reach heave, roll, pitch
and yaw; its faults and feedback age then never reach this arbiter. Otherwise — and always
under the default ``"disarm"`` — the table's rows apply.

**Not yet available.** A navigation source that has never delivered a sample (age ``inf``:
the INS, DVL or depth sensor still starting after boot) is not a failure while the vehicle is
disarmed: its stale trigger (and the DVL's bottom-lock trigger) returns a :class:`NotYet`
reason, which :func:`evaluate` turns into a name in :attr:`Decision.waiting` instead of an
event while ``Health.armed`` is false — and arming is refused while anything waits
(:func:`uvd.runtime.lifecycle.builtin_checks`, ``failsafe_clear``). Armed, the same reason
fires as any other; a source heard once and then silent is stale, armed or not.

A new trigger is one more :class:`TriggerDef` in the registry (the ground-station link adds
operator-heartbeat loss this way, reading ``health.extra["operator_heartbeat_age_s"]``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Literal

import numpy as np

from uvd.runtime.schema import setting

__all__ = ["Action", "Health", "NotYet", "Thresholds", "TriggerDef", "TriggerState", "ArbiterState",
           "ActiveTrigger", "FailsafeEvent", "Decision", "builtin_triggers", "evaluate",
           "reset", "arbiter_init", "make_registry", "nonfinite_names", "nav_health",
           "nav_health_values", "NAV_HEALTH_FIELDS"]

_INF = float("inf")


class Action(IntEnum):
    """Failsafe actions, ordered by severity."""

    NONE = 0
    WARN = 1
    FALLBACK = 2
    HOLD_DEPTH = 3
    ZERO_THRUST = 4
    DISARM = 5

    @property
    def label(self) -> str:
        return self.name.lower().replace("_", "-")


@dataclass(slots=True)
class Health:
    """Health signals of one cycle; the defaults mean "nothing known", which is not healthy.

    Treat it as immutable once handed to the arbiter (it is a plain, non-frozen dataclass only
    because building one every cycle must be cheap).

    Ages are seconds since the latest usable sample (``inf`` before the first one). Optional
    signals (``None``) belong to subsystems that are not fitted and never trigger.

    Attributes
    ----------
    t_ns : int
        Monotonic time of the cycle.
    ins_age_s, dvl_age_s, depth_age_s : float
        Ages of the navigation sources (as :class:`uvd.estimation.navigation.NavState`).
    rates_degraded : bool
        INS rates derived from attitude.
    bottom_lock : bool
        The latest DVL sample had bottom lock.
    depth_m : float
        Latest raw depth value (for stuck detection), NaN when none.
    nonfinite_inputs, nonfinite_outputs : tuple of str
        Names of inputs / outputs holding NaN or inf this cycle.
    m_hat_min_eig : float or None
        Smallest eigenvalue of the estimated mass matrix M̂ (None: no estimate running).
    theta_hat : ndarray or None
        Current parameter estimate θ̂ (None: no estimate running).
    amplifiers_enabled : bool
        Every amplifier is in "operation enabled" (arming check).
    amplifier_faults : tuple of str
        Named faults currently reported ("thruster 3: over-current").
    feedback_age_s : float or None
        Age of the oldest amplifier's latest feedback; None when no amplifiers are fitted.
    bus_off : bool
        The CAN controller is bus-off.
    overrun_streak : int
        Current streak of overrunning cycles.
    overrun_streak_exceeded : bool
        The streak reached the ``[loop] overrun_streak`` limit.
    cycle_failed : bool
        The cycle callback raised during the last cycle.
    leak : bool or None
        Leak input asserted; None when no leak sensor is configured.
    extra : mapping or None
        Signals of plug-in triggers (e.g. ``operator_heartbeat_age_s``).
    armed : bool
        The lifecycle is ARMED or FAILSAFE as the cycle starts; while false, a source never
        heard from is waited for rather than a failsafe (module docstring). The default is the
        strict reading.
    """

    t_ns: int = 0
    ins_age_s: float = _INF
    dvl_age_s: float = _INF
    depth_age_s: float = _INF
    rates_degraded: bool = False
    bottom_lock: bool = False
    depth_m: float = float("nan")
    nonfinite_inputs: tuple[str, ...] = ()
    nonfinite_outputs: tuple[str, ...] = ()
    m_hat_min_eig: float | None = None
    theta_hat: np.ndarray | None = None
    amplifiers_enabled: bool = False
    amplifier_faults: tuple[str, ...] = ()
    feedback_age_s: float | None = _INF
    bus_off: bool = False
    overrun_streak: int = 0
    overrun_streak_exceeded: bool = False
    cycle_failed: bool = False
    leak: bool | None = None
    extra: Mapping[str, Any] | None = None
    armed: bool = True


BUILTIN_NAMES = ("ins_stale", "ins_rates_degraded", "dvl_stale", "dvl_bottom_lock_lost",
                 "depth_stale", "depth_stuck", "nonfinite_input", "nonfinite_output",
                 "parameter_divergence", "amplifier_fault", "feedback_missing", "bus_off",
                 "loop_overrun_streak", "cycle_exception", "leak")


@dataclass(frozen=True)
class Thresholds:
    """Failsafe thresholds (``[failsafe]``); every trigger is described in docs/runtime.md."""

    ins_stale_s: float = setting(0.1, unit="s", gt=0.0, max=60.0, reload=True,
                                 doc="INS sample age that trips ins_stale (zero thrust)")
    dvl_stale_s: float = setting(1.0, unit="s", gt=0.0, max=60.0, reload=True,
                                 doc="DVL sample age that trips dvl_stale (hold depth)")
    dvl_lock_lost_s: float = setting(
        0.0, unit="s", min=0.0, max=60.0, reload=True,
        doc="how long bottom lock may be lost before dvl_bottom_lock_lost (hold depth); "
            "0 = at once")
    depth_stale_s: float = setting(0.5, unit="s", gt=0.0, max=60.0, reload=True,
                                   doc="depth sample age that trips depth_stale (zero thrust)")
    depth_stuck_s: float = setting(
        2.0, unit="s", gt=0.0, max=3600.0, reload=True,
        doc="time the depth value may stay exactly unchanged before depth_stuck (zero "
            "thrust, latched)")
    feedback_stale_s: float = setting(
        0.5, unit="s", gt=0.0, max=60.0, reload=True,
        doc="amplifier feedback age that trips feedback_missing (zero thrust)")
    m_hat_min_eig: float = setting(
        1e-6, unit="kg", min=0.0, reload=True,
        doc="smallest eigenvalue M̂ must keep (positive definite) before parameter_divergence "
            "(freeze adaptation, PDC)")
    theta_abs_max: float = setting(
        1e6, unit="SI", gt=0.0, reload=True,
        doc="bound on every |θ̂ᵢ| before parameter_divergence")
    clear_after_s: float = setting(
        1.0, unit="s", min=0.0, max=600.0, reload=True,
        doc="a non-latching trigger clears once its condition has been false this long")
    amplifier_fault: Literal["disarm", "reallocate"] = setting(
        "disarm", reload=True,
        doc="what an amplifier's own fault (EMCY, FAULT, heartbeat or feedback lost) does: "
            "disarm (the default: the fault may have a cause the other amplifiers share — "
            "supply, water, a fouled propeller — and a disarmed, positively buoyant vehicle "
            "surfaces), or reallocate: that thruster's eta 0 through the cycle "
            "(uvd.runtime.cycle.amplifier_source) while heave, roll, pitch and yaw stay "
            "actuated, else disarm")
    disabled: tuple[str, ...] = setting(
        (), reload=True,
        doc="names of built-in triggers to switch off (e.g. dvl_bottom_lock_lost in a "
            "tank); every name must exist")

    def _check(self, ctx) -> list[tuple[str, str]]:
        bad = [n for n in self.disabled if n not in BUILTIN_NAMES]
        if bad:
            return [("disabled", f"unknown trigger(s) {', '.join(map(repr, bad))}; known: "
                                 f"{', '.join(BUILTIN_NAMES)}")]
        return []


Condition = Callable[[Health, Thresholds, Any], tuple[str | None, Any]]


class NotYet(str):
    """A condition's reason that holds only because the source has never been heard from:
    it fires while armed; while disarmed the trigger waits (:attr:`Decision.waiting`)."""

    __slots__ = ()


@dataclass(frozen=True)
class TriggerDef:
    """One failsafe trigger.

    Attributes
    ----------
    name : str
        Unique name (used in events, config ``disabled`` lists and operator resets).
    action : Action
        What the application must do while it is active.
    condition : callable
        ``(health, thresholds, memory) -> (reason or None, memory)``; a non-None reason means
        the condition holds. ``memory`` is the trigger's own state (None initially).
    latch : bool
        Stays active until :func:`reset` once fired.
    doc : str
        One line for the documentation.
    """

    name: str
    action: Action
    condition: Condition
    latch: bool = False
    doc: str = ""


@dataclass(frozen=True, slots=True)
class TriggerState:
    """Arbiter memory of one trigger."""

    active: bool = False
    since_ns: int = 0
    reason: str = ""
    false_since_ns: int | None = None
    memory: Any = None


@dataclass(frozen=True, slots=True)
class ArbiterState:
    """Arbiter memory: one :class:`TriggerState` per trigger name, and the last action."""

    triggers: Mapping[str, TriggerState]
    action: Action = Action.NONE
    decision: Decision | None = None


_IDLE = TriggerState()


@dataclass(frozen=True, slots=True)
class ActiveTrigger:
    name: str
    action: Action
    reason: str
    since_ns: int
    latched: bool


@dataclass(frozen=True, slots=True)
class FailsafeEvent:
    """Something that happened this cycle: ``kind`` is fired, cleared, reset or action."""

    t_ns: int
    kind: str
    trigger: str
    action: Action
    reason: str

    def as_dict(self) -> dict[str, Any]:
        return {"t_ns": self.t_ns, "kind": self.kind, "trigger": self.trigger,
                "action": self.action.label, "reason": self.reason}

    def __str__(self) -> str:
        return f"failsafe {self.kind}: {self.trigger} → {self.action.label} ({self.reason})"


@dataclass(frozen=True, slots=True)
class Decision:
    """The arbiter's output for one cycle."""

    action: Action
    active: tuple[ActiveTrigger, ...]
    events: tuple[FailsafeEvent, ...]
    #: triggers waiting for their source's first sample while disarmed (:class:`NotYet`)
    waiting: tuple[str, ...] = ()

    @property
    def freeze_adaptation(self) -> bool:
        """Hold θ̂ and control with PDC (FALLBACK or worse)."""
        return self.action >= Action.FALLBACK

    @property
    def zero_horizontal(self) -> bool:
        """No surge/sway/yaw thrust (HOLD_DEPTH or worse)."""
        return self.action >= Action.HOLD_DEPTH

    @property
    def zero_thrust(self) -> bool:
        """Zero thrust on every amplifier (ZERO_THRUST or worse)."""
        return self.action >= Action.ZERO_THRUST

    @property
    def disarm(self) -> bool:
        return self.action >= Action.DISARM

    @property
    def causes(self) -> str:
        """The active triggers of the winning action, as text."""
        top = [a for a in self.active if a.action == self.action]
        return "; ".join(f"{a.name}: {a.reason}" for a in top)


# ------------------------------------------------------------------ built-in conditions

def _age(name: str, age: float | None, limit: float) -> str | None:
    if age is None:
        return None
    if not (age <= limit):  # also catches NaN
        return f"{name} age {age:.3g} s > {limit:g} s"
    return None


def _source_age(name: str, age: float, limit: float) -> str | None:
    """:func:`_age` of a navigation source; never heard from (age inf) is :class:`NotYet`."""
    reason = _age(name, age, limit)
    return NotYet(reason) if reason is not None and age == _INF else reason


def _ins_stale(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    return _source_age("INS", h.ins_age_s, th.ins_stale_s), mem


def _ins_degraded(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    return ("angular rates derived from attitude" if h.rates_degraded else None), mem


def _dvl_stale(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    return _source_age("DVL", h.dvl_age_s, th.dvl_stale_s), mem


def _dvl_lock(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    """mem: time (ns) bottom lock was first seen lost, or None."""
    if h.bottom_lock:
        return None, None
    lost_since = h.t_ns if mem is None else mem
    lost_s = (h.t_ns - lost_since) * 1e-9
    if lost_s >= th.dvl_lock_lost_s:
        reason = f"DVL bottom lock lost for {lost_s:.3g} s"
        return (NotYet(reason) if h.dvl_age_s == _INF else reason), lost_since
    return None, lost_since


def _depth_stale(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    return _source_age("depth", h.depth_age_s, th.depth_stale_s), mem


def _depth_stuck(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    """mem: (last value, time it last changed). Only fresh depth counts (stale is its own
    trigger): while the depth is stale or missing the memory restarts."""
    v = h.depth_m
    if not math.isfinite(v) or not (h.depth_age_s <= th.depth_stale_s):
        return None, None
    if mem is None or mem[0] != v:
        return None, (v, h.t_ns)
    same_s = (h.t_ns - mem[1]) * 1e-9
    if same_s >= th.depth_stuck_s:
        return f"depth stuck at {v:.4f} m for {same_s:.3g} s", mem
    return None, mem


def _nonfinite_in(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    if h.nonfinite_inputs:
        return f"non-finite input: {', '.join(h.nonfinite_inputs)}", mem
    return None, mem


def _nonfinite_out(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    if h.nonfinite_outputs:
        return f"non-finite output: {', '.join(h.nonfinite_outputs)}", mem
    return None, mem


def _param_div(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    e = h.m_hat_min_eig
    if e is not None and not (e > th.m_hat_min_eig):
        return f"M̂ not positive definite (smallest eigenvalue {e:.3g})", mem
    if h.theta_hat is not None:
        a = np.abs(np.asarray(h.theta_hat, dtype=float))
        if a.size:
            worst = float(a.max())
            if not math.isfinite(worst) or not math.isfinite(float(a.sum())):
                return "θ̂ not finite", mem
            if worst > th.theta_abs_max:
                i = int(a.argmax())
                return f"|θ̂[{i}]| = {worst:.3g} > {th.theta_abs_max:g}", mem
    return None, mem


def _amp_fault(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    if h.amplifier_faults:
        return "; ".join(h.amplifier_faults), mem
    return None, mem


def _feedback(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    return _age("amplifier feedback", h.feedback_age_s, th.feedback_stale_s), mem


def _bus_off(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    return ("CAN bus-off" if h.bus_off else None), mem


def _overrun(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    if h.overrun_streak_exceeded:
        return f"{h.overrun_streak} consecutive loop overruns", mem
    return None, mem


def _cycle_exc(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    return ("the control cycle raised an exception" if h.cycle_failed else None), mem


def _leak(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    return ("leak detected" if h.leak else None), mem


def builtin_triggers() -> tuple[TriggerDef, ...]:
    """The built-in trigger definitions (see the module table)."""
    A = Action
    return (
        TriggerDef("ins_stale", A.ZERO_THRUST, _ins_stale, doc="INS stale"),
        TriggerDef("ins_rates_degraded", A.WARN, _ins_degraded,
                   doc="INS angular rates derived from attitude"),
        TriggerDef("dvl_stale", A.HOLD_DEPTH, _dvl_stale, doc="DVL stale"),
        TriggerDef("dvl_bottom_lock_lost", A.HOLD_DEPTH, _dvl_lock,
                   doc="DVL bottom lock lost"),
        TriggerDef("depth_stale", A.ZERO_THRUST, _depth_stale, doc="depth stale"),
        TriggerDef("depth_stuck", A.ZERO_THRUST, _depth_stuck, latch=True,
                   doc="depth value unchanged"),
        TriggerDef("nonfinite_input", A.ZERO_THRUST, _nonfinite_in,
                   doc="non-finite sensor input"),
        TriggerDef("nonfinite_output", A.ZERO_THRUST, _nonfinite_out, latch=True,
                   doc="non-finite command or estimate"),
        TriggerDef("parameter_divergence", A.FALLBACK, _param_div, latch=True,
                   doc="M̂ not positive definite or θ̂ out of bounds"),
        TriggerDef("amplifier_fault", A.DISARM, _amp_fault, latch=True,
                   doc="amplifier fault"),
        TriggerDef("feedback_missing", A.ZERO_THRUST, _feedback,
                   doc="amplifier feedback missing"),
        TriggerDef("bus_off", A.DISARM, _bus_off, latch=True, doc="CAN bus-off"),
        TriggerDef("loop_overrun_streak", A.ZERO_THRUST, _overrun,
                   doc="control loop overrun streak"),
        TriggerDef("cycle_exception", A.ZERO_THRUST, _cycle_exc, latch=True,
                   doc="the cycle callback raised"),
        TriggerDef("leak", A.DISARM, _leak, latch=True, doc="leak input"),
    )


def make_registry(thresholds: Thresholds,
                  extra: Iterable[TriggerDef] = ()) -> tuple[TriggerDef, ...]:
    """Built-in triggers minus ``thresholds.disabled``, plus ``extra`` (names must be unique)."""
    defs = [d for d in builtin_triggers() if d.name not in thresholds.disabled]
    defs += list(extra)
    names = [d.name for d in defs]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"duplicate failsafe trigger name(s): {', '.join(dup)}")
    return tuple(defs)


def nonfinite_names(**values: Any) -> tuple[str, ...]:
    """Names of the keyword arguments holding any NaN/inf (numbers or arrays; None ignored).

    >>> nonfinite_names(thrust=np.array([1.0, np.nan]), u=np.zeros(6))
    ('thrust',)
    """
    bad = []
    for name, v in values.items():
        if v is None:
            continue
        try:
            ok = math.isfinite(float(np.sum(np.asarray(v, dtype=float))))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            bad.append(name)
    return tuple(bad)


#: the :class:`Health` fields navigation provides, in Health's order (right after ``t_ns``)
NAV_HEALTH_FIELDS = ("ins_age_s", "dvl_age_s", "depth_age_s", "rates_degraded", "bottom_lock",
                     "depth_m")


def nav_health_values(nav: Any) -> tuple:
    """The values of :data:`NAV_HEALTH_FIELDS` a :class:`uvd.estimation.navigation.NavState`
    provides: ``Health(t_ns, *nav_health_values(nav), …)`` (positional: the cycle's way, a
    few µs cheaper than keywords)."""
    return (float(nav.ins_age_s), float(nav.dvl_age_s), float(nav.depth_age_s),
            bool(nav.rates_degraded), bool(nav.bottom_lock), float(nav.H[2, 3]))


def nav_health(nav: Any) -> dict[str, Any]:
    """The :class:`Health` fields a :class:`uvd.estimation.navigation.NavState` provides."""
    return dict(zip(NAV_HEALTH_FIELDS, nav_health_values(nav), strict=True))


# ------------------------------------------------------------------------- the arbiter

def arbiter_init(registry: Sequence[TriggerDef]) -> ArbiterState:
    """Initial state: nothing active."""
    return ArbiterState(triggers={d.name: _IDLE for d in registry})


def _safe_condition(d: TriggerDef, h: Health, th: Thresholds, mem: Any
                    ) -> tuple[str | None, Any]:
    try:
        reason, mem = d.condition(h, th, mem)
    except Exception as exc:  # a broken condition is itself a reason to act
        return f"condition could not be evaluated ({type(exc).__name__}: {exc})", mem
    return (None if reason is None else str(reason)), mem


def evaluate(registry: Sequence[TriggerDef], th: Thresholds, state: ArbiterState,
             health: Health) -> tuple[Decision, ArbiterState]:
    """One arbiter step: evaluate every trigger on ``health``; never raises.

    Parameters
    ----------
    registry : sequence of TriggerDef
        From :func:`make_registry`.
    th : Thresholds
    state : ArbiterState
        From :func:`arbiter_init` or the previous call (unknown trigger names are added).
    health : Health

    Returns
    -------
    decision : Decision
    state : ArbiterState
    """
    t = health.t_ns
    clear_ns = int(th.clear_after_s * 1e9)
    old = state.triggers
    new: dict[str, TriggerState] = {}
    events: list[FailsafeEvent] = []
    active: list[ActiveTrigger] = []
    waiting: list[str] = []
    changed = False
    same = len(registry) == len(old)  # every trigger's state the very object it was
    for d in registry:
        ts = was = old.get(d.name)
        if ts is None:
            ts = _IDLE
            changed = True
        try:
            reason, mem = d.condition(health, th, ts.memory)
        except Exception as exc:  # a broken condition is itself a reason to act
            reason, mem = f"condition could not be evaluated ({type(exc).__name__}: {exc})", \
                ts.memory
        if isinstance(reason, NotYet) and not health.armed and not ts.active:
            waiting.append(d.name)  # a source still starting while disarmed: no failsafe
            reason = None
        if reason is not None:
            if not ts.active:
                ts = TriggerState(True, t, reason, None, mem)
                events.append(FailsafeEvent(t, "fired", d.name, d.action, reason))
                changed = True
            elif reason != ts.reason or ts.false_since_ns is not None or mem is not ts.memory:
                changed = changed or reason != ts.reason or ts.false_since_ns is not None
                ts = TriggerState(True, ts.since_ns, reason, None, mem)
        elif ts.active:
            false_since = ts.false_since_ns if ts.false_since_ns is not None else t
            if not d.latch and t - false_since >= clear_ns:
                events.append(FailsafeEvent(t, "cleared", d.name, d.action,
                                            f"condition false for {th.clear_after_s:g} s"))
                ts = TriggerState(memory=mem)
                changed = True
            elif false_since != ts.false_since_ns or mem is not ts.memory:
                ts = TriggerState(True, ts.since_ns, ts.reason, false_since, mem)
        elif mem is not ts.memory:
            ts = TriggerState(memory=mem)
        new[d.name] = ts
        same = same and ts is was
        if ts.active:
            active.append(ActiveTrigger(d.name, d.action, ts.reason, ts.since_ns, d.latch))
    action = max((a.action for a in active), default=Action.NONE) if active else Action.NONE
    if action != state.action:
        top = [a for a in active if a.action == action]
        why = "; ".join(f"{a.name}: {a.reason}" for a in top) or "no trigger active"
        events.append(FailsafeEvent(t, "action", ",".join(a.name for a in top) or "-",
                                    action, why))
    prev = state.decision
    if not changed and not events and prev is not None and not prev.events \
            and len(prev.active) == len(active) and prev.waiting == tuple(waiting):
        decision = prev  # nothing changed: reuse it (cheap at 1 kHz)
        if same and action == state.action:
            return prev, state  # every trigger's memory as it was: the same state
    else:
        decision = Decision(action=action, active=tuple(active), events=tuple(events),
                            waiting=tuple(waiting))
    return decision, ArbiterState(triggers=new, action=action, decision=decision)


def reset(registry: Sequence[TriggerDef], th: Thresholds, state: ArbiterState,
          health: Health, names: Iterable[str] | None = None
          ) -> tuple[ArbiterState, tuple[FailsafeEvent, ...], tuple[tuple[str, str], ...]]:
    """Operator reset of latched triggers whose condition no longer holds.

    Parameters
    ----------
    names : iterable of str, optional
        Triggers to reset; when None, every active one whose condition no longer holds, and
        a latched one whose condition holds is refused — one that clears by itself and still
        holds is left to clear (an operator's "reset" of a vehicle whose INS gives no rates
        would otherwise never succeed), and one that no longer holds is cleared now, not
        ``clear_after_s`` later (the operator's reset after a fault has just gone).

    Returns
    -------
    state : ArbiterState
    events : tuple of FailsafeEvent
        One ``reset`` event per trigger cleared.
    refused : tuple of (name, reason)
        Triggers that could not be reset and why (condition still true, unknown name).
    """
    by_name = {d.name: d for d in registry}
    wanted = list(names) if names is not None else [
        n for n, ts in state.triggers.items() if ts.active]
    new = dict(state.triggers)
    events: list[FailsafeEvent] = []
    refused: list[tuple[str, str]] = []
    for n in wanted:
        d = by_name.get(n)
        ts = state.triggers.get(n)
        if d is None or ts is None:
            refused.append((n, "unknown trigger"))
            continue
        if not ts.active:
            continue
        reason, mem = _safe_condition(d, health, th, ts.memory)
        if reason is not None:
            if names is not None or d.latch:
                refused.append((n, f"condition still true: {reason}"))
            continue
        new[n] = TriggerState(memory=mem)
        events.append(FailsafeEvent(health.t_ns, "reset", n, d.action, "operator reset"))
    return (ArbiterState(triggers=new, action=state.action), tuple(events), tuple(refused))
