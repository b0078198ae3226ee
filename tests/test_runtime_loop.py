"""The fixed-rate loop: absolute deadlines, skip-and-count overruns, error handling, statistics.

Most tests run on :class:`FakeClock` (no real sleeping, exact times); a few run a short real
loop to check the timerfd and asyncio waits work — they check counts, never timing figures
(those belong to ``uvd bench loop``).
"""

from __future__ import annotations

import asyncio
import errno
import types

import numpy as np
import pytest

from uvd.runtime.clock import FakeClock, MonotonicClock, timerfd_available
from uvd.runtime.loop import FixedRateLoop, LoopSettings, apply_realtime
from uvd.runtime.stats import Histogram

MS = 1_000_000


def run(coro, timeout=20.0):
    async def bounded():
        return await asyncio.wait_for(coro, timeout)
    return asyncio.run(bounded())


def test_cycles_run_on_absolute_deadlines_with_measured_dt():
    clock = FakeClock(start_ns=5 * MS)
    seen: list[tuple[int, float]] = []

    def cycle(t, dt):
        seen.append((t, dt))
        clock.advance(300_000)  # 0.3 ms of "compute", less than the 1 ms period

    loop = FixedRateLoop(cycle, LoopSettings(rate_hz=1000.0), clock=clock)
    snap = run(loop.run(max_cycles=50))
    ts = np.array([t for t, _ in seen])
    # deadline k is start + (k+1)·T exactly: compute time does not accumulate as drift
    assert np.array_equal(ts, 5 * MS + MS * np.arange(1, 51))
    assert seen[0][1] == pytest.approx(1e-3) and all(dt == pytest.approx(1e-3) for _, dt in seen)
    assert snap["cycles"] == 50 and snap["overruns"] == 0 and snap["skipped"] == 0
    assert snap["compute_us"]["p50"] == pytest.approx(300.0, rel=0.02)
    assert snap["lateness_us"]["max"] == 0.0


def test_lateness_is_recorded_per_cycle():
    late = iter([0, 50_000, 120_000] * 100)
    clock = FakeClock(fine_late_ns=lambda d: next(late))
    loop = FixedRateLoop(lambda t, dt: None, LoopSettings(rate_hz=100.0), clock=clock)
    snap = run(loop.run(max_cycles=300))
    assert snap["lateness_us"]["max"] == pytest.approx(120.0, rel=0.02)
    assert snap["lateness_us"]["p50"] == pytest.approx(50.0, rel=0.02)
    assert snap["lateness_us"]["n"] == 300


def test_overrun_skips_missed_deadlines_without_a_catch_up_burst():
    clock = FakeClock(start_ns=0)
    times: list[int] = []

    def cycle(t, dt):
        times.append(t)
        if len(times) == 3:
            clock.advance(int(2.5 * 10 * MS))  # one cycle takes 2.5 periods

    loop = FixedRateLoop(cycle, LoopSettings(rate_hz=100.0), clock=clock)
    snap = run(loop.run(max_cycles=6))
    assert snap["overruns"] == 1
    assert snap["skipped"] == 2          # the deadlines at 40 and 50 ms were skipped
    gaps = np.diff(times) / MS
    # after the long cycle (started at 30 ms, ended at 55 ms) the next runs at 60 ms: no burst
    assert list(gaps) == [10, 10, 30, 10, 10]
    assert all(g >= 10 for g in gaps)


def test_overrun_streak_and_threshold():
    clock = FakeClock(start_ns=0)
    n = [0]

    def cycle(t, dt):
        n[0] += 1
        if 3 <= n[0] <= 9:
            clock.advance(12 * MS)  # each of these overruns the 10 ms period

    loop = FixedRateLoop(cycle, LoopSettings(rate_hz=100.0, overrun_streak=5), clock=clock)
    exceeded = []
    loop.after_cycle.append(lambda t, ok: exceeded.append(loop.streak_exceeded))
    snap = run(loop.run(max_cycles=12))
    assert snap["overruns"] == 7 and snap["max_overrun_streak"] == 7
    assert exceeded.index(True) == 6          # the 5th consecutive overrun (cycle 7)
    assert exceeded[-1] is False and snap["overrun_streak"] == 0


def test_cycle_exception_is_caught_counted_and_reported():
    clock = FakeClock()
    errors = []
    ok_flags = []

    def cycle(t, dt):
        if len(ok_flags) in (2, 3):
            raise ValueError("boom")

    loop = FixedRateLoop(cycle, LoopSettings(rate_hz=50.0), clock=clock,
                         on_error=lambda exc, t: errors.append((type(exc), t)))
    loop.after_cycle.append(lambda t, ok: ok_flags.append(ok))
    snap = run(loop.run(max_cycles=6))
    assert snap["cycles"] == 6 and snap["cycle_errors"] == 2
    assert ok_flags == [True, True, False, False, True, True]
    assert [e[0] for e in errors] == [ValueError, ValueError]
    assert "ValueError: boom" in snap["last_error"] and "test_runtime_loop.py" in \
        snap["last_error"]
    assert loop.consecutive_errors == 0


def test_failing_error_hook_and_after_cycle_hook_do_not_break_the_loop():
    clock = FakeClock()

    def bad_hook(*a):
        raise RuntimeError("hook")

    def cycle(t, dt):
        raise KeyError("x")

    loop = FixedRateLoop(cycle, LoopSettings(rate_hz=50.0), clock=clock, on_error=bad_hook,
                         after_cycle=[bad_hook])
    snap = run(loop.run(max_cycles=4))
    assert snap["cycles"] == 4 and snap["cycle_errors"] == 4 and snap["hook_errors"] == 8


def test_stop_and_duration():
    clock = FakeClock(start_ns=0)
    loop = FixedRateLoop(lambda t, dt: None, LoopSettings(rate_hz=100.0), clock=clock)
    snap = run(loop.run(duration_s=0.5))
    assert snap["cycles"] == 50

    count = [0]

    def cycle(t, dt):
        count[0] += 1
        if count[0] == 7:
            loop2.stop()

    loop2 = FixedRateLoop(cycle, LoopSettings(rate_hz=100.0), clock=FakeClock())
    assert run(loop2.run(max_cycles=1000))["cycles"] == 7
    assert not loop2.running


def test_other_tasks_run_while_the_loop_waits():
    clock = FakeClock()
    ticks = []

    async def main():
        loop = FixedRateLoop(lambda t, dt: ticks.append("cycle"), LoopSettings(rate_hz=10.0),
                             clock=clock)

        async def other():
            for _ in range(20):
                ticks.append("other")
                await asyncio.sleep(0)

        await asyncio.gather(loop.run(max_cycles=20), other())
        return loop

    loop = run(main())
    assert ticks.count("cycle") == 20 and ticks.count("other") == 20
    # interleaved, not one after the other
    first_other = ticks.index("other")
    assert first_other < ticks.index("cycle") + 3
    assert clock.coarse_waits == 20 and loop.cycles == 20


def test_cancellation_propagates_from_the_wait():
    async def main():
        loop = FixedRateLoop(lambda t, dt: None, LoopSettings(rate_hz=10.0),
                             clock=MonotonicClock())
        task = asyncio.create_task(loop.run())
        await asyncio.sleep(0.25)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        loop.close()
        return loop

    loop = run(main())
    assert 1 <= loop.cycles <= 4 and not loop.running


@pytest.mark.parametrize("coarse,fine", [("timerfd", "spin"), ("timerfd", "sleep"),
                                         ("asyncio", "spin")])
def test_real_clock_runs_the_requested_cycles(coarse, fine):
    if coarse == "timerfd" and not timerfd_available():
        pytest.skip("no timerfd on this platform")
    settings = LoopSettings(rate_hz=500.0, timer=coarse, fine=fine)
    stamps = []
    loop = FixedRateLoop(lambda t, dt: stamps.append(t), settings, trace_capacity=100)
    try:
        snap = run(loop.run(max_cycles=100))
    finally:
        loop.close()
    assert snap["cycles"] == 100 and snap["timer"]["coarse"] == coarse
    assert snap["lateness_us"]["n"] == 100 and snap["compute_us"]["n"] == 100
    assert loop.trace.n == 100
    d = np.diff(stamps)
    # never early: every wake-up is at or after its deadline, so no gap is shorter than T
    # minus the lateness of the previous one (bounded by the recorded maximum)
    assert np.all(loop.trace.lateness_ns[:100] >= 0)
    assert d.min() >= 2_000_000 - loop.trace.lateness_ns[:100].max()


def test_timerfd_clock_wakes_at_or_after_the_deadline():
    if not timerfd_available():
        pytest.skip("no timerfd on this platform")
    clock = MonotonicClock("timerfd", "spin")

    async def main():
        out = []
        for _ in range(20):
            d = clock.monotonic_ns() + 2 * MS
            await clock.wait_until_ns(d)
            out.append(clock.monotonic_ns() - d)
        await clock.wait_until_ns(clock.monotonic_ns() - MS)  # past deadline: returns at once
        return out

    try:
        late = run(main())
    finally:
        clock.close()
    assert min(late) >= 0


def test_apply_realtime_reports_refusals_clearly():
    def refuse(*a):
        raise PermissionError(errno.EPERM, "Operation not permitted")

    def bad_cpu(*a):
        raise OSError(errno.EINVAL, "Invalid argument")

    fake = types.SimpleNamespace(SCHED_FIFO=1, sched_param=lambda p: p,
                                 sched_setscheduler=refuse, sched_setaffinity=bad_cpu,
                                 sched_getaffinity=lambda pid: {0, 1})
    rep = apply_realtime(50, [7], os_module=fake)
    assert rep.sched_fifo_priority == 0 and rep.cpu_affinity == () and not rep.ok
    text = "\n".join(rep.messages)
    assert "SCHED_FIFO priority 50 not permitted" in text and "LimitRTPRIO=50" in text
    assert "CAP_SYS_NICE" in text and "CPU affinity [7] refused" in text and "[0, 1]" in text

    calls = []
    ok = types.SimpleNamespace(SCHED_FIFO=1, sched_param=lambda p: p,
                               sched_setscheduler=lambda *a: calls.append(("fifo", a)),
                               sched_setaffinity=lambda *a: calls.append(("cpu", a)))
    rep = apply_realtime(20, [1, 0, 1], os_module=ok)
    assert rep.ok and rep.sched_fifo_priority == 20 and rep.cpu_affinity == (0, 1)
    assert calls == [("cpu", (0, (0, 1))), ("fifo", (0, 1, 20))]
    assert apply_realtime(0, (), os_module=ok).ok and len(calls) == 2


def test_histogram_percentiles_match_numpy_within_resolution():
    rng = np.random.default_rng(1)
    values = np.concatenate([rng.integers(0, 100, 500),              # exact region
                             rng.lognormal(11, 1.0, 5000).astype(np.int64)])
    h = Histogram()
    for v in values:
        h.record(int(v))
    assert h.count == values.size and h.max == values.max() and h.min == values.min()
    for q in (1, 50, 90, 99, 99.9):
        exact = np.percentile(values, q, method="inverted_cdf")
        assert h.percentile(q) == pytest.approx(exact, rel=0.016, abs=1.0), q
    assert h.percentile(100) == values.max()
    assert h.mean() == pytest.approx(values.mean())


def test_histogram_buckets_are_contiguous_and_negative_values_counted():
    h = Histogram(sub_bits=5)
    prev_hi = 0
    for idx in range(len(h.counts) - 1):
        lo, hi = h.bucket_bounds(idx)
        assert lo == prev_hi and hi > lo
        assert h._index(lo) == idx and h._index(hi - 1) == idx
        prev_hi = hi
        if hi > 1 << 40:
            break
    h.record(-5)
    assert h.negatives == 1 and h.min == 0
    s = h.summary_us()
    assert set(s) >= {"p50", "p99", "p999", "max", "mean", "n"}
    h.reset()
    assert h.count == 0 and np.isnan(h.percentile(50))


def test_fine_margin_defaults_scale_with_the_period():
    assert LoopSettings(rate_hz=1000.0).margin_ns == 200_000       # 20 % of 1 ms
    assert LoopSettings(rate_hz=100.0).margin_ns == 1_000_000      # capped at 1 ms
    assert LoopSettings(rate_hz=10.0).margin_ns == 1_000_000
    assert LoopSettings(rate_hz=10.0, timer="asyncio").margin_ns == 1_100_000
    assert LoopSettings(rate_hz=10.0, fine_margin_us=50.0).margin_ns == 50_000
    # never more than a period
    loop = FixedRateLoop(lambda t, dt: None, LoopSettings(rate_hz=1000.0, timer="asyncio"),
                         clock=FakeClock())
    assert loop.margin_ns == loop.period_ns == 1_000_000


class _Node:
    """A self-referencing object: only the cyclic collector frees it."""

    def __init__(self) -> None:
        self.me = self


def _gc_run(compute_ns: int, cycles: int, policy: str):
    import gc
    import weakref
    clock = FakeClock(start_ns=0)
    refs: list = []
    enabled_inside: list[bool] = []

    def cycle(t, dt):
        enabled_inside.append(gc.isenabled())
        for _ in range(100):
            refs.append(weakref.ref(_Node()))
        clock.advance(compute_ns)

    was = gc.isenabled()
    loop = FixedRateLoop(cycle, LoopSettings(rate_hz=1000.0, gc=policy), clock=clock)
    snap = run(loop.run(max_cycles=cycles))
    assert gc.isenabled() == was  # restored on exit
    live = sum(r() is not None for r in refs)
    return snap, enabled_inside, live, len(refs)


def test_gc_slack_policy_collects_only_between_cycles_with_slack():
    # 0.3 ms of compute at 1 kHz leaves 0.5 ms before the coarse wait ends: room to collect
    snap, enabled_inside, live, made = _gc_run(300_000, 200, "slack")
    assert not any(enabled_inside)  # never CPython's automatic collection inside a cycle
    assert snap["gc"]["collections"][0] > 0 and snap["gc"]["forced"] == 0
    assert live < 0.1 * made  # the cyclic garbage was collected (memory stays bounded)


def test_gc_slack_policy_forces_a_collection_when_no_cycle_leaves_slack():
    # 0.95 ms of compute at 1 kHz: no slack ever; the collection is forced, memory bounded
    snap, enabled_inside, live, made = _gc_run(950_000, 400, "slack")
    assert snap["gc"]["forced"] > 0
    assert live < 0.5 * made


def test_gc_python_policy_leaves_the_automatic_collector_on():
    import gc
    if not gc.isenabled():
        pytest.skip("the collector is disabled in this process")
    snap, enabled_inside, _live, _made = _gc_run(300_000, 20, "python")
    assert all(enabled_inside) and snap["gc"]["collections"] == [0, 0, 0]


# --------------------------------------------------------------- sensor-synchronous cycle

def _frames_at(loop, clock, times):
    """A simulated INS: whenever it gets the event loop it moves the fake time to its next
    frame and wakes the loop, as the INS reader does after decoding a frame."""
    async def ins():
        for t in times:
            while clock.monotonic_ns() >= t:    # the loop has not waited yet
                await asyncio.sleep(0)
            clock.now_ns = t
            loop.wake()
            await asyncio.sleep(0)
    return ins()


def test_ins_trigger_runs_each_cycle_on_its_frame_then_falls_back_to_fixed_rate():
    clock = FakeClock(start_ns=0)
    seen: list[int] = []

    def cycle(t, dt):
        seen.append(t)
        clock.advance(MS)

    loop = FixedRateLoop(cycle, LoopSettings(rate_hz=50.0, trigger="ins"), clock=clock)
    frames = [7 * MS + 20 * MS * k for k in range(10)]

    async def both():
        ins = asyncio.ensure_future(_frames_at(loop, clock, frames))
        snap = await loop.run(max_cycles=14)
        await ins
        return snap

    snap = run(both())
    # every frame: a cycle at its very arrival (zero lateness), not at the fixed-rate tick
    assert seen[:10] == frames
    # the INS falls silent: 1.5 periods after the last frame, then every period
    assert seen[10:] == [frames[-1] + 30 * MS + 20 * MS * k for k in range(4)]
    assert snap["woken"] == 10 and snap["trigger"] == "ins" and snap["overruns"] == 0
    assert snap["lateness_us"]["max"] == 0.0


def test_ins_trigger_never_runs_sooner_than_half_a_period_after_the_last_cycle():
    clock = FakeClock(start_ns=0)
    seen: list[int] = []
    loop = FixedRateLoop(lambda t, dt: seen.append(t), LoopSettings(rate_hz=50.0,
                                                                    trigger="ins"), clock=clock)
    frames = [5 * MS, 7 * MS, 30 * MS]        # a burst of two, then one in time

    async def both():
        ins = asyncio.ensure_future(_frames_at(loop, clock, frames))
        await loop.run(max_cycles=3)
        await ins

    run(both())
    assert seen == [5 * MS, 15 * MS, 30 * MS]


def test_fixed_trigger_ignores_wakes():
    clock = FakeClock(start_ns=0)
    seen: list[int] = []
    loop = FixedRateLoop(lambda t, dt: seen.append(t), LoopSettings(rate_hz=50.0), clock=clock)

    async def both():
        ins = asyncio.ensure_future(_frames_at(loop, clock, [7 * MS, 27 * MS]))
        snap = await loop.run(max_cycles=3)
        await ins
        return snap

    snap = run(both())
    assert seen == [20 * MS, 40 * MS, 60 * MS] and snap["woken"] == 0


@pytest.mark.skipif(not timerfd_available(), reason="needs timerfd")
def test_ins_trigger_on_the_real_clock_runs_one_cycle_per_frame_after_it():
    """The timerfd wait and the wake share one future: each frame ends the wait."""
    wakes: list[int] = []
    seen: list[int] = []
    loop = FixedRateLoop(lambda t, dt: seen.append(t),
                         LoopSettings(rate_hz=50.0, trigger="ins", gc="python"))

    async def both():
        async def ins():
            await asyncio.sleep(0.005)
            for _ in range(20):
                wakes.append(loop.clock.monotonic_ns())
                loop.wake()
                await asyncio.sleep(0.02)
        task = asyncio.ensure_future(ins())
        snap = await loop.run(max_cycles=20)
        await task
        return snap

    try:
        snap = run(both())
    finally:
        loop.close()
    assert snap["woken"] >= 18           # a frame may land in a cycle under heavy load
    starts = np.searchsorted(seen, wakes)
    assert np.all(starts[:-1] < len(seen))    # every frame but the last got its own cycle
