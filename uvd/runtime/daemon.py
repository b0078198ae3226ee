"""The daemon (``uvd run``): read → update → write, once per period of the fixed-rate loop.

:class:`Daemon` wires, from a validated :class:`~uvd.runtime.config.Config`, what the
:class:`~uvd.runtime.app.App` runs: the cycle (:func:`uvd.runtime.build.make_cycle`, held by
the :class:`~uvd.runtime.supervisor.Supervisor`) and the hardware interfaces
(:mod:`uvd.runtime.interfaces`) — the instruments, the CAN bus with the amplifiers, the leak
input, the ground-station link's heartbeat. Its :meth:`Daemon.tick` is glue only::

    commands      the operator's commands queued since the last cycle (App.commands); a
                  failsafe reset of a disarmed vehicle held while the amplifiers are
                  brought back (uvd.runtime.recovery)
    read          each hardware interface adds its part of the cycle's inputs
    update        uvd.runtime.cycle.update — the same update lockstep and replay run
    write         the command to the amplifiers, one telemetry record, every
                  publish_every_s the online estimates

Everything that decides a command is in the update; nothing here changes what it returns.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import asdict
from typing import Any

import numpy as np

from uvd import _jitcache, core
from uvd.runtime.app import App
from uvd.runtime.build import make_cycle, start_pose
from uvd.runtime.commands import AutoArm, CommandResult, FaultReport, SetParams
from uvd.runtime.config import Config
from uvd.runtime.cycle import CycleInputs, CycleResult
from uvd.runtime.hardware import Hardware
from uvd.runtime.interfaces import InputParts
from uvd.runtime.lifecycle import State
from uvd.runtime.recovery import AmplifierRecovery
from uvd.runtime.reporting import Estimates, cycle_record
from uvd.runtime.startup import kept_params, prepare, start_record
from uvd.runtime.supervisor import Supervisor
from uvd.runtime.triggers import OperatorHeartbeat

__all__ = ["Daemon", "kept_params"]

log = logging.getLogger("uvd.daemon")


class Daemon:
    """``uvd run``: the hardware interfaces, the cycle and the :class:`App` that runs them.

    ``auto_arm`` (``uvd run --arm``, :class:`~uvd.runtime.commands.AutoArm`); ``sinks``: extra
    telemetry sinks (tests); ``notifier``, ``clock``, ``realtime``: passed to :class:`App`.
    """

    def __init__(self, config: Config, *, auto_arm: bool = False, sinks: Sequence = (),
                 notifier=None, clock=None, realtime: bool = True) -> None:
        cold, t_init = _jitcache.cache_is_empty(), time.perf_counter()  # before any kernel
        #: parameters a ground station set before this start (in the start record: a replay
        #: applies them too)
        self.params_kept: dict[str, Any] = {}
        if config.mavlink.enabled and config.mavlink.params_file:
            config, self.params_kept = kept_params(config, config.mavlink.params_file)
        self.config = config
        self.vehicle = config.load_vehicle()
        self.supervisor = Supervisor(make_cycle(config, self.vehicle))
        self.hardware = hw = Hardware(config, self.vehicle)
        self.app = App(config, self.tick, components=hw.components, sinks=sinks,
                       supervisor=self.supervisor, notifier=notifier, clock=clock,
                       realtime=realtime)
        # the faces (uvd.links) are the App's; the black box taps every raw input frame
        self.recorder, self.mavlink = self.app.links.get("mcap"), self.app.links.get("mavlink")
        if self.recorder is not None:
            hw.tap(self.recorder)
        if config.can.log.path is not None:  # told as the sinks are, though no sink
            self.app.hub.watch("canlog", hw.can.log_trouble, hw.can.log_counts,
                               label="CAN log")
        if self.recorder is not None and config.recording.min_free_mb > 0:
            self.app.hub.watch("recording-disk", self.recorder.low_space,
                               label="recording disk", failing_as="low",
                               ok_as="has room again")
        if hw.instruments.sync:
            hw.wake_on_ins(self.app.loop.wake)
        self.app.set_amplifier_hooks(zero=hw.can.zero, disable=hw.can.disable)
        self.app.reload_hooks.append(self._on_reload)
        self.max_thrust = np.asarray(self.core_cfg.allocator.max_thrust_n, dtype=float)
        if self.mavlink is not None:
            hw.inputs.insert(-1, OperatorHeartbeat(self.mavlink))
        self.estimates = Estimates(self.app.hub, self.supervisor,
                                   config.estimation.publish_every_s)
        self.estimates.attach(self.app)
        self.app.hub.publish(start_record(config, self.params_kept, self.supervisor.config,
                                          self.supervisor.data), always=True)
        self.auto_arm = AutoArm(config.loop.rate_hz) if auto_arm else None
        #: an operator's failsafe reset, disarmed, brings the amplifiers back first
        self.recovery = AmplifierRecovery(hw.can,
                                          lambda: self.config.failsafe.feedback_stale_s)
        self.counters = {"cycles": 0, "guard_nonfinite": 0, "guard_clamped": 0}
        self.commands_max_abs = 0.0
        self.warm_up_s = prepare(self.supervisor.config, start_pose(config)[0],
                                 self.app.notifier.status, cold=cold, t_init=t_init)

    # -- the cycle's configuration and state, for tests and tools --

    @property
    def core_cfg(self) -> core.CoreConfig:
        return self.supervisor.config.core

    @property
    def state(self) -> core.CoreState:
        return self.supervisor.data.core

    @property
    def armed_at_ns(self) -> int | None:
        return self.supervisor.armed_at_ns

    def _on_reload(self, cfg: Config, applied: list[str]) -> None:
        """The reloaded configuration's cycle, built as at start; the running estimators stay
        (their keys need a restart; initial_params is not read again), and so does the state
        — the running reference, the controller's memory."""
        self.config = cfg
        self.supervisor.reconfigure(make_cycle(cfg, self.vehicle,
                                               estimators=self.core_cfg.estimators))
        self.estimates.period_ns = int(cfg.estimation.publish_every_s * 1e9)

    # -- one period of the loop: commands, read, update, write --

    def tick(self, t_ns: int, dt: float) -> None:
        """One period of the fixed-rate loop (see the module docstring)."""
        for p in self.app.commands.drain():
            if not self.recovery.hold(p, t_ns, self.supervisor.state):
                p.future.set_result(self._apply(p.command, t_ns))
        for p in self.recovery.due(t_ns):
            p.future.set_result(self._apply(p.command, t_ns))
        if self.auto_arm is not None:
            sup = self.supervisor
            arm = self.auto_arm.due(t_ns, sup.state is State.STANDBY, sup.armed_at_ns is not None)
            if arm is not None:
                self.auto_arm.answered(self._apply(arm, t_ns), t_ns, log)
        inp = self.read(t_ns)
        self.recovery.seen(t_ns, inp.actuators)
        self.write(t_ns, dt, inp, self.supervisor.update(inp, dt))

    def read(self, t_ns: int) -> CycleInputs:
        """Every hardware interface's part of the cycle's inputs, gathered without waiting."""
        parts = InputParts()
        armed = self.supervisor.armed
        for hw in self.hardware.inputs:
            hw.read(t_ns, armed, parts)
        loop = self.app.loop
        return parts.inputs(t_ns, loop.overrun_streak, loop.streak_exceeded)

    def write(self, t_ns: int, dt: float, inp: CycleInputs, r: CycleResult) -> None:
        """The command to the amplifiers, the counters, one telemetry record."""
        out = r.out
        thrust = out.thrust_n
        self.hardware.write(t_ns, thrust)
        if out.guard:
            self.counters["guard_clamped" if out.guard == 1 else "guard_nonfinite"] += 1
        self.commands_max_abs = max(self.commands_max_abs, float(np.abs(thrust).max()))
        self.counters["cycles"] += 1
        self.app.hub.publish(cycle_record(t_ns, dt, inp, r))
        self.estimates.after_cycle(t_ns, dt)

    def _apply(self, c, t_ns: int) -> CommandResult:
        """Apply one command at this cycle boundary; its result is published as a
        ``"command"`` record (what a replay applies again at the same cycle)."""
        try:
            res = self.app.set_params(c.values) if isinstance(c, SetParams) else \
                self.supervisor.apply(c, t_ns)
        except Exception as exc:  # noqa: BLE001 - a bad command never breaks the cycle
            res = CommandResult(False, f"{type(exc).__name__}: {exc}")
        self.app.hub.publish({"type": "command", "t_ns": t_ns, "command": type(c).__name__,
                              "args": asdict(c), "source": c.source, "ok": res.ok,
                              "reason": res.reason}, always=True)
        if isinstance(c, FaultReport):  # acted on, advisory or refused: in the daemon's log
            log.warning("fault sample %s: %s", "accepted" if res.ok else "refused", res.reason)
        return res

    # -- running --

    async def run(self) -> int:
        """Run until stopped (SIGTERM/SIGINT or :meth:`stop`); returns the exit code. After
        the App's bounded shutdown, a port or bus it had no time left to close is closed here
        (a daemon run inside a longer-lived process — tests, tools — leaves none locked)."""
        try:
            return await self.app.run()
        finally:
            self.hardware.close_now()

    def stop(self, reason: str = "requested") -> None:
        self.app.request_stop(reason)

    def summary(self) -> dict[str, Any]:
        """App summary (loop statistics, failsafe events, …) plus the daemon's counters."""
        out = self.app.summary()
        out["daemon"] = {**self.counters, **self.hardware.counters,
                         "amplifier_recoveries": self.recovery.recoveries,
                         "commands_max_abs_n": self.commands_max_abs,
                         "armed_at_ns": self.armed_at_ns,
                         "arm_refusal": None if self.auto_arm is None else self.auto_arm.refusal}
        out.update(self.hardware.stats())
        fdc = self.supervisor.data.fdc
        if fdc is not None:  # uvd-fdc's samples by outcome ([faults.fdc])
            out["fault_samples"] = fdc.counts()
        z = self.app.links.get("zenoh")
        if getattr(z, "faults", None) is not None:  # and as they arrived (dropped: not taken)
            out["fault_samples_in"] = {"received": z.faults_received,
                                       "dropped": z.faults_dropped,
                                       "flooded": z.faults_flooded,
                                       "malformed": z.faults_malformed}
        out["shutdown"] = self.app.shutdown_report
        return out

