"""Telemetry fed off the loop: bounded non-blocking queues (drop oldest, count), per-sink pumps,
the JSON-lines sink, and the latest-value mailbox."""

from __future__ import annotations

import asyncio
import json
import math
import time
from itertools import pairwise

import numpy as np

from uvd.links.jsonl import JsonLinesSink
from uvd.runtime.mailbox import Mailbox
from uvd.telemetry import BoundedQueue, TelemetryHub
from uvd.telemetry._worker import DaemonWorker, run_in_daemon_thread


def run(coro, timeout=20.0):
    async def bounded():
        return await asyncio.wait_for(coro, timeout)
    return asyncio.run(bounded())


class ListSink:
    def __init__(self, name="list", delay_s=0.0, fail_every=0, hang_close=False):
        self.name = name
        self.delay_s = delay_s
        self.fail_every = fail_every
        self.hang_close = hang_close
        self.records = []
        self.calls = 0
        self.closed = self.flushed = self.opened = False

    async def open(self):
        self.opened = True

    async def write(self, records):
        self.calls += 1
        if self.fail_every and self.calls % self.fail_every == 0:
            raise OSError("link down")
        if self.delay_s:
            await asyncio.sleep(self.delay_s)
        self.records.extend(records)

    async def flush(self):
        self.flushed = True

    async def aclose(self):
        if self.hang_close:
            await asyncio.sleep(60)
        self.closed = True


def test_bounded_queue_drops_the_oldest_and_counts():
    q = BoundedQueue(3)
    assert [q.put(i) for i in range(5)] == [True, True, True, False, False]
    assert q.dropped == 2 and q.published == 5 and len(q) == 3
    assert q.drain(2) == [2, 3] and q.drain() == [4] and q.drain() == []


def test_hub_delivers_everything_to_a_fast_sink_in_order():
    sink = ListSink()

    async def main():
        hub = TelemetryHub([sink], queue_size=10_000, flush_interval_s=0.01)
        pump = asyncio.create_task(hub.run())
        for i in range(500):
            hub.publish({"i": i})
            if i % 50 == 0:
                await asyncio.sleep(0.005)
        stats = await hub.aclose(1.0)
        await asyncio.wait_for(pump, 2.0)
        return stats

    stats = run(main())["list"]
    assert [r["i"] for r in sink.records] == list(range(500))
    assert stats["published"] == 500 and stats["written"] == 500 and stats["dropped"] == 0
    assert sink.opened and sink.flushed and sink.closed


def test_a_slow_sink_loses_the_oldest_records_and_never_blocks_the_publisher():
    slow, fast = ListSink("slow", delay_s=0.05), ListSink("fast")

    async def main():
        hub = TelemetryHub([slow, fast], queue_size=64, flush_interval_s=0.005, batch=32)
        pump = asyncio.create_task(hub.run())
        for i in range(3000):
            hub.publish({"i": i})          # a burst: no await in between, like the loop
            if i % 100 == 99:
                await asyncio.sleep(0.002)
        stats = await hub.aclose(2.0)
        await asyncio.wait_for(pump, 2.0)
        return stats

    stats = run(main())
    s = stats["slow"]
    assert s["dropped"] > 0
    assert s["written"] + s["dropped"] == s["published"] == 3000
    got = [r["i"] for r in slow.records]
    assert got == sorted(got) and got[-1] == 2999   # the freshest survive, order kept
    f = stats["fast"]
    assert f["written"] + f["dropped"] == 3000 and f["written"] > s["written"]


def test_a_failing_sink_is_counted_and_others_carry_on():
    bad, good = ListSink("bad", fail_every=2), ListSink("good")

    async def main():
        hub = TelemetryHub([bad, good], queue_size=1000, flush_interval_s=0.005, batch=10)
        pump = asyncio.create_task(hub.run())
        for i in range(100):
            hub.publish({"i": i})
            await asyncio.sleep(0)
        await asyncio.sleep(0.05)
        stats = await hub.aclose(1.0)
        await asyncio.wait_for(pump, 2.0)
        return stats

    stats = run(main())
    assert stats["bad"]["errors"] >= 1 and "link down" in stats["bad"]["last_error"]
    assert stats["bad"]["written"] + stats["bad"]["dropped"] == stats["bad"]["published"]
    told = [r for r in good.records if r.get("type") == "sink"]
    assert [r["i"] for r in good.records if "i" in r] == list(range(100))
    assert stats["good"]["errors"] == 0
    # the operator told, once (a change at most every TELL_HOLD_S): the bad sink fails
    assert [(r["sink"], r["ok"]) for r in told] == [("bad", False)], told
    assert "link down" in told[0]["text"] and told[0]["write_errors"] >= 1
    assert stats["bad"]["published"] == 100 + len(told)


def test_a_sink_failing_by_turns_is_told_at_most_once_a_hold_and_its_last_state_told():
    """A sink whose writes fail and succeed by turns every 20 ms for 1 s, then work: the
    operator is told of it (``"sink"`` records to every sink) at most once every
    ``tell_hold_s`` (0.3 s here, 10 s in the daemon), failing first and working again last —
    not 50 changes. A sink that cannot open is told once. Each told record names the sink,
    says ok or not, and what fails."""

    class Flaky(ListSink):
        down = False

        async def write(self, records):
            if self.down:
                raise OSError("No space left on device")
            self.records.extend(records)

    class Closed(ListSink):
        async def open(self):
            raise PermissionError("[Errno 13] Permission denied: '/var/lib/uvd/rec'")

    flaky, good, closed = Flaky("flaky"), ListSink("good"), Closed("closed")
    hold = 0.3

    async def main():
        hub = TelemetryHub([flaky, good, closed], flush_interval_s=0.005, tell_hold_s=hold)
        pump = asyncio.create_task(hub.run())
        for k in range(50):
            flaky.down = k % 2 == 0
            hub.publish({"i": k})
            await asyncio.sleep(0.02)
        flaky.down = False
        for k in range(50, 80):  # 0.6 s working: the hold ends, the last change is told
            hub.publish({"i": k})
            await asyncio.sleep(0.02)
        stats = await hub.aclose(1.0)
        await asyncio.wait_for(pump, 2.0)
        return stats

    stats = run(main())
    told = [r for r in good.records if r.get("type") == "sink"]
    assert [(r["sink"], r["ok"]) for r in told if r["sink"] == "closed"] == [("closed", False)]
    assert "did not open" in next(r["text"] for r in told if r["sink"] == "closed")
    flips = [r for r in told if r["sink"] == "flaky"]
    oks = [r["ok"] for r in flips]
    assert oks[0] is False and oks[-1] is True and 2 <= len(oks) <= 1 + 1.6 / hold, oks
    assert all(a != b for a, b in pairwise(oks))  # each a change
    gaps = [(b["t_ns"] - a["t_ns"]) / 1e9 for a, b in pairwise(flips)]
    assert min(gaps) >= hold, gaps
    assert "No space left on device" in flips[0]["problem"] and flips[-1]["problem"] == ""
    assert "writes again after" in flips[-1]["text"] and stats["flaky"]["errors"] >= 20


def test_a_watched_recording_is_told_as_a_sink_and_a_broken_watch_never_raises():
    """A recording the hub does not feed (the daemon's CAN log) watched through its
    ``trouble()``: failing then writing again is told as a sink's is, under its own label
    and counts; a watch whose ``trouble()`` and ``counts()`` raise is told as unknown, with no
    counts, and the hub runs on and closes."""
    good = ListSink("good")
    state = {"problem": None}

    def broken():
        raise RuntimeError("recorder gone")

    async def main():
        hub = TelemetryHub([good], flush_interval_s=0.005, tell_hold_s=0.1)
        hub.watch("canlog", lambda: state["problem"],
                  lambda: {"records_dropped": 7, "write_errors": 7}, label="CAN log")
        hub.watch("odd", broken, broken)
        pump = asyncio.create_task(hub.run())
        await asyncio.sleep(0.05)
        state["problem"] = "/data/bus.log: OSError: [Errno 28] No space left on device"
        await asyncio.sleep(0.2)
        state["problem"] = None
        await asyncio.sleep(0.2)
        stats = await hub.aclose(1.0)
        await asyncio.wait_for(pump, 2.0)
        return stats

    stats = run(main())
    told = [r for r in good.records if r.get("type") == "sink"]
    can_log = [r for r in told if r["sink"] == "canlog"]
    assert [r["ok"] for r in can_log] == [False, True], can_log
    assert can_log[0]["text"] == ("CAN log cannot write: /data/bus.log: OSError: [Errno 28] "
                                  "No space left on device")
    assert can_log[1]["text"].startswith("CAN log writes again after ") \
        and "(7 records dropped, 0 bytes given up so far)" in can_log[1]["text"]
    assert (can_log[0]["records_dropped"], can_log[0]["write_errors"],
            can_log[0]["bytes_given_up"]) == (7, 7, 0)
    odd = [r for r in told if r["sink"] == "odd"]
    assert len(odd) == 1 and odd[0]["ok"] is False, odd
    assert odd[0]["text"] == ("telemetry sink odd cannot write: its state unknown: "
                              "RuntimeError: recorder gone")
    assert (odd[0]["records_dropped"], odd[0]["write_errors"]) == (0, 0)
    assert stats["good"]["errors"] == 0


def test_closing_is_bounded_even_if_a_sink_hangs():
    hang, ok = ListSink("hang", hang_close=True), ListSink("ok")

    async def main():
        hub = TelemetryHub([hang, ok], flush_interval_s=0.01)
        pump = asyncio.create_task(hub.run())
        hub.publish({"x": 1})
        await asyncio.sleep(0.03)
        t0 = time.monotonic()
        stats = await hub.aclose(0.2)
        took = time.monotonic() - t0
        await asyncio.wait_for(pump, 2.0)
        return stats, took

    stats, took = run(main())
    assert stats["hang"]["errors"] == 1 and "not finished" in stats["hang"]["last_error"]
    assert ok.closed and took < 1.0


def test_decimation_is_per_sink_and_events_are_never_decimated():
    every10, every1 = ListSink("ten"), ListSink("one")

    async def main():
        hub = TelemetryHub([every10], every_n=10, flush_interval_s=0.01)
        hub.add_sink(every1)
        pump = asyncio.create_task(hub.run())
        for i in range(100):
            hub.publish({"i": i})
            if i == 42:
                hub.publish({"event": "fired"}, always=True)
            if i == 49:
                hub.set_every_n("ten", 25)
        await hub.aclose(1.0)
        await asyncio.wait_for(pump, 2.0)

    run(main())
    got = [r.get("i", r.get("event")) for r in every10.records]
    assert got == [9, 19, 29, 39, "fired", 49, 74, 99]
    assert len(every1.records) == 101


def test_jsonl_sink_writes_complete_lines(tmp_path):
    path = tmp_path / "sub" / "t.jsonl"

    async def main():
        sink = JsonLinesSink(path, truncate=True, slice_s=1e-6)
        hub = TelemetryHub([sink], flush_interval_s=0.01)
        pump = asyncio.create_task(hub.run())
        for i in range(200):
            hub.publish({"i": i, "thrust": np.array([1.0, np.nan, -np.inf]),
                         "flag": np.bool_(True), "n": np.int64(i), "obj": object})
        stats = await hub.aclose(2.0)
        await asyncio.wait_for(pump, 2.0)
        return sink, stats

    sink, stats = run(main())
    lines = path.read_text().splitlines()
    assert len(lines) == 200 == sink.lines == stats["jsonl"]["written"]
    rec = json.loads(lines[7])
    assert rec["i"] == 7 and rec["thrust"] == [1.0, None, None] and rec["flag"] is True
    assert rec["n"] == 7 and "object" in rec["obj"]

    async def append():
        sink = JsonLinesSink(path)
        await sink.open()
        await sink.write([{"again": math.pi}])
        await sink.aclose()

    run(append())
    assert json.loads(path.read_text().splitlines()[-1]) == {"again": math.pi}


def test_daemon_threads():
    async def main():
        w = DaemonWorker("t")
        out = [await w.submit(lambda x: x * 2, 21)]
        try:
            await w.submit(lambda: 1 / 0)
        except ZeroDivisionError:
            out.append("raised")
        w.close()
        out.append(await run_in_daemon_thread(lambda: "done"))
        return out

    assert run(main()) == [42, "raised", "done"]


def test_mailbox_keeps_the_newest_untaken_item():
    m: Mailbox[int] = Mailbox("ins")
    assert m.take() is None
    m.put(1)
    m.put(2)
    assert m.peek() == 2 and m.take() == 2 and m.take() is None
    m.put(3)
    assert m.take() == 3
    assert m.stats() == {"puts": 3, "takes": 2, "overwritten": 1}


def test_mailbox_take_until_leaves_a_later_item_for_the_next_take():
    from drivers.samples import DvlSample
    m: Mailbox[DvlSample] = Mailbox("dvl")
    assert m.take_until(10) is None
    late = DvlSample(t_ns=11, velocity_body=np.zeros(3), bottom_lock=True)
    m.put(late)
    assert m.take_until(10) is None and m.peek() is late   # stamped after the cut: stays
    assert m.take_until(11) is late and m.peek() is None   # at the cut: taken
    assert m.stats() == {"puts": 1, "takes": 1, "overwritten": 0}


def test_a_sink_can_take_only_some_record_types():
    cycles_too, estimates = ListSink("all"), ListSink("est")

    async def main():
        hub = TelemetryHub([cycles_too], flush_interval_s=0.01)
        hub.add_sink(estimates, types=("estimate",))
        pump = asyncio.create_task(hub.run())
        for i in range(50):
            hub.publish({"type": "cycle", "i": i})
            if i % 10 == 0:
                hub.publish({"type": "estimate", "i": i}, always=True)
        hub.publish({"type": "failsafe"}, always=True)
        stats = await hub.aclose(1.0)
        await asyncio.wait_for(pump, 2.0)
        return stats

    stats = run(main())
    assert [r["i"] for r in estimates.records] == [0, 10, 20, 30, 40]
    assert len(cycles_too.records) == 56
    assert stats["est"]["published"] == 5 and stats["est"]["dropped"] == 0


def _estimate(k, theta):
    return {"type": "estimate", "t_ns": k, "estimator": "aid6", "theta": theta, "steps": k,
            "m_min_eig": 1.0, "m_max_eig": 2.0, "frozen": k >= 3,
            "freeze_reason": "M̂ not positive definite at t = 3 s" if k >= 3 else ""}


def test_params_file_sink_keeps_the_newest_estimate(tmp_path):
    from uvd.estimation.aid import INITP_6DOF
    from uvd.io.params import params_from_toml
    from uvd.links.params_file import ParamsFileSink

    path = tmp_path / "state" / "aid.toml"
    now = [0.0]
    thetas = [INITP_6DOF.theta + k for k in range(5)]
    seen = []

    async def main():
        sink = ParamsFileSink(path, every_s=10.0, clock=lambda: now[0])
        await sink.open()
        await sink.write([{"type": "cycle"}])
        assert not path.exists()  # nothing to keep yet
        await sink.write([_estimate(0, thetas[0])])  # the first estimate: written at once
        seen.append(params_from_toml(path).theta)
        now[0] = 5.0
        await sink.write([_estimate(1, thetas[1]), _estimate(2, thetas[2])])
        seen.append(params_from_toml(path).theta)  # not yet: 5 s < every_s
        now[0] = 10.0
        await sink.write([_estimate(3, thetas[3])])
        seen.append(params_from_toml(path).theta)
        await sink.write([_estimate(4, thetas[4])])
        await sink.aclose()  # the newest, whatever the interval
        seen.append(params_from_toml(path).theta)
        return sink

    sink = run(main())
    for got, k in zip(seen, (0, 0, 3, 4), strict=True):
        np.testing.assert_array_equal(got, thetas[k])
    assert sink.writes == 3
    text = path.read_text()
    assert text.startswith("# aid6: online estimate") and "FROZEN" in text
    assert sorted(p.name for p in path.parent.iterdir()) == ["aid.toml"]  # no temporary left


def test_params_file_sink_that_cannot_write_is_counted(tmp_path):
    from uvd.estimation.aid import INITP_6DOF
    from uvd.links.params_file import ParamsFileSink

    (tmp_path / "file").write_text("")  # a file where the folder should be

    async def main():
        hub = TelemetryHub(flush_interval_s=0.01)
        hub.add_sink(ParamsFileSink(tmp_path / "file" / "aid.toml"), types=("estimate",))
        pump = asyncio.create_task(hub.run())
        hub.publish(_estimate(0, INITP_6DOF.theta), always=True)
        stats = await hub.aclose(1.0)
        await asyncio.wait_for(pump, 2.0)
        return stats

    st = run(main())["params-file"]
    assert st["errors"] == 1 and "open" in st["last_error"] and "file" in st["last_error"]
