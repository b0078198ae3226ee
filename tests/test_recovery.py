"""uvd.runtime.recovery's rules for a held failsafe reset, on the event loop with a CAN
component whose recovery takes as long as the test says (the real one, over sim-bridge's
drives, is tests/test_reset_failsafe_cli.py): the reset waits for the amplifiers, at most
HOLD_MAX_S; a recovery that outlasts it does not stop the next reset from recovering anew."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

from uvd.runtime import recovery
from uvd.runtime.commands import Arm, ResetFailsafe
from uvd.runtime.lifecycle import State
from uvd.runtime.recovery import AmplifierRecovery

S = 1_000_000_000


class SlowCan:
    """A CAN component with amplifiers whose recovery takes ``seconds``."""

    def __init__(self, seconds: float) -> None:
        self.group = object()
        self.seconds = seconds
        self.calls = 0

    async def recover(self) -> str:
        self.calls += 1
        await asyncio.sleep(self.seconds)
        return "fault reset sent to the amplifiers"


def pending(command):
    return SimpleNamespace(command=command)


BACK = SimpleNamespace(faults=(), bus_off=False, enabled=True, feedback_t_ns=0)
FAULTED = SimpleNamespace(faults=("node 5: drive_fault",), bus_off=False, enabled=False,
                          feedback_t_ns=0)


def test_a_reset_is_held_until_the_amplifiers_are_back_and_only_disarmed():
    async def main():
        r = AmplifierRecovery(SlowCan(0.05), lambda: 0.5)
        assert not r.hold(pending(ResetFailsafe()), 0, State.ARMED)  # armed: at once
        assert not r.hold(pending(Arm()), 0, State.STANDBY)  # only a reset is held
        reset = pending(ResetFailsafe())
        assert r.hold(reset, 0, State.STANDBY) and r.due(1) == []
        await asyncio.sleep(0.1)  # the recovery is over
        r.seen(S // 10, FAULTED)
        assert r.due(S // 10) == []  # not back yet
        r.seen(S // 5, SimpleNamespace(**{**BACK.__dict__, "feedback_t_ns": S // 5}))
        assert r.due(S // 5) == [reset] and r.held == []
        return r

    r = asyncio.run(asyncio.wait_for(main(), 10.0))
    assert r.recoveries == 1 and r.can.calls == 1


def test_a_recovery_that_outlasts_the_hold_does_not_keep_the_next_reset_from_its_own(
        monkeypatch, caplog):
    monkeypatch.setattr(recovery, "HOLD_MAX_S", 0.1)

    async def main():
        r = AmplifierRecovery(SlowCan(0.3), lambda: 0.5)
        first = pending(ResetFailsafe())
        assert r.hold(first, 0, State.STANDBY)
        await asyncio.sleep(0.15)
        assert r.due(S // 10) == [first]  # applied as things are, the recovery still on
        await asyncio.sleep(0.3)  # it ends, no reset waiting for it
        r.seen(S, FAULTED)
        second = pending(ResetFailsafe())
        assert r.hold(second, 2 * S, State.STANDBY)  # a recovery of its own, not the old one
        assert r.due(2 * S + 1) == []
        await asyncio.sleep(0.35)
        r.seen(3 * S, SimpleNamespace(**{**BACK.__dict__, "feedback_t_ns": 3 * S}))
        assert r.due(3 * S) == [second]
        return r

    r = asyncio.run(asyncio.wait_for(main(), 10.0))
    assert r.recoveries == 2 and r.can.calls == 2
    assert "amplifier recovery not over" in caplog.text  # the first reset said so
