"""The fixed-rate control loop: absolute monotonic deadlines, no catch-up, statistics.

:class:`FixedRateLoop` calls a plain function ``tick(t_ns, dt)`` once per period, on deadlines
``t₀ + k·T`` of the monotonic clock (never ``sleep(T)`` after the work, which drifts). Each
wait has two phases (:mod:`uvd.runtime.clock`): a coarse wait in the event loop to
``deadline − margin`` (a timerfd, so other tasks run meanwhile and there is no millisecond
rounding), then a short fine wait (busy-wait by default) to the deadline itself. The cycle
runs in the event-loop thread and must not await; anything slow (telemetry encoding, file or
network I/O) is handed off through a bounded queue (:mod:`uvd.telemetry`) or a
:class:`~uvd.runtime.mailbox.Mailbox`.

**Overruns.** A cycle *overruns* when it ends after the next deadline (lateness + compute >
T). The loop then skips every deadline already passed — counted in ``skipped`` — and resumes
on the schedule; it never bursts several cycles to catch up. ``overrun_streak`` counts
consecutive overrunning cycles; reaching ``LoopSettings.overrun_streak`` sets
``streak_exceeded`` (an input of the failsafe arbiter).

**Errors.** An exception from ``cycle`` is caught, counted (``cycle_errors``), remembered
(``last_error``) and handed to ``on_error(exc, t_ns)`` — the application's zero-thrust path;
the loop itself keeps its schedule. ``after_cycle`` hooks (the systemd watchdog) run after
every cycle that *completed* (returned or raised — the loop is alive); a cycle that never
returns stops them.

**Garbage collection** (``LoopSettings.gc``). CPython runs its cyclic collector whenever the
count of new container objects passes a threshold — at any moment, so inside a cycle, and a
full collection of a heap with numba/llvmlite/scipy loaded (~10⁵ objects) stalls for
70–80 ms. With ``gc = "slack"`` (the default) the loop owns the collector while it runs:

1. on entry to :meth:`FixedRateLoop.run`, before the first deadline is set: ``gc.collect()``
   then ``gc.freeze()`` — everything alive after start-up and warm-up moves to the permanent
   generation and is never walked again (the daemon has already done this once at normal
   priority, so here it only walks what appeared since);
2. automatic collection is disabled (``gc.disable()``) for as long as the loop runs, and
   re-enabled on exit if it was enabled;
3. after a cycle, once the young generation has passed CPython's own threshold
   (``gc.get_threshold()``), the loop collects the generation CPython would have collected
   (0, or 1/2 when their counters are due), but only if the time left before the next
   deadline's coarse wait ends is at least a quarter of the period and twice the longest
   collection of that generation seen so far; otherwise it tries a younger generation, or
   waits for a cycle with slack;
4. memory stays bounded: when no slack has been found for 20 thresholds' worth of
   allocations, the due collection runs anyway (``gc_forced``).

Counted in :meth:`snapshot` under ``gc``: collections per generation, forced ones, the
longest and the total time spent. ``gc = "python"`` leaves CPython's automatic collector alone
(the behaviour before this policy).

**Sensor-synchronous cycle** (``LoopSettings.trigger = "ins"``). The INS reader calls
:meth:`FixedRateLoop.wake` when a frame has been decoded; the coarse wait ends then (the
timerfd and the wake share one future), and the cycle runs at once — or at the previous cycle
plus half a period, if the frame came sooner. Without a frame the wait ends on a fallback
deadline 1.5 periods after a synchronous cycle, then every period (the fixed-rate schedule),
until a frame wakes the loop again. A synchronous cycle's lateness is measured from the wake;
it overruns when it ends more than a period after it started.

**Statistics.** Lateness (wake-up minus deadline) and compute time (cycle return minus
wake-up) go into constant-memory histograms (:class:`~uvd.runtime.stats.Histogram`);
:meth:`FixedRateLoop.snapshot` returns a plain dict with p50/p99/p999/max in µs, and counts of
cycles, overruns, skipped deadlines and errors. ``dt`` passed to the cycle is the *measured*
time since the previous cycle's wake-up (the nominal period on the first cycle), as in
ros2_control; ``t_ns`` is the wake-up time.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import errno
import gc
import os
import resource
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from uvd.runtime.clock import Clock, MonotonicClock
from uvd.runtime.schema import setting
from uvd.runtime.stats import Histogram

__all__ = ["LoopSettings", "FixedRateLoop", "RealtimeReport", "apply_realtime",
           "drop_realtime", "DEFAULT_MARGIN_US", "CpuLatencyRequest"]

DEFAULT_MARGIN_US = {"timerfd": 1000.0, "asyncio": 1100.0}


@dataclass(frozen=True)
class LoopSettings:
    """The fixed-rate control loop (``[loop]``)."""

    rate_hz: float = setting(10.0, unit="Hz", gt=0.0, max=2000.0,
                             doc="control rate; the thesis ran 10 Hz, the loop holds 1 kHz")
    sched_fifo_priority: int = setting(
        0, min=0, max=99,
        doc="SCHED_FIFO priority of the loop thread, 0 = normal scheduling (needs "
            "LimitRTPRIO= or CAP_SYS_NICE, see docs/runtime.md)")
    cpu_affinity: tuple[int, ...] = setting(
        (), min=0, max=1023, doc="CPUs the daemon may run on, empty = no restriction")
    overrun_streak: int = setting(
        5, min=1, max=100000, reload=True,
        doc="consecutive overrunning cycles that trip the loop_overrun_streak failsafe")
    timer: Literal["timerfd", "asyncio"] = setting(
        "timerfd", doc="coarse wait in the event loop: timerfd (ns resolution) or asyncio "
                       "(rounded up to 1 ms)")
    fine: Literal["spin", "sleep"] = setting(
        "spin", doc="the last stretch to the deadline: busy-wait or time.sleep")
    gc: Literal["slack", "python"] = setting(
        "slack", doc="garbage collection while the loop runs: slack = freeze the start-up heap, "
                     "no automatic collection, young generations collected in a cycle's slack "
                     "time (forced only if memory would grow); python = CPython's automatic "
                     "collector, at any moment")
    trigger: Literal["fixed", "ins"] = setting(
        "fixed", doc="fixed: cycles on the fixed-rate schedule; ins: each cycle right after an "
                     "INS frame arrives, so the command goes out on the freshest attitude (set "
                     "rate_hz to the INS's rate) — never sooner than half a period after the "
                     "previous cycle, and without a frame for 1.5 periods the fixed-rate "
                     "schedule takes over until frames return (the INS failsafes fire on "
                     "their thresholds as ever)")
    fine_margin_us: float | None = setting(
        None, unit="µs", min=0.0, max=5000.0,
        doc="how long before the deadline the coarse wait ends (default: 20 % of the period "
            "up to 1000 with timerfd — 200 at 1 kHz; 1100 with asyncio)")

    @property
    def period_ns(self) -> int:
        return int(round(1e9 / self.rate_hz))

    @property
    def margin_ns(self) -> int:
        """The fine-wait margin: as configured, else 20 % of the period up to 1 ms (timerfd;
        a wake-up after a long sleep is sometimes a few hundred µs late) or 1.1 ms (asyncio,
        whose timers are rounded up to whole milliseconds)."""
        if self.fine_margin_us is not None:
            m = self.fine_margin_us
        elif self.timer == "timerfd":
            m = min(DEFAULT_MARGIN_US["timerfd"], 0.2 * 1e6 / self.rate_hz)
        else:
            m = DEFAULT_MARGIN_US["asyncio"]
        return int(round(m * 1e3))


# ------------------------------------------------------------------------------ real time

@dataclass(frozen=True)
class RealtimeReport:
    """What :func:`apply_realtime` did. ``messages`` explain every refusal."""

    sched_fifo_priority: int = 0
    cpu_affinity: tuple[int, ...] = ()
    timer_slack_ns: int | None = None
    messages: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return not self.messages


_PR_SET_TIMERSLACK = 29


def apply_realtime(priority: int = 0, cpus: Sequence[int] = (), *,
                   os_module: Any = os) -> RealtimeReport:
    """Ask for SCHED_FIFO ``priority`` and CPU ``cpus`` for the calling thread; never raises.

    Also sets the thread's timer slack to 1 ns (finer wake-ups under normal scheduling).
    Threads created *afterwards* inherit the policy; give worker pools
    :func:`drop_realtime` as initializer. Each refusal becomes a clear message saying what
    to change (``LimitRTPRIO=``, ``CAP_SYS_NICE``, ``RestrictRealtime=no``).

    Parameters
    ----------
    priority : int
        1–99 for SCHED_FIFO, 0 to leave scheduling alone.
    cpus : sequence of int
        CPU numbers; empty leaves the affinity alone.
    os_module : module
        Injected for tests (``sched_setscheduler``, ``sched_setaffinity``…).
    """
    msgs: list[str] = []
    applied_prio = 0
    applied_cpus: tuple[int, ...] = ()
    slack: int | None = None
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0) == 0:
            slack = 1
    except (OSError, AttributeError):
        pass
    if cpus:
        want = tuple(sorted(set(int(c) for c in cpus)))
        try:
            os_module.sched_setaffinity(0, want)
            applied_cpus = want
        except OSError as exc:
            have = sorted(os_module.sched_getaffinity(0)) if hasattr(
                os_module, "sched_getaffinity") else "?"
            msgs.append(f"CPU affinity {list(want)} refused ({exc.strerror or exc}); this "
                        f"process may run on CPUs {have}")
        except AttributeError:
            msgs.append("CPU affinity is not supported on this platform")
    if priority:
        try:
            os_module.sched_setscheduler(0, os_module.SCHED_FIFO,
                                         os_module.sched_param(int(priority)))
            applied_prio = int(priority)
        except PermissionError:
            try:
                soft, _hard = resource.getrlimit(resource.RLIMIT_RTPRIO)
            except (OSError, AttributeError, ValueError):
                soft = "?"
            msgs.append(f"SCHED_FIFO priority {priority} not permitted (RLIMIT_RTPRIO is "
                        f"{soft}): running with normal scheduling. Under systemd set "
                        f"LimitRTPRIO={priority} and RestrictRealtime=no (docs/runtime.md), "
                        f"or grant CAP_SYS_NICE")
        except OSError as exc:
            reason = "invalid priority" if exc.errno == errno.EINVAL else exc.strerror
            msgs.append(f"SCHED_FIFO priority {priority} refused ({reason}): running with "
                        f"normal scheduling")
        except AttributeError:
            msgs.append("SCHED_FIFO is not supported on this platform")
    return RealtimeReport(sched_fifo_priority=applied_prio, cpu_affinity=applied_cpus,
                          timer_slack_ns=slack, messages=tuple(msgs))


class CpuLatencyRequest:
    """Hold a PM-QoS CPU wake-up latency request (``/dev/cpu_dma_latency``) while open.

    Idle CPUs otherwise halt (``haltpoll`` in a VM, C-states on metal), and waking a halted
    CPU takes hundreds of µs: on the CI VM a SCHED_FIFO loop at 1 kHz went from a lateness p99
    of 620 µs to 8 µs with the request held (``uvd bench loop --cycle none``). The request
    lasts as long as the file descriptor is open (the kernel drops it when the process ends).
    Never raises: ``message`` says why it was not granted (needs root or a udev rule; under
    systemd ``DeviceAllow=/dev/cpu_dma_latency rw``).
    """

    PATH = "/dev/cpu_dma_latency"

    def __init__(self, latency_us: int = 0) -> None:
        self.latency_us = int(latency_us)
        self.fd: int | None = None
        self.message = ""

    def open(self) -> CpuLatencyRequest:
        if self.fd is not None:
            return self
        try:
            fd = os.open(self.PATH, os.O_WRONLY)
        except OSError as exc:
            self.message = (f"CPU wake-up latency request not held ({self.PATH}: "
                            f"{exc.strerror or exc}); idle CPUs may wake late")
            return self
        try:
            os.write(fd, self.latency_us.to_bytes(4, "little", signed=True))
        except OSError as exc:
            os.close(fd)
            self.message = f"CPU wake-up latency request refused: {exc.strerror or exc}"
            return self
        self.fd = fd
        return self

    @property
    def held(self) -> bool:
        return self.fd is not None

    def close(self) -> None:
        fd, self.fd = self.fd, None
        if fd is not None:
            with contextlib.suppress(OSError):
                os.close(fd)


def drop_realtime() -> None:
    """Return the calling thread to normal scheduling (worker-pool initializer; never raises)."""
    with contextlib.suppress(OSError, AttributeError):
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


# ------------------------------------------------------------------------------ the loop

TickFn = Callable[[int, float], None]


@dataclass
class _Trace:
    lateness_ns: np.ndarray
    compute_ns: np.ndarray
    n: int = 0


@dataclass
class FixedRateLoop:
    """Run ``tick(t_ns, dt)`` at a fixed rate on absolute deadlines.

    Parameters
    ----------
    tick : callable
        ``tick(t_ns, dt) -> None``, one period's work (the daemon's: its commands, then the
        cycle — read, update, write); plain function, must not await, should not block.
    settings : LoopSettings
        Rate, timer and overrun-streak threshold (scheduling is applied by
        :func:`apply_realtime`, not here).
    clock : Clock, optional
        Time source and waits; a :class:`~uvd.runtime.clock.MonotonicClock` built from the
        settings by default (closed by :meth:`close`).
    on_error : callable, optional
        ``on_error(exc, t_ns)`` after a cycle raised (the zero-thrust path). Its own
        exceptions are swallowed and counted.
    after_cycle : list of callables
        ``hook(t_end_ns, ok)`` after each completed cycle (e.g. the watchdog ping).
    trace_capacity : int
        Keep the first N raw lateness/compute samples (benchmarks); 0 = none.
    """

    tick: TickFn
    settings: LoopSettings = field(default_factory=LoopSettings)
    clock: Clock | None = None
    on_error: Callable[[BaseException, int], None] | None = None
    after_cycle: list[Callable[[int, bool], None]] = field(default_factory=list)
    trace_capacity: int = 0

    def __post_init__(self) -> None:
        self._own_clock = self.clock is None
        if self.clock is None:
            self.clock = MonotonicClock(coarse=self.settings.timer, fine=self.settings.fine)
        self.period_ns = self.settings.period_ns
        self.margin_ns = min(self.settings.margin_ns, self.period_ns)
        self.lateness = Histogram()
        self.compute = Histogram()
        self.cycles = 0
        self.overruns = 0
        self.skipped = 0
        self.overrun_streak = 0
        self.max_overrun_streak = 0
        self.cycle_errors = 0
        self.consecutive_errors = 0
        self.hook_errors = 0
        self.last_error: str | None = None
        self.last_cycle_ok = True
        self.last_t_ns: int | None = None
        self.running = False
        self._stop = False
        self.gc_collections = [0, 0, 0]
        self.gc_forced = 0
        self.gc_max_ns = [0, 0, 0]
        self.gc_total_ns = 0
        self.woken = 0            # cycles started by a wake (trigger = "ins")
        self._wake_ns: int | None = None
        self._wake_fut: asyncio.Future | None = None
        self.trace: _Trace | None = None
        if self.trace_capacity > 0:
            self.trace = _Trace(np.zeros(self.trace_capacity, dtype=np.int64),
                                np.zeros(self.trace_capacity, dtype=np.int64))

    # -- control

    @property
    def period_s(self) -> float:
        return self.period_ns * 1e-9

    @property
    def streak_exceeded(self) -> bool:
        """The overrun streak reached ``settings.overrun_streak``."""
        return self.overrun_streak >= self.settings.overrun_streak

    def wake(self) -> None:
        """An INS frame has arrived: with ``trigger = "ins"`` the next cycle runs now (from the
        event loop's thread; a no-op otherwise)."""
        if self.settings.trigger != "ins":
            return
        if self._wake_ns is None:
            self._wake_ns = self.clock.monotonic_ns()
        fut = self._wake_fut
        if fut is not None and not fut.done():
            fut.set_result(None)

    async def _wait_for_frame(self, until_ns: int) -> int | None:
        """The coarse wait of the sensor-synchronous loop: until a wake or ``until_ns``;
        returns the wake's time (None: the deadline came first)."""
        if self._wake_ns is None:
            self._wake_fut = asyncio.get_running_loop().create_future()
            try:
                await self.clock.wait_until_ns(until_ns, self._wake_fut)
            finally:
                self._wake_fut = None
        t, self._wake_ns = self._wake_ns, None
        return t

    def stop(self) -> None:
        """Ask the loop to return after the cycle in progress (or before the next one)."""
        self._stop = True

    def set_overrun_streak(self, n: int) -> None:
        """Change the overrun-streak threshold (reloadable)."""
        self.settings = replace(self.settings, overrun_streak=int(n))

    def close(self) -> None:
        """Release the clock's timer if the loop created it."""
        if self._own_clock and hasattr(self.clock, "close"):
            self.clock.close()

    # run is long (~105 lines) on purpose: it is the real-time loop, whose per-cycle state
    # lives in locals (an attribute look-up costs every cycle) and whose schedule, accounting
    # and slack collection share them; split, they would be passed around each cycle.
    async def run(self, *, max_cycles: int | None = None,
                  duration_s: float | None = None) -> dict[str, Any]:
        """Run until :meth:`stop`, ``max_cycles`` cycles, or ``duration_s`` of schedule.

        Returns the final :meth:`snapshot`. Cancellation (TaskGroup shutdown) propagates
        from the coarse wait, never from inside a cycle.
        """
        clock = self.clock
        period = self.period_ns
        margin = self.margin_ns
        tick = self.tick
        lat_h, comp_h = self.lateness, self.compute
        trace = self.trace
        own_gc = self.settings.gc == "slack"
        gc_was_enabled = gc.isenabled()
        if own_gc:
            gc.collect()
            gc.freeze()
            gc.disable()
            gc_threshold = gc.get_threshold()
            gc_get_count = gc.get_count
            gc_trigger = max(1, gc_threshold[0])
            gc_min_slack = period // 4
        sync = self.settings.trigger == "ins"
        self._wake_ns = None
        start = clock.monotonic_ns()
        deadline = start + period
        end_ns = start + int(duration_s * 1e9) if duration_s is not None else None
        prev_t: int | None = None
        self._stop = False
        self.running = True
        try:
            while not self._stop:
                if max_cycles is not None and self.cycles >= max_cycles:
                    break
                if end_ns is not None and deadline > end_ns:
                    break
                woke = None
                if sync:
                    woke = await self._wait_for_frame(deadline - margin)
                else:
                    await clock.wait_until_ns(deadline - margin)
                if self._stop:
                    break
                if woke is not None:     # a frame: now, or half a period after the last
                    self.woken += 1
                    deadline = woke
                    clock.sleep_until_ns(woke if prev_t is None else prev_t + period // 2)
                else:
                    clock.sleep_until_ns(deadline)
                t = clock.monotonic_ns()
                dt = (t - prev_t) * 1e-9 if prev_t is not None else period * 1e-9
                prev_t = t
                ok = True
                try:
                    tick(t, dt)
                except Exception as exc:  # failure is data: never raises out of the loop
                    ok = False
                    self._cycle_failed(exc, t)
                t_end = clock.monotonic_ns()
                lateness = t - deadline
                compute = t_end - t
                lat_h.record(lateness)
                comp_h.record(compute)
                if trace is not None and trace.n < trace.lateness_ns.shape[0]:
                    trace.lateness_ns[trace.n] = lateness
                    trace.compute_ns[trace.n] = compute
                    trace.n += 1
                self.cycles += 1
                self.last_t_ns = t
                self.last_cycle_ok = ok
                if ok:
                    self.consecutive_errors = 0
                if woke is not None:    # next: the fixed-rate fallback, 1.5 periods on
                    deadline = t + period
                    fallback = deadline + period // 2
                else:
                    deadline += period
                    fallback = deadline
                if t_end > deadline:
                    missed = (t_end - deadline) // period + 1
                    self.overruns += 1
                    self.skipped += missed
                    deadline += missed * period
                    self.overrun_streak += 1
                    self.max_overrun_streak = max(self.max_overrun_streak,
                                                  self.overrun_streak)
                else:
                    self.overrun_streak = 0
                    deadline = fallback
                for hook in self.after_cycle:
                    try:
                        hook(t_end, ok)
                    except Exception:
                        self.hook_errors += 1
                if own_gc and gc_get_count()[0] >= gc_trigger:
                    # synchronous: the next frame is due a period after this cycle
                    due = min(deadline, t + period) if woke is not None else deadline
                    self._collect_in_slack(due - margin, gc_threshold, gc_min_slack)
        finally:
            self.running = False
            if own_gc and gc_was_enabled:
                gc.enable()
        return self.snapshot()

    def _collect_in_slack(self, wait_end_ns: int, threshold: tuple[int, ...],
                          min_slack_ns: int) -> None:
        """The young generation passed its threshold: collect the generation CPython would
        collect if there is slack for it before ``wait_end_ns``, else a younger one that fits,
        else nothing (forced once 20 thresholds' worth is pending). See the module docstring."""
        c0, c1, c2 = gc.get_count()
        due = 2 if c2 >= threshold[2] else 1 if c1 >= threshold[1] else 0
        slack = wait_end_ns - self.clock.monotonic_ns()
        gen = -1
        for g in range(due, -1, -1):
            if slack >= max(min_slack_ns, 2 * self.gc_max_ns[g]):
                gen = g
                break
        if gen < 0:
            if c0 < 20 * threshold[0]:
                return
            gen = due
            self.gc_forced += 1
        t = self.clock.monotonic_ns()
        gc.collect(gen)
        took = self.clock.monotonic_ns() - t
        self.gc_collections[gen] += 1
        self.gc_total_ns += took
        if took > self.gc_max_ns[gen]:
            self.gc_max_ns[gen] = took

    def _cycle_failed(self, exc: BaseException, t_ns: int) -> None:
        self.cycle_errors += 1
        self.consecutive_errors += 1
        tb = traceback.extract_tb(exc.__traceback__)
        where = f" at {tb[-1].filename}:{tb[-1].lineno}" if tb else ""
        self.last_error = f"{type(exc).__name__}: {exc}{where}"
        if self.on_error is not None:
            try:
                self.on_error(exc, t_ns)
            except Exception:
                self.hook_errors += 1

    # -- statistics

    def snapshot(self) -> dict[str, Any]:
        """Counters and latency percentiles as a plain dict (µs)."""
        clock = self.clock
        return {
            "rate_hz": 1e9 / self.period_ns,
            "period_us": self.period_ns / 1e3,
            "cycles": self.cycles,
            "trigger": self.settings.trigger,
            "woken": self.woken,
            "overruns": self.overruns,
            "skipped": self.skipped,
            "overrun_streak": self.overrun_streak,
            "max_overrun_streak": self.max_overrun_streak,
            "streak_exceeded": self.streak_exceeded,
            "cycle_errors": self.cycle_errors,
            "last_error": self.last_error,
            "hook_errors": self.hook_errors,
            "lateness_us": self.lateness.summary_us(),
            "compute_us": self.compute.summary_us(),
            "gc": {"policy": self.settings.gc, "collections": list(self.gc_collections),
                   "forced": self.gc_forced, "max_us": [x / 1e3 for x in self.gc_max_ns],
                   "total_ms": self.gc_total_ns / 1e6},
            "timer": {"coarse": getattr(clock, "coarse", type(clock).__name__),
                      "fine": getattr(clock, "fine", type(clock).__name__),
                      "margin_us": self.margin_ns / 1e3},
        }

    def reset_stats(self) -> None:
        """Start the histograms and counters afresh (e.g. after warm-up)."""
        self.lateness.reset()
        self.compute.reset()
        self.overruns = self.skipped = self.max_overrun_streak = 0
        self.cycles = 0
        self.gc_collections = [0, 0, 0]
        self.gc_forced = 0
        self.gc_total_ns = 0


async def run_loop_until_stopped(loop: FixedRateLoop, stop: asyncio.Event) -> dict[str, Any]:
    """Run ``loop`` until ``stop`` is set (helper for a TaskGroup)."""

    async def watcher() -> None:
        await stop.wait()
        loop.stop()

    w = asyncio.ensure_future(watcher())
    try:
        return await loop.run()
    finally:
        w.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await w
