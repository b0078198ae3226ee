"""The daemon (``uvd run``): drivers, the one core cycle, failsafes and amplifier commands.

:class:`Daemon` builds, from a validated :class:`~uvd.runtime.config.Config`, everything the
:class:`~uvd.runtime.app.App` runs:

* **components** — one :class:`SerialSensor` per serial instrument (PHINS STDBIN or ASCII,
  RDI PD0, Digiquartz; ``udp://``/``tcp://`` ports use the network readers) and the
  :class:`CanComponent` (the CAN bus, the :class:`~drivers.can.AmplifierGroup` of
  ``[can.amplifiers]`` and, when ``[can.depth] enabled``, the CiA 404 depth sensor). Their
  reader tasks only decode and convert a frame to a :mod:`drivers.samples` sample and put it
  in a :class:`~uvd.runtime.mailbox.Mailbox` — no other work on the sensors' path;
* **the cycle** :meth:`Daemon.cycle`, run by the fixed-rate loop::

      newest samples (mailboxes) + amplifier feedback
        → core.step (the same pure cycle lockstep and replay run; armed per lifecycle)
        → Health (ages, validity, non-finite in/out, M̂/θ̂, amplifiers, bus, overruns)
        → Supervisor.step (failsafe arbiter + lifecycle)
        → the decision applied: FALLBACK freezes adaptation (θ̂ kept) and commands PDC;
          HOLD_DEPTH commands a PD on depth, roll and pitch only (the reference's
          closed-loop DOF mask) — zero surge, sway and yaw; ZERO_THRUST / DISARM / not armed
          command zero
        → the last guard before the bus (finite, within ±max thrust)
        → AmplifierGroup.write (RPDOs + SYNC)
        → one telemetry record (never blocks); with ``[estimation] aid`` also, every
          ``publish_every_s``, an ``"estimate"`` record (θ̂, M̂'s eigenvalues, frozen or not:
          :meth:`Daemon.estimate_records`), which ``save_path`` keeps as a parameters file
          (:class:`~uvd.telemetry.params_file.ParamsFileSink`; once more at shutdown)

The navigation timeouts are the failsafe thresholds (:func:`nav_config`: one source of truth).
The reference clock starts when the vehicle is armed; ``reference = "hold"`` holds the pose
the vehicle had then. :func:`build_core` is shared with the lockstep comparison of ``uvd
demo``, so simulation and daemon run the very same controller configuration.
"""

from __future__ import annotations

import asyncio
import gc
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from drivers.samples import R_to_euler
from uvd import _jitcache, core
from uvd.control.allocation import Allocator, allocate
from uvd.control.pdc import PDGains, PDState, pdc_step
from uvd.control.types import Reference, VehicleState
from uvd.estimation.navigation import NavConfig
from uvd.runtime.app import App, ShutdownStep
from uvd.runtime.commands import CommandResult
from uvd.runtime.config import Config
from uvd.runtime.failsafe import Action, Health, nav_health
from uvd.runtime.leak import LeakInput, leak_sensor_fault_trigger
from uvd.runtime.lifecycle import State
from uvd.runtime.loop import CpuLatencyRequest
from uvd.runtime.mailbox import Mailbox
from uvd.runtime.supervisor import Supervisor
from uvd.telemetry.records import CycleRecord

__all__ = ["Daemon", "SerialSensor", "CanComponent", "build_core", "nav_config",
           "make_reference", "start_pose", "theta_hat_of", "m_hat_min_eig"]

log = logging.getLogger("uvd.daemon")

#: closed-loop mask of the hold-depth failsafe: depth, roll and pitch; no surge, sway, yaw
HOLD_DEPTH_MASK = np.array([False, False, True, True, True, False])
#: feedback faults the failsafe handles as missing feedback (``feedback_missing``), not as
#: amplifier faults: a silent node is an absence of data
_FEEDBACK_FAULTS = frozenset({"feedback_lost", "heartbeat_lost"})


# ----------------------------------------------------------------------------- configuration

def nav_config(cfg: Config) -> NavConfig:
    """Navigation timeouts from the failsafe thresholds: a source is valid exactly as long as
    its stale trigger is quiet."""
    th = cfg.failsafe
    return NavConfig(ins_timeout_s=th.ins_stale_s, dvl_timeout_s=th.dvl_stale_s,
                     depth_timeout_s=th.depth_stale_s,
                     propagate_ins=cfg.navigation.propagate_ins)


def make_reference(cfg: Config, center=None):
    """The trajectory of ``[control] reference`` (None for ``hold``: set when armed)."""
    from uvd.control.trajectory import DEFAULT_CENTER, reftraj1, reftraj2
    c = DEFAULT_CENTER if center is None else center
    ref = cfg.control.reference
    if ref == "reftraj1":
        return reftraj1(c)
    if ref == "reftraj2":
        return reftraj2(c)
    return None


def start_pose(cfg: Config) -> tuple[np.ndarray, np.ndarray]:
    """Where a run of this configuration starts (the simulated plant's initial state).

    North and east from ``[navigation]``; depth and attitude of the reference at t = 0
    (the centre depth, level, heading north for ``hold``); at rest.
    """
    from uvd.control.trajectory import DEFAULT_CENTER
    traj = make_reference(cfg)
    H = np.eye(4)
    if traj is not None:
        H = np.array(traj.at(0.0).H, dtype=float)
    else:
        H[2, 3] = DEFAULT_CENTER[2]
    H[0, 3] = cfg.navigation.initial_north_m
    H[1, 3] = cfg.navigation.initial_east_m
    return H, np.zeros(6)


def _theta0(cfg: Config, vehicle, model: str) -> np.ndarray:
    from uvd.control.ambc import gravity_index, theta_of
    truth = theta_of(vehicle.params, model)
    kind = cfg.control.theta0
    if kind == "vehicle":
        return truth.copy()
    th = np.zeros_like(truth)
    if kind == "vehicle-gb":
        gi = gravity_index(model)
        th[gi] = truth[gi]
    return th


def _robust(cfg: Config):
    from uvd.control.ambc import ROBUST_DAEMON_DEFAULT, RobustAdaptation
    return ROBUST_DAEMON_DEFAULT if cfg.control.robust_adaptation else RobustAdaptation()


def make_controller(cfg: Config, vehicle, allocator: Allocator) -> core.ControllerSpec:
    """The ``[control]`` controller as a :class:`uvd.core.ControllerSpec`."""
    c = cfg.control
    if c.controller == "pdc":
        return core.ControllerSpec("pdc", pdc_step, PDGains(kp=c.kp, kd=c.kd), PDState())
    if c.controller == "ambc":
        from uvd.control.ambc import ambc_init, ambc_params, ambc_step
        p = ambc_params(c.model, kp=c.kp, kd=c.kd, eps=c.eps, robust=_robust(cfg),
                        allocator=allocator)
        return core.ControllerSpec("ambc", ambc_step, p,
                                   ambc_init(p, _theta0(cfg, vehicle, c.model)))
    from uvd.control.twostep import two_step_init, two_step_params, two_step_step
    p = two_step_params(c.model, kp=c.kp, kd=c.kd, eps=c.eps, robust=_robust(cfg),
                        allocator=allocator, theta0=_theta0(cfg, vehicle, c.model),
                        step1_duration_s=c.step1_duration_s)
    return core.ControllerSpec("two-step-ambc", two_step_step, p, two_step_init(p))


def build_core(cfg: Config, vehicle=None, estimators: tuple | None = None
               ) -> core.CoreConfig:
    """The :class:`uvd.core.CoreConfig` of a configuration — shared by the daemon and the
    lockstep comparison of ``uvd demo``.

    For ``reference = "hold"`` the reference is a setpoint at the start pose until the
    daemon replaces it with the pose it has when armed. ``estimators`` given (a reload: the
    ``[estimation]`` keys need a restart) are kept as they are; None builds them from
    ``[estimation]``, reading ``initial_params``.
    """
    from uvd.control.trajectory import setpoint
    vehicle = vehicle if vehicle is not None else cfg.load_vehicle()
    alloc = Allocator.from_vehicle(vehicle)
    traj = make_reference(cfg)
    if traj is None:
        H0, _ = start_pose(cfg)
        traj = setpoint(_eta(H0))
    if estimators is None:
        estimators = ()
        if cfg.estimation.aid:
            from uvd.estimation.aid import aid6_estimator
            estimators = (aid6_estimator(aid_theta0(cfg), cfg.estimation.aid_params()),)
    return core.CoreConfig(nav=nav_config(cfg), controller=make_controller(cfg, vehicle, alloc),
                           reference=traj, allocator=alloc, k_thrust=vehicle.k_thrust,
                           estimators=estimators, lag_compensation=cfg.control.lag_compensation)


def aid_theta0(cfg: Config) -> np.ndarray | None:
    """θ̂(0) of online AID: the last run's ``save_path`` file (``resume``), else
    ``[estimation] initial_params``, else None (INITP of §4.6)."""
    base = Path(cfg.source).parent if cfg.source else Path.cwd()
    path = cfg.estimation.start_path(base)
    log.info("AID starts from %s", path or "INITP (§4.6, Tables 4.6-4.7)")
    if path is None:
        return None
    from uvd.io.params import params_from_toml
    return params_from_toml(path).theta


def _eta(H: np.ndarray) -> np.ndarray:
    roll, pitch, heading = R_to_euler(H[:3, :3])
    return np.array([H[0, 3], H[1, 3], H[2, 3], roll, pitch, heading])


# ----------------------------------------------------------------------------- parameters

def _inner(ctrl: Any) -> Any:
    return getattr(ctrl, "ambc", ctrl)


def theta_hat_of(ctrl: Any) -> np.ndarray | None:
    """θ̂ of an AMBC / two-step state (None for memoryless controllers)."""
    return getattr(_inner(ctrl), "theta", None)


def m_hat_min_eig(ctrl: Any, spec: core.ControllerSpec) -> float | None:
    """Smallest eigenvalue of the controller's M̂, or None when it does not adapt M̂.

    Step 1 of two-step AMBC holds M̂ = 0 by design (the quasi-static model (5.37)); it is not
    reported there.
    """
    theta = theta_hat_of(ctrl)
    if theta is None:
        return None
    if getattr(ctrl, "phase", 2) == 1:
        return None
    from uvd.model.params import SL_M, M_from_theta
    if theta.shape[0] == 16:
        return float(theta[:6].min())
    return float(np.linalg.eigvalsh(M_from_theta(theta[SL_M]))[0])


# ----------------------------------------------------------------------------- components

class SerialSensor:
    """One instrument: a framed reader, a frame → sample converter, a mailbox.

    The reader decodes in the event loop's read callback; :meth:`run` converts each frame
    (a few µs) and puts the sample in the mailbox. Nothing else happens on this path.

    Parameters
    ----------
    name : str
        ``ins``, ``dvl`` or ``depth``.
    reader : drivers.transport.FrameReader
    convert : callable
        ``convert(stamped) -> sample or None``.
    box : Mailbox
    on_connect : callable, optional
        ``on_connect(reader)`` after the port opened (the Digiquartz gets ``P4``).
    connect_timeout_s : float
        :meth:`start` waits this long for the port to open.
    """

    def __init__(self, name: str, reader, convert: Callable[[Any], Any], box: Mailbox, *,
                 on_connect: Callable[[Any], None] | None = None,
                 connect_timeout_s: float = 5.0) -> None:
        self.name = name
        self.reader = reader
        self.convert = convert
        self.box = box
        self.on_connect = on_connect
        self.connect_timeout_s = connect_timeout_s
        self.samples = 0
        self.rejected = 0

    async def start(self) -> None:
        self.reader.start()
        try:
            await self.reader.wait_connected(self.connect_timeout_s)
        except asyncio.CancelledError:  # the App's start timeout: say which port it was
            log.error("%s: %s did not open%s", self.name, self.reader.where,
                      f" ({self.reader.last_error})" if self.reader.last_error else "")
            raise
        if self.on_connect is not None:
            self.on_connect(self.reader)

    async def run(self) -> None:
        was_connected = True
        while True:
            st = await self.reader.get()
            if not was_connected and self.on_connect is not None:
                self.on_connect(self.reader)
            was_connected = self.reader.connected
            try:
                sample = self.convert(st)
            except Exception as exc:  # noqa: BLE001 - a bad frame is dropped and counted
                self.rejected += 1
                log.warning("%s: frame not converted: %s: %s", self.name, type(exc).__name__,
                            exc)
                continue
            if sample is not None:
                self.samples += 1
                self.box.put(sample)

    async def stop(self, timeout_s: float = 0.3) -> None:
        await self.reader.close()
        # pyserial-asyncio-fast closes the port in a background task (flush and close in the
        # default executor); wait for it, bounded, so the exclusive lock is released before
        # the App shuts its executor down
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while self.reader._transport is not None and loop.time() < deadline:
            await asyncio.sleep(0.005)

    def force_close(self) -> None:
        """Close the port under the transport if its graceful close never completed."""
        tr = self.reader._transport
        ser = getattr(tr, "serial", None) if tr is not None else None
        if ser is not None:
            try:
                ser.close()
            except OSError:
                pass

    def stats(self) -> dict[str, Any]:
        return {"samples": self.samples, "rejected": self.rejected,
                "connected": bool(self.reader.connected),
                "last_error": self.reader.last_error or "",
                "counters": self.reader.counters.as_dict()
                if hasattr(self.reader.counters, "as_dict") else {},
                "mailbox": self.box.stats()}


def _open_reader(port: str, codec, baud: int, name: str):
    from urllib.parse import urlsplit
    if port.startswith(("udp://", "tcp://")):
        from drivers.net_transport import TcpFrameReader, UdpFrameReader
        u = urlsplit(port)
        kind = UdpFrameReader if u.scheme == "udp" else TcpFrameReader
        return kind(u.hostname, u.port, codec, name=name)
    from drivers.serial_transport import SerialFrameReader
    return SerialFrameReader(port, codec, baudrate=baud, name=name)


def make_sensors(cfg: Config, ins_box: Mailbox, dvl_box: Mailbox, depth_box: Mailbox
                 ) -> list[SerialSensor]:
    """The serial (or network) instruments of ``[sensors]``."""
    from drivers import digiquartz, pd0, phins_ascii, phins_stdbin
    s = cfg.sensors
    out = []
    if s.ins.format == "phins-stdbin":
        def ins_convert(st):
            return phins_stdbin.to_ins_sample(st.frame, st.t_ns)
        ins_codec = phins_stdbin.StdbinCodec()
    else:
        asm = phins_ascii.AsciiInsAssembler()

        def ins_convert(st):
            return asm.push(st.t_ns, st.frame)
        ins_codec = phins_ascii.PhinsAsciiCodec()
    out.append(SerialSensor("ins", _open_reader(s.ins.port, ins_codec, s.ins.baud, "ins"),
                            ins_convert, ins_box))

    def dvl_convert(st):
        return pd0.to_dvl_sample(st.frame, st.t_ns)
    out.append(SerialSensor("dvl", _open_reader(s.dvl.port, pd0.Pd0Codec(), s.dvl.baud, "dvl"),
                            dvl_convert, dvl_box))
    if s.depth.source == "serial" and s.depth.port is not None:
        conv = s.depth.conversion

        def depth_convert(st):
            return conv.to_sample(st.frame, st.t_ns)

        def start_continuous(reader) -> None:
            reader.write(digiquartz.command("P4"))  # continuous pressure output
        out.append(SerialSensor("depth", _open_reader(s.depth.port, digiquartz.DigiquartzCodec(),
                                                      s.depth.baud, "depth"),
                                depth_convert, depth_box, on_connect=start_continuous))
    return out


class GcFreeze:
    """Last component to start: collect once, then freeze every object that exists.

    A full collection of the daemon's heap (numba, llvmlite, scipy: ~10⁵ objects) takes
    70–80 ms — a stall the loop would feel whenever Python decides to run one. Objects alive
    once the drivers are up live as long as the process; :func:`gc.freeze` moves them out of
    the collector's reach, so later collections only walk what the cycles allocate (µs).
    """

    name = "gc-freeze"

    async def start(self) -> None:
        gc.collect()
        gc.freeze()

    async def run(self) -> None:
        return None

    async def stop(self) -> None:
        return None


class CanComponent:
    """The CAN bus, the amplifier group and (optionally) the CiA 404 depth sensor.

    :meth:`start` opens the bus, configures and starts the amplifiers (SDO + NMT, blocking
    and bounded, in a worker thread), clears faults left from a previous run and sets the
    goal OPERATION ENABLED — reached over the next cycles with zero targets. A node that does
    not answer does not stop the start: it carries a fault and arming is refused.
    """

    name = "can"

    def __init__(self, cfg: Config, vehicle, depth_box: Mailbox | None = None) -> None:
        self.cfg = cfg
        self.vehicle = vehicle
        self.depth_box = depth_box
        self.bus = None
        self.group = None
        self.depth = None
        self.recorder = None
        self.start_report = None
        self.last_can_depth = None

    def _open_bus(self) -> None:
        """Open the bus from the event loop's thread: its receive thread inherits that
        thread's scheduling (SCHED_FIFO when configured; the App then puts it one below the
        loop, with every other thread, :mod:`uvd.runtime.rtthreads`). A normally scheduled
        thread that holds the GIL while other processes preempt it would delay the loop by
        milliseconds (priority inversion through the GIL)."""
        from drivers.can import CanBus, CanRecorder
        c = self.cfg.can
        self.recorder = CanRecorder.from_config(c.log)
        self.bus = CanBus(c.bus, recorder=self.recorder).open()

    def _open(self) -> None:
        from drivers.can import AmplifierGroup, CanDepthSensor
        c = self.cfg.can
        self.group = AmplifierGroup.from_config(self.bus, c.amplifiers, self.vehicle.thrusters)
        if c.depth.enabled:
            use = self.cfg.sensors.depth.source == "can" and self.depth_box is not None
            box = self.depth_box

            def on_sample(sample) -> None:
                self.last_can_depth = sample
                if use:
                    box.put(sample)
            self.depth = CanDepthSensor(self.bus, c.depth, on_sample=on_sample)
        self.start_report = self.group.start()
        if not self.start_report.ok:
            log.error("amplifiers not all started: %s", self.start_report.nodes)
        self.group.reset_faults()
        self.group.enable()
        if self.depth is not None and not self.depth.start():
            log.warning("CAN depth sensor %d: no sample within 1 s", c.depth.node_id)

    async def start(self) -> None:
        self._open_bus()
        await asyncio.to_thread(self._open)  # SDO configuration: blocking, bounded

    async def run(self) -> None:
        return None

    def zero(self) -> None:
        """Zero target on every amplifier (one cycle: RPDOs + SYNC); never raises."""
        if self.group is not None:
            self.group.write(np.zeros(len(self.group.nodes)))

    def disable(self) -> None:
        """Zero and disable voltage, release the heartbeat consumers, NMT pre-operational."""
        if self.group is not None:
            self.group.shutdown(cycles=2, period_s=0.01, release_consumer=True)

    async def stop(self) -> None:
        def close() -> None:
            if self.bus is not None:
                self.bus.close()
            if self.recorder is not None:
                self.recorder.stop(timeout=0.5)
        await asyncio.to_thread(close)


# ----------------------------------------------------------------------------- the daemon

@dataclass
class LastCycle:
    """What the last cycle decided (for tests and the demo)."""

    t_ns: int = 0
    action: Action = Action.NONE
    state: State = State.BOOT
    status: str = ""
    thrust_n: np.ndarray | None = None
    mode: str = "idle"


def _nonfinite_inputs(ins, dvl, depth) -> tuple[str, ...]:
    bad = []
    if ins is not None:
        vals = (ins.roll, ins.pitch, ins.heading)
        if not all(math.isfinite(x) for x in vals) or (
                ins.rates_valid and not math.isfinite(float(np.sum(ins.omega_body)))):
            bad.append("ins")
    if dvl is not None and dvl.bottom_lock and not math.isfinite(float(np.sum(
            dvl.velocity_body))):
        bad.append("dvl")
    if depth is not None and not math.isfinite(depth.depth_m):
        bad.append("depth")
    return tuple(bad)


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
        self.config = config
        self.vehicle = config.load_vehicle()
        self.core_cfg = build_core(config, self.vehicle)
        self.state = core.core_init(self.core_cfg, north_m=config.navigation.initial_north_m,
                                    east_m=config.navigation.initial_east_m)
        self.allocator = self.core_cfg.allocator
        self.max_thrust = np.asarray(self.allocator.max_thrust_n, dtype=float)
        B = np.asarray(self.allocator.B, dtype=float)
        self._vertical = np.all(np.abs(B[[0, 1, 5], :]) < 1e-9, axis=0)
        self._vertical_pinv = np.linalg.pinv(B[2:5][:, self._vertical]) \
            if self._vertical.any() else np.zeros((0, 3))
        self.pd_gains = PDGains(kp=config.control.kp, kd=config.control.kd)
        self.ins_box: Mailbox = Mailbox("ins")
        self.dvl_box: Mailbox = Mailbox("dvl")
        self.depth_box: Mailbox = Mailbox("depth")
        self.sensors = make_sensors(config, self.ins_box, self.dvl_box, self.depth_box)
        self.can = CanComponent(config, self.vehicle, self.depth_box)
        self.leak = LeakInput(config.sensors.leak) if config.sensors.leak.enabled else None
        self.supervisor = Supervisor(
            config.failsafe,
            extra_triggers=[leak_sensor_fault_trigger()] if self.leak is not None else ())
        self.app = App(config, self.cycle,
                       components=[*self.sensors, *([self.leak] if self.leak else []),
                                   self.can, GcFreeze()],
                       sinks=sinks,
                       supervisor=self.supervisor, notifier=notifier, clock=clock,
                       realtime=realtime)
        self.app.set_amplifier_hooks(zero=self.can.zero, disable=self.can.disable)
        self.app.reload_hooks.append(self._on_reload)
        est = config.estimation
        self._estimate_period_ns = int(est.publish_every_s * 1e9)
        self._next_estimate_ns = 0
        self._frozen_logged: set[str] = set()
        if self.core_cfg.estimators:
            if est.save_path:
                from uvd.telemetry.params_file import RECORD_TYPE, ParamsFileSink
                self.app.hub.add_sink(ParamsFileSink(est.save_path, every_s=est.save_every_s),
                                      types=(RECORD_TYPE,))
            # after the amplifiers are safe, before the sinks close: the newest θ̂ reaches
            # them (and save_path) however long ago the last periodic record went out
            self.app.add_shutdown_step(ShutdownStep("publish the final estimate",
                                                    self._publish_final_estimates))
        self.auto_arm = auto_arm
        self._armed_once = False
        self._last_arm_try_ns = 0
        self._last_refusal_log_ns = 0
        self.arm_refusal: str | None = None
        self.armed_at_ns: int | None = None
        self._hold_ref: Reference | None = None
        self.last = LastCycle()
        self.counters = {"cycles": 0, "guard_nonfinite": 0, "guard_clamped": 0,
                         "write_failed": 0, "feedback_invalid": 0}
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

    def _warm_up(self) -> float:
        """Run every numeric path of the cycle once on synthetic samples, off the clock.

        The compiled kernels (numba, cached on disk) load on their first call — tens to
        hundreds of ms; done in the first armed cycle, that would starve the amplifiers past
        their command timeout. Returns the seconds spent.
        """
        from drivers.samples import DepthSample, DvlSample, InsSample
        t0 = time.perf_counter()
        H, _ = start_pose(self.config)
        roll, pitch, heading = R_to_euler(H[:3, :3])
        st = self.state
        for k in range(3):
            t = (k + 1) * 100_000_000
            # stamped before the cycle and apart, as in flight: the INS sample carried to the
            # cycle's time, the DVL's attitude carried to its own stamp (every kernel loaded)
            ins = InsSample(t_ns=t - 30_000_000, roll=roll, pitch=pitch, heading=heading,
                            omega_body=np.zeros(3))
            dvl = DvlSample(t_ns=t - 50_000_000, velocity_body=np.zeros(3), bottom_lock=True)
            depth = DepthSample(t_ns=t - 20_000_000, depth_m=float(H[2, 3]))
            # the first cycle disarmed (as after boot), the others armed: both paths loaded
            out, st = core.step(self.core_cfg, core.CoreInputs(
                t_ns=t, ins=ins, dvl=dvl, depth=depth, armed=k > 0,
                propeller_speed_rad_s=np.zeros(self.allocator.n_thrusters)), st, 0.1)
            m_hat_min_eig(st.ctrl, self.core_cfg.controller)
            self._fallback(out.nav, out.reference, 0.1)
            self._hold_depth(out.nav, 0.1)
            self._hold_ref = None
            _eta(out.nav.H)
        return time.perf_counter() - t0

    # -- requests (operator, tests) --

    def request_arm(self, t_ns: int | None = None, cause: str = "operator request"):
        """Run the arming checks on the latest health and arm (returns the lifecycle step)."""
        t = time.monotonic_ns() if t_ns is None else t_ns
        step = self.supervisor.request_arm(t, cause=cause)
        if step.ok and self.supervisor.armed:
            self._on_armed(t)
        return step

    def _on_armed(self, t_ns: int) -> None:
        self._armed_once = True
        self.armed_at_ns = t_ns
        # the reference's clock starts now; "hold" holds the pose the vehicle has now
        self.state = replace(self.state, t0_ns=None)
        if self.config.control.reference == "hold":
            from uvd.control.trajectory import setpoint
            self.core_cfg = replace(self.core_cfg, reference=setpoint(_eta(self._nav_H)))
        log.info("armed: tracking %s", getattr(self.core_cfg.reference, "name", "a setpoint"))

    def _on_reload(self, cfg: Config, applied: list[str]) -> None:
        self.config = cfg
        self.pd_gains = PDGains(kp=cfg.control.kp, kd=cfg.control.kd)
        # the running estimators stay (their keys need a restart; initial_params is not read
        # again: a running estimate does not restart from it)
        new = build_core(cfg, self.vehicle, estimators=self.core_cfg.estimators)
        # keep the running reference (hold setpoint) and the controller's memory
        self.core_cfg = replace(new, reference=self.core_cfg.reference)
        self._estimate_period_ns = int(cfg.estimation.publish_every_s * 1e9)

    # -- the estimates --

    def estimate_records(self, t_ns: int) -> list[dict[str, Any]]:
        """One ``"estimate"`` telemetry record per online estimator (``[estimation]``).

        Keys: ``estimator`` (name), ``theta`` (θ̂, for AID θ_UV ∈ R²⁴¹ in the order of (2.48),
        a copy), ``m_min_eig``/``m_max_eig`` (M̂'s extreme eigenvalues), ``frozen`` and
        ``freeze_reason`` (AID stops adapting when M̂ would lose positive definiteness and
        keeps the last positive-definite θ̂), ``steps``, ``skipped`` (non-finite inputs),
        ``resyncs`` (v̂ re-synchronised after a navigation gap), ``velocity_error`` (‖v̂ − v‖).
        """
        out = []
        for spec, st in zip(self.core_cfg.estimators, self.state.est, strict=True):
            theta = getattr(st, "theta", None)
            dv = getattr(st, "dv", None)
            out.append({"type": "estimate", "t_ns": t_ns, "estimator": spec.name,
                        "theta": None if theta is None else np.array(theta, dtype=float),
                        "m_min_eig": getattr(st, "m_min_eig", None),
                        "m_max_eig": getattr(st, "m_max_eig", None),
                        "frozen": bool(getattr(st, "frozen", False)),
                        "freeze_reason": getattr(st, "freeze_reason", ""),
                        "steps": getattr(st, "steps", None),
                        "skipped": getattr(st, "skipped", None),
                        "resyncs": getattr(st, "resyncs", None),
                        "velocity_error": None if dv is None else float(np.linalg.norm(dv))})
        return out

    def _publish_estimates(self, t_ns: int) -> None:
        for rec in self.estimate_records(t_ns):
            if rec["frozen"] and rec["estimator"] not in self._frozen_logged:
                self._frozen_logged.add(rec["estimator"])
                log.warning("%s stopped adapting: %s (the estimate kept is the last with M̂ "
                            "positive definite)", rec["estimator"], rec["freeze_reason"])
            self.app.hub.publish(rec, always=True)

    async def _publish_final_estimates(self) -> None:
        self._publish_estimates(self.last.t_ns)

    # -- the cycle --

    _nav_H = np.eye(4)

    def _apply_commands(self, t_ns: int) -> None:
        """The commands queued since the previous cycle, applied at this cycle boundary; each
        one's result resolves its future and is published as a ``"command"`` record."""
        for p in self.app.commands.drain():
            cmd = p.command
            try:
                res = self._apply_command(cmd, t_ns)
            except Exception as exc:  # noqa: BLE001 - a bad command never breaks the cycle
                res = CommandResult(False, f"{type(exc).__name__}: {exc}")
            self.app.hub.publish({"type": "command", "t_ns": t_ns,
                                  "command": type(cmd).__name__,
                                  "source": getattr(cmd, "source", ""), "ok": res.ok,
                                  "reason": res.reason}, always=True)
            p.future.set_result(res)

    def _apply_command(self, cmd, t_ns: int) -> CommandResult:
        from uvd.runtime import commands as c
        if isinstance(cmd, c.Arm):
            step = self.request_arm(t_ns, cause=cmd.cause)
            return CommandResult(bool(step.ok and self.supervisor.armed), step.refused or "")
        if isinstance(cmd, c.Disarm):
            step = self.supervisor.request_disarm(t_ns, cause=cmd.cause)
            return CommandResult(True, "" if step.transitions else "not armed")
        if isinstance(cmd, c.ResetFailsafe):
            refused = self.supervisor.reset_failsafe(t_ns, cmd.names)
            return CommandResult(not refused, "; ".join(f"{n}: {r}" for n, r in refused))
        return CommandResult(False, f"{type(cmd).__name__} is not supported")

    def cycle(self, t_ns: int, dt: float) -> None:
        """One control cycle (called by the fixed-rate loop; see the module docstring)."""
        self._apply_commands(t_ns)
        ins = self.ins_box.take()
        dvl = self.dvl_box.take()
        depth = self.depth_box.take()
        group = self.can.group
        fb = group.read() if group is not None else None
        sup = self.supervisor
        armed = sup.armed
        omega = None
        if fb is not None:
            if bool(fb.valid.all()):
                omega = fb.omega_rad_s
            else:
                self.counters["feedback_invalid"] += 1
        prev = self.state
        inputs = core.CoreInputs(t_ns=t_ns, ins=ins, dvl=dvl, depth=depth,
                                 propeller_speed_rad_s=omega, armed=armed)
        out, new_state = core.step(self.core_cfg, inputs, prev, dt)
        nav = out.nav
        self._nav_H = nav.H

        # -- health --
        theta = theta_hat_of(new_state.ctrl)
        faults: list[str] = []
        bus_off = False
        fb_age: float | None = None
        enabled = False
        if fb is not None:
            enabled = bool(fb.enabled.all())
            for nid, names in fb.faults.items():
                if nid == 0:
                    for n in names:
                        if n in ("bus_off", "bus_closed"):
                            bus_off = True
                        elif n == "send_failed":
                            faults.append(f"bus: {n}")
                    continue
                real = [n for n in names if n not in _FEEDBACK_FAULTS]
                if real:
                    faults.append(f"node {nid}: {', '.join(real)}")
            # feedback is expected from the first SYNC on: its age counts from then
            oldest = max(min(n.t_ns for n in fb.nodes), self._first_write_ns)
            fb_age = (t_ns - oldest) * 1e-9 if oldest > 0 else 0.0
        loop = self.app.loop
        leak = leak_extra = None
        if self.leak is not None:
            leak, fault = self.leak.health(t_ns)
            leak_extra = {"leak_sensor_fault": fault}
        h = Health(t_ns=t_ns, **nav_health(nav),
                   nonfinite_inputs=_nonfinite_inputs(ins, dvl, depth),
                   nonfinite_outputs=("command",) if out.status == "non-finite" else (),
                   m_hat_min_eig=m_hat_min_eig(new_state.ctrl, self.core_cfg.controller),
                   theta_hat=theta, amplifiers_enabled=enabled,
                   amplifier_faults=tuple(faults), feedback_age_s=fb_age, bus_off=bus_off,
                   overrun_streak=loop.overrun_streak,
                   overrun_streak_exceeded=loop.streak_exceeded, leak=leak,
                   extra=leak_extra)
        d = sup.step(h)

        # -- the decision --
        mode = "control"
        thrust = out.thrust_n
        if d.freeze_adaptation:
            new_state = replace(new_state, ctrl=prev.ctrl)  # θ̂ held
        if not sup.armed or d.zero_thrust:
            thrust = np.zeros_like(out.thrust_n)
            mode = "zero" if sup.armed else "disarmed"
        elif d.zero_horizontal:
            thrust = self._hold_depth(nav, dt)
            mode = "hold-depth"
        else:
            self._hold_ref = None
            if d.freeze_adaptation:
                thrust = self._fallback(nav, out.reference, dt)
                mode = "pdc-fallback"
        if not d.zero_horizontal:
            self._hold_ref = None

        # -- last guard before the bus --
        thrust = np.asarray(thrust, dtype=float)
        if thrust.shape != self.max_thrust.shape or not math.isfinite(float(thrust.sum())):
            self.counters["guard_nonfinite"] += 1
            thrust = np.zeros_like(self.max_thrust)
        over = np.abs(thrust) > self.max_thrust
        if over.any():
            self.counters["guard_clamped"] += 1
            thrust = np.clip(thrust, -self.max_thrust, self.max_thrust)
        if group is not None:
            if not self._first_write_ns:
                self._first_write_ns = t_ns
            st = group.write(thrust)
            if not st.ok:
                self.counters["write_failed"] += 1
        self.commands_max_abs = max(self.commands_max_abs, float(np.abs(thrust).max()))
        # the wrench actually commanded, for the estimators when no speed feedback comes
        new_state.u_last = self.allocator.B @ thrust
        self.state = new_state
        self.counters["cycles"] += 1

        # -- arming on request --
        if self.auto_arm and not self._armed_once and sup.state is State.STANDBY \
                and t_ns - self._last_arm_try_ns >= 200_000_000:
            self._last_arm_try_ns = t_ns
            step = sup.request_arm(t_ns, h, cause="uvd run --arm")
            if step.ok and sup.armed:
                self._on_armed(t_ns)
                self.arm_refusal = None
            else:
                self.arm_refusal = step.refused
                if t_ns - self._last_refusal_log_ns >= 2_000_000_000:
                    self._last_refusal_log_ns = t_ns
                    log.info("%s", step.refused)

        self.last = LastCycle(t_ns, d.action, sup.state, out.status, thrust, mode)
        ref = out.reference
        rec = CycleRecord(
            t_ns=t_ns, dt=dt, state=sup.state.value, action=d.action.label, mode=mode,
            status=out.status, p=nav.H[:3, 3], R=nav.H[:3, :3], v=nav.v, nav_valid=nav.valid,
            u=out.u_applied, u_cmd=self.allocator.B @ thrust, thrust=thrust,
            ages=(h.ins_age_s, h.dvl_age_s, h.depth_age_s, fb_age),
            ins_rx_ns=ins.t_ns if ins is not None else None,
            triggers=tuple(a.name for a in d.active),
            p_ref=None if ref is None else ref.H[:3, 3],
            R_ref=None if ref is None else ref.H[:3, :3],
            v_ref=None if ref is None else np.asarray(ref.v),
            armed_at_ns=self.armed_at_ns).to_dict()
        self.app.hub.publish(rec)
        # within half a period of the due time: a cycle a few µs early is not skipped
        if self.core_cfg.estimators and t_ns >= self._next_estimate_ns - int(dt * 5e8):
            self._next_estimate_ns = t_ns + self._estimate_period_ns
            self._publish_estimates(t_ns)

    def _hold_depth(self, nav, dt: float) -> np.ndarray:
        """PD on depth, roll and pitch only (closed-loop mask), zero surge/sway/yaw thrust.

        The setpoint is the depth at entry, level; without a valid DVL the body translational
        velocity is not known, so only the attitude rates feed the derivative term.
        """
        if self._hold_ref is None:
            from uvd.control.trajectory import setpoint
            e = _eta(nav.H)
            sp = setpoint((e[0], e[1], e[2], 0.0, 0.0, e[5])).at(0.0)
            self._hold_ref = Reference(H=sp.H, v=np.zeros(6), vdot=np.zeros(6),
                                       closed_loop=HOLD_DEPTH_MASK)
        if not (nav.ins_valid and nav.depth_valid):
            return np.zeros(self.allocator.n_thrusters)
        ref = self._hold_ref
        H = nav.H.copy()
        H[0, 3], H[1, 3] = ref.H[0, 3], ref.H[1, 3]  # horizontal position is not controlled
        roll, pitch, heading = R_to_euler(H[:3, :3])
        from drivers.samples import euler_to_R
        ref_H = ref.H.copy()
        ref_H[:3, :3] = euler_to_R(0.0, 0.0, heading)  # follow the heading, level
        v = np.array(nav.v, dtype=float)
        if not nav.dvl_valid:
            v[:3] = 0.0
        u, _ = pdc_step(VehicleState(H=H, v=v), replace(ref, H=ref_H), self.pd_gains,
                        PDState(), dt)
        # heave, roll and pitch from the thrusters that produce no surge, sway or yaw; the
        # others get exactly zero
        thrust = np.zeros(self.allocator.n_thrusters)
        if self._vertical.any():
            f = self._vertical_pinv @ u[2:5]
            scale = float(np.max(np.abs(f) / self.max_thrust[self._vertical], initial=0.0))
            thrust[self._vertical] = f / scale if scale > 1.0 else f
        return thrust

    def _fallback(self, nav, reference, dt: float) -> np.ndarray:
        """PDC on the reference (adaptation frozen); zero when navigation is not valid."""
        if reference is None or not nav.valid:
            return np.zeros(self.allocator.n_thrusters)
        u, _ = pdc_step(VehicleState(H=nav.H, v=nav.v), reference, self.pd_gains, PDState(), dt)
        if reference.open_loop_wrench is not None:
            u = u + reference.open_loop_wrench
        thrust, _, _ = allocate(self.allocator, u)
        return thrust

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
