"""The update of read → **update** → write: one cycle with its failsafes, shared by the daemon,
lockstep simulation and replay.

:class:`Cycle` owns the pure core's configuration and state, the failsafe arbiter with the
lifecycle (:class:`~uvd.runtime.supervisor.Supervisor`) and the operator's choices (mode,
manual wrench, a pose to hold). :meth:`Cycle.update` takes what the read phase gathered — the
new sensor samples and the amplifiers' typed status, as :class:`CycleInputs` — and returns
everything the write phase needs (:class:`CycleResult`)::

    uvd.core.sense      navigation, applied wrench, online estimators
    Health              source ages, non-finite inputs and the last command, M̂/θ̂ of the
                        controller (its spec's diagnostics hook), amplifiers, bus, loop, leak
    Supervisor.step     the arbiter's action and the lifecycle (armed or not)
    mode                the operator's mode, overridden by a more restrictive failsafe action
    uvd.core.act        reference, control in that mode, allocation, the output guard

The mode is decided *before* anything is commanded: a FALLBACK runs PDC and does not step the
adaptive controller (θ̂ frozen, nothing undone afterwards); HOLD_DEPTH, ZERO_THRUST and DISARM
are modes of :func:`uvd.core.act`. ``CycleResult.out.thrust_n`` is exactly what the amplifiers
get. Deterministic: no clock (time comes in ``CycleInputs.t_ns``), no I/O, no logging — the
supervisor's listeners (logging, systemd status, telemetry) are the only effects, and lockstep
runs without them.

Two signals reach the arbiter one cycle late, by construction: a non-finite command (the core
has already zeroed that cycle's command) and the controller's θ̂/M̂ (read from the state the
previous cycle committed).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from drivers.samples import DepthSample, DvlSample, InsSample, eta_of
from uvd import core
from uvd.control.trajectory import setpoint
from uvd.core import Mode
from uvd.runtime import commands as cmd
from uvd.runtime.commands import OPERATOR_MODES, CommandResult
from uvd.runtime.failsafe import Action, Decision, Health, nav_health
from uvd.runtime.lifecycle import State
from uvd.runtime.supervisor import Supervisor

__all__ = ["ActuatorStatus", "CycleInputs", "CycleResult", "Cycle", "mode_for",
           "nonfinite_inputs", "inputs_record", "inputs_from_record"]

_OPERATOR_MODE = {"auto": Mode.CONTROL, "pdc": Mode.PDC, "hold-depth": Mode.HOLD_DEPTH,
                  "manual": Mode.MANUAL, "observe": Mode.ZERO}
#: how restrictive each mode is: a failsafe action never makes the mode less restrictive
_RANK = {Mode.CONTROL: 0, Mode.PDC: 1, Mode.MANUAL: 1, Mode.HOLD_DEPTH: 2, Mode.ZERO: 3}
_ACTION_MODE = {Action.FALLBACK: Mode.PDC, Action.HOLD_DEPTH: Mode.HOLD_DEPTH,
                Action.ZERO_THRUST: Mode.ZERO, Action.DISARM: Mode.ZERO}


@dataclass(frozen=True, slots=True)
class ActuatorStatus:
    """What the read phase learned from the amplifiers this cycle.

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
    """

    omega_rad_s: np.ndarray | None = None
    enabled: bool = False
    faults: tuple[str, ...] = ()
    feedback_t_ns: int | None = None
    bus_off: bool = False


@dataclass(frozen=True, slots=True)
class CycleInputs:
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


def inputs_record(inp: CycleInputs) -> dict[str, Any]:
    """Everything of ``inp`` but the sensor samples, as plain data for the cycle record (the
    samples travel as raw frames and their receive stamps); :func:`inputs_from_record` reads
    it back."""
    a = inp.actuators
    return {"actuators": None if a is None else {
                "omega_rad_s": a.omega_rad_s, "enabled": a.enabled, "faults": list(a.faults),
                "feedback_t_ns": a.feedback_t_ns, "bus_off": a.bus_off},
            "overrun_streak": inp.overrun_streak,
            "overrun_streak_exceeded": inp.overrun_streak_exceeded,
            "leak": inp.leak, "extra": None if inp.extra is None else dict(inp.extra)}


def inputs_from_record(t_ns: int, rec: Mapping[str, Any], ins=None, dvl=None, depth=None
                       ) -> CycleInputs:
    """The :class:`CycleInputs` of a recorded cycle: ``rec`` from :func:`inputs_record` (hub or
    JSON form) and the samples decoded again from the recorded frames."""
    a = rec.get("actuators")
    act = None
    if a is not None:
        w = a.get("omega_rad_s")
        act = ActuatorStatus(
            omega_rad_s=None if w is None else np.asarray(w, dtype=float),
            enabled=bool(a["enabled"]), faults=tuple(a.get("faults") or ()),
            feedback_t_ns=None if a.get("feedback_t_ns") is None else int(a["feedback_t_ns"]),
            bus_off=bool(a.get("bus_off", False)))
    return CycleInputs(t_ns, ins, dvl, depth, act, int(rec.get("overrun_streak", 0)),
                       bool(rec.get("overrun_streak_exceeded", False)), rec.get("leak"),
                       rec.get("extra"))


@dataclass(frozen=True, slots=True)
class CycleResult:
    """Everything the write phase needs from one update."""

    out: core.CoreOutputs
    health: Health
    decision: Decision
    state: State
    operator_mode: str


def mode_for(action: Action, operator_mode: str) -> Mode:
    """The core's mode: the operator's, unless the failsafe action asks a more restrictive
    one (FALLBACK turns the configured controller into PDC and leaves the others as they
    are; HOLD_DEPTH and ZERO_THRUST/DISARM override all but a more restrictive choice)."""
    mode = _OPERATOR_MODE[operator_mode]
    forced = _ACTION_MODE.get(action)
    if forced is None:
        return mode
    if forced is Mode.PDC:
        return Mode.PDC if mode is Mode.CONTROL else mode
    return forced if _RANK[forced] >= _RANK[mode] else mode


def nonfinite_inputs(ins, dvl, depth) -> tuple[str, ...]:
    """Names of the new samples holding NaN or inf where a number is used."""
    bad = []
    if ins is not None:
        vals = (ins.roll, ins.pitch, ins.heading)
        if not all(math.isfinite(x) for x in vals) or (
                ins.rates_valid and not math.isfinite(float(np.sum(ins.omega_body)))):
            bad.append("ins")
    if dvl is not None and dvl.bottom_lock and not math.isfinite(float(np.sum(
            dvl.velocity_body))):
        bad.append("dvl")
    if depth is not None and not math.isfinite(depth.depth_m):
        bad.append("depth")
    return tuple(bad)


class Cycle:
    """The cycle's update and the state it carries between cycles (module docstring).

    Parameters
    ----------
    core_cfg : uvd.core.CoreConfig
    supervisor : Supervisor
        Failsafe arbiter + lifecycle (its listeners are the caller's effects).
    hold_on_arm : bool
        ``[control] reference = "hold"``: arming replaces the reference with the pose the
        vehicle has then.
    north_m, east_m : float
        Navigation's initial horizontal position.
    """

    def __init__(self, core_cfg: core.CoreConfig, supervisor: Supervisor, *,
                 hold_on_arm: bool = False, north_m: float = 0.0, east_m: float = 0.0) -> None:
        self.core_cfg = core_cfg
        self.state = core.core_init(core_cfg, north_m=north_m, east_m=east_m)
        self.supervisor = supervisor
        self.hold_on_arm = hold_on_arm
        self.operator_mode = "auto"
        #: each thruster's effectiveness η the cycle allocates with (None: all healthy)
        self.thruster_eta: np.ndarray | None = None
        self.armed_at_ns: int | None = None
        self._manual: np.ndarray | None = None
        self._manual_until_ns = 0
        self._manual_timeout_ns = 0
        self._nonfinite_out: tuple[str, ...] = ()
        self._was_armed = False
        self._pending_hold: core.Reference | None = None

    # -- the operator (applied between cycles, by the caller's thread) --

    def apply(self, c: Any, t_ns: int) -> CommandResult:
        """Apply a command of :mod:`uvd.runtime.commands` (all but ``SetParams``, which is the
        configuration's: the daemon applies it)."""
        sup = self.supervisor
        if isinstance(c, cmd.Arm):
            step = sup.request_arm(t_ns, cause=c.cause)
            return CommandResult(bool(step.ok and sup.armed), step.refused or "")
        if isinstance(c, cmd.Disarm):
            step = sup.request_disarm(t_ns, cause=c.cause)
            return CommandResult(True, "" if step.transitions else "not armed")
        if isinstance(c, cmd.ResetFailsafe):
            refused = sup.reset_failsafe(t_ns, c.names)
            return CommandResult(not refused, "; ".join(f"{n}: {r}" for n, r in refused))
        if isinstance(c, cmd.SetMode):
            if c.mode not in OPERATOR_MODES:
                return CommandResult(False, f"unknown mode {c.mode!r} (one of "
                                            f"{', '.join(OPERATOR_MODES)})")
            if c.mode == "manual":
                self._manual = None  # a new manual session starts from zero wrench
            self.operator_mode = c.mode
            return CommandResult(True)
        if isinstance(c, cmd.ManualWrench):
            u = np.asarray(c.u, dtype=float)
            if u.shape != (6,) or not np.all(np.isfinite(u)):
                return CommandResult(False, "manual wrench must be six finite numbers")
            if not (math.isfinite(c.timeout_s) and c.timeout_s > 0.0):
                return CommandResult(False, "manual timeout_s must be > 0")
            self._manual = u
            self._manual_timeout_ns = int(c.timeout_s * 1e9)
            self._manual_until_ns = 0  # counted from the cycle that takes it
            return CommandResult(True, "" if self.operator_mode == "manual"
                                 else f"stored; mode is {self.operator_mode}, not manual")
        if isinstance(c, cmd.HoldPose):
            vals = (c.north_m, c.east_m, c.down_m, c.heading_rad)
            if not all(math.isfinite(float(x)) for x in vals):
                return CommandResult(False, "hold pose must be finite numbers")
            self._pending_hold = setpoint((c.north_m, c.east_m, c.down_m, 0.0, 0.0,
                                           c.heading_rad))
            return CommandResult(True)
        if isinstance(c, cmd.SetThrusterEta):
            return self._set_eta(c)
        return CommandResult(False, f"{type(c).__name__} is not supported by the cycle")

    def _set_eta(self, c: cmd.SetThrusterEta) -> CommandResult:
        """One thruster's effectiveness η (the operator's source); the result says which DOFs
        the cycle gives up with it."""
        n = self.core_cfg.allocator.n_thrusters
        try:
            i, e = int(c.thruster), float(c.eta)
        except (TypeError, ValueError):
            return CommandResult(False, "thruster must be an integer and eta a number")
        if not 1 <= i <= n:
            return CommandResult(False, f"thruster {i} is not one of 1…{n}")
        if not 0.0 <= e <= 1.0:  # NaN fails too
            return CommandResult(False, f"eta {c.eta!r} is not in [0, 1]")
        eta = np.ones(n) if self.thruster_eta is None else self.thruster_eta.copy()
        eta[i - 1] = e
        self.thruster_eta = None if (eta == 1.0).all() else eta
        given_up = self.core_cfg.accommodation_for(eta)[0].given_up
        return CommandResult(True, f"thruster {i} eta {e:g} ({c.source or 'operator'}); "
                                   f"given up: {', '.join(given_up) or 'none'}")

    def request_arm(self, t_ns: int, cause: str = "operator request"):
        """Run the arming checks on the latest health and arm (the lifecycle's step)."""
        return self.supervisor.request_arm(t_ns, cause=cause)

    def _manual_wrench(self, t_ns: int) -> np.ndarray | None:
        if self._manual is None:
            return None
        if self._manual_until_ns == 0:
            self._manual_until_ns = t_ns + self._manual_timeout_ns
        if t_ns > self._manual_until_ns:
            self._manual = None  # a silent joystick stops the vehicle
            return None
        return self._manual

    # -- the update --

    def update(self, inp: CycleInputs, dt: float) -> CycleResult:
        """One cycle: sense → health → arbiter → mode → act (module docstring)."""
        cfg = self.core_cfg
        st = self.state
        a = inp.actuators
        omega = a.omega_rad_s if a is not None else None
        ci = core.CoreInputs(inp.t_ns, inp.ins, inp.dvl, inp.depth, omega,
                             thruster_eta=self.thruster_eta)
        sensed = core.sense(cfg, ci, st, dt)
        nav = sensed.nav

        diag = cfg.controller.diagnostics(st.ctrl)
        fb_age = None
        if a is not None:
            fb_age = 0.0 if a.feedback_t_ns is None else (inp.t_ns - a.feedback_t_ns) * 1e-9
        h = Health(inp.t_ns, **nav_health(nav),
                   nonfinite_inputs=nonfinite_inputs(inp.ins, inp.dvl, inp.depth),
                   nonfinite_outputs=self._nonfinite_out, m_hat_min_eig=diag.m_min_eig,
                   theta_hat=diag.theta, amplifiers_enabled=bool(a is not None and a.enabled),
                   amplifier_faults=a.faults if a is not None else (), feedback_age_s=fb_age,
                   bus_off=bool(a is not None and a.bus_off),
                   overrun_streak=inp.overrun_streak,
                   overrun_streak_exceeded=inp.overrun_streak_exceeded, leak=inp.leak,
                   extra=inp.extra, armed=self.supervisor.armed)
        sup = self.supervisor
        d = sup.step(h)
        armed = sup.armed

        if armed and not self._was_armed:
            # armed since the last cycle: the reference's clock starts now; "hold" holds the
            # pose the vehicle has now
            self.armed_at_ns = inp.t_ns
            st = replace(st, t0_ns=None)
            if self.hold_on_arm:
                self.core_cfg = cfg = replace(cfg, reference=setpoint(eta_of(nav.H)))
        self._was_armed = armed
        if self._pending_hold is not None:
            self.core_cfg = cfg = replace(cfg, reference=self._pending_hold)
            self._pending_hold = None
            st = replace(st, t0_ns=None)

        mode = mode_for(d.action, self.operator_mode)
        manual = self._manual_wrench(inp.t_ns) if mode is Mode.MANUAL else None
        ci = core.CoreInputs(inp.t_ns, inp.ins, inp.dvl, inp.depth, omega, armed, mode, manual,
                             self.thruster_eta)
        out, self.state = core.act(cfg, sensed, ci, st, dt)
        self._nonfinite_out = ("command",) if out.status == "non-finite" else ()
        return CycleResult(out, h, d, sup.state, self.operator_mode)
