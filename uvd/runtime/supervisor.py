"""The running cycle's holder: its configuration and its state — one value each — and the
effects at the edge.

Every decision is a pure function of :mod:`uvd.runtime.cycle` (``update``, ``apply``, the
lifecycle's requests); :class:`Supervisor` only keeps the current
:class:`~uvd.runtime.cycle.CycleConfig` and :class:`~uvd.runtime.cycle.CycleState` of a
running daemon, lockstep run or replay, and hands what each call returned as data — failsafe
events and lifecycle transitions — to the listeners (logging through a queue handler,
``STATUS=`` to systemd, a telemetry record), all non-blocking. Operator requests (arm, disarm,
failsafe reset) and the application's boot/shutdown go through the same object, so every
change of state has one record with its cause.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import replace
from typing import Any

from uvd.runtime import cycle
from uvd.runtime.commands import CommandResult
from uvd.runtime.cycle import CycleConfig, CycleInputs, CycleResult, CycleState
from uvd.runtime.failsafe import Decision, FailsafeEvent, Health, Thresholds
from uvd.runtime.lifecycle import LifecycleStep, State, Transition

__all__ = ["Supervisor"]


class Supervisor:
    """The running cycle: :attr:`config` (constant between reloads) and :attr:`data` (the
    cycle's state, replaced by every call), with listeners for what changed.

    Parameters
    ----------
    config : CycleConfig, optional
        The cycle (:func:`uvd.runtime.build.make_cycle`); None: a lifecycle and the default
        failsafe thresholds without a core (an :class:`~uvd.runtime.app.App` run alone).
    on_event : callable, optional
        ``on_event(FailsafeEvent)`` for every arbiter event.
    on_transition : callable, optional
        ``on_transition(Transition, decision)`` for every lifecycle transition.
    history : int
        Events and transitions kept in :attr:`history` (for the demo's ``failsafe_events``).
    armed, north_m, east_m
        As :func:`uvd.runtime.cycle.cycle_init`.
    """

    def __init__(self, config: CycleConfig | None = None, *,
                 on_event: Callable[[FailsafeEvent], None] | None = None,
                 on_transition: Callable[[Transition, Decision | None], None] | None = None,
                 history: int = 1000, armed: bool = False, north_m: float | None = None,
                 east_m: float | None = None) -> None:
        self.config = config if config is not None else CycleConfig(None)
        #: the cycle's state: one immutable value, replaced by every update and request
        self.data: CycleState = cycle.cycle_init(self.config, armed=armed, north_m=north_m,
                                                 east_m=east_m)
        self.on_event = on_event
        self.on_transition = on_transition
        self.history: deque[dict[str, Any]] = deque(maxlen=history)
        self.listener_errors = 0

    # -- edges

    def _emit(self, effects: Iterable[Any]) -> None:
        for e in effects:
            if isinstance(e, FailsafeEvent):
                self.history.append({"type": "failsafe", **e.as_dict()})
                fn, args = self.on_event, (e,)
            else:
                self.history.append({"type": "lifecycle", **e.as_dict()})
                fn, args = self.on_transition, (e, self.data.decision)
            if fn is not None:
                try:
                    fn(*args)
                except Exception:  # a listener never breaks the cycle
                    self.listener_errors += 1

    def _step(self, step: LifecycleStep, data: CycleState) -> LifecycleStep:
        self.data = data
        self._emit(step.transitions)
        return step

    # -- per cycle

    def update(self, inputs: CycleInputs, dt: float) -> CycleResult:
        """One cycle (:func:`uvd.runtime.cycle.update`); the new state is kept."""
        r, self.data = cycle.update(self.config, self.data, inputs, dt)
        if r.effects:
            self._emit(r.effects)
        return r

    def step(self, health: Health) -> Decision:
        """The arbiter and the lifecycle alone on ``health`` (a cycle that raised)."""
        d, self.data, effects = cycle.supervise(self.config, self.data, health)
        self._emit(effects)
        return d

    # -- requests (between cycles)

    def apply(self, command: Any, t_ns: int) -> CommandResult:
        """An operator command (:func:`uvd.runtime.cycle.apply`)."""
        res, self.data, effects = cycle.apply(self.config, self.data, command, t_ns)
        self._emit(effects)
        return res

    def boot_complete(self, t_ns: int, cause: str = "drivers up") -> LifecycleStep:
        return self._step(*cycle.boot_complete(self.data, t_ns, cause))

    def request_arm(self, t_ns: int, health: Health | None = None,
                    cause: str = "operator request") -> LifecycleStep:
        """Run the arming checks on ``health`` (the last one stepped by default) and arm."""
        return self._step(*cycle.request_arm(self.config, self.data, t_ns, cause, health))

    def request_disarm(self, t_ns: int, cause: str = "operator request") -> LifecycleStep:
        return self._step(*cycle.request_disarm(self.data, t_ns, cause))

    def request_shutdown(self, t_ns: int, cause: str) -> LifecycleStep:
        return self._step(*cycle.request_shutdown(self.data, t_ns, cause))

    def reset_failsafe(self, t_ns: int, names: Iterable[str] | None = None
                       ) -> tuple[tuple[str, str], ...]:
        """Operator reset of latched triggers; returns the refused ones with reasons."""
        refused, self.data, events = cycle.reset_failsafe(self.config, self.data, t_ns, names)
        self._emit(events)
        return refused

    def reconfigure(self, config: CycleConfig) -> None:
        """Run on with a new configuration (a reload, between cycles); the state stays —
        trigger states by name."""
        self.config = config

    def set_thresholds(self, thresholds: Thresholds) -> None:
        """New failsafe thresholds (a reload); trigger states are kept by name."""
        self.config = replace(self.config, thresholds=thresholds)

    # -- views of the state

    @property
    def thresholds(self) -> Thresholds:
        return self.config.thresholds

    @property
    def state(self) -> State:
        """The lifecycle's state."""
        return self.data.lifecycle.state

    @property
    def armed(self) -> bool:
        return self.data.lifecycle.armed

    @property
    def decision(self) -> Decision | None:
        return self.data.decision

    @property
    def last_health(self) -> Health | None:
        return self.data.health

    @property
    def armed_at_ns(self) -> int | None:
        return self.data.armed_at_ns

    def status_text(self) -> str:
        return self.data.lifecycle.status_text(self.data.decision)

    def failsafe_events(self) -> list[dict[str, Any]]:
        """Every event and transition kept, oldest first (plain dicts, for JSON)."""
        return list(self.history)
