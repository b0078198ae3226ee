"""Every thread of a real-time App runs with the configured policy (uvd.rtthreads).

The GIL makes the loop wait for whichever thread holds it: a normally scheduled helper thread
preempted by other load while holding it stalls the SCHED_FIFO loop (issue 7's demo stall).
The App therefore puts every other thread at SCHED_FIFO one below the loop, on the loop's
CPUs: threads that existed before it started, threads the drivers start, worker-pool
threads, and threads started later (telemetry writers).
"""

from __future__ import annotations

import asyncio
import os
import subprocess
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest

from uvd.rtthreads import (
    ThreadPolicyReport,
    promote_threads,
    restore_threads,
    thread_table,
)
from uvd.runtime.app import App
from uvd.runtime.config import load_config
from uvd.runtime.notify import SdNotifier

ROOT = Path(__file__).resolve().parents[1]
LOOP_PRIO = 5  # low: whatever else runs on this machine at real-time priority stays above

pytestmark = pytest.mark.timeout(60)


def _fifo_permitted() -> str | None:
    out: list[str | None] = []

    def probe() -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
            out.append(None)
        except (OSError, AttributeError) as exc:
            out.append(f"SCHED_FIFO not permitted here: {exc}")
    t = threading.Thread(target=probe)
    t.start()
    t.join()
    return out[0]


needs_fifo = pytest.mark.skipif(_fifo_permitted() is not None,
                                reason=str(_fifo_permitted()))


class ThreadStarter:
    """A component that starts a thread from start() (as python-can's receive thread) and
    calls a blocking function through the default executor (as the CAN SDO set-up)."""

    name = "threads"

    def __init__(self) -> None:
        self.stop_evt = threading.Event()
        self.tids: dict[str, int] = {}

    async def start(self) -> None:
        t = threading.Thread(target=self.stop_evt.wait, name="driver-rx", daemon=True)
        t.start()
        self.tids["driver-rx"] = t.native_id
        self.tids["worker"] = await asyncio.to_thread(threading.get_native_id)

    async def run(self) -> None:
        await asyncio.sleep(0.3)  # a thread started while running (a telemetry writer)
        t = threading.Thread(target=self.stop_evt.wait, name="late", daemon=True)
        t.start()
        self.tids["late"] = t.native_id

    async def stop(self) -> None:
        self.stop_evt.set()


@needs_fifo
def test_every_thread_of_a_started_app_runs_at_the_configured_policy():
    cfg = load_config(ROOT / "config" / "sim.toml")
    cpus = sorted(os.sched_getaffinity(0))
    cfg = replace(cfg, loop=replace(cfg.loop, rate_hz=50.0, sched_fifo_priority=LOOP_PRIO,
                                    cpu_affinity=(cpus[-1],)),
                  telemetry=replace(cfg.telemetry,
                                    jsonl=replace(cfg.telemetry.jsonl, enabled=False)),
                  daemon=replace(cfg.daemon, helper_thread_priority=LOOP_PRIO - 1),
                  mavlink=replace(cfg.mavlink, enabled=False))  # an App without its link
    # a thread that exists before the App starts, normally scheduled (the logging listener,
    # an OpenBLAS worker): it inherits nothing
    early_stop = threading.Event()
    early = threading.Thread(target=early_stop.wait, name="early", daemon=True)
    early.start()
    comp = ThreadStarter()
    seen: dict = {}

    def runner() -> None:
        app = App(cfg, lambda t, dt: None, components=[comp], realtime=True,
                  notifier=SdNotifier(env={}))
        seen["app"] = app

        async def main():
            task = asyncio.get_running_loop().create_task(app.run())
            deadline = time.monotonic() + 20.0
            while "late" not in comp.tids or app.thread_tables.get("running") is None:
                assert time.monotonic() < deadline, "the App did not see the late thread"
                assert not task.done()
                await asyncio.sleep(0.05)
            seen["loop_tid"] = threading.get_native_id()
            seen["table"] = {t.tid: t for t in thread_table()}
            app.request_stop("test")
            seen["code"] = await task
        asyncio.run(main())

    th = threading.Thread(target=runner, name="app-thread")
    th.start()
    th.join(40.0)
    early_stop.set()
    assert not th.is_alive() and seen.get("code") == 0, seen
    app = seen["app"]
    assert app.realtime_report.ok, app.realtime_report.messages
    assert app.thread_policy.ok, app.thread_policy.messages
    table = seen["table"]
    loop = table[seen["loop_tid"]]
    assert (loop.policy, loop.priority, loop.cpus) == ("SCHED_FIFO", LOOP_PRIO, (cpus[-1],))
    helpers = {tid: t for tid, t in table.items() if tid != seen["loop_tid"]}
    for name in ("driver-rx", "worker", "late"):
        assert comp.tids[name] in helpers, name
    assert early.native_id in helpers
    # every thread of the process, pytest's own included, one below the loop, on its CPU
    wrong = [t for t in helpers.values()
             if (t.policy, t.priority, t.cpus) != ("SCHED_FIFO", LOOP_PRIO - 1, (cpus[-1],))]
    assert not wrong, wrong
    # the report carries the tables (before: the early thread was normally scheduled)
    before = {t["tid"]: t for t in app.thread_tables["before"]}
    assert before[early.native_id]["policy"] == "SCHED_OTHER"
    summary = app.summary()["realtime"]
    assert summary["helper_thread_priority"] == LOOP_PRIO - 1
    assert {t["tid"] for t in summary["threads"]["booted"]} >= {early.native_id}
    # after the run, the threads the App changed are as they were (a test process goes on)
    assert os.sched_getscheduler(threading.get_native_id()) == os.SCHED_OTHER
    assert os.sched_getaffinity(threading.get_native_id()) == set(cpus)


@needs_fifo
def test_helper_priority_zero_leaves_other_threads_alone_and_the_config_bounds_it():
    cfg = load_config(ROOT / "config" / "sim.toml")
    cfg = replace(cfg, loop=replace(cfg.loop, sched_fifo_priority=LOOP_PRIO),
                  daemon=replace(cfg.daemon, helper_thread_priority=0),
                  mavlink=replace(cfg.mavlink, enabled=False))
    app = App(cfg, lambda t, dt: None, realtime=True, notifier=SdNotifier(env={}))
    from uvd.runtime.loop import RealtimeReport
    app.realtime_report = RealtimeReport(sched_fifo_priority=LOOP_PRIO)
    assert app.helper_priority() == 0
    app.config = replace(cfg, daemon=replace(cfg.daemon, helper_thread_priority=LOOP_PRIO - 1))
    assert app.helper_priority() == LOOP_PRIO - 1
    assert load_config(ROOT / "config" / "sim.toml").daemon.helper_thread_priority == 0  # default
    app.realtime_report = RealtimeReport(sched_fifo_priority=0)  # refused: nothing to do
    assert app.helper_priority() == 0

    import tomllib

    from uvd.runtime.config import ConfigValidationError, parse_config
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    data["loop"]["sched_fifo_priority"] = 20
    data.setdefault("daemon", {})["helper_thread_priority"] = 30
    with pytest.raises(ConfigValidationError, match="daemon.helper_thread_priority"):
        parse_config(data)


@needs_fifo
def test_promote_and_restore_by_thread_id():
    stop = threading.Event()
    t = threading.Thread(target=stop.wait, daemon=True)
    t.start()
    try:
        me = threading.get_native_id()
        rep = promote_threads(3, exclude={me} | {x.tid for x in thread_table()
                                                 if x.tid != t.native_id})
        assert rep.ok and t.native_id in rep.changed
        assert os.sched_getscheduler(t.native_id) == os.SCHED_FIFO
        assert os.sched_getparam(t.native_id).sched_priority == 3
        assert os.sched_getscheduler(me) == os.SCHED_OTHER  # excluded
        assert restore_threads(rep) == 1
        assert os.sched_getscheduler(t.native_id) == os.SCHED_OTHER
    finally:
        stop.set()


def test_restore_leaves_a_task_of_another_process_alone():
    """A remembered thread that has ended may have lent its id to another process' task."""
    other = subprocess.Popen(["sleep", "10"])
    try:
        before = (os.sched_getscheduler(other.pid), os.sched_getparam(other.pid).sched_priority)
        rep = ThreadPolicyReport()
        rep.changed[other.pid] = (os.SCHED_FIFO, 1, (0,))
        assert restore_threads(rep) == 0 and not rep.changed
        assert (os.sched_getscheduler(other.pid),
                os.sched_getparam(other.pid).sched_priority) == before
    finally:
        other.kill()
        other.wait(5)
