"""Commands from outside the loop — ground stations, Zenoh, tests — as data the cycle reads.

A link (MAVLink, a test, a tool) never calls into the loop. It builds a command and
:meth:`CommandQueue.put`\\ s it, from any thread; the daemon's cycle drains the queue at its next
start, applies each command at that cycle boundary (arming through the lifecycle's checks, a
mode through the arbiter's rules, gains as a reload does) and resolves the command's future with
a :class:`CommandResult`. Each command and its result is also published on the telemetry hub
as a ``"command"`` record, so every sink sees who asked for what and what came of it.

The queue is bounded: when full, :meth:`~CommandQueue.put` resolves the new command at once
with ``ok=False, reason="command queue full"`` and counts it — never blocks, never grows.

A ``"command"`` record carries ``t_ns`` (the cycle that applied it), ``command`` (the class
name), ``args`` (its fields), ``source``, ``ok`` and ``reason``: a replay applies the same
commands at the same cycles (:func:`command_from_record`).

Operator modes (:class:`SetMode`) are the values of :data:`OPERATOR_MODES`; the arbiter's
failsafe action always overrides them when it is more restrictive (docs/architecture.md).
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Mapping
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

__all__ = ["CommandResult", "command_from_record", "Arm", "Disarm", "SetMode", "ManualWrench",
           "HoldPose", "ResetFailsafe", "SetParams", "SetThrusterEta", "FaultReport", "Command",
           "CommandQueue", "OPERATOR_MODES", "AutoArm"]

#: the operator's modes: ``auto`` runs the configured controller (PDC, AMBC, two-step AMBC);
#: ``pdc`` PD control with adaptation frozen; ``hold-depth`` depth, roll and pitch only;
#: ``manual`` the operator's body wrench (:class:`ManualWrench`); ``observe`` zero thrust while
#: the online estimators run (identification only)
OPERATOR_MODES = ("auto", "pdc", "hold-depth", "manual", "observe")


@dataclass(frozen=True)
class CommandResult:
    """What became of a command: ``ok``, and why not (``reason``) when refused."""

    ok: bool
    reason: str = ""


@dataclass(frozen=True)
class Arm:
    """Run the arming checks and arm."""

    cause: str = "operator request"
    source: str = ""


@dataclass(frozen=True)
class Disarm:
    cause: str = "operator request"
    source: str = ""


@dataclass(frozen=True)
class SetMode:
    """Switch the operator mode (one of :data:`OPERATOR_MODES`)."""

    mode: str
    source: str = ""


@dataclass(frozen=True)
class ManualWrench:
    """Body force and torque for ``manual`` mode, [f; τ] in N and N m (body frame).

    It holds until ``timeout_s`` after the cycle that took it; then the manual wrench is zero
    (a silent joystick stops the vehicle).
    """

    u: tuple[float, float, float, float, float, float]
    timeout_s: float = 0.5
    source: str = ""


@dataclass(frozen=True)
class HoldPose:
    """A setpoint to hold: position NED (m) and heading (rad), level attitude."""

    north_m: float
    east_m: float
    down_m: float
    heading_rad: float
    source: str = ""


@dataclass(frozen=True)
class ResetFailsafe:
    """Reset failsafe triggers whose condition no longer holds (``names``; when None, every
    active one, and a latched one whose condition holds is refused: MAVLink's
    MAV_CMD_USER_2, ``uvd reset-failsafe``; :func:`uvd.runtime.failsafe.reset`)."""

    names: tuple[str, ...] | None = None
    source: str = ""


@dataclass(frozen=True)
class SetParams:
    """Change reloadable configuration keys (``{"control.kp": 300.0, …}``), applied at a cycle
    boundary exactly as a SIGHUP reload applies them; refused as a whole if any key is unknown,
    not reloadable or invalid (the reason names it)."""

    values: Mapping[str, Any]
    source: str = ""


@dataclass(frozen=True)
class SetThrusterEta:
    """Set thruster ``thruster``'s (1-based, the vehicle's order) effectiveness η ∈ [0, 1]
    (1 healthy — clears it —, 0.5 half its thrust, 0 dead): from the next cycle allocation
    uses it (:func:`uvd.control.allocation.accommodate`); the result names the DOFs then
    given up. The operator's source of η (issue 33); recorded and replayed as every command."""

    thruster: int
    eta: float
    source: str = ""


@dataclass(frozen=True)
class FaultReport:
    """A fault sample of uvd-fdc (``uvd/<vehicle>/fault/<kind>``, schema ``uvd.fault.v1``) as
    the daemon's Zenoh face received it: uvd-fdc's source of η (issue 33). The cycle decides
    what to do with it by ``[faults.fdc] accept`` (:mod:`uvd.runtime.fdc_source`): a
    ``thruster`` sample names ``channel`` thrusterI with ``relative_change`` η − 1; every other
    kind is told to the operator, never acted on. ``since_t_ns``: the change time uvd-fdc's
    residual found (None: not given)."""

    kind: str
    channel: str
    relative_change: float | None
    t_ns: int
    confidence: float = 1.0
    since_t_ns: int | None = None
    source: str = "uvd-fdc"


Command = (Arm | Disarm | SetMode | ManualWrench | HoldPose | ResetFailsafe | SetParams
           | SetThrusterEta | FaultReport)
_BY_NAME = {c.__name__: c for c in (Arm, Disarm, SetMode, ManualWrench, HoldPose, ResetFailsafe,
                                    SetParams, SetThrusterEta, FaultReport)}


def command_from_record(rec: Mapping[str, Any]) -> Any:
    """The command of a ``"command"`` record (hub or JSON form).

    Raises
    ------
    ValueError
        Unknown command or arguments that do not fit it (the message names them).
    """
    cls = _BY_NAME.get(str(rec.get("command")))
    if cls is None:
        raise ValueError(f"unknown command {rec.get('command')!r} (one of {', '.join(_BY_NAME)})")
    args = rec.get("args") or {}
    if not isinstance(args, Mapping):
        raise ValueError(f"{cls.__name__}: args {args!r:.40} are not an object")
    args = dict(args)
    for key in ("u", "names"):
        if isinstance(args.get(key), list):
            args[key] = tuple(args[key])
    try:
        return cls(**args)
    except TypeError as exc:
        raise ValueError(f"{cls.__name__}: {exc}") from exc


@dataclass
class _Pending:
    command: Any
    future: Future = field(default_factory=Future)


class CommandQueue:
    """Bounded, thread-safe queue of commands for the cycle.

    Parameters
    ----------
    capacity : int
        Commands waiting at most; more are refused at once (``dropped`` counts them).
    """

    def __init__(self, capacity: int = 64) -> None:
        self.capacity = int(capacity)
        self._q: deque[_Pending] = deque()
        self._lock = threading.Lock()
        self.accepted = 0
        self.dropped = 0

    def put(self, command: Any) -> Future:
        """Queue ``command``; returns a future resolved with its :class:`CommandResult` at the
        next cycle (``asyncio.wrap_future`` awaits it from a coroutine)."""
        p = _Pending(command)
        with self._lock:
            if len(self._q) >= self.capacity:
                self.dropped += 1
                p.future.set_result(CommandResult(False, "command queue full"))
                return p.future
            self._q.append(p)
            self.accepted += 1
        return p.future

    def drain(self) -> list[_Pending]:
        """From the cycle: every waiting command, oldest first."""
        with self._lock:
            if not self._q:
                return []
            out = list(self._q)
            self._q.clear()
        return out

    def stats(self) -> dict[str, int]:
        return {"accepted": self.accepted, "dropped": self.dropped, "waiting": len(self._q)}


class AutoArm:
    """``uvd run --arm``: an :class:`Arm` every 200 ms of cycles (every second cycle at 10 Hz,
    counted from the first in STANDBY) until one succeeds — once: a failsafe disarm is never
    undone automatically. Tries are counted in cycles, not measured in time: the cycle a try
    falls on must not depend on jitter, or a realtime replay arms a cycle apart from the
    recording. Refusals are logged with their reasons every 2 s."""

    def __init__(self, rate_hz: float) -> None:
        self.every = max(1, round(0.2 * rate_hz))
        self._wait = 0
        self._last_log_ns = 0
        #: the last try's refusal (None: armed, or not tried)
        self.refusal: str | None = None

    def due(self, t_ns: int, standby: bool, armed_before: bool) -> Arm | None:
        """The command to apply at this cycle, if a try falls on it."""
        if armed_before or not standby:
            return None
        if self._wait > 0:
            self._wait -= 1
            return None
        self._wait = self.every - 1
        return Arm(cause="uvd run --arm", source="uvd run --arm")

    def answered(self, res: CommandResult, t_ns: int, log) -> None:
        self.refusal = None if res.ok else res.reason
        if self.refusal and t_ns - self._last_log_ns >= 2_000_000_000:
            self._last_log_ns = t_ns
            log.info("%s", self.refusal)
