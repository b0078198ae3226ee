"""Clocks for the fixed-rate loop: monotonic nanoseconds and the two ways of waiting on them.

The loop waits for an absolute deadline in two phases (see ``docs/runtime.md`` for the
measurements behind the choice):

1. **coarse**, :meth:`Clock.wait_until_ns`, awaited in the event loop, so every other task runs
   meanwhile. asyncio's own timers are rounded up to whole milliseconds by ``epoll_wait``;
   :class:`MonotonicClock` therefore arms a Linux ``timerfd`` on the absolute
   ``CLOCK_MONOTONIC`` deadline and waits for it to become readable (nanosecond resolution,
   the event loop is woken by the file descriptor, not by its timeout). Where no timerfd exists
   it falls back to ``asyncio.sleep`` (millisecond rounding: give it a larger margin).
2. **fine**, :meth:`Clock.sleep_until_ns`, a short blocking wait from the margin before the
   deadline (0.2–1 ms) to the deadline itself: a busy-wait on ``time.monotonic_ns`` (``"spin"``) or
   ``time.sleep`` (``"sleep"``, ``clock_nanosleep`` underneath).

:class:`FakeClock` implements the same protocol on a simulated time line, so tests of the loop
run thousands of cycles without sleeping.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import ctypes.util
import os
import time
from collections.abc import Callable
from typing import Literal, Protocol, runtime_checkable

__all__ = ["Clock", "MonotonicClock", "FakeClock", "timerfd_available"]


@runtime_checkable
class Clock(Protocol):
    """What the loop needs of time: read it, and wait for absolute deadlines on it."""

    def monotonic_ns(self) -> int:
        """Monotonic time, integer nanoseconds."""

    def sleep(self, seconds: float) -> None:
        """Block the calling thread for ``seconds`` (never awaits)."""

    async def wait_until_ns(self, deadline_ns: int, wake: asyncio.Future | None = None
                            ) -> None:
        """Await (yielding to the event loop at least once) until about ``deadline_ns``, or
        until ``wake`` (a future of the running loop) is done, whichever is first.

        May return somewhat late (the coarse phase); never raises for a deadline in the past.
        """

    def sleep_until_ns(self, deadline_ns: int) -> None:
        """Block until ``deadline_ns`` exactly (the fine phase; meant for short waits)."""


# --------------------------------------------------------------------------- timerfd (Linux)

_CLOCK_MONOTONIC = 1
_TFD_TIMER_ABSTIME = 1


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


class _Itimerspec(ctypes.Structure):
    _fields_ = [("it_interval", _Timespec), ("it_value", _Timespec)]


_libc = None


def _get_libc():
    global _libc
    if _libc is None:
        _libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
    return _libc


class _TimerFd:
    """A non-blocking CLOCK_MONOTONIC timerfd armed on absolute deadlines."""

    def __init__(self) -> None:
        if hasattr(os, "timerfd_create"):  # Python ≥ 3.13
            self.fd = os.timerfd_create(time.CLOCK_MONOTONIC,
                                        flags=os.TFD_NONBLOCK | os.TFD_CLOEXEC)
            self._native = True
        else:
            libc = _get_libc()
            fd = libc.timerfd_create(_CLOCK_MONOTONIC, os.O_NONBLOCK | os.O_CLOEXEC)
            if fd < 0:
                err = ctypes.get_errno()
                raise OSError(err, f"timerfd_create: {os.strerror(err)}")
            self.fd = fd
            self._native = False
            self._spec = _Itimerspec()

    def arm(self, deadline_ns: int) -> None:
        if self._native:
            os.timerfd_settime_ns(self.fd, flags=os.TFD_TIMER_ABSTIME, initial=deadline_ns)
            return
        spec = self._spec
        spec.it_value.tv_sec, spec.it_value.tv_nsec = divmod(max(deadline_ns, 1), 1_000_000_000)
        if _get_libc().timerfd_settime(self.fd, _TFD_TIMER_ABSTIME, ctypes.byref(spec),
                                       None) != 0:
            err = ctypes.get_errno()
            raise OSError(err, f"timerfd_settime: {os.strerror(err)}")

    def drain(self) -> bool:
        try:
            os.read(self.fd, 8)
            return True
        except BlockingIOError:
            return False

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


def timerfd_available() -> bool:
    """True when a timerfd can be created here (Linux)."""
    try:
        _TimerFd().close()
        return True
    except (OSError, AttributeError):
        return False


class MonotonicClock:
    """The real clock: ``time.monotonic_ns`` with a timerfd coarse wait and a fine spin.

    Parameters
    ----------
    coarse : {"timerfd", "asyncio"}
        How :meth:`wait_until_ns` waits in the event loop. ``"timerfd"`` falls back to
        ``"asyncio"`` (and says so in :attr:`coarse`) where a timerfd cannot be created.
    fine : {"spin", "sleep"}
        How :meth:`sleep_until_ns` waits the last stretch: busy-wait, or ``time.sleep``.

    Notes
    -----
    One instance serves one event loop at a time (the timerfd reader is registered on the
    running loop for each wait). Call :meth:`close` when done.
    """

    def __init__(self, coarse: Literal["timerfd", "asyncio"] = "timerfd",
                 fine: Literal["spin", "sleep"] = "spin") -> None:
        if coarse not in ("timerfd", "asyncio") or fine not in ("spin", "sleep"):
            raise ValueError(f"unknown clock mode coarse={coarse!r} fine={fine!r}")
        self._tfd: _TimerFd | None = None
        if coarse == "timerfd":
            try:
                self._tfd = _TimerFd()
            except (OSError, AttributeError):
                coarse = "asyncio"
        self.coarse = coarse
        self.fine = fine

    def monotonic_ns(self) -> int:
        return time.monotonic_ns()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    async def wait_until_ns(self, deadline_ns: int, wake: asyncio.Future | None = None
                            ) -> None:
        remaining = deadline_ns - time.monotonic_ns()
        if remaining <= 0 or (wake is not None and wake.done()):
            await asyncio.sleep(0)
            return
        if self._tfd is None:
            if wake is None:
                await asyncio.sleep(remaining * 1e-9)
            else:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(asyncio.shield(wake), remaining * 1e-9)
            return
        loop = asyncio.get_running_loop()
        fut = wake if wake is not None else loop.create_future()
        tfd = self._tfd

        def readable() -> None:
            if tfd.drain() and not fut.done():
                fut.set_result(None)

        tfd.arm(deadline_ns)
        loop.add_reader(tfd.fd, readable)
        try:
            await fut
        finally:
            loop.remove_reader(tfd.fd)

    def sleep_until_ns(self, deadline_ns: int) -> None:
        now = time.monotonic_ns
        if self.fine == "sleep":
            remaining = deadline_ns - now()
            if remaining > 0:
                time.sleep(remaining * 1e-9)
            return
        while now() < deadline_ns:
            pass

    def close(self) -> None:
        if self._tfd is not None:
            self._tfd.close()
            self._tfd = None


class FakeClock:
    """A simulated monotonic clock for tests: waiting advances time instead of sleeping.

    Parameters
    ----------
    start_ns : int
        Initial time.
    coarse_late_ns : callable, optional
        ``f(deadline_ns) -> ns`` added to every coarse wake-up (simulates scheduling delay).
    fine_late_ns : callable, optional
        Same for the fine phase.

    Notes
    -----
    :meth:`wait_until_ns` yields to the event loop once (``asyncio.sleep(0)``) so other tasks
    run, then jumps the time to the deadline (plus the configured lateness). A cycle callback
    simulates its compute time with :meth:`advance`.
    """

    def __init__(self, start_ns: int = 1_000_000_000, *,
                 coarse_late_ns: Callable[[int], int] | None = None,
                 fine_late_ns: Callable[[int], int] | None = None) -> None:
        self.now_ns = int(start_ns)
        self.coarse_late_ns = coarse_late_ns
        self.fine_late_ns = fine_late_ns
        self.coarse_waits = 0

    def monotonic_ns(self) -> int:
        return self.now_ns

    def advance(self, ns: int) -> None:
        """Move time forward by ``ns`` (e.g. a simulated compute time)."""
        self.now_ns += int(ns)

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self.now_ns += int(round(seconds * 1e9))

    async def wait_until_ns(self, deadline_ns: int, wake: asyncio.Future | None = None
                            ) -> None:
        self.coarse_waits += 1
        await asyncio.sleep(0)
        if wake is not None and wake.done():  # woken: time stays where the waker left it
            return
        late = self.coarse_late_ns(deadline_ns) if self.coarse_late_ns else 0
        self.now_ns = max(self.now_ns, deadline_ns + int(late))

    def sleep_until_ns(self, deadline_ns: int) -> None:
        late = self.fine_late_ns(deadline_ns) if self.fine_late_ns else 0
        self.now_ns = max(self.now_ns, deadline_ns + int(late))
