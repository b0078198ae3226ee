"""The operator's failsafe reset of a disarmed vehicle brings the amplifiers back first.

A drive that faulted (its command timeout during a CAN silence, a bus-off, its own EMCY)
stays in FAULT until the daemon sends it a fault reset, and one that rebooted stays
pre-operational, unconfigured, until the daemon configures and starts it again: neither
happens by itself (docs/can.md, "Nothing is re-enabled by the bus"), so a reset of the
latched ``amplifier_fault`` would be refused for as long as the daemon runs. The decision is
the operator's: a :class:`~uvd.runtime.commands.ResetFailsafe` taken while disarmed
(STANDBY) is held, the CAN component's :meth:`~uvd.runtime.can_component.CanComponent.recover`
runs (off the loop's thread), and the reset is applied at the first cycle after it whose
amplifier status has no fault, every drive enabled and the feedback fresh — or
:data:`SETTLE_S` after it, or :data:`HOLD_MAX_S` after the reset came, whichever is first:
then a fault that persists refuses the reset by name, as before. The reset goes through the
cycle as every command does, recorded at the cycle that applied it (a replay applies it
there). Armed, a reset is applied at once and nothing is recovered: a thruster never comes
back mid-flight by a reset.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Any

from uvd.runtime.commands import ResetFailsafe
from uvd.runtime.lifecycle import State

__all__ = ["AmplifierRecovery", "SETTLE_S", "HOLD_MAX_S"]

log = logging.getLogger("uvd.daemon")

#: after the recovery, how long a held reset waits for the amplifiers' faults to clear (a
#: fault reset takes six cycles, the CiA 402 way back to OPERATION ENABLED three more)
SETTLE_S = 3.0
#: the longest a reset is held in all (the recovery's SDO exchanges are bounded well within)
HOLD_MAX_S = 10.0


class AmplifierRecovery:
    """Resets held while the amplifiers are brought back (the module docstring).

    ``can``: the :class:`~uvd.runtime.can_component.CanComponent` (no amplifiers fitted:
    resets are never held); ``feedback_stale_s``: the ``[failsafe]`` threshold in force
    (a callable: it reloads) that the amplifiers' feedback must be younger than."""

    def __init__(self, can: Any, feedback_stale_s: Callable[[], float]) -> None:
        self.can = can
        self.feedback_stale_s = feedback_stale_s
        self.held: list[tuple[Any, int]] = []  # (pending command, t_ns it came)
        self._task: asyncio.Task | None = None
        self._done_ns = 0
        self._clear = False
        self.recoveries = 0

    def hold(self, pending: Any, t_ns: int, state: State) -> bool:
        """Hold ``pending`` (a queued command) when it is a reset of a disarmed vehicle with
        amplifiers, and start their recovery unless one runs; False: apply it now."""
        if not (isinstance(pending.command, ResetFailsafe) and state is State.STANDBY
                and getattr(self.can, "group", None) is not None):
            return False
        self.held.append((pending, t_ns))
        if self._task is None or (self._task.done() and len(self.held) == 1):
            # none runs, or the last one ended after the reset it outlasted was applied
            if self._task is not None and not self._done_ns:
                self._tell(self._task)
            self._done_ns, self._clear = 0, False
            self.recoveries += 1
            self._task = asyncio.get_running_loop().create_task(self.can.recover(),
                                                               name="amplifier recovery")
        return True

    def seen(self, t_ns: int, actuators: Any) -> None:
        """The cycle's amplifier status read after the recovery: are they back — no fault,
        every drive in OPERATION ENABLED, their feedback fresh (so that the reset clears
        ``feedback_missing`` too, not a second later by itself)?"""
        if self._task is not None and self._task.done():
            if not self._done_ns:
                self._done_ns = t_ns
                self._tell(self._task)
            a = actuators
            self._clear = a is not None and not a.faults and not a.bus_off and a.enabled \
                and a.feedback_t_ns is not None \
                and (t_ns - a.feedback_t_ns) * 1e-9 <= self.feedback_stale_s()

    def due(self, t_ns: int) -> list[Any]:
        """The held commands to apply at this cycle (the recovery over, see the module
        docstring)."""
        if not self.held:
            return []
        since_first = (t_ns - self.held[0][1]) * 1e-9
        settled = self._done_ns and (self._clear or (t_ns - self._done_ns) * 1e-9 >= SETTLE_S)
        if not (settled or since_first >= HOLD_MAX_S):
            return []
        if not settled:
            log.warning("amplifier recovery not over %.0f s after the operator's reset: the "
                        "reset is applied as things are", HOLD_MAX_S)
        out = [p for p, _ in self.held]
        self.held.clear()
        if self._task is not None and self._task.done():
            self._task = None  # else the next reset waits for it, then recovers anew
        return out

    @staticmethod
    def _tell(task: asyncio.Task) -> None:
        if task.cancelled():
            return
        exc = task.exception()
        if exc is not None:
            log.error("amplifier recovery failed: %s: %s", type(exc).__name__, exc)
        else:
            log.info("amplifier recovery for the operator's reset: %s", task.result())
