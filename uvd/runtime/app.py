"""The asyncio application: one TaskGroup owns every task; signals; shutdown; reload.

:class:`App` is the skeleton ``uvd run`` fills in. It owns

* the :class:`~uvd.runtime.loop.FixedRateLoop` running the integration's ``tick(t_ns, dt)``
  (the daemon's: commands, then the cycle — read, update, write), with the systemd watchdog
  ping as its ``after_cycle`` hook;
* the :class:`~uvd.runtime.supervisor.Supervisor` (failsafe arbiter + lifecycle), whose events
  and transitions it logs, reports as ``STATUS=`` and publishes as telemetry;
* the :class:`~uvd.telemetry.sink.TelemetryHub` with the faces the configuration enables,
  built from the one registry :data:`uvd.links.LINKS` (:attr:`App.links`: the black box, JSON
  lines, Zenoh, MAVLink, the parameters file);
* the :class:`Component`\\ s (drivers, estimator workers):
  ``start()`` all (bounded by ``[daemon] start_timeout_s``), then ``run()`` each as a task.

Task structure (``asyncio.TaskGroup``)::

    App.run()
     └─ TaskGroup
         ├─ main: start components → open the links → BOOT→STANDBY → READY=1 → wait for stop
         │                      → shutdown
         ├─ control-loop        FixedRateLoop.run()
         ├─ telemetry           TelemetryHub.run()  (one pump per sink inside)
         ├─ <component>.run()   one per component
         └─ reload              (on SIGHUP, short-lived)

Every task is wrapped so that its failure *requests* an orderly stop with exit code 1 instead of
tearing the group down mid-cycle: the shutdown sequence always runs.

**Signals.** SIGTERM/SIGINT → :meth:`App.request_stop` → the shutdown sequence, bounded by
``[daemon] shutdown_timeout_s`` (1.5 s, inside the 2 s budget):

1. ``STOPPING=1`` and lifecycle → SHUTDOWN;
2. the loop stops at once (it can only be waiting for its next deadline: a cycle is a plain
   function of this thread, so none is ever interrupted);
3. the shutdown steps in order, each bounded (:meth:`App.set_amplifier_hooks` puts "zero
   current" — repeated ``shutdown_zero_cycles`` times — and "disable amplifiers" first);
4. components stopped in reverse order;
5. telemetry sinks drained, flushed and closed (bounded);
6. exit code 0 (1 if a task failed or the drivers did not start).

SIGHUP → :meth:`App.request_reload`: the file is read and validated again; keys marked
*reload* in the schema are applied (failsafe thresholds, gains, overrun streak, telemetry
decimation; the integration's ``reload_hooks`` get the merged config), every other changed key
is named in the log as needing a restart, and an invalid file changes nothing.
"""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import logging
import logging.handlers
import os
import queue
import signal
import sys
import threading
import time
from collections.abc import Awaitable, Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from uvd.links import LINKS, LinkContext
from uvd.rtthreads import (
    ThreadPolicyReport,
    helper_initializer,
    promote_threads,
    restore_threads,
    thread_table,
)
from uvd.runtime.clock import Clock
from uvd.runtime.commands import CommandQueue, CommandResult
from uvd.runtime.config import Config, ConfigValidationError, load_config
from uvd.runtime.cycle import CycleConfig
from uvd.runtime.failsafe import Decision, FailsafeEvent, Health
from uvd.runtime.lifecycle import Transition
from uvd.runtime.loop import CpuLatencyRequest, FixedRateLoop, RealtimeReport, apply_realtime
from uvd.runtime.notify import SdNotifier, WatchdogPinger
from uvd.runtime.schema import reloadable_changes, with_values
from uvd.runtime.supervisor import Supervisor
from uvd.telemetry._worker import run_in_daemon_thread
from uvd.telemetry.sink import TelemetryHub, TelemetrySink

__all__ = ["App", "Component", "ShutdownStep", "setup_logging"]

log = logging.getLogger("uvd.runtime")


@runtime_checkable
class Component(Protocol):
    """A long-lived part of the daemon (a driver, a link, a worker)."""

    name: str

    async def start(self) -> None:
        """Open ports/buses; return when ready (bounded by the app's start timeout)."""

    async def run(self) -> None:
        """The component's own work until cancelled (may return at once)."""

    async def stop(self) -> None:
        """Release resources (bounded by ``[daemon] step_timeout_s``)."""


@dataclass
class ShutdownStep:
    """One step of the shutdown sequence.

    ``fn`` is a plain function (run in a daemon thread, so its timeout holds even if it
    blocks, and a call that never returns cannot keep the process from exiting) or a
    coroutine function; it is called ``repeat`` times ``interval_s`` apart.
    """

    name: str
    fn: Callable[[], Any]
    repeat: int = 1
    interval_s: float = 0.0
    timeout_s: float | None = None


def setup_logging(level: int = logging.INFO) -> logging.handlers.QueueListener:
    """Route every log record through a queue to stderr (journald under systemd).

    Logging from the control cycle then costs a queue put; the formatting and the write
    happen in the listener's thread. Returns the started listener (``.stop()`` it at exit).
    """
    q: queue.SimpleQueue = queue.SimpleQueue()
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    listener = logging.handlers.QueueListener(q, handler, respect_handler_level=True)
    root = logging.getLogger()
    for h in list(root.handlers):
        root.removeHandler(h)
    root.addHandler(logging.handlers.QueueHandler(q))
    root.setLevel(level)
    listener.start()
    return listener


class App:
    """The daemon application.

    Parameters
    ----------
    config : Config
        Validated configuration.
    tick : callable
        ``tick(t_ns, dt)`` — one period of the loop (plain function, must not await).
    components : sequence of Component
        Started in order, stopped in reverse order.
    sinks : sequence of TelemetrySink
        Fed before the faces the configuration enables (:data:`uvd.links.LINKS`: the black
        box, JSON lines, Zenoh, MAVLink, the parameters file), which the App builds.
    supervisor : Supervisor, optional
        Built from ``config.failsafe`` by default. Its ``on_event``/``on_transition``
        listeners are kept and called after the App's own (log, STATUS=, telemetry).
    notifier : SdNotifier, optional
        From ``$NOTIFY_SOCKET`` by default.
    clock : Clock, optional
        For the loop (tests inject a fake one).
    config_path : path, optional
        File re-read on SIGHUP (``config.source`` by default).
    realtime : bool
        Apply ``[loop] sched_fifo_priority`` / ``cpu_affinity`` when running.
    """

    def __init__(self, config: Config, tick: Callable[[int, float], None], *,
                 components: Sequence[Component] = (), sinks: Sequence[TelemetrySink] = (),
                 supervisor: Supervisor | None = None, notifier: SdNotifier | None = None,
                 clock: Clock | None = None, config_path: str | Path | None = None,
                 realtime: bool = True) -> None:
        self.config = config
        self.config_path = Path(config_path) if config_path is not None else (
            Path(config.source) if config.source else None)
        self.components = list(components)
        self.notifier = notifier if notifier is not None else SdNotifier()
        self.supervisor = supervisor or Supervisor(CycleConfig(None, config.failsafe))
        self._user_on_event = self.supervisor.on_event
        self._user_on_transition = self.supervisor.on_transition
        self.supervisor.on_event = self._on_failsafe_event
        self.supervisor.on_transition = self._on_transition
        #: commands from links and tools; the integration's cycle drains it at its start
        self.commands = CommandQueue()
        tel = config.telemetry
        self.hub = TelemetryHub(sinks, queue_size=tel.queue_size,
                                flush_interval_s=tel.flush_interval_s)
        #: the faces the configuration enables, by name (uvd.links.LINKS, in its order)
        self.links: dict[str, TelemetrySink] = {}
        ctx = LinkContext(config, self.hub, self.commands, lambda: self.config)
        for name, make in LINKS.items():
            face = make(ctx)
            if face is not None:
                self.hub.add_sink(face.sink, every_n=face.every_n, types=face.types)
                self.links[name] = face.sink
        self.loop = FixedRateLoop(tick, config.loop, clock=clock, on_error=self._on_cycle_error)
        self.watchdog = WatchdogPinger.from_env(self.notifier)
        if self.watchdog is not None:
            self.loop.after_cycle.append(self.watchdog)
        self.realtime = realtime
        self.realtime_report: RealtimeReport | None = None
        self.thread_policy: ThreadPolicyReport | None = None
        self.thread_tables: dict[str, list[dict[str, Any]]] = {}
        self._helper_prio = 0
        self._loop_tid: int | None = None
        self.shutdown_steps: list[ShutdownStep] = []
        self.reload_hooks: list[Callable[[Config, list[str]], None]] = []
        self.cycle_error_hooks: list[Callable[[BaseException, int], None]] = []
        self.exit_code = 0
        self.stop_reason: str | None = None
        self.last_reload: dict[str, Any] | None = None
        self.shutdown_report: dict[str, Any] = {}
        self._stop: asyncio.Event | None = None
        self._tg: asyncio.TaskGroup | None = None
        self._stopping = False
        self._pending_stop: tuple[str, int] | None = None

    # ------------------------------------------------------------------ integration hooks

    def set_amplifier_hooks(self, zero: Callable[[], Any],
                            disable: Callable[[], Any] | None = None) -> None:
        """Put "zero current" (repeated) and "disable amplifiers" first in the shutdown steps.

        ``zero`` is also called at once, from the loop thread, when a cycle raises.
        """
        d = self.config.daemon
        steps = [ShutdownStep("zero current", zero, repeat=d.shutdown_zero_cycles,
                              interval_s=d.shutdown_zero_period_s)]
        if disable is not None:
            steps.append(ShutdownStep("disable amplifiers", disable))
        self.shutdown_steps[:0] = steps

        def zero_now(exc: BaseException, t_ns: int) -> None:
            result = zero()
            if inspect.isawaitable(result):  # a coroutine cannot run inside the cycle
                result.close()
        self.cycle_error_hooks.insert(0, zero_now)

    def add_shutdown_step(self, step: ShutdownStep) -> None:
        self.shutdown_steps.append(step)

    # ------------------------------------------------------------------ edges

    def _on_failsafe_event(self, ev: FailsafeEvent) -> None:
        level = logging.INFO if ev.kind in ("cleared", "reset") or \
            ev.action.value <= 1 else logging.WARNING
        log.log(level, "%s", ev)
        self.hub.publish({"type": "failsafe", **ev.as_dict()}, always=True)
        if self._user_on_event is not None:
            self._user_on_event(ev)

    def _on_transition(self, tr: Transition, decision: Decision | None) -> None:
        log.info("lifecycle %s", tr)
        self.notifier.status(self.supervisor.status_text())
        self.hub.publish({"type": "lifecycle", **tr.as_dict()}, always=True)
        if self._user_on_transition is not None:
            self._user_on_transition(tr, decision)

    def _on_cycle_error(self, exc: BaseException, t_ns: int) -> None:
        """A cycle raised: zero thrust now, and latch the cycle_exception failsafe."""
        for hook in self.cycle_error_hooks:
            try:
                hook(exc, t_ns)
            except Exception:
                log.exception("cycle-error hook failed")
        base = self.supervisor.last_health or Health(t_ns=t_ns)
        self.supervisor.step(replace(base, t_ns=t_ns, cycle_failed=True))
        log.error("control cycle raised %s: %s (zero thrust commanded)", type(exc).__name__,
                  exc)

    # ------------------------------------------------------------------ requests

    def request_stop(self, reason: str = "requested", exit_code: int = 0) -> None:
        """Begin the orderly shutdown (idempotent; the first reason and worst code win)."""
        self.exit_code = max(self.exit_code, exit_code)
        if self.stop_reason is None:
            self.stop_reason = reason
        if self._stop is None:
            self._pending_stop = (reason, exit_code)
            return
        self._stop.set()

    def request_reload(self) -> None:
        """Re-read the configuration file and apply what may change (SIGHUP)."""
        if self._tg is None or self._stopping:
            return
        self._tg.create_task(self._reload(), name="reload")

    async def _reload(self) -> dict[str, Any]:
        if self.config_path is None:
            log.warning("SIGHUP: no configuration file to reload from")
            self.last_reload = {"error": "no configuration file"}
            return self.last_reload
        self.notifier.reloading()
        try:
            new = await asyncio.to_thread(load_config, self.config_path)
        except ConfigValidationError as exc:
            log.error("reload refused, the running configuration is kept:\n%s", exc)
            self.last_reload = {"error": str(exc), "applied": [], "refused": []}
            self.hub.publish({"type": "reload", "t_ns": time.monotonic_ns(), "ok": False,
                              "applied": [], "restart_needed": [], "error": str(exc)},
                             always=True)
            self.notifier.ready(self.supervisor.status_text())
            return self.last_reload
        merged, applied, refused = reloadable_changes(self.config, new)
        self.apply_config(merged, applied)
        if applied:
            log.info("reload: applied %s", ", ".join(applied))
        if refused:
            log.warning("reload: these keys changed but need a restart (kept as they were): %s",
                        ", ".join(refused))
        if not applied and not refused:
            log.info("reload: nothing changed")
        self.last_reload = {"applied": applied, "refused": refused}
        self.hub.publish({"type": "reload", "t_ns": time.monotonic_ns(), "ok": True,
                          "applied": list(applied), "restart_needed": list(refused),
                          "error": None}, always=True)
        self.notifier.ready(self.supervisor.status_text())
        return self.last_reload

    def set_params(self, values: dict[str, Any]) -> CommandResult:
        """A ``SetParams`` command at a cycle boundary: reloadable keys changed exactly as a
        SIGHUP reload changes them; refused as a whole when a key is unknown, needs a restart
        or its value is bad."""
        new, errors = with_values(self.config, values, reload_only=True)
        if errors:
            return CommandResult(False, "; ".join(f"{k}: {r}" for k, r in errors))
        merged, applied, _ = reloadable_changes(self.config, new)
        self.apply_config(merged, applied)
        return CommandResult(True)

    def apply_config(self, merged: Config, applied: list[str]) -> None:
        """Take a configuration whose changes from the running one are all reloadable (a
        SIGHUP reload, a ``SetParams`` command at a cycle boundary): thresholds, overrun
        streak, decimation, and the integration's ``reload_hooks``."""
        self.config = merged
        self.loop.set_overrun_streak(merged.loop.overrun_streak)
        self.supervisor.set_thresholds(merged.failsafe)
        self.hub.set_every_n("jsonl", merged.telemetry.jsonl.every_n_cycles)
        for hook in self.reload_hooks:
            try:
                hook(merged, applied)
            except Exception:
                log.exception("reload hook failed")

    # ------------------------------------------------------------------ running

    def _install_signals(self, loop: asyncio.AbstractEventLoop) -> list[int]:
        installed = []
        handlers = {signal.SIGTERM: lambda: self.request_stop("SIGTERM"),
                    signal.SIGINT: lambda: self.request_stop("SIGINT"),
                    signal.SIGHUP: self.request_reload}
        for sig, fn in handlers.items():
            try:
                loop.add_signal_handler(sig, fn)
                installed.append(sig)
            except (NotImplementedError, RuntimeError, ValueError) as exc:
                log.warning("cannot handle %s here (%s)", signal.Signals(sig).name, exc)
        return installed

    async def _guard(self, name: str, run: Callable[[], Awaitable[Any]]) -> Any:
        """Await ``run()``; an exception stops the daemon (exit 1) instead of escaping. The
        coroutine is made here, so a task cancelled before it starts leaves none unawaited."""
        try:
            return await run()
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            log.exception("%s failed: %s", name, exc)
            self.request_stop(f"{name} failed: {type(exc).__name__}: {exc}", exit_code=1)
            return None

    async def run(self) -> int:
        """Run until stopped; returns the process exit code (0 after SIGTERM/SIGINT)."""
        aloop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        if self._pending_stop is not None:
            self._stop.set()
        old_switch = sys.getswitchinterval()
        sys.setswitchinterval(self.config.daemon.gil_switch_interval_us * 1e-6)
        # workers start later, from the loop's thread: each puts itself at the helpers'
        # priority (normal scheduling when real time is not in force)
        executor = ThreadPoolExecutor(max_workers=4, thread_name_prefix="uvd-worker",
                                      initializer=helper_initializer(lambda: self._helper_prio))
        aloop.set_default_executor(executor)
        installed = self._install_signals(aloop)
        cpu_latency = None
        if self.realtime:
            self.realtime_report = apply_realtime(self.config.loop.sched_fifo_priority,
                                                  self.config.loop.cpu_affinity)
            for m in self.realtime_report.messages:
                log.warning("%s", m)
            self._promote_helpers("start")
            if self.config.loop.sched_fifo_priority > 0:
                # keep idle CPUs from halting (a halted vCPU wakes in hundreds of µs)
                cpu_latency = CpuLatencyRequest(0).open()
                if cpu_latency.message:
                    log.warning("%s", cpu_latency.message)
        try:
            async with asyncio.TaskGroup() as tg:
                self._tg = tg
                tg.create_task(self._main(tg), name="main")
        except* Exception as eg:  # should not happen: every task is guarded
            for exc in eg.exceptions:
                log.error("unexpected failure: %r", exc)
            self.exit_code = max(self.exit_code, 1)
        finally:
            self._tg = None
            for sig in installed:
                aloop.remove_signal_handler(sig)
            sys.setswitchinterval(old_switch)
            if cpu_latency is not None:
                cpu_latency.close()
            executor.shutdown(wait=False, cancel_futures=True)
            self.loop.close()
            if self.thread_policy is not None:  # a run inside a longer-lived process (tests)
                restore_threads(self.thread_policy)
            self._helper_prio = 0
        return self.exit_code

    def helper_priority(self) -> int:
        """SCHED_FIFO priority for the daemon's other threads (0: leave them alone)."""
        rep = self.realtime_report
        loop_prio = rep.sched_fifo_priority if rep is not None else 0
        if loop_prio <= 0:
            return 0
        return min(int(self.config.daemon.helper_thread_priority), loop_prio)

    def _promote_helpers(self, when: str) -> None:
        """Every thread but the loop's to SCHED_FIFO at :meth:`helper_priority`, on the
        loop's CPUs (see :mod:`uvd.rtthreads`); tables before/after are kept."""
        if self._loop_tid is None:
            self._loop_tid = threading.get_native_id()
            self.thread_tables["before"] = [t.as_dict() for t in thread_table()]
        prio = self.helper_priority()
        self._helper_prio = prio
        if prio <= 0:
            self.thread_tables[when] = [t.as_dict() for t in thread_table()]
            return
        first = self.thread_policy is None
        self.thread_policy = promote_threads(
            prio, self.realtime_report.cpu_affinity if self.realtime_report else (),
            exclude={self._loop_tid}, report=self.thread_policy)
        table = [t.as_dict() for t in thread_table()]
        self.thread_tables[when] = table
        for m in self.thread_policy.messages[:1] if first else ():
            log.warning("%s", m)
        fifo = sum(t["policy"] == "SCHED_FIFO" for t in table)
        log.info("threads (%s): %d of %d at SCHED_FIFO (loop %d, helpers %d)", when, fifo,
                 len(table), self.realtime_report.sched_fifo_priority, prio)

    async def _main(self, tg: asyncio.TaskGroup) -> None:
        cfg = self.config.daemon
        # The links open first, before the daemon says it is up (a station that comes at once
        # finds the MAVLink port bound), and before the drivers: those touch the vehicle, and
        # started drives consume a heartbeat only the control loop sends ([can.amplifiers]
        # node_consumer_ms) — a link waited for after them faulted every drive. A link not
        # open within start_timeout_s is told and goes on opening; the drivers then have
        # start_timeout_s of their own.
        tasks = [tg.create_task(self._guard("telemetry", self.hub.run), name="telemetry")]
        opening = await self.hub.wait_open(cfg.start_timeout_s)
        if opening:
            log.warning("telemetry: %s not open within [daemon] start_timeout_s %g s; up "
                        "without them, they go on opening", ", ".join(opening),
                        cfg.start_timeout_s)
        started: list[Component] = []
        try:
            async with asyncio.timeout(cfg.start_timeout_s):
                for c in self.components:
                    await c.start()
                    started.append(c)
        except Exception as exc:
            what = "timed out" if isinstance(exc, TimeoutError) else f"{type(exc).__name__}: {exc}"
            log.error("start failed (%s) after %s", what,
                      ", ".join(c.name for c in started) or "no component")
            self.request_stop(f"start failed: {what}", exit_code=1)
            await self._shutdown(None, started)
            for task in tasks:
                task.cancel()
            return
        t = time.monotonic_ns()
        if self.realtime:  # threads the drivers started (python-can, canopen, pyserial)
            self._promote_helpers("booted")
        self.supervisor.boot_complete(t, "components up: " +
                                      (", ".join(c.name for c in started) or "none"))
        self.notifier.ready(self.supervisor.status_text())
        tasks += [tg.create_task(self._guard(c.name, c.run), name=c.name) for c in started]
        loop_task = tg.create_task(self._guard("control loop", self._run_loop),
                                   name="control-loop")
        if self._helper_prio > 0:
            tasks.append(tg.create_task(self._guard("thread policy", self._watch_threads),
                                        name="thread-policy"))
        await self._stop.wait()
        await self._shutdown(loop_task, started)
        for task in tasks:
            task.cancel()

    async def _watch_threads(self, period_s: float = 2.0) -> None:
        """Threads started later (the telemetry sinks' writers, a reconnecting driver)
        inherit their creator's priority — the loop's own when created from its thread: put
        each new one at the helpers' priority too (a directory listing every ``period_s``)."""
        known = set(os.listdir("/proc/self/task"))
        while True:
            await asyncio.sleep(period_s)
            try:
                now = set(os.listdir("/proc/self/task"))
            except OSError:
                return
            if now - known:
                self._promote_helpers("running")
            known = now

    async def _run_loop(self) -> None:
        await self.loop.run()
        if not self._stopping:
            self.request_stop("the control loop returned", exit_code=1)

    async def _step(self, step: ShutdownStep, budget_s: float) -> str:
        timeout = min(step.timeout_s or self.config.daemon.step_timeout_s, max(budget_s, 0.0))

        async def once() -> None:
            if inspect.iscoroutinefunction(step.fn):
                await step.fn()
            else:  # a daemon thread: a call that hangs is abandoned, never joined at exit
                result = await run_in_daemon_thread(step.fn, name=f"uvd-{step.name}")
                if inspect.isawaitable(result):
                    await result

        async def all_repeats() -> None:
            for i in range(max(1, step.repeat)):
                await once()
                if i + 1 < step.repeat and step.interval_s > 0:
                    await asyncio.sleep(step.interval_s)

        try:
            await asyncio.wait_for(all_repeats(), timeout)
            return "ok"
        except TimeoutError:
            log.error("shutdown step %r did not finish within %.3g s", step.name, timeout)
            return "timeout"
        except Exception as exc:
            log.error("shutdown step %r failed: %s: %s", step.name, type(exc).__name__, exc)
            return f"failed: {type(exc).__name__}: {exc}"

    async def _shutdown(self, loop_task: asyncio.Task | None,
                        started: Sequence[Component]) -> None:
        if self._stopping:
            return
        self._stopping = True
        t0 = time.monotonic()
        cfg = self.config.daemon
        budget = cfg.shutdown_timeout_s

        def left() -> float:
            return budget - (time.monotonic() - t0)

        reason = self.stop_reason or "requested"
        self.supervisor.request_shutdown(time.monotonic_ns(), reason)
        self.notifier.stopping(self.supervisor.status_text())
        log.info("shutting down: %s", reason)
        report: dict[str, Any] = {"reason": reason, "steps": {}}
        self.loop.stop()
        if loop_task is not None and not loop_task.done():
            # The loop task can only be suspended at its coarse wait (a cycle is a plain
            # function running in this thread), so cancelling it never interrupts a cycle;
            # waiting for its next deadline instead would delay "zero current" by up to a
            # period (100 ms at 10 Hz).
            loop_task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await loop_task
            report["loop"] = "stopped at its wait"
        for step in self.shutdown_steps:
            report["steps"][step.name] = await self._step(step, left())
        for c in reversed(list(started)):
            report["steps"][f"stop {c.name}"] = await self._step(
                ShutdownStep(f"stop {c.name}", c.stop), left())
        sink_budget = min(cfg.step_timeout_s, max(left(), 0.05))
        report["telemetry"] = await self.hub.aclose(sink_budget)
        report["duration_s"] = time.monotonic() - t0
        report["loop_stats"] = self.loop.snapshot()
        self.shutdown_report = report
        log.info("shutdown complete in %.3f s (exit code %d)", report["duration_s"],
                 self.exit_code)

    def summary(self) -> dict[str, Any]:
        """Loop statistics, lifecycle, failsafe history, telemetry and notify counters."""
        return {
            "loop": self.loop.snapshot(),
            "lifecycle": self.supervisor.state.value,
            "failsafe_events": self.supervisor.failsafe_events(),
            "telemetry": self.hub.stats(),
            "notify": {"enabled": self.notifier.enabled, "sent": self.notifier.sent,
                       "errors": self.notifier.errors,
                       "watchdog_pings": self.watchdog.pings if self.watchdog else 0},
            "realtime": None if self.realtime_report is None else {
                "sched_fifo_priority": self.realtime_report.sched_fifo_priority,
                "cpu_affinity": list(self.realtime_report.cpu_affinity),
                "messages": list(self.realtime_report.messages),
                "helper_thread_priority": self.thread_policy.helper_priority
                if self.thread_policy is not None else 0,
                "helper_messages": list(self.thread_policy.messages)
                if self.thread_policy is not None else [],
                "threads": self.thread_tables},
        }
