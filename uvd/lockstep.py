"""Lockstep simulation, one of the three ways of running the cycle: the plant, its instruments
and the cycle advance together on a simulated clock — no I/O, no sleeping
(docs/architecture.md, "the three ways of running the one cycle").

Each control period the plant takes ``plant_rate_hz / control_rate_hz`` RKMK4 steps with the
thrust command held (zero-order hold, as the thesis's 100 ms cycle, §5.3.1); the instruments
sample the true state at their own rates (Table A.1); the samples that arrived during the
period, and the propeller speeds, are the next cycle's :class:`uvd.runtime.cycle.CycleInputs`.

The cycle is always the daemon's very update (:func:`uvd.runtime.cycle.update`): health, the
failsafe arbiter, the lifecycle and the operator's commands (:meth:`Lockstep.command`), every
failsafe mode included. Instrument faults (:attr:`Lockstep.faults`,
:mod:`sim_bridge.instruments.faults`) and amplifier faults (:attr:`Lockstep.amplifier_faults`)
are injected on the simulated clock — the same faulty samples the real-time bridge produces.
What a run supervises is its cycle's configuration: ``uvd demo``'s reference run takes the
daemon's (:func:`uvd.runtime.build.make_cycle`), the thesis's experiments, which ran no
failsafes, :func:`uvd.runtime.cycle.unsupervised` — armed from the start in the configured
controller's mode.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sim_bridge.instruments.faults import FaultyInstruments, SensorFaults
from sim_bridge.instruments.models import InstrumentConfig, Instruments
from sim_bridge.plant import Plant, PlantConfig
from uvd import core
from uvd.control.errors import error_coordinates
from uvd.geometry import eta_of, wrap_angles
from uvd.model.vehicle import Vehicle
from uvd.runtime.cycle import ActuatorStatus, CycleConfig, CycleInputs, CycleResult
from uvd.runtime.supervisor import Supervisor

DOF_NAMES = ("x", "y", "z", "roll", "pitch", "heading")
VEL_NAMES = ("u", "v", "w", "p", "q", "r")


#: the plant's rate of a lockstep run when none is given: sim-bridge's (its fastest
#: instrument's)
PLANT_RATE_HZ = 100.0


def plant_rate_for(control_rate_hz: float) -> float:
    """The plant rate of a lockstep run at ``control_rate_hz``: the least integer multiple of
    it that is at least :data:`PLANT_RATE_HZ` — that rate itself for a control rate that
    divides it (10, 20, 25, 50, 100 Hz), 120 Hz for 30 Hz, the control rate above it. (Before
    session 34 a fixed 100 Hz: ``uvd demo`` of a configuration at 30 Hz or 1 kHz — within
    ``[loop] rate_hz``'s bounds — ended in a ValueError traceback.)"""
    return control_rate_hz * max(1, math.ceil(PLANT_RATE_HZ / control_rate_hz - 1e-9))


@dataclass(frozen=True)
class LockstepConfig:
    #: None: :func:`plant_rate_for` the control rate
    plant_rate_hz: float | None = None
    control_rate_hz: float = 10.0
    plant: PlantConfig = field(default_factory=PlantConfig)
    instruments: InstrumentConfig = field(default_factory=InstrumentConfig)
    seed: int = 0
    #: instrument noise keyed per frame as sim-bridge draws it (``frame_seed`` of
    #: :class:`~sim_bridge.instruments.models.Instruments`, the epoch at the first cycle);
    #: off, the one stream of ``seed`` the thesis experiments (docs/RESULTS.md) draw from
    frame_noise: bool = False
    #: the cycle runs on the INS frame (``[loop] trigger = "ins"``, the demo's lockstep run of
    #: such a configuration): a DVL or depth frame sampled at the instant of the INS frame a
    #: cycle runs on reaches the next cycle, as the daemon receives it after the frame that
    #: woke it; off, every frame of the period, the cycle's instant included, reaches the
    #: cycle (the experiments)
    ins_trigger: bool = False

    def __post_init__(self) -> None:
        if self.plant_rate_hz is None:
            object.__setattr__(self, "plant_rate_hz", plant_rate_for(self.control_rate_hz))
        ratio = self.plant_rate_hz / self.control_rate_hz
        if abs(ratio - round(ratio)) > 1e-9 or ratio < 1:
            raise ValueError("plant_rate_hz must be an integer multiple of control_rate_hz "
                             f"(got {self.plant_rate_hz} and {self.control_rate_hz})")


def lockstep_config(cfg, seed: int = 0) -> LockstepConfig:
    """The lockstep run of a daemon configuration (:class:`uvd.runtime.config.Config`): its
    control rate, its ``[simulation.instruments]``, sim-bridge's noise of ``seed`` (frame
    ``f`` after arming carries the noise of the bridge's frame ``f`` after the release) and
    the DVL's wire resolution (PD0: 1 mm/s); with ``[loop] trigger = "ins"`` the DVL's and
    depth's frames of the INS frame's instant reach the next cycle (``ins_trigger``)."""
    from dataclasses import replace

    from drivers.pd0 import VELOCITY_RESOLUTION_M_S
    from sim_bridge.instruments.models import instrument_config
    inst = replace(instrument_config(cfg.simulation.instruments),
                   dvl_resolution_m_s=VELOCITY_RESOLUTION_M_S)
    return LockstepConfig(control_rate_hz=cfg.loop.rate_hz, seed=seed, frame_noise=True,
                          instruments=inst, ins_trigger=cfg.loop.trigger == "ins")


def of_config(cfg, lcfg: LockstepConfig | None = None, *, armed: bool = True,
              **supervisor_args) -> Lockstep:
    """A daemon configuration's very cycle (:func:`uvd.runtime.build.make_cycle`: the same
    core, failsafes and lifecycle) in lockstep, from its start pose
    (:func:`uvd.runtime.build.start_pose`).

    ``lcfg`` defaults to the configuration's control rate with seed 0 and no frame noise;
    :func:`lockstep_config` gives the daemon's instruments (``uvd demo``'s reference run).
    ``armed=False`` starts in STANDBY (arm with :meth:`Lockstep.command`)."""
    from uvd.runtime.build import make_cycle, start_pose
    vehicle = cfg.load_vehicle()
    H0, v0 = start_pose(cfg)
    if lcfg is None:
        lcfg = LockstepConfig(control_rate_hz=cfg.loop.rate_hz, seed=0)
    return Lockstep(vehicle, make_cycle(cfg, vehicle), lcfg, H0=H0, v0=v0, armed=armed,
                    **supervisor_args)


@dataclass
class LockstepLog:
    """Per-cycle records (arrays of length n_cycles)."""

    t: np.ndarray
    eta: np.ndarray        # true [x, y, z, roll, pitch, heading]
    eta_ref: np.ndarray    # reference, same layout
    v: np.ndarray          # true body velocity
    dpsi: np.ndarray       # Δψ of (5.3), true state vs reference
    dv: np.ndarray         # Δv of (5.4)
    u_cmd: np.ndarray
    u_applied: np.ndarray
    thrust: np.ndarray
    saturated: np.ndarray
    status: list
    mode: list = field(default_factory=list)  # the mode each cycle applied (core.Mode)
    wall_s: float = 0.0
    #: the supervisor's failsafe events and lifecycle transitions (plain dicts), when kept
    failsafe_events: list = field(default_factory=list)


class Lockstep:
    """A plant + instruments + the cycle, advanced one control period at a time.

    Parameters
    ----------
    vehicle : Vehicle
        The plant's vehicle.
    cycle : CycleConfig
        The cycle to run (:func:`uvd.runtime.build.make_cycle`,
        :func:`uvd.runtime.cycle.unsupervised`).
    cfg : LockstepConfig
    H0, v0 : ndarray, optional
        The plant's initial pose and velocity; navigation starts at its position.
    armed : bool
        The lifecycle starts ARMED (else in STANDBY: arm with :meth:`command`).
    supervisor_args
        For the :class:`~uvd.runtime.supervisor.Supervisor` (listeners, history).
    """

    def __init__(self, vehicle: Vehicle, cycle: CycleConfig, cfg: LockstepConfig, *,
                 H0: np.ndarray | None = None, v0: np.ndarray | None = None,
                 armed: bool = True, **supervisor_args) -> None:
        if not isinstance(cycle, CycleConfig):
            raise TypeError("Lockstep runs a cycle (uvd.runtime.build.make_cycle or "
                            f"uvd.runtime.cycle.unsupervised), not a {type(cycle).__name__}")
        self.cfg = cfg
        self.plant = Plant(vehicle, PlantConfig(rate_hz=cfg.plant_rate_hz,
                                                thrusters=cfg.plant.thrusters), H0=H0, v0=v0)
        self.rng = np.random.default_rng(cfg.seed)
        self.t_ns = 0
        #: instrument faults, on the simulated clock (``faults.set("ins", "silence", 0.5)``)
        self.faults = SensorFaults(clock=lambda: self.t_ns)
        self.instruments = FaultyInstruments(cfg.instruments, self.rng, self.faults,
                                             frame_seed=cfg.seed if cfg.frame_noise else None)
        #: amplifier faults the cycle sees (names, e.g. ``("node 3: overcurrent",)``)
        self.amplifier_faults: tuple[str, ...] = ()
        #: the thrusters (1…n) whose amplifier reports them (:meth:`amplifier_fault`)
        self.amplifier_faulted: tuple[int, ...] = ()
        #: the thrusters' effectiveness η the cycle is told (None: all healthy), as an amplifier
        #: reports it; the plant's own is ``plant.thrusters.health``. Set, it replaces the
        #: cycle's η (the operator's SetThrusterEta) before the next cycle
        self.thruster_eta: np.ndarray | None = None
        #: signals of plug-in failsafe triggers the cycle sees, as the daemon's read phase
        #: gathers them (``{"operator_heartbeat_age_s": 6.0}``, uvd/runtime/triggers.py)
        self.extra: dict | None = None
        self.substeps = int(round(cfg.plant_rate_hz / cfg.control_rate_hz))
        self.dt_control = 1.0 / cfg.control_rate_hz
        self.plant_dt_ns = int(round(1e9 / cfg.plant_rate_hz))
        #: the plant's state after each step of a period (Plant.steps_held's trace)
        self._trace = (np.empty((self.substeps, 4, 4)), np.empty((self.substeps, 6)))
        north, east = self.plant.H[0, 3], self.plant.H[1, 3]
        self.instruments.dr_north, self.instruments.dr_east = north, east
        #: the running cycle: its configuration and its state (``supervisor.data``)
        self.supervisor = Supervisor(cycle, armed=armed, north_m=north, east_m=east,
                                     **supervisor_args)
        if not armed:
            self.supervisor.boot_complete(0, "lockstep")
        self.last_result: CycleResult | None = None
        self.thrust_cmd = np.zeros(vehicle.n_thrusters)
        # prime the instruments so the first cycle has every source (the daemon has them from
        # standby)
        self._pending = list(self.instruments.sample(0, self.plant.H, self.plant.v))
        self._deferred = [None, None, None]  # frames held for the cycle after next (ins_trigger)

    @property
    def core_cfg(self) -> core.CoreConfig:
        return self.supervisor.config.core

    @property
    def state(self) -> core.CoreState:
        """The core's part of the cycle's state."""
        return self.supervisor.data.core

    def command(self, c):
        """Apply an operator command (:mod:`uvd.runtime.commands`) before the next cycle, as
        the daemon applies a queued one; returns its result."""
        return self.supervisor.apply(c, self.t_ns)

    def amplifier_fault(self, thruster: int, name: str = "overcurrent") -> None:
        """Thruster ``thruster`` (1…n)'s amplifier faults, as a CiA 402 drive does: its output
        goes to zero (the plant's thruster health 0) and it reports the fault
        (``"node k: name"``, :attr:`ActuatorStatus.faulted`) from the next cycle on — what the
        cycle's amplifier source of η sees (:func:`uvd.runtime.cycle.amplifier_source`)."""
        n = self.plant.thrusters.health.shape[0]
        if not 1 <= int(thruster) <= n:
            raise ValueError(f"thruster {thruster} is not one of 1…{n}")
        self.plant.thrusters.health[int(thruster) - 1] = 0.0
        self.amplifier_faults = (*self.amplifier_faults, f"node {int(thruster)}: {name}")
        self.amplifier_faulted = tuple(sorted({*self.amplifier_faulted, int(thruster)}))

    def advance(self) -> core.CoreOutputs:
        """One cycle, then one control period of the plant under its command."""
        ins, dvl, depth = self._pending
        omega = self.plant.thrusters.omega.copy()
        if self.thruster_eta is not None and \
                self.supervisor.data.thruster_eta is not self.thruster_eta:
            self.supervisor.data = self.supervisor.data._replace(thruster_eta=self.thruster_eta)
        act = ActuatorStatus(omega_rad_s=omega, enabled=not self.amplifier_faulted,
                             faults=self.amplifier_faults, feedback_t_ns=self.t_ns,
                             faulted=self.amplifier_faulted, healthy_feedback_t_ns=self.t_ns)
        self.last_result = r = self.supervisor.update(
            CycleInputs(self.t_ns, ins, dvl, depth, act, extra=self.extra), self.dt_control)
        out = r.out
        self.thrust_cmd = out.thrust_n
        newest = self._sample_period(out.thrust_n)
        if self.cfg.ins_trigger:
            self._defer_coincident(newest)
        self._pending = newest
        return out

    def _sample_period(self, thrust: np.ndarray) -> list:
        """One control period of the plant with ``thrust`` held, in one compiled call that
        keeps the state after every step (``self._trace``); the instruments then sample it at
        the steps where their samples fall due, in time order — in one compiled walk
        (:meth:`Instruments.sample_trace`), or one sample at a time with the faults' clock at
        each (:meth:`Instruments.sample_steps`) while a fault is injected or the noise is
        frame-keyed. Instruments of any other class (a wrapper that changes the samples, as
        :class:`sim_bridge.tank.TankInstruments`) are sampled one call at a time through their
        own ``sample``, whatever they delegate: the walk never bypasses them. Returns the
        newest sample of each instrument ([ins, dvl, depth], None where none came)."""
        n, step_ns, t0 = self.substeps, self.plant_dt_ns, self.t_ns
        H_trace, v_trace = trace = self._trace
        self.plant.steps_held(thrust, n, trace)
        instruments = self.instruments
        if not isinstance(instruments, Instruments):
            newest = Instruments.sample_steps(instruments, t0, step_ns, H_trace, v_trace,
                                              at=self._tick)
        elif instruments.can_sample_trace:
            newest = instruments.sample_trace(t0, step_ns, H_trace, v_trace)
        else:
            newest = instruments.sample_steps(t0, step_ns, H_trace, v_trace, at=self._tick)
        self.t_ns = t0 + n * step_ns
        return newest

    def _tick(self, t_ns: int) -> None:
        """The simulated clock at an instrument's sample (the faults' clock, SensorFaults)."""
        self.t_ns = t_ns

    def _defer_coincident(self, newest: list) -> None:
        """``ins_trigger``: the next cycle runs on the INS frame of its instant ``t_ns``; a DVL
        or depth frame sampled at that instant too reaches the daemon after that frame (its
        own port, written after it) and so the cycle after. Holds those back and hands on the
        ones held the period before, unless a newer frame came (``newest`` changed in place).

        In sim-bridge this is what the daemon sees: on the BlueROV2 at 50 Hz half the DVL's
        frames (8 Hz) and every depth frame (10 Hz) share their plant instant with an INS frame,
        and in a recorded 120 s run 459 of those 479 DVL frames and 1139 of 1198 depth frames
        reached the cycle of the next INS frame."""
        held, self._deferred = self._deferred, [None, None, None]
        for i in (1, 2):
            s = newest[i]
            if s is not None and s.t_ns == self.t_ns:
                self._deferred[i], s = s, None
            newest[i] = s if s is not None else held[i]


def run(sim: Lockstep, duration_s: float, *, progress: Callable[[str], None] | None = None,
        progress_every_s: float = 600.0) -> LockstepLog:
    """Run ``duration_s`` simulated seconds, recording every cycle (true state vs reference)."""
    n = int(round(duration_s / sim.dt_control))
    nthr = sim.plant.thrusters.omega.shape[0]
    log = LockstepLog(t=np.empty(n), eta=np.empty((n, 6)), eta_ref=np.empty((n, 6)),
                      v=np.empty((n, 6)), dpsi=np.empty((n, 6)), dv=np.empty((n, 6)),
                      u_cmd=np.empty((n, 6)), u_applied=np.empty((n, 6)),
                      thrust=np.empty((n, nthr)), saturated=np.zeros((n, nthr), dtype=bool),
                      status=[])
    t_wall = time.perf_counter()
    next_report = progress_every_s
    for k in range(n):
        H, v = sim.plant.H.copy(), sim.plant.v.copy()
        out = sim.advance()
        ref = out.reference
        log.t[k] = k * sim.dt_control
        log.eta[k] = eta_of(H)
        log.eta_ref[k] = eta_of(ref.H)
        log.v[k] = v
        _, dpsi, dv, _ = error_coordinates(H, v, ref.H, ref.v)
        log.dpsi[k], log.dv[k] = dpsi, dv
        log.u_cmd[k] = out.u_cmd
        log.u_applied[k] = out.u_applied
        log.thrust[k] = out.thrust_n
        log.saturated[k] = out.saturated
        log.status.append(out.status)
        log.mode.append(out.mode)
        if progress is not None and log.t[k] >= next_report:
            next_report += progress_every_s
            progress(f"  simulated {log.t[k] / 60:.0f} / {duration_s / 60:.0f} min "
                     f"({time.perf_counter() - t_wall:.0f} s wall)")
    log.wall_s = time.perf_counter() - t_wall
    return log



def tracking_errors(log: LockstepLog, start_s: float = 0.0, end_s: float | None = None) -> dict:
    """Per-DOF tracking MAE (SI: m and rad; body velocities m/s and rad/s) and the MNE of
    Δψ and Δv (mean of the error-vector norms, §5.3.1) over [start_s, end_s)."""
    sel = log.t >= start_s
    if end_s is not None:
        sel &= log.t < end_s
    e = log.eta[sel] - log.eta_ref[sel]
    e[:, 3:] = wrap_angles(e[:, 3:])
    return {
        "position_mae": {n: float(np.mean(np.abs(e[:, i]))) for i, n in enumerate(DOF_NAMES)},
        "velocity_mae": {n: float(np.mean(np.abs(log.dv[sel, i])))
                         for i, n in enumerate(VEL_NAMES)},
        "position_mne": float(np.mean(np.linalg.norm(log.dpsi[sel], axis=1))),
        "velocity_mne": float(np.mean(np.linalg.norm(log.dv[sel], axis=1))),
        "samples": int(np.count_nonzero(sel)),
    }


def format_tracking_table(errs: dict, title: str = "") -> str:
    """A per-DOF table: position MAE (m / deg) and velocity MAE (m/s / deg/s)."""
    lines = []
    if title:
        lines.append(title)
    lines.append(f"{'DOF':>8} {'position MAE':>14} {'velocity MAE':>14}")
    for i, (pn, vn) in enumerate(zip(DOF_NAMES, VEL_NAMES, strict=True)):
        pe, ve = errs["position_mae"][pn], errs["velocity_mae"][vn]
        if i < 3:
            lines.append(f"{pn:>8} {pe:>11.4f} m  {ve:>9.4f} m/s")
        else:
            lines.append(f"{pn:>8} {math.degrees(pe):>9.3f} deg  {math.degrees(ve):>7.3f} deg/s")
    lines.append(f"MNE: position {errs['position_mne']:.4f}, velocity {errs['velocity_mne']:.4f} "
                 f"({errs['samples']} cycles)")
    return "\n".join(lines)


def hil_tracking(telemetry, truth: np.ndarray, since_ns: int | None = None,
                 until_ns: int | None = None) -> dict[str, Any]:
    """Tracking error of a hardware-in-the-loop run's armed cycles (those in [``since_ns``,
    ``until_ns``) when given, monotonic ns): the true state (``truth``, sim-bridge's truth log,
    :func:`sim_bridge.bridge.read_truth`, interpolated at each cycle's time) against the
    reference the daemon used (``telemetry``, its JSON lines file) — the measures of
    :func:`tracking_errors`."""
    import json

    from uvd.geometry import euler_to_R
    from uvd.telemetry.records import CycleRecord

    t, ref_eta, ref_v = [], [], []
    with telemetry.open(encoding="utf-8") as fh:
        for line in fh:
            try:
                r = json.loads(line)
            except ValueError:
                continue
            if r.get("type") != "cycle" or r.get("state") not in ("ARMED", "FAILSAFE") \
                    or r.get("p_ref") is None:
                continue
            rec = CycleRecord.from_dict(r)
            if (since_ns is not None and rec.t_ns < since_ns) or \
                    (until_ns is not None and rec.t_ns >= until_ns):
                continue
            t.append(rec.t_ns * 1e-9)
            ref_eta.append(rec.eta_ref())
            ref_v.append(rec.v_ref)
    if len(t) < 2 or truth.shape[0] < 2:
        return {"samples": 0}
    t = np.asarray(t)
    # the first armed cycle ends with arming; the reference clock starts on the next one
    t, ref_eta, ref_v = t[1:], np.asarray(ref_eta)[1:], np.asarray(ref_v)[1:]
    tt = truth[:, 0]
    keep = (t >= tt[0]) & (t <= tt[-1])
    t, ref_eta, ref_v = t[keep], ref_eta[keep], ref_v[keep]
    eta = np.empty((t.size, 6))
    for i in range(6):
        col = truth[:, 1 + i]
        if i >= 3:
            col = np.unwrap(col)
        eta[:, i] = np.interp(t, tt, col)
    v = np.stack([np.interp(t, tt, truth[:, 7 + i]) for i in range(6)], axis=1)
    e = eta - ref_eta
    e[:, 3:] = wrap_angles(e[:, 3:])
    dpsi = np.empty((t.size, 6))
    dv = np.empty((t.size, 6))
    for k in range(t.size):
        H = np.eye(4)
        H[:3, :3] = euler_to_R(*eta[k, 3:])
        H[:3, 3] = eta[k, :3]
        Hr = np.eye(4)
        Hr[:3, :3] = euler_to_R(*ref_eta[k, 3:])
        Hr[:3, 3] = ref_eta[k, :3]
        _, dpsi[k], dv[k], _ = error_coordinates(H, v[k], Hr, ref_v[k])
    return {
        "position_mae": {n: float(np.mean(np.abs(e[:, i]))) for i, n in enumerate(DOF_NAMES)},
        "velocity_mae": {n: float(np.mean(np.abs(dv[:, i]))) for i, n in enumerate(VEL_NAMES)},
        "position_mne": float(np.mean(np.linalg.norm(dpsi, axis=1))),
        "velocity_mne": float(np.mean(np.linalg.norm(dv, axis=1))),
        "samples": int(t.size),
        "duration_s": float(t[-1] - t[0]),
    }
