"""Progress of a long command: one helper for every command that takes minutes.

On a terminal a tqdm bar with rate and ETA; when stderr is not a terminal (a log, CI,
``make results > out``) a plain line every ``every_s`` seconds with the same figures; nothing
with ``quiet``. Text lines (:meth:`Progress.note`) go through the same path, so they never
tear a bar. The plain lines' ETA is the recent pace's (:class:`Pace`), as is that of ``make
results``' campaign lines (``uvd.campaign.publish``). tqdm rather than rich: it does this one
job, has no dependencies of its own, and is imported only when a bar is shown.
"""

from __future__ import annotations

import sys
import time
from collections import deque
from collections.abc import Callable
from typing import Any, TextIO

__all__ = ["Pace", "Progress"]

#: the span of the recent pace (s): long enough to average over runs of different lengths,
#: short enough to forget a start made beside other work
PACE_WINDOW_S = 600.0


class Pace:
    """Time left at the recent pace: the count's progress over about the last ``window_s``
    seconds (from the start while the work is younger), not since the start — a campaign that
    started beside other work and then had the machine to itself would otherwise be told
    hours too many (a false-alarm campaign: "~4 h 34 min left" at 30 of 130 runs when 1 h 40
    min was).

    ``mark(done, total, now)`` each time the count moves; it returns the seconds left to
    ``total`` (0 when reached; None: no total, or nothing to estimate from yet)."""

    def __init__(self, start: float, done: float = 0.0, window_s: float = PACE_WINDOW_S) -> None:
        self.window_s = window_s
        self._marks: deque[tuple[float, float]] = deque([(start, done)])

    def mark(self, done: float, total: float | None, now: float) -> float | None:
        marks = self._marks
        marks.append((now, done))
        while len(marks) > 2 and now - marks[1][0] >= self.window_s:
            marks.popleft()  # the oldest kept is the newest at least window_s old
        t_old, done_old = marks[0]
        if not total:
            return None
        if done >= total:
            return 0.0
        if done <= done_old or now <= t_old:
            return None
        return (now - t_old) * (total - done) / (done - done_old)


class Progress:
    """A progress display.

    Parameters
    ----------
    what : str
        What is counted (the bar's label), e.g. ``"replay"``.
    unit : str
        Unit of the count (``"cycles"``, ``"s simulated"``).
    quiet : bool
        Show nothing (``--quiet``).
    stream : text file, optional
        Where to write (stderr by default); a terminal gets a bar.
    every_s : float
        Interval of the plain lines when ``stream`` is not a terminal.
    clock : callable
        Monotonic seconds.
    """

    def __init__(self, what: str, *, unit: str = "", quiet: bool = False,
                 stream: TextIO | None = None, every_s: float = 10.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.what, self.unit, self.quiet = what, unit, quiet
        self.stream = sys.stderr if stream is None else stream
        self.every_s, self.clock = every_s, clock
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._bar: Any = None
        self._total: float | None = None
        self._t0 = clock()
        self._pace = Pace(self._t0)
        self._next = self._t0 + every_s
        self._done = 0.0
        self._started = False

    def update(self, done: float, total: float | None = None, label: str | None = None) -> None:
        """The count has reached ``done`` (of ``total``); a smaller ``done`` or another
        ``total`` starts over (the next run of an experiment)."""
        if self.quiet:
            return
        restart = self._started and (total != self._total or done < self._done)
        if restart:
            self._t0 = self.clock()
            self._pace = Pace(self._t0)
        self._started, self._total, self._done = True, total, done
        if label is not None:
            self.what = label
        if self.tty:
            self._bar_update(done, total, restart)
            return
        now = self.clock()
        if now < self._next:
            return
        self._next = now + self.every_s
        self._line(done, total, now)

    def _bar_update(self, done: float, total: float | None, restart: bool) -> None:
        if self._bar is None or restart:
            from tqdm import tqdm
            if self._bar is not None:
                self._bar.close()
            self._bar = tqdm(total=total, desc=self.what, unit=f" {self.unit}".rstrip(),
                             file=self.stream, dynamic_ncols=True, leave=False)
        self._bar.update(done - self._bar.n)

    def _line(self, done: float, total: float | None, now: float) -> None:
        el = now - self._t0
        text = f"  {self.what}: {done:,.0f}"
        if total:
            text += f" / {total:,.0f}"
        text += f" {self.unit}".rstrip()
        eta = self._pace.mark(done, total, now)
        if total and done > 0:
            text += f" ({100 * done / total:.0f} %, {el:.0f} s elapsed" + \
                ("" if eta is None else f", ETA {eta:.0f} s") + ")"
        print(text, file=self.stream, flush=True)

    def note(self, message: str) -> None:
        """A line of text (a stage, a result): printed, or written above the bar."""
        if self.quiet:
            return
        if self._bar is not None:
            self._bar.write(message, file=self.stream)
        else:
            print(message, file=self.stream, flush=True)

    def close(self) -> None:
        """Remove the bar (the command's own summary follows)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
