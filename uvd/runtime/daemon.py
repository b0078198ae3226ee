"""The daemon (``uvd run``): read → update → write, once per period of the fixed-rate loop.

:class:`Daemon` wires, from a validated :class:`~uvd.runtime.config.Config`, what the
:class:`~uvd.runtime.app.App` runs: the serial instruments (:mod:`uvd.runtime.sensors`), the
CAN bus with the amplifiers (:mod:`uvd.runtime.can_component`), the leak input, and the cycle
(:class:`~uvd.runtime.cycle.Cycle`, built by :mod:`uvd.runtime.build`). Its
:meth:`Daemon.cycle` is glue only::

    commands      the operator's commands queued since the last cycle (App.commands)
    read          the newest samples (mailboxes), the amplifiers' typed status, leak, loop
    update        Cycle.update — the same update lockstep and replay run, failsafes included
    write         the thrust command to the amplifiers (RPDOs + SYNC), one telemetry record,
                  every publish_every_s the online estimates

Everything that decides a command is in the update; nothing here changes what it returns.
"""

from __future__ import annotations

import gc
import logging
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivers.samples import R_to_euler
from uvd import __version__, _jitcache, core
from uvd.runtime.app import App, ShutdownStep
from uvd.runtime.build import build_core, start_pose
from uvd.runtime.can_component import CanComponent, GcFreeze, actuator_status
from uvd.runtime.commands import Arm, CommandResult, SetParams
from uvd.runtime.config import Config
from uvd.runtime.cycle import Cycle, CycleInputs, CycleResult, inputs_record
from uvd.runtime.failsafe import Action
from uvd.runtime.leak import LeakInput
from uvd.runtime.lifecycle import State
from uvd.runtime.loop import CpuLatencyRequest
from uvd.runtime.mailbox import Mailbox
from uvd.runtime.schema import reloadable_changes, with_values
from uvd.runtime.sensors import make_sensors
from uvd.runtime.supervisor import Supervisor
from uvd.runtime.triggers import OPERATOR_AGE, plugin_triggers
from uvd.telemetry.records import CycleRecord, estimate_records

__all__ = ["Daemon", "LastCycle", "kept_params"]

log = logging.getLogger("uvd.daemon")


@dataclass
class LastCycle:
    """What the last cycle decided (for tests and the demo)."""

    t_ns: int = 0
    action: Action = Action.NONE
    state: State = State.BOOT
    status: str = ""
    thrust_n: np.ndarray | None = None
    mode: str = "idle"


def kept_params(config: Config, path: str) -> tuple[Config, dict[str, Any]]:
    """``config`` with the parameters a ground station set (``[mavlink] params_file``,
    docs/mavlink.md), and those applied; a value that is no longer valid is named in the log
    and skipped."""
    from uvd.links.mavlink.params import read_params_file
    try:
        values = read_params_file(path)
    except ValueError as exc:
        log.error("%s (parameters kept over MAVLink not applied)", exc)
        return config, {}
    applied = {}
    for key, value in values.items():
        new, errors = with_values(config, {key: value})
        if errors:
            log.error("%s: %s (not applied)", path, "; ".join(f"{k}: {r}" for k, r in errors))
            continue
        config, applied[key] = new, value
    if applied:
        log.info("parameters set over MAVLink applied from %s: %s", path, ", ".join(applied))
    return config, applied


class Daemon:
    """``uvd run``: the components, the cycle and the :class:`App` that runs them.

    Parameters
    ----------
    config : Config
        Validated configuration.
    auto_arm : bool
        Request arming as soon as the arming checks pass (once; a failsafe disarm is never
        undone automatically). Refusals are logged with their reasons every 2 s.
    sinks : sequence of TelemetrySink
        Extra telemetry sinks (tests).
    notifier, clock, realtime
        Passed to :class:`App`.
    """

    def __init__(self, config: Config, *, auto_arm: bool = False, sinks: Sequence = (),
                 notifier=None, clock=None, realtime: bool = True) -> None:
        cold = _jitcache.cache_is_empty()  # before anything below calls a kernel
        t_init = time.perf_counter()
        #: parameters a ground station set before this start (in the start record: a replay
        #: applies them too)
        self.params_kept: dict[str, Any] = {}
        if config.mavlink.enabled and config.mavlink.params_file:
            config, self.params_kept = kept_params(config, config.mavlink.params_file)
        self.config = config
        self.vehicle = config.load_vehicle()
        self.ins_box: Mailbox = Mailbox("ins")
        self.dvl_box: Mailbox = Mailbox("dvl")
        self.depth_box: Mailbox = Mailbox("depth")
        self.sensors = make_sensors(config, self.ins_box, self.dvl_box, self.depth_box)
        self.can = CanComponent(config, self.vehicle, self.depth_box)
        self.leak = LeakInput(config.sensors.leak) if config.sensors.leak.enabled else None
        self.supervisor = Supervisor(config.failsafe, extra_triggers=plugin_triggers(config))
        nav = config.navigation
        self.control = Cycle(build_core(config, self.vehicle), self.supervisor,
                             hold_on_arm=config.control.reference == "hold",
                             north_m=nav.initial_north_m, east_m=nav.initial_east_m)
        self.allocator = self.core_cfg.allocator
        self.max_thrust = np.asarray(self.allocator.max_thrust_n, dtype=float)
        self.app = App(config, self.cycle,
                       components=[*self.sensors, *([self.leak] if self.leak else []),
                                   self.can, GcFreeze()],
                       sinks=sinks,
                       supervisor=self.supervisor, notifier=notifier, clock=clock,
                       realtime=realtime)
        if config.loop.trigger == "ins":   # the sensor-synchronous cycle (docs/runtime.md)
            for s in self.sensors:
                if s.name == "ins":
                    s.on_sample = self.app.loop.wake
        # the faces (uvd.links) are the App's; the black box taps every raw input frame
        self.recorder, self.mavlink = self.app.links.get("mcap"), self.app.links.get("mavlink")
        if self.recorder is not None:
            self.can.tap = self.recorder.tap_can
            for s in self.sensors:
                s.reader.tap = self.recorder.tap_serial
        self.app.set_amplifier_hooks(zero=self.can.zero, disable=self.can.disable)
        self.app.reload_hooks.append(self._on_reload)
        est = config.estimation
        self._estimate_period_ns = int(est.publish_every_s * 1e9)
        self._next_estimate_ns = 0
        self._frozen_logged: set[str] = set()
        #: estimates to publish: online estimators, or a controller adapting its own θ̂
        self._adapts = bool(self.core_cfg.estimators) or \
            self.core_cfg.controller.diagnostics(self.state.ctrl).theta is not None
        if self.core_cfg.estimators:
            # after the amplifiers are safe, before the sinks close: the newest θ̂ reaches
            # them (and save_path) however long ago the last periodic record went out
            self.app.add_shutdown_step(ShutdownStep("publish the final estimate",
                                                    self._publish_final_estimates))
        self.app.hub.publish(self.start_record(), always=True)
        self.auto_arm = auto_arm
        # tries counted in cycles, not measured in time: the cycle a try falls on must not
        # depend on jitter, or a realtime replay arms a cycle apart from the recording
        self._arm_every = max(1, round(0.2 * config.loop.rate_hz))
        self._arm_wait = 0
        self._last_refusal_log_ns = 0
        self.arm_refusal: str | None = None
        self.last = LastCycle()
        self.counters = {"cycles": 0, "guard_nonfinite": 0, "guard_clamped": 0,
                         "write_failed": 0, "feedback_invalid": 0, "dvl_deferred": 0,
                         "depth_deferred": 0}
        self.commands_max_abs = 0.0
        self._first_write_ns = 0
        what = "compiling the numeric kernels (once after an install or upgrade: up to a " \
            "minute)" if cold else "loading the compiled kernels"
        self.app.notifier.status(what)  # systemctl status shows it
        log.info("%s", what)
        self.warm_up_s = self._warm_up()
        log.info("kernels ready in %.1f s", time.perf_counter() - t_init)
        # the long collection now, at normal priority; GcFreeze only walks what the drivers
        # add when they start (the loop's thread may be real-time by then)
        gc.collect()
        gc.freeze()

    def start_record(self) -> dict[str, Any]:
        """The ``"start"`` record: what a replay needs besides the cycles — the configuration
        file's text, the parameters kept over MAVLink applied on top of it, and the online
        estimators' θ̂(0) (a resumed estimate starts elsewhere
        than the file says)."""
        text = None
        if self.config.source:
            try:
                text = Path(self.config.source).read_text(encoding="utf-8")
            except OSError as exc:
                log.warning("the start record carries no configuration: %s", exc)
        return {"type": "start", "t_ns": time.monotonic_ns(), "version": __version__,
                "config_path": str(self.config.source or ""), "config_toml": text,
                "params_kept": dict(self.params_kept),
                "estimators": {spec.name: spec.diagnostics(st).theta for spec, st in
                               zip(self.core_cfg.estimators, self.state.est, strict=True)}}

    # -- the cycle's state, for tests and tools --

    @property
    def core_cfg(self) -> core.CoreConfig:
        return self.control.core_cfg

    @property
    def state(self) -> core.CoreState:
        return self.control.state

    @property
    def armed_at_ns(self) -> int | None:
        return self.control.armed_at_ns

    def _warm_up(self) -> float:
        """Run every numeric path of the cycle once on synthetic samples, off the clock.

        The compiled kernels (numba, cached on disk) load on their first call — tens to
        hundreds of ms; done in the first armed cycle, that would starve the amplifiers past
        their command timeout. Every mode of :func:`uvd.core.act` runs, on a scratch state
        (the cycle's own state is not touched). Returns the seconds spent.
        """
        from drivers.samples import DepthSample, DvlSample, InsSample
        t0 = time.perf_counter()
        cfg = self.core_cfg
        H, _ = start_pose(self.config)
        roll, pitch, heading = R_to_euler(H[:3, :3])
        n = self.allocator.n_thrusters
        modes = [(False, core.Mode.CONTROL)] + [(True, m) for m in core.Mode]
        for mask in (None, np.arange(n) != 0):
            st = core.core_init(cfg)
            for k, (armed, mode) in enumerate(modes):
                t = (k + 1) * 100_000_000
                # stamped before the cycle and apart, as in flight: the INS sample carried to
                # the cycle's time, the DVL's attitude carried to its own stamp
                ins = InsSample(t_ns=t - 30_000_000, roll=roll, pitch=pitch, heading=heading,
                                omega_body=np.zeros(3))
                dvl = DvlSample(t_ns=t - 50_000_000, velocity_body=np.zeros(3),
                                bottom_lock=True)
                depth = DepthSample(t_ns=t - 20_000_000, depth_m=float(H[2, 3]))
                out, st = core.step(cfg, core.CoreInputs(
                    t, ins, dvl, depth, np.zeros(n), armed, mode, np.zeros(6), mask), st, 0.1)
                cfg.controller.diagnostics(st.ctrl)
        return time.perf_counter() - t0

    # -- requests (operator, tests) --

    def request_arm(self, t_ns: int | None = None, cause: str = "operator request"):
        """Run the arming checks on the latest health and arm (returns the lifecycle step).
        From the loop's own thread between cycles (tests); links queue an ``Arm`` command."""
        t = time.monotonic_ns() if t_ns is None else t_ns
        return self.control.request_arm(t, cause=cause)

    def _on_reload(self, cfg: Config, applied: list[str]) -> None:
        self.config = cfg
        # the running estimators stay (their keys need a restart; initial_params is not read
        # again: a running estimate does not restart from it); the running reference (a hold
        # setpoint) and the controller's memory stay
        new = build_core(cfg, self.vehicle, estimators=self.core_cfg.estimators)
        self.control.core_cfg = core.CoreConfig(
            nav=new.nav, controller=new.controller, reference=self.core_cfg.reference,
            allocator=new.allocator, k_thrust=new.k_thrust, estimators=new.estimators,
            lag_compensation=new.lag_compensation, ff_preview_s=new.ff_preview_s, pd=new.pd)
        self._estimate_period_ns = int(cfg.estimation.publish_every_s * 1e9)

    # -- the estimates --

    def estimate_records(self, t_ns: int) -> list[dict[str, Any]]:
        """One ``"estimate"`` telemetry record per online estimator (``[estimation]``) and one
        for an adaptive controller's own θ̂ (AMBC; :func:`uvd.telemetry.records.estimate_records`).

        Keys: ``estimator`` (name), ``theta`` (θ̂, for AID θ_UV ∈ R²⁴¹ in the order of (2.48),
        a copy), ``m_min_eig``/``m_max_eig`` (M̂'s extreme eigenvalues), ``frozen`` and
        ``freeze_reason`` (AID stops adapting when M̂ would lose positive definiteness and
        keeps the last positive-definite θ̂), ``steps``, ``skipped`` (non-finite inputs),
        ``resyncs`` (v̂ re-synchronised after a navigation gap), ``velocity_error`` (‖v̂ − v‖).
        """
        return estimate_records(self.core_cfg, self.state, t_ns)

    def _publish_estimates(self, t_ns: int) -> None:
        for rec in self.estimate_records(t_ns):
            if rec["frozen"] and rec["estimator"] not in self._frozen_logged:
                self._frozen_logged.add(rec["estimator"])
                log.warning("%s stopped adapting: %s (the estimate kept is the last with M̂ "
                            "positive definite)", rec["estimator"], rec["freeze_reason"])
            self.app.hub.publish(rec, always=True)

    async def _publish_final_estimates(self) -> None:
        self._publish_estimates(self.last.t_ns)

    # -- the cycle: commands, read, update, write --

    def cycle(self, t_ns: int, dt: float) -> None:
        """One control cycle (called by the fixed-rate loop; see the module docstring)."""
        self._apply_commands(t_ns)
        self._auto_arm(t_ns)
        inp = self.read(t_ns)
        self.write(t_ns, dt, inp, self.control.update(inp, dt))

    def read(self, t_ns: int) -> CycleInputs:
        """Everything the update needs from outside, gathered without waiting."""
        group = self.can.group
        act = None
        if group is not None:
            fb = group.read()
            if not bool(fb.valid.all()):
                self.counters["feedback_invalid"] += 1
            act = actuator_status(fb, self._first_write_ns)
        loop = self.app.loop
        leak = extra = None
        if self.leak is not None:
            leak, fault = self.leak.health(t_ns)
            extra = {"leak_sensor_fault": fault}
        if self.mavlink is not None:
            # the operator's heartbeat counts while armed, once one was heard (triggers.py)
            hb = self.mavlink.operator_heartbeat_ns
            age = None if hb is None or not self.supervisor.armed else (t_ns - hb) * 1e-9
            extra = {**(extra or {}), OPERATOR_AGE: age}
        ins = self.ins_box.take()
        if ins is not None and loop.settings.trigger == "ins":
            # the sensor-synchronous cycle acts on the state as of its INS frame: a DVL or depth
            # frame received after that frame waits for the next cycle (docs/runtime.md), so
            # which cycle gets a frame follows the receive stamps, not the order in which the
            # event loop happened to serve the readers
            dvl, depth = self.dvl_box.take_until(ins.t_ns), self.depth_box.take_until(ins.t_ns)
            self.counters["dvl_deferred"] += dvl is None and self.dvl_box.peek() is not None
            self.counters["depth_deferred"] += depth is None and self.depth_box.peek() is not None
        else:
            dvl, depth = self.dvl_box.take(), self.depth_box.take()
        return CycleInputs(t_ns, ins, dvl, depth, act, loop.overrun_streak,
                           loop.streak_exceeded, leak, extra)

    def write(self, t_ns: int, dt: float, inp: CycleInputs, r: CycleResult) -> None:
        """The command to the amplifiers, the counters, one telemetry record."""
        out = r.out
        thrust = out.thrust_n
        group = self.can.group
        if group is not None:
            if not self._first_write_ns:
                self._first_write_ns = t_ns
            if not group.write(thrust).ok:
                self.counters["write_failed"] += 1
        if out.guard == 1:
            self.counters["guard_clamped"] += 1
        elif out.guard == 2:
            self.counters["guard_nonfinite"] += 1
        self.commands_max_abs = max(self.commands_max_abs, float(np.abs(thrust).max()))
        self.counters["cycles"] += 1
        d, h = r.decision, r.health
        self.last = LastCycle(t_ns, d.action, r.state, out.status, thrust, out.mode)
        nav, ref = out.nav, out.reference
        self.app.hub.publish(CycleRecord(
            t_ns=t_ns, dt=dt, state=r.state.value, action=d.action.label, mode=out.mode,
            status=out.status, p=nav.H[:3, 3], R=nav.H[:3, :3], v=nav.v, nav_valid=nav.valid,
            u=out.u_applied, u_cmd=out.u_cmd, thrust=thrust,
            ages=(h.ins_age_s, h.dvl_age_s, h.depth_age_s, h.feedback_age_s),
            ins_rx_ns=None if inp.ins is None else inp.ins.t_ns,
            dvl_rx_ns=None if inp.dvl is None else inp.dvl.t_ns,
            depth_rx_ns=None if inp.depth is None else inp.depth.t_ns,
            inputs=inputs_record(inp),
            triggers=tuple(a.name for a in d.active), operator_mode=r.operator_mode,
            p_ref=None if ref is None else ref.H[:3, 3],
            R_ref=None if ref is None else ref.H[:3, :3],
            v_ref=None if ref is None else np.asarray(ref.v),
            armed_at_ns=self.control.armed_at_ns).to_dict())
        # within half a period of the due time: a cycle a few µs early is not skipped
        if self._adapts and t_ns >= self._next_estimate_ns - int(dt * 5e8):
            self._next_estimate_ns = t_ns + self._estimate_period_ns
            self._publish_estimates(t_ns)

    # -- commands --

    def _apply_commands(self, t_ns: int) -> None:
        """The commands queued since the previous cycle, applied at this cycle boundary."""
        for p in self.app.commands.drain():
            p.future.set_result(self._apply(p.command, t_ns))

    def _apply(self, c, t_ns: int) -> CommandResult:
        """Apply one command; its result is published as a ``"command"`` record (what a
        replay applies again at the same cycle)."""
        try:
            res = self._set_params(c) if isinstance(c, SetParams) else \
                self.control.apply(c, t_ns)
        except Exception as exc:  # noqa: BLE001 - a bad command never breaks the cycle
            res = CommandResult(False, f"{type(exc).__name__}: {exc}")
        self.app.hub.publish({"type": "command", "t_ns": t_ns, "command": type(c).__name__,
                              "args": asdict(c), "source": c.source, "ok": res.ok,
                              "reason": res.reason}, always=True)
        return res

    def _set_params(self, c: SetParams) -> CommandResult:
        """Reloadable keys changed at this cycle boundary, exactly as a SIGHUP reload changes
        them; refused as a whole when a key is unknown, needs a restart or its value is bad."""
        old = self.app.config
        new, errors = with_values(old, c.values, reload_only=True)
        if errors:
            return CommandResult(False, "; ".join(f"{k}: {r}" for k, r in errors))
        merged, applied, _ = reloadable_changes(old, new)
        self.app.apply_config(merged, applied)
        return CommandResult(True)

    def _auto_arm(self, t_ns: int) -> None:
        """``uvd run --arm``: an ``Arm`` command every 200 ms of cycles (every second cycle
        at 10 Hz, counted from the first in STANDBY) until one succeeds."""
        if not self.auto_arm or self.control.armed_at_ns is not None \
                or self.supervisor.state is not State.STANDBY:
            return
        if self._arm_wait > 0:
            self._arm_wait -= 1
            return
        self._arm_wait = self._arm_every - 1
        res = self._apply(Arm(cause="uvd run --arm", source="uvd run --arm"), t_ns)
        self.arm_refusal = None if res.ok else res.reason
        if self.arm_refusal and t_ns - self._last_refusal_log_ns >= 2_000_000_000:
            self._last_refusal_log_ns = t_ns
            log.info("%s", self.arm_refusal)

    # -- running --

    async def run(self) -> int:
        """Run until stopped (SIGTERM/SIGINT or :meth:`stop`); returns the exit code.

        After the App's bounded shutdown, anything it had no time left to close (a serial
        port, the bus) is closed here, so that a daemon run inside a longer-lived process
        (tests, tools) leaves no port locked.
        """
        cpu_latency = None
        if self.config.loop.sched_fifo_priority > 0 and self.app.realtime:
            # real-time loop: keep idle CPUs from halting (wake-up latency of a halted vCPU
            # is hundreds of µs)
            cpu_latency = CpuLatencyRequest(0).open()
            if cpu_latency.message:
                log.warning("%s", cpu_latency.message)
        try:
            return await self.app.run()
        finally:
            if cpu_latency is not None:
                cpu_latency.close()
            for s in self.sensors:
                if s.reader.connected or s.reader._transport is not None:
                    s.force_close()
            if self.can.bus is not None and self.can.bus.is_open:
                await self.can.stop()

    def stop(self, reason: str = "requested") -> None:
        self.app.request_stop(reason)

    def summary(self) -> dict[str, Any]:
        """App summary (loop statistics, failsafe events, …) plus the daemon's counters."""
        out = self.app.summary()
        out["daemon"] = dict(self.counters)
        out["daemon"]["commands_max_abs_n"] = self.commands_max_abs
        out["daemon"]["armed_at_ns"] = self.armed_at_ns
        out["daemon"]["arm_refusal"] = self.arm_refusal
        out["sensors"] = {s.name: s.stats() for s in self.sensors}
        if self.leak is not None:
            out["sensors"]["leak"] = self.leak.stats()
        if self.can.group is not None:
            out["can"] = self.can.group.stats()
            out["can"]["start"] = None if self.can.start_report is None else \
                self.can.start_report.nodes
        out["shutdown"] = self.app.shutdown_report
        return out
