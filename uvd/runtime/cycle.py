"""The cycle: the update of read → **update** → write with its failsafes, shared by the
daemon, lockstep simulation and replay — the one thing uvd calls "cycle".

As Pinocchio splits a constant model from its data, the cycle is a constant
:class:`CycleConfig` (the pure core's :class:`~uvd.core.CoreConfig`, the failsafe thresholds
and triggers, the arming checks; :func:`uvd.runtime.build.make_cycle` builds it from a
configuration file) and one value, :class:`CycleState`, that holds everything carried from
one cycle to the next: the core's state (navigation, controller, estimators, the running
reference, the pose held), the arbiter's memory, the lifecycle, the operator's mode and manual
wrench. Free functions take both and return a new state; nothing else holds any::

    result, state = update(config, state, inputs, dt)       one cycle
    result, state, effects = apply(config, state, command, t_ns)   an operator command
    state = cycle_init(config)                              the state a run starts in

:func:`update` takes what the read phase gathered — the new sensor samples and the
amplifiers' typed status, as :class:`CycleInputs` — and returns everything the write phase
needs (:class:`CycleResult`)::

    amplifier_source    η from the amplifiers' own faults (``[failsafe] amplifier_fault``)
    uvd.core.sense      navigation, applied wrench, online estimators
    Health              source ages, non-finite inputs and the last command, M̂/θ̂ of the
                        controller (its spec's diagnostics hook), amplifiers, bus, loop, leak
    supervise           the arbiter's action and the lifecycle (armed or not)
    mode                the operator's mode, overridden by a more restrictive failsafe action
    uvd.core.act        reference, control in that mode, allocation, the output guard

The mode is decided *before* anything is commanded: a FALLBACK runs PDC and does not step the
adaptive controller (θ̂ frozen, nothing undone afterwards); HOLD_DEPTH, ZERO_THRUST and DISARM
are modes of :func:`uvd.core.act`. ``CycleResult.out.thrust_n`` is exactly what the amplifiers
get. Deterministic: no clock (time comes in ``CycleInputs.t_ns``), no I/O, no logging. What
changed — failsafe events and lifecycle transitions — comes back as data (``effects``); the
holder of the running state (:class:`~uvd.runtime.supervisor.Supervisor`) hands it to the
listeners (logging, systemd status, telemetry).

Two signals reach the arbiter one cycle late, by construction: a non-finite command (the core
has already zeroed that cycle's command) and the controller's θ̂/M̂ (read from the state the
previous cycle committed).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cache
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from drivers.samples import DepthSample, DvlSample, InsSample
from uvd.geometry import eta_of
from uvd.runtime import commands as cmd
from uvd.runtime.commands import OPERATOR_MODES, CommandResult
from uvd.runtime.failsafe import (
    BUILTIN_NAMES,
    Action,
    ArbiterState,
    Decision,
    FailsafeEvent,
    Health,
    Thresholds,
    TriggerDef,
    arbiter_init,
    evaluate,
    make_registry,
    nav_health_values,
    reset,
)
from uvd.runtime.lifecycle import (
    ArmingCheck,
    Lifecycle,
    LifecycleStep,
    State,
    builtin_checks,
    run_checks,
)

__all__ = ["ActuatorStatus", "CycleInputs", "CycleResult", "CycleConfig", "CycleState",
           "cycle_init", "update", "apply", "supervise", "boot_complete", "request_arm",
           "request_disarm", "request_shutdown", "reset_failsafe", "unsupervised",
           "mode_for", "nonfinite_inputs", "inputs_record", "inputs_from_record",
           "amplifier_source", "KEEP_DOFS"]

if TYPE_CHECKING:
    from uvd import core
    from uvd.core import Mode

# The numerical core (uvd.core, uvd.control: numba and its ~30 000 objects) is imported by the
# functions that run it, not with this module: the lifecycle and the arbiter run without it
# (an App alone; tests of the runtime), and the heap a loop freezes at start stays small.


@cache
def _modes() -> tuple[dict, dict, dict]:
    """The operator's modes, the failsafe actions' modes and how restrictive each mode is."""
    from uvd.core import Mode
    operator = {"auto": Mode.CONTROL, "pdc": Mode.PDC, "hold-depth": Mode.HOLD_DEPTH,
                "manual": Mode.MANUAL, "observe": Mode.ZERO}
    #: how restrictive each mode is: a failsafe action never makes the mode less restrictive
    rank = {Mode.CONTROL: 0, Mode.PDC: 1, Mode.MANUAL: 1, Mode.HOLD_DEPTH: 2, Mode.ZERO: 3}
    action = {Action.FALLBACK: Mode.PDC, Action.HOLD_DEPTH: Mode.HOLD_DEPTH,
              Action.ZERO_THRUST: Mode.ZERO, Action.DISARM: Mode.ZERO}
    return operator, rank, action


class ActuatorStatus(NamedTuple):
    """What the read phase learned from the amplifiers this cycle (immutable: a named tuple,
    as the cycle's other per-cycle values — built every cycle, it costs a fraction of a frozen
    dataclass).

    Attributes
    ----------
    omega_rad_s : ndarray or None
        Measured propeller speeds (rad/s, thruster order) when every node's is valid.
    enabled : bool
        Every amplifier is in OPERATION ENABLED (an arming check).
    faults : tuple of str
        Named faults ("node 3: over_current", "bus: send_failed").
    feedback_t_ns : int or None
        Time of the oldest node's latest feedback, counted from the first command at the
        earliest (None: no command sent yet — age 0).
    bus_off : bool
        The CAN controller is bus-off (or the bus is closed).
    faulted : tuple of int
        The thrusters (1…n, thruster order) whose amplifier reports a fault of its own —
        EMCY, a FAULT statusword, heartbeat lost, a reset (a few missed TPDOs alone are not:
        they age the feedback): the amplifier source of η (``[failsafe] amplifier_fault =
        "reallocate"``). Their names are in ``faults`` (``"node N: …"``; the bus's
        ``"bus: …"``).
    healthy_feedback_t_ns : int or None
        As ``feedback_t_ns``, over the amplifiers not ``faulted`` only.
    """

    omega_rad_s: np.ndarray | None = None
    enabled: bool = False
    faults: tuple[str, ...] = ()
    feedback_t_ns: int | None = None
    bus_off: bool = False
    faulted: tuple[int, ...] = ()
    healthy_feedback_t_ns: int | None = None


class CycleInputs(NamedTuple):
    """What the read phase gathered for one cycle (samples as :mod:`drivers.samples`).

    ``actuators`` is None when no amplifiers are fitted; ``leak`` None when no leak sensor
    is; ``extra`` carries the signals of plug-in triggers (e.g. the ground-station link's
    ``operator_heartbeat_age_s``)."""

    t_ns: int
    ins: InsSample | None = None
    dvl: DvlSample | None = None
    depth: DepthSample | None = None
    actuators: ActuatorStatus | None = None
    overrun_streak: int = 0
    overrun_streak_exceeded: bool = False
    leak: bool | None = None
    extra: Mapping[str, Any] | None = None


def inputs_record(inp: CycleInputs, thruster_eta: np.ndarray | None = None
                  ) -> dict[str, Any]:
    """Everything of ``inp`` but the sensor samples, as plain data for the cycle record (the
    samples travel as raw frames and their receive stamps); :func:`inputs_from_record` reads
    it back. ``thruster_eta``: the effectiveness η the update allocated with
    (:attr:`CycleResult.thruster_eta`), recorded beside the inputs it came from — a replay
    derives it again from them and the recorded commands, and compares."""
    a = inp.actuators
    return {"actuators": None if a is None else {
                "omega_rad_s": a.omega_rad_s, "enabled": a.enabled, "faults": list(a.faults),
                "feedback_t_ns": a.feedback_t_ns, "bus_off": a.bus_off,
                "faulted": list(a.faulted), "healthy_feedback_t_ns": a.healthy_feedback_t_ns},
            "overrun_streak": inp.overrun_streak,
            "overrun_streak_exceeded": inp.overrun_streak_exceeded,
            "leak": inp.leak, "extra": None if inp.extra is None else dict(inp.extra),
            "thruster_eta": None if thruster_eta is None else np.array(thruster_eta)}


def inputs_from_record(t_ns: int, rec: Mapping[str, Any], ins=None, dvl=None, depth=None
                       ) -> CycleInputs:
    """The :class:`CycleInputs` of a recorded cycle: ``rec`` from :func:`inputs_record` (hub or
    JSON form) and the samples decoded again from the recorded frames."""
    a = rec.get("actuators")
    act = None
    if a is not None:
        w = a.get("omega_rad_s")
        hf = a.get("healthy_feedback_t_ns")
        act = ActuatorStatus(
            omega_rad_s=None if w is None else np.asarray(w, dtype=float),
            enabled=bool(a["enabled"]), faults=tuple(a.get("faults") or ()),
            feedback_t_ns=None if a.get("feedback_t_ns") is None else int(a["feedback_t_ns"]),
            bus_off=bool(a.get("bus_off", False)),
            faulted=tuple(int(i) for i in a.get("faulted") or ()),
            healthy_feedback_t_ns=None if hf is None else int(hf))
    return CycleInputs(t_ns, ins, dvl, depth, act, int(rec.get("overrun_streak", 0)),
                       bool(rec.get("overrun_streak_exceeded", False)), rec.get("leak"),
                       rec.get("extra"))


class CycleResult(NamedTuple):
    """Everything the write phase needs from one update.

    ``state`` is the lifecycle's (ARMED, FAILSAFE, …); ``effects`` the failsafe events and
    lifecycle transitions of this update, in order, for the listeners; ``armed_at_ns`` when
    the vehicle was last armed (None: not yet); ``thruster_eta`` the effectiveness η the
    update allocated with (None: every thruster healthy)."""

    out: core.CoreOutputs
    health: Health
    decision: Decision
    state: State
    operator_mode: str
    effects: tuple = ()
    armed_at_ns: int | None = None
    thruster_eta: np.ndarray | None = None


def mode_for(action: Action, operator_mode: str) -> Mode:
    """The core's mode: the operator's, unless the failsafe action asks a more restrictive
    one (FALLBACK turns the configured controller into PDC and leaves the others as they
    are; HOLD_DEPTH and ZERO_THRUST/DISARM override all but a more restrictive choice)."""
    operator, rank, forcing = _modes()
    mode = operator[operator_mode]
    forced = forcing.get(action)
    if forced is None:
        return mode
    if forced is forcing[Action.FALLBACK]:
        return forced if rank[mode] == 0 else mode  # PDC instead of the controller
    return forced if rank[forced] >= rank[mode] else mode


def _finite_sum(x) -> bool:
    """Whether the sum of ``x`` is finite (NaN or inf anywhere makes it not): ``np.sum``'s
    very reduction without its dispatch, which cost a lockstep cycle ~10 µs. Three float64
    entries each within ±1e300 have a finite sum in any order of summation: those are
    answered without the reduction (~2 µs), everything else by it."""
    if type(x) is np.ndarray and x.shape == (3,) and x.dtype == _F64:
        a, b, c = x.tolist()
        if -1e300 < a < 1e300 and -1e300 < b < 1e300 and -1e300 < c < 1e300:
            return True
    return math.isfinite(float(_ADD_REDUCE(x, axis=None)))


_F64 = np.dtype(np.float64)


_ADD_REDUCE = np.add.reduce


def nonfinite_inputs(ins, dvl, depth) -> tuple[str, ...]:
    """Names of the new samples holding NaN or inf where a number is used."""
    bad = []
    if ins is not None:
        if not (math.isfinite(ins.roll) and math.isfinite(ins.pitch)
                and math.isfinite(ins.heading)) or (
                ins.rates_valid and not _finite_sum(ins.omega_body)):
            bad.append("ins")
    if dvl is not None and dvl.bottom_lock and not _finite_sum(dvl.velocity_body):
        bad.append("dvl")
    if depth is not None and not math.isfinite(depth.depth_m):
        bad.append("depth")
    return tuple(bad)


Effects = tuple  # of FailsafeEvent and Transition, in the order they happened


@dataclass(frozen=True)
class CycleConfig:
    """Everything constant about the cycle for the life of a run (a reload makes a new one,
    between cycles, with :func:`uvd.runtime.build.make_cycle`).

    Parameters
    ----------
    core : uvd.core.CoreConfig or None
        The pure core (None: a lifecycle without a core — an :class:`~uvd.runtime.app.App`
        run alone).
    thresholds : Thresholds
        ``[failsafe]``.
    extra_triggers : tuple of TriggerDef
        Plug-in triggers (:func:`uvd.runtime.triggers.plugin_triggers`).
    checks : tuple of ArmingCheck, optional
        Arming checks; :func:`~uvd.runtime.lifecycle.builtin_checks` of ``thresholds`` when
        None.
    hold_on_arm : bool
        ``[control] reference = "hold"``: arming replaces the reference with the pose the
        vehicle has then.
    north_m, east_m : float
        Navigation's initial horizontal position (``[navigation]``).
    fdc : uvd.runtime.fdc_source.FdcRule or None
        ``[faults.fdc]``: what a fault sample of uvd-fdc may do (None: the source is off).
    """

    core: core.CoreConfig | None
    thresholds: Thresholds = field(default_factory=Thresholds)
    extra_triggers: tuple[TriggerDef, ...] = ()
    checks: tuple[ArmingCheck, ...] | None = None
    hold_on_arm: bool = False
    north_m: float = 0.0
    east_m: float = 0.0
    fdc: Any = None
    registry: tuple[TriggerDef, ...] = field(init=False, repr=False, compare=False)
    arming_checks: tuple[ArmingCheck, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "extra_triggers", tuple(self.extra_triggers))
        object.__setattr__(self, "registry", make_registry(self.thresholds,
                                                           self.extra_triggers))
        object.__setattr__(self, "arming_checks", tuple(self.checks) if self.checks is not None
                           else builtin_checks(self.thresholds))


def unsupervised(core_cfg: core.CoreConfig) -> CycleConfig:
    """The cycle of the thesis's experiments: ``core_cfg`` with every built-in failsafe
    trigger switched off (the thesis ran none). Started armed (``cycle_init(…, armed=True)``)
    it commands exactly what :func:`uvd.core.step` does in the configured controller's mode."""
    return CycleConfig(core_cfg, Thresholds(disabled=BUILTIN_NAMES))


class CycleState(NamedTuple):
    """Everything the cycle carries from one cycle to the next — one immutable value
    (a named tuple: a new one every cycle costs less than a frozen dataclass).

    Attributes
    ----------
    core : uvd.core.CoreState or None
        Navigation memory, the controller's and estimators' states, the running reference and
        the pose held.
    arbiter : ArbiterState
        The failsafe triggers' memory.
    lifecycle : Lifecycle
    decision : Decision or None
        The arbiter's last decision.
    health : Health or None
        The last cycle's health (arming checks and failsafe resets read it).
    operator_mode : str
        One of :data:`uvd.runtime.commands.OPERATOR_MODES`.
    manual, manual_until_ns, manual_timeout_ns
        The operator's manual wrench and when it lapses (0: counted from the next cycle).
    pending_hold : Reference or None
        A pose to hold (``HoldPose``), taken by the next update.
    thruster_eta : ndarray or None
        Each thruster's effectiveness η the cycle allocates with (None: all healthy;
        ``SetThrusterEta``).
    was_armed : bool
        Armed at the end of the last update.
    armed_at_ns : int or None
        When the vehicle was last armed.
    nonfinite_out : tuple of str
        ``("command",)`` when the last command was not finite (the arbiter sees it next cycle).
    fdc : uvd.runtime.fdc_source.FdcState or None
        The daemon's own thrust evidence and the fault samples counted (``[faults.fdc]``).
    """

    core: core.CoreState | None
    arbiter: ArbiterState
    lifecycle: Lifecycle
    decision: Decision | None = None
    health: Health | None = None
    operator_mode: str = "auto"
    manual: np.ndarray | None = None
    manual_until_ns: int = 0
    manual_timeout_ns: int = 0
    pending_hold: Any = None
    thruster_eta: np.ndarray | None = None
    was_armed: bool = False
    armed_at_ns: int | None = None
    nonfinite_out: tuple[str, ...] = ()
    fdc: Any = None

    @property
    def armed(self) -> bool:
        return self.lifecycle.armed


def cycle_init(config: CycleConfig, *, armed: bool = False, north_m: float | None = None,
               east_m: float | None = None) -> CycleState:
    """The state a run starts in: the lifecycle in BOOT, or — ``armed`` — ARMED from the start
    (lockstep runs: the thesis's experiments, the demo's reference run); navigation at
    ``north_m``, ``east_m`` (the configuration's by default)."""
    c = config.core
    cs = None
    if c is not None:
        from uvd.core import core_init
        cs = core_init(c, north_m=config.north_m if north_m is None else north_m,
                       east_m=config.east_m if east_m is None else east_m)
    life = Lifecycle(State.ARMED, 0) if armed else Lifecycle()
    fdc = None
    if config.fdc is not None:
        from uvd.runtime.fdc_source import fdc_init
        fdc = fdc_init(config.fdc)
    return CycleState(cs, arbiter_init(config.registry), life, fdc=fdc)


# -- the lifecycle and the arbiter (between cycles, and inside update) --

def _step(state: CycleState, step: LifecycleStep) -> CycleState:
    return state._replace(lifecycle=step.lifecycle)


def _supervise(config: CycleConfig, state: CycleState, health: Health
               ) -> tuple[Decision, ArbiterState, LifecycleStep]:
    decision, arbiter = evaluate(config.registry, config.thresholds, state.arbiter, health)
    return decision, arbiter, state.lifecycle.on_failsafe(health.t_ns, decision)


def supervise(config: CycleConfig, state: CycleState, health: Health
              ) -> tuple[Decision, CycleState, Effects]:
    """Evaluate the arbiter on ``health`` and follow it with the lifecycle; never raises."""
    decision, arbiter, step = _supervise(config, state, health)
    return decision, state._replace(arbiter=arbiter, lifecycle=step.lifecycle,
                                    decision=decision, health=health), \
        (*decision.events, *step.transitions)


def boot_complete(state: CycleState, t_ns: int, cause: str = "drivers up"
                  ) -> tuple[LifecycleStep, CycleState]:
    step = state.lifecycle.boot_complete(t_ns, cause)
    return step, _step(state, step)


def request_arm(config: CycleConfig, state: CycleState, t_ns: int,
                cause: str = "operator request", health: Health | None = None
                ) -> tuple[LifecycleStep, CycleState]:
    """Run the arming checks on ``health`` (the last cycle's by default) and arm."""
    h = health if health is not None else (state.health or Health(t_ns=t_ns))
    step = state.lifecycle.request_arm(t_ns, run_checks(config.arming_checks, h,
                                                        state.decision), cause)
    return step, _step(state, step)


def request_disarm(state: CycleState, t_ns: int, cause: str = "operator request"
                   ) -> tuple[LifecycleStep, CycleState]:
    step = state.lifecycle.request_disarm(t_ns, cause)
    return step, _step(state, step)


def request_shutdown(state: CycleState, t_ns: int, cause: str
                     ) -> tuple[LifecycleStep, CycleState]:
    step = state.lifecycle.request_shutdown(t_ns, cause)
    return step, _step(state, step)


def reset_failsafe(config: CycleConfig, state: CycleState, t_ns: int,
                   names: Sequence[str] | None = None
                   ) -> tuple[tuple[tuple[str, str], ...], CycleState, Effects]:
    """Operator reset of latched triggers: the refused ones with reasons, the new state and
    the events."""
    h = state.health or Health(t_ns=t_ns)
    if h.t_ns != t_ns:
        h = replace(h, t_ns=t_ns)
    arbiter, events, refused = reset(config.registry, config.thresholds, state.arbiter,
                                     h, names)
    return refused, state._replace(arbiter=arbiter), tuple(events)


# -- the operator (applied between cycles) --

def apply(config: CycleConfig, state: CycleState, c: Any, t_ns: int
          ) -> tuple[CommandResult, CycleState, Effects]:
    """Apply a command of :mod:`uvd.runtime.commands` (all but ``SetParams``, which is the
    configuration's: the daemon applies it through a reload)."""
    if isinstance(c, cmd.Arm):
        step, st = request_arm(config, state, t_ns, cause=c.cause)
        return CommandResult(bool(step.ok and st.armed), step.refused or ""), st, \
            step.transitions
    if isinstance(c, cmd.Disarm):
        step, st = request_disarm(state, t_ns, cause=c.cause)
        return CommandResult(True, "" if step.transitions else "not armed"), st, \
            step.transitions
    if isinstance(c, cmd.ResetFailsafe):
        refused, st, events = reset_failsafe(config, state, t_ns, c.names)
        return CommandResult(not refused, "; ".join(f"{n}: {r}" for n, r in refused)), st, \
            events
    if isinstance(c, cmd.SetMode):
        if c.mode not in OPERATOR_MODES:
            return CommandResult(False, f"unknown mode {c.mode!r} (one of "
                                        f"{', '.join(OPERATOR_MODES)})"), state, ()
        st = state._replace(operator_mode=c.mode)
        if c.mode == "manual":
            st = st._replace(manual=None)  # a new manual session starts from zero wrench
        return CommandResult(True), st, ()
    if isinstance(c, cmd.ManualWrench):
        u = np.asarray(c.u, dtype=float)
        if u.shape != (6,) or not np.all(np.isfinite(u)):
            return CommandResult(False, "manual wrench must be six finite numbers"), state, ()
        if not (math.isfinite(c.timeout_s) and c.timeout_s > 0.0):
            return CommandResult(False, "manual timeout_s must be > 0"), state, ()
        # the timeout is counted from the cycle that takes it (manual_until_ns 0)
        st = state._replace(manual=u, manual_timeout_ns=int(c.timeout_s * 1e9),
                            manual_until_ns=0)
        return CommandResult(True, "" if state.operator_mode == "manual"
                             else f"stored; mode is {state.operator_mode}, not manual"), st, ()
    if isinstance(c, cmd.HoldPose):
        vals = (c.north_m, c.east_m, c.down_m, c.heading_rad)
        if not all(math.isfinite(float(x)) for x in vals):
            return CommandResult(False, "hold pose must be finite numbers"), state, ()
        from uvd.control.trajectory import setpoint
        return CommandResult(True), state._replace(pending_hold=setpoint(
            (c.north_m, c.east_m, c.down_m, 0.0, 0.0, c.heading_rad))), ()
    if isinstance(c, cmd.SetThrusterEta):
        return _set_eta(config, state, c)
    if isinstance(c, cmd.FaultReport):
        from uvd.runtime.fdc_source import decide
        v = decide(config.fdc, state.fdc, c, config.core.allocator.n_thrusters, t_ns)
        state = state._replace(fdc=v.state)
        if v.thruster is None:
            return CommandResult(v.ok, v.text), state, ()
        res, state, effects = _set_eta(config, state, cmd.SetThrusterEta(v.thruster, v.eta,
                                                                         c.source))
        return CommandResult(res.ok, f"{v.text} → {res.reason}"), state, effects
    return CommandResult(False, f"{type(c).__name__} is not supported by the cycle"), state, ()


def _set_eta(config: CycleConfig, state: CycleState, c: Any
             ) -> tuple[CommandResult, CycleState, Effects]:
    """One thruster's effectiveness η (the operator's source); the result says which DOFs the
    cycle gives up with it."""
    n = config.core.allocator.n_thrusters
    try:
        i, e = int(c.thruster), float(c.eta)
    except (TypeError, ValueError):
        return CommandResult(False, "thruster must be an integer and eta a number"), state, ()
    if not 1 <= i <= n:
        return CommandResult(False, f"thruster {i} is not one of 1..{n}"), state, ()
    if not 0.0 <= e <= 1.0:  # NaN fails too
        return CommandResult(False, f"eta {c.eta!r} is not in [0, 1]"), state, ()
    eta = np.ones(n) if state.thruster_eta is None else state.thruster_eta.copy()
    eta[i - 1] = e
    given_up = config.core.accommodation_for(eta)[0].given_up
    return CommandResult(True, f"thruster {i} eta {e:.3g} ({c.source or 'operator'}); "
                               f"given up: {', '.join(given_up) or 'none'}"), \
        state._replace(thruster_eta=None if (eta == 1.0).all() else eta), ()


# -- the amplifier's own source of η (inside the update) --

#: the DOFs the amplifier source must keep to accommodate a fault: depth and attitude (safety)
KEEP_DOFS = ("heave", "roll", "pitch", "yaw")


class _AmplifierView(NamedTuple):
    eta: np.ndarray | None      # the η the update allocates with
    faults: tuple[str, ...]     # the amplifier faults the arbiter sees
    feedback_t_ns: int | None   # the feedback time the arbiter ages
    effects: Effects            # one "accommodated" event per thruster newly at η 0


def amplifier_source(config: CycleConfig, state: CycleState, a: ActuatorStatus | None,
                     t_ns: int) -> _AmplifierView:
    """The amplifier's own fault as a source of η (``[failsafe] amplifier_fault``).

    ``"disarm"`` (the default) leaves η alone: the arbiter's ``amplifier_fault`` disarms and
    ``feedback_missing`` zeroes thrust, as before. ``"reallocate"``: every thruster whose
    amplifier reports a fault of its own (:attr:`ActuatorStatus.faulted`) gets η = 0 — when the
    allocation of that η still keeps :data:`KEEP_DOFS` (depth and attitude); the arbiter then
    sees neither those amplifiers' faults nor their feedback's age, the bus's faults still
    count, and each newly dead thruster is told as a ``FailsafeEvent`` of kind
    ``accommodated`` (trigger ``amplifier_fault``, action WARN: "thruster 4 eta 0 (amplifier);
    given up: surge"). If the remaining thrusters cannot keep them, nothing is accommodated and
    the failsafe acts as under ``"disarm"``. η 0 stays once set (the cycle's state): only the
    operator's ``SetThrusterEta`` gives the thruster back, and only once its amplifier has
    stopped reporting (while it reports, the next update sets η 0 again)."""
    eta = state.thruster_eta
    if a is None:
        return _AmplifierView(eta, (), None, ())
    if (not a.faulted or config.core is None
            or config.thresholds.amplifier_fault != "reallocate"):
        return _AmplifierView(eta, a.faults, a.feedback_t_ns, ())
    n = config.core.allocator.n_thrusters
    idx = sorted({i - 1 for i in a.faulted if 1 <= i <= n})
    new = np.ones(n) if eta is None else eta.copy()
    newly = [i for i in idx if new[i] != 0.0]
    new[idx] = 0.0
    given_up = config.core.accommodation_for(new)[0].given_up
    if any(d in KEEP_DOFS for d in given_up):
        return _AmplifierView(eta, a.faults, a.feedback_t_ns, ())
    lost = ", ".join(given_up) or "none"
    effects = tuple(FailsafeEvent(t_ns, "accommodated", "amplifier_fault", Action.WARN,
                                  f"thruster {i + 1} eta 0 (amplifier); given up: {lost}")
                    for i in newly)
    return _AmplifierView(new if newly else eta,
                          tuple(f for f in a.faults if f.startswith("bus:")),
                          a.healthy_feedback_t_ns, effects)


def _fdc_update(config: CycleConfig, fdc: Any, t_ns: int, sensed: Any, nav: Any,
                thrust: np.ndarray, eta: np.ndarray | None
                ) -> tuple[Any, np.ndarray | None, Effects]:
    """uvd-fdc's source in the update (:mod:`uvd.runtime.fdc_source`): this cycle's sample for
    the daemon's evidence, then the samples that await it decided again — a confirmed one
    sets η from the next cycle on and is told as an ``accommodated`` event of trigger
    ``fdc`` ("… confirmed: … → thruster 7 eta 0.28 (uvd-fdc); given up: none"), a refused
    one as a ``refused`` event. Returns the source's state, the η on and the events."""
    from uvd.runtime.fdc_source import fdc_awaited, fdc_init, fdc_observe
    rule = config.fdc
    before = fdc if fdc is not None else fdc_init(rule)
    fdc = fdc_observe(rule, before, t_ns, sensed.nav_ok, nav.v, nav.H[:3, :3], sensed.speeds,
                      thrust)
    if not fdc.awaiting:
        return fdc, eta, ()
    old, new = before.evidence.seg_t, fdc.evidence.seg_t
    closed = len(new) > 0 and (len(old) == 0 or new[-1, 1] != old[-1, 1])
    fdc, verdicts = fdc_awaited(rule, fdc, t_ns * 1e-9, closed)
    events = []
    for v in verdicts:
        if v.thruster is None:
            events.append(FailsafeEvent(t_ns, "refused", "fdc", Action.NONE, v.text))
            continue
        eta = np.ones(rule.evidence.B.shape[1]) if eta is None else eta.copy()
        eta[v.thruster - 1] = v.eta
        lost = ", ".join(config.core.accommodation_for(eta)[0].given_up) or "none"
        events.append(FailsafeEvent(t_ns, "accommodated", "fdc", Action.WARN,
                                    f"{v.text} → thruster {v.thruster} eta {v.eta:.3g} "
                                    f"({v.source}); given up: {lost}"))
        eta = None if (eta == 1.0).all() else eta
    return fdc, eta, tuple(events)


# -- the update --

_CORE = None  # uvd.core once the first update imported it (module comment above)


def _core():
    global _CORE
    from uvd import core
    _CORE = core
    return core


def update(config: CycleConfig, state: CycleState, inp: CycleInputs, dt: float
           ) -> tuple[CycleResult, CycleState]:
    """One cycle: sense → health → arbiter → mode → act (module docstring). Pure: ``state``
    is not modified; the new one is returned with the result."""
    core = _CORE or _core()
    cfg = config.core
    st = state.core
    a = inp.actuators
    omega = a.omega_rad_s if a is not None else None
    amp = amplifier_source(config, state, a, inp.t_ns)
    eta = amp.eta
    ci = core.CoreInputs(inp.t_ns, inp.ins, inp.dvl, inp.depth, omega, thruster_eta=eta)
    sensed = core.sense(cfg, ci, st, dt)
    nav = sensed.nav

    diag = cfg.controller.diagnostics(st.ctrl)
    fb_age = None
    if a is not None:
        fb_age = 0.0 if amp.feedback_t_ns is None else (inp.t_ns - amp.feedback_t_ns) * 1e-9
    # positional, in Health's field order (tests/test_failsafe.py checks it): ~3 µs cheaper
    # than keywords every cycle
    h = Health(inp.t_ns, *nav_health_values(nav), nonfinite_inputs(inp.ins, inp.dvl, inp.depth),
               state.nonfinite_out, diag.m_min_eig, diag.theta,
               bool(a is not None and a.enabled), amp.faults, fb_age,
               bool(a is not None and a.bus_off), inp.overrun_streak,
               inp.overrun_streak_exceeded, False,  # cycle_failed: the loop's, not the update's
               inp.leak, inp.extra, state.lifecycle.armed)
    d, arbiter, step = _supervise(config, state, h)
    lifecycle = step.lifecycle
    effects = (*amp.effects, *d.events, *step.transitions)
    armed = lifecycle.armed

    armed_at = state.armed_at_ns
    if armed and not state.was_armed:
        # armed since the last cycle: the reference's clock starts now; "hold" holds the
        # pose the vehicle has now
        armed_at = inp.t_ns
        st = replace(st, t0_ns=None)
        if config.hold_on_arm:
            from uvd.control.trajectory import setpoint
            st = replace(st, reference=setpoint(eta_of(nav.H)))
    if state.pending_hold is not None:
        st = replace(st, reference=state.pending_hold, t0_ns=None)

    mode = mode_for(d.action, state.operator_mode)
    manual, until = None, state.manual_until_ns
    manual_mode = mode is core.Mode.MANUAL
    if manual_mode and state.manual is not None:
        if until == 0:
            until = inp.t_ns + state.manual_timeout_ns
        if inp.t_ns <= until:
            manual = state.manual
    ci = core.CoreInputs(inp.t_ns, inp.ins, inp.dvl, inp.depth, omega, armed, mode, manual,
                         eta)
    out, st = core.act(cfg, sensed, ci, st, dt)
    lapsed = manual_mode and state.manual is not None and manual is None
    fdc, eta_next = state.fdc, eta
    if config.fdc is not None:  # the daemon's own evidence (fdc_source)
        fdc, eta_next, decided = _fdc_update(config, fdc, inp.t_ns, sensed, nav, out.thrust_n,
                                             eta)
        effects = (*effects, *decided)
    new = CycleState(st, arbiter, lifecycle, d, h, state.operator_mode,
                     None if lapsed else state.manual,  # a silent joystick stops the vehicle
                     until, state.manual_timeout_ns, None, eta_next, armed, armed_at,
                     ("command",) if out.status == "non-finite" else (), fdc)
    return CycleResult(out, h, d, lifecycle.state, state.operator_mode, effects,
                       armed_at, eta), new
