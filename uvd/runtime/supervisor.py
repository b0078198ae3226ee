"""Per-cycle glue of the pure failsafe arbiter and the pure lifecycle, with effects at the edge.

:class:`Supervisor` owns the arbiter state, the lifecycle and the trigger registry. The control
cycle calls :meth:`Supervisor.step` once with a :class:`~uvd.runtime.failsafe.Health`
snapshot; it evaluates the arbiter, lets the lifecycle follow the decision, and hands every
event and transition to the listeners (logging through a queue handler, ``STATUS=`` to
systemd, a telemetry record) — the only effects, and all non-blocking. Operator requests
(arm, disarm, failsafe reset) and the application's boot/shutdown go through the same object,
so every change of state has one record with its cause.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from uvd.runtime.failsafe import (
    ArbiterState,
    Decision,
    FailsafeEvent,
    Health,
    Thresholds,
    TriggerDef,
    arbiter_init,
    evaluate,
    make_registry,
    reset,
)
from uvd.runtime.lifecycle import (
    ArmingCheck,
    Lifecycle,
    LifecycleStep,
    State,
    Transition,
    builtin_checks,
    run_checks,
)

__all__ = ["Supervisor"]


class Supervisor:
    """Failsafe arbiter + lifecycle, stepped by the control cycle.

    Parameters
    ----------
    thresholds : Thresholds
        ``[failsafe]``.
    extra_triggers : iterable of TriggerDef
        Plug-in triggers (e.g. operator-heartbeat loss from the ground-station link).
    checks : sequence of ArmingCheck, optional
        Arming checks; :func:`~uvd.runtime.lifecycle.builtin_checks` by default.
    on_event : callable, optional
        ``on_event(FailsafeEvent)`` for every arbiter event.
    on_transition : callable, optional
        ``on_transition(Transition, decision)`` for every lifecycle transition.
    history : int
        Events and transitions kept in :attr:`history` (for the demo's ``failsafe_events``).
    """

    def __init__(self, thresholds: Thresholds | None = None, *,
                 extra_triggers: Iterable[TriggerDef] = (),
                 checks: Sequence[ArmingCheck] | None = None,
                 on_event: Callable[[FailsafeEvent], None] | None = None,
                 on_transition: Callable[[Transition, Decision | None], None] | None = None,
                 history: int = 1000) -> None:
        self.thresholds = thresholds or Thresholds()
        self.extra_triggers = tuple(extra_triggers)
        self.registry = make_registry(self.thresholds, self.extra_triggers)
        self.checks = tuple(checks) if checks is not None else builtin_checks(self.thresholds)
        self._custom_checks = checks is not None
        self.arbiter: ArbiterState = arbiter_init(self.registry)
        self.lifecycle = Lifecycle()
        self.decision: Decision | None = None
        self.last_health: Health | None = None
        self.on_event = on_event
        self.on_transition = on_transition
        self.history: deque[dict[str, Any]] = deque(maxlen=history)
        self.listener_errors = 0

    # -- edges

    def _emit_event(self, ev: FailsafeEvent) -> None:
        self.history.append({"type": "failsafe", **ev.as_dict()})
        if self.on_event is not None:
            try:
                self.on_event(ev)
            except Exception:  # a listener never breaks the cycle
                self.listener_errors += 1

    def _apply(self, step: LifecycleStep) -> LifecycleStep:
        self.lifecycle = step.lifecycle
        for tr in step.transitions:
            self.history.append({"type": "lifecycle", **tr.as_dict()})
            if self.on_transition is not None:
                try:
                    self.on_transition(tr, self.decision)
                except Exception:
                    self.listener_errors += 1
        return step

    # -- per cycle

    def step(self, health: Health) -> Decision:
        """Evaluate the arbiter on ``health`` and follow it with the lifecycle; never raises."""
        self.last_health = health
        decision, self.arbiter = evaluate(self.registry, self.thresholds, self.arbiter, health)
        self.decision = decision
        for ev in decision.events:
            self._emit_event(ev)
        self._apply(self.lifecycle.on_failsafe(health.t_ns, decision))
        return decision

    @property
    def state(self) -> State:
        return self.lifecycle.state

    @property
    def armed(self) -> bool:
        return self.lifecycle.armed

    def status_text(self) -> str:
        return self.lifecycle.status_text(self.decision)

    # -- requests

    def boot_complete(self, t_ns: int, cause: str = "drivers up") -> LifecycleStep:
        return self._apply(self.lifecycle.boot_complete(t_ns, cause))

    def request_arm(self, t_ns: int, health: Health | None = None,
                    cause: str = "operator request") -> LifecycleStep:
        """Run the arming checks on ``health`` (the last one stepped by default) and arm."""
        h = health if health is not None else (self.last_health or Health(t_ns=t_ns))
        results = run_checks(self.checks, h, self.decision)
        return self._apply(self.lifecycle.request_arm(t_ns, results, cause))

    def request_disarm(self, t_ns: int, cause: str = "operator request") -> LifecycleStep:
        return self._apply(self.lifecycle.request_disarm(t_ns, cause))

    def request_shutdown(self, t_ns: int, cause: str) -> LifecycleStep:
        return self._apply(self.lifecycle.request_shutdown(t_ns, cause))

    def reset_failsafe(self, t_ns: int, names: Iterable[str] | None = None
                       ) -> tuple[tuple[str, str], ...]:
        """Operator reset of latched triggers; returns the refused ones with reasons."""
        h = self.last_health or Health(t_ns=t_ns)
        if h.t_ns != t_ns:
            h = _with_time(h, t_ns)
        self.arbiter, events, refused = reset(self.registry, self.thresholds, self.arbiter, h,
                                              names)
        for ev in events:
            self._emit_event(ev)
        return refused

    def set_thresholds(self, thresholds: Thresholds) -> None:
        """Apply new thresholds (reload); trigger states are kept by name."""
        self.thresholds = thresholds
        self.registry = make_registry(thresholds, self.extra_triggers)
        if not self._custom_checks:
            self.checks = builtin_checks(thresholds)

    def failsafe_events(self) -> list[dict[str, Any]]:
        """Every event and transition kept, oldest first (plain dicts, for JSON)."""
        return list(self.history)


def _with_time(h: Health, t_ns: int) -> Health:
    from dataclasses import replace
    return replace(h, t_ns=t_ns)
