"""A latest-value mailbox between a producer task (a sensor reader) and the control cycle.

Sensor callbacks must not run heavy work on the loop's critical path, and the cycle must not
wait for a sensor. A :class:`Mailbox` decouples them: the producer :meth:`~Mailbox.put`\\ s
each new sample (O(1), the newest replaces an untaken one, which is counted as overwritten);
the cycle :meth:`~Mailbox.take`\\ s whatever arrived since its previous take — the newest
sample, or ``None`` — exactly what :class:`uvd.core.CoreInputs` expects per source;
:meth:`~Mailbox.take_until` takes it only if it was stamped by a given time. Both run
in the event loop's thread; a producer in another thread is also safe (attribute swaps are
atomic under the GIL).
"""

from __future__ import annotations

from typing import Generic, TypeVar

__all__ = ["Mailbox"]

T = TypeVar("T")


class Mailbox(Generic[T]):
    """Holds the newest untaken item.

    Attributes
    ----------
    puts, takes, overwritten : int
        Items put, items taken, items replaced before anyone took them.
    """

    __slots__ = ("_item", "puts", "takes", "overwritten", "name")

    def __init__(self, name: str = "") -> None:
        self.name = name
        self._item: T | None = None
        self.puts = 0
        self.takes = 0
        self.overwritten = 0

    def put(self, item: T) -> None:
        """Deposit ``item`` (replacing an untaken one)."""
        if self._item is not None:
            self.overwritten += 1
        self._item = item
        self.puts += 1

    def take(self) -> T | None:
        """The newest item since the previous take, or None; empties the mailbox."""
        item, self._item = self._item, None
        if item is not None:
            self.takes += 1
        return item

    def take_until(self, t_ns: int) -> T | None:
        """The newest item if it was stamped (``item.t_ns``) at or before ``t_ns``, else None;
        a later item stays for the next take."""
        item = self._item
        if item is None or item.t_ns > t_ns:
            return None
        return self.take()

    def peek(self) -> T | None:
        """The untaken item without taking it."""
        return self._item

    def stats(self) -> dict[str, int]:
        return {"puts": self.puts, "takes": self.takes, "overwritten": self.overwritten}
