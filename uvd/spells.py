"""When to tell of failures that come in spells — a full disk, a lost peer: the one rule of the
daemon's record files, its telemetry sinks and the CAN log (a utility: it imports nothing of
the project, so drivers may use it)."""

from __future__ import annotations

__all__ = ["FailureSpells"]


class FailureSpells:
    """When to tell of failures that come in spells (a full disk, a lost peer): each spell's
    first failure and its end for the first ``told`` spells, and every ``every`` th failure
    throughout — a disk that fills and empties by turns is not a line a write."""

    def __init__(self, every: int, told: int = 10) -> None:
        self.every = int(every)
        self.told = int(told)
        self.total = 0  # failures
        self.in_a_row = 0  # of this spell
        self.spells = 0

    def failed(self) -> bool:
        """Count a failure; True when it is to be told."""
        self.total += 1
        self.in_a_row += 1
        if self.in_a_row == 1:
            self.spells += 1
        return (self.in_a_row == 1 and self.spells <= self.told) or self.total % self.every == 0

    def recovered(self) -> bool:
        """A success: True when it ends a spell that is to be told (then the spell is over)."""
        ended = self.in_a_row > 0
        self.in_a_row = 0
        return ended and self.spells <= self.told
