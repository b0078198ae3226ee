"""``sim-bridge``: the simulated vehicle behind the daemon's real wire protocols, in real time.

:class:`SimBridge` runs, in one process,

* the **plant** (:class:`sim_bridge.plant.Plant`, RKMK4 at 100 Hz on absolute deadlines of the
  monotonic clock) — its :class:`~sim_bridge.thrusters.ThrusterBank` is the only one: the
  emulated amplifiers' commands drive it, and the amplifiers report its propeller speeds;
* the **instruments** (:class:`~sim_bridge.instruments.pty_emulators.InstrumentEmulators`):
  PHINS (STDBIN or ASCII, per ``[sensors.ins] format``), PD0 DVL and Digiquartz on
  pseudo-terminals linked at the configured ``[sensors.*] port`` paths, with Table A.1 rates
  and noise from a seeded generator (each frame's keyed by its index since the release from
  the cradle, as the demo's lockstep run draws it);
* the **CAN nodes** (:class:`~sim_bridge.amplifiers.emulators.CanEmulators`): the six CiA 402
  amplifiers of ``[can.amplifiers]`` and, with ``[can.depth] enabled``, the CiA 404 pressure
  transmitter, on the configured bus (``udp_multicast`` on an interface-local ``ff11::`` group:
  it never leaves this machine).

So ``uvd run`` with the same configuration connects to it exactly as to the vehicle.

**Instrument timing.** The instruments are sampled right after each plant step, from the
state of that instant (the frames that fell due since the previous step; DVL at 8 Hz on a
100 Hz plant: 0, 130, 250, 380 ms …) — the timing lockstep simulation gives them. Sampled on
their own clock between steps, they would carry a state up to one step old while a command
that arrives within a step acts from its start: on the BlueROV2 at 50 Hz that alone moved
lockstep's heading MAE from 1.32° to 1.15° and its x MAE from 3.4 to 4.7 mm over 120 s.

**Hold.** With ``hold=True`` the vehicle sits in its cradle at the start pose until the first
non-zero thrust command arrives (the thrusters spin, the body does not move): a run armed at
any moment then starts exactly where a lockstep simulation of the same configuration starts.

**Fault injection** (:meth:`SimBridge.call`, also over the JSON control channel of
``sim-bridge --control``): per instrument ``silence`` (no frames), ``garbage`` (random bytes
instead of each frame), ``nan`` (NaN attitude / depth in otherwise valid frames), ``stuck``
(the value frozen) — for ``seconds`` or until ``ok``; every amplifier fault of
:meth:`CanEmulators.call` (``fault``, ``silence``, ``unsilence``, ``health``, ``bus_off``,
``reset``, …); the plant's ``release``/``place``; ``writes`` (when each frame of an
instrument was written, for ``uvd bench latency``). Every answer carries the bridge's
monotonic time ``t_ns`` (the same clock as the daemon's on this machine).

**Faults of the vehicle** (for fault detection, docs/zenoh.md): ``plant_fault`` changes the
plant's true parameters (:class:`~sim_bridge.plant.PlantFault`: ``drag_scale`` 1.5 for an
entanglement, ``mass_scale`` 1.1 for a flooding, ``g_delta``/``b_delta`` for a buoyancy
change; no argument: the vehicle file's own again); ``health`` (``node``, ``value``) weakens
one thruster (0.5) or kills it (0). Any command given ``at_s`` is carried out that many
seconds later, by the plant's loop (answer: ``scheduled_ns``); ``sim-bridge --at S JSON``
schedules one from the start.

**Truth.** ``truth_log`` receives one row per plant step: monotonic time (s), the true
[x, y, z, roll, pitch, heading], body velocity [ν; ω] and the thrust produced (float64,
``TRUTH_COLUMNS``), for the demo's tracking errors.
"""

from __future__ import annotations

import asyncio
import contextlib
import copy
import dataclasses
import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from drivers.pty import PtyPort
from sim_bridge.config import BridgeConfig
from sim_bridge.instruments.faults import SENSOR_MODES, FaultyInstruments, SensorFaults
from sim_bridge.instruments.pty_emulators import EmulatorConfig, InstrumentEmulators
from sim_bridge.plant import Plant, PlantConfig, PlantFault
from sim_bridge.thrusters import ThrusterBank, ThrusterEffects
from uvd.geometry import R_to_euler
from uvd.io.toml import dump_toml
from uvd.netports import free_port

__all__ = ["SimBridge", "PlantStopped", "SensorFaults", "TRUTH_COLUMNS", "read_truth",
           "write_local_config", "merge_tables", "BridgeProcess", "SENSOR_MODES", "hil_scheduling"]

log = logging.getLogger("sim_bridge")

TRUTH_COLUMNS = ("t_s", "x", "y", "z", "roll", "pitch", "heading", "u", "v", "w", "p", "q",
                 "r", "f1", "f2", "f3", "f4", "f5", "f6")

#: the commands :meth:`SimBridge.call` carries out itself; the others go to the CAN emulators
BRIDGE_OPS = ("leak", "ping", "place", "plant_fault", "release", "reset", "sensor", "stats",
              "truth", "writes")


# ----------------------------------------------------------------------------- fault injection

class FaultyPort(PtyPort):
    """A pty whose frames are replaced by random bytes of the same length in ``garbage``."""

    def __init__(self, link, name: str, faults: SensorFaults, rng: np.random.Generator) -> None:
        super().__init__(link)
        self.name = name
        self.faults = faults
        self.rng = rng
        self.garbage_written = 0
        self.last_write_end_ns = 0
        #: monotonic time each frame's last byte was handed to the pty (``uvd bench latency``)
        self.write_times: deque[int] = deque(maxlen=100_000)

    def write(self, data: bytes) -> bool:
        if self.faults.get(self.name) == "garbage":
            data = self.rng.integers(0, 256, len(data), dtype=np.uint8).tobytes()
            self.garbage_written += 1
        ok = super().write(data)
        self.last_write_end_ns = time.monotonic_ns()
        if ok:
            self.write_times.append(self.last_write_end_ns)
        return ok


class _PlantBank:
    """What :class:`CanEmulators` reads from a thruster bank, backed by the plant's own bank.

    The emulators' tick thread calls ``step``: a no-op here, because the plant steps its bank
    with the amplifiers' commands at its own rate. ``omega`` (the amplifiers' velocity
    feedback), ``thrust`` and ``health`` are the plant bank's arrays.
    """

    def __init__(self, bank: ThrusterBank) -> None:
        self.bank = bank

    @property
    def omega(self) -> np.ndarray:
        return self.bank.omega

    @property
    def thrust(self) -> np.ndarray:
        return self.bank.thrust

    @property
    def health(self) -> np.ndarray:
        return self.bank.health

    def step(self, command_n, dt: float) -> np.ndarray:
        return self.bank.thrust

    def reset(self) -> None:
        self.bank.reset()


# ----------------------------------------------------------------------------- the bridge

class PlantStopped(RuntimeError):
    """The plant's task ended on an error: the simulated vehicle is gone (its instruments
    silent), so sim-bridge ends too, naming it, rather than answer on as if alive."""


class SimBridge:
    """Plant + instruments + CAN nodes in real time (module docstring).

    Parameters
    ----------
    config : sim_bridge.config.BridgeConfig
        The simulated vehicle (model, start pose, ports, bus): made from the daemon's
        configuration file by ``uvd.commands.sim_bridge.bridge_config``.
    seed : int
        Seed of every random number (instrument noise, garbage bytes).
    hold : bool
        Keep the vehicle in its cradle until the first non-zero thrust command.
    truth_log : path, optional
        Binary file of ``TRUTH_COLUMNS`` rows (float64), one per plant step.
    plant_rate_hz : float
        Plant integration rate.
    """

    def __init__(self, config: BridgeConfig, *, seed: int = 0, hold: bool = False,
                 truth_log: str | Path | None = None, plant_rate_hz: float = 100.0,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        from uvd.control.trajectory import start_pose
        self.config = config
        self.clock = clock
        self.vehicle = config.vehicle
        self.H0, self.v0 = start_pose(config.trajectory, config.start_north_m,
                                      config.start_east_m)
        self.plant = Plant(self.vehicle, PlantConfig(rate_hz=plant_rate_hz), H0=self.H0,
                           v0=self.v0)
        self.rng = np.random.default_rng(seed)
        self.faults = SensorFaults(clock)
        self.hold = hold
        self.held = hold
        self.released_at_ns: int | None = None
        self.truth_path = Path(truth_log) if truth_log is not None else None
        self._truth_fh = None
        self._truth_buf: list[np.ndarray] = []
        self.counters = {"plant_steps": 0, "late_steps": 0, "skipped_steps": 0,
                         "rpdo_rx": 0, "rpdo_out_of_range": 0, "rpdo_max_abs_permille": 0}
        self._stop: asyncio.Event | None = None
        self._pending: list[tuple[str, Any]] = []
        self._timed: list[tuple[int, str, dict]] = []  # (due ns, op, args), soonest first
        self._timed_lock = threading.Lock()  # the control thread adds, the plant loop takes
        self._timed_running = 0  # taken from _timed and not yet carried out (stats' scheduled)
        self.timed_results: list[dict] = []
        self._links = dict(config.serial_ports)
        # each frame's noise keyed by (seed, instrument, frame since the release) as the
        # demo's lockstep run draws it (sim_bridge.instruments.models, "Noise streams")
        self.instruments = FaultyInstruments(config.instruments,
                                             self.rng, self.faults, frame_seed=seed)
        if hold:
            self.instruments.set_epoch(None)
        self.instruments.dr_north, self.instruments.dr_east = self.H0[0, 3], self.H0[1, 3]
        self.emulators = InstrumentEmulators(
            self._truth_now, self._links, self.instruments,
            EmulatorConfig(ins_protocol=config.ins_protocol, depth=config.depth),
            clock=clock)
        self.emulators.ports = {name: FaultyPort(path, name, self.faults, self.rng)
                                for name, path in self._links.items()}
        self.can = None
        # the leak detector's digital input ([sensors.leak]): a file holding 0 or 1, as a
        # GPIO's sysfs value file; dry until a "leak" command floods it
        self.leak_path = config.leak_path
        self.leak_wet = False
        if self.leak_path is not None:
            self.set_leak(False)
        self.warm_up_s = self._warm_up()

    def _warm_up(self) -> float:
        """Load the plant's compiled code now, before any port or bus is up.

        While the vehicle sits in its cradle only the thrusters are stepped; the fused
        thrusters + rigid-body kernel first runs at the first thrust command. With an empty
        on-disk cache its compilation takes seconds there — every emulated device (SYNC
        answers, heartbeat watch, INS, DVL, depth) stalls with it and the daemon disarms. A
        scratch copy of the plant takes one step of each kind here instead. Returns seconds.
        """
        t0 = time.perf_counter()
        scratch = copy.deepcopy(self.plant)
        cmd = np.zeros(len(scratch.thrusters.specs))
        scratch.thrusters.step(cmd, scratch.dt)
        scratch.step(cmd)
        return time.perf_counter() - t0

    def set_leak(self, wet: bool) -> int:
        """Put the emulated leak input at its active level (``wet``) or the other one,
        replaced in one step (a reader never sees a half-written file). Returns the time
        (monotonic ns) the new level became readable."""
        if self.leak_path is None:
            raise ValueError("no leak input configured ([sensors.leak] enabled = false)")
        active = self.config.leak_active_level
        level = active if wet else 1 - active
        self.leak_path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.leak_path.with_name(self.leak_path.name + ".tmp")
        tmp.write_text(f"{level}\n", encoding="ascii")
        os.replace(tmp, self.leak_path)
        self.leak_wet = bool(wet)
        return self.clock()

    def _truth_now(self, t_ns: int) -> tuple[np.ndarray, np.ndarray]:
        return self.plant.H.copy(), self.plant.v.copy()

    # -- CAN --
    def _open_can(self) -> None:
        from sim_bridge.amplifiers.emulators import CanEmulators
        c = self.config.can
        a = c.amplifiers
        plant = self.plant
        d = c.depth
        self.can = CanEmulators(
            c.bus, self.vehicle.thrusters, a.node_ids, eds=a.eds, effects=ThrusterEffects(),
            thrust_per_permille_n=a.thrust_per_permille_n,
            velocity_rad_s_per_count=a.velocity_rad_s_per_count,
            pressure_node=d.node_id if d.enabled else None,
            depth_m=lambda: float(plant.H[2, 3]), depth_cfg=d,
            pressure_noise_pa=0.00075 * d.density_kg_m3 * d.gravity_m_s2, rng=self.rng,
            clock=self.clock)
        self.can.bank = _PlantBank(plant.thrusters)  # one bank: the plant's
        self.can.open()
        for amp in self.can.amps:
            for m in amp.rpdo_maps:
                m.add_callback(lambda pdo, amp=amp: self._on_rpdo(amp, pdo))

    def _on_rpdo(self, amp, pdo) -> None:
        """Watch every target torque on the wire (before the drive clamps it)."""
        try:
            target = int(pdo[0x6071].raw)
        except Exception:  # noqa: BLE001 - malformed: the node counts it
            return
        c = self.counters
        c["rpdo_rx"] += 1
        a = abs(target)
        if a > c["rpdo_max_abs_permille"]:
            c["rpdo_max_abs_permille"] = a
        if a > self.config.can.amplifiers.max_torque_permille:
            c["rpdo_out_of_range"] += 1

    def thrust_commands(self) -> np.ndarray:
        """What each amplifier drives now, as thrust (N)."""
        return np.array([a.thrust_command_n() for a in self.can.amps])

    # -- plant --
    def _plant_step(self, t_ns: int) -> None:
        if self._timed:
            self.run_due(t_ns)
        plant = self.plant
        with self.can.lock:
            cmd = self.thrust_commands()
            if self.held:
                if np.any(cmd != 0.0):
                    self.held = False
                    self.released_at_ns = t_ns
                    # the epoch: this step's start, where the frame of the cycle that sent
                    # the command was sampled (lockstep's t = 0; models, "Noise streams")
                    self.emulators.set_epoch(t_ns - round(1e9 * plant.dt))
                    log.info("released from the cradle by the first thrust command")
            if self.held:
                plant.thrusters.step(cmd, plant.dt)
            else:
                plant.step(cmd)
        self.counters["plant_steps"] += 1
        if self.truth_path is not None:
            roll, pitch, heading = R_to_euler(plant.H[:3, :3])
            row = np.empty(len(TRUTH_COLUMNS))
            row[0] = t_ns * 1e-9
            row[1:4] = plant.H[:3, 3]
            row[4:7] = (roll, pitch, heading)
            row[7:13] = plant.v
            nthr = min(6, plant.thrusters.thrust.shape[0])
            row[13:] = 0.0
            row[13:13 + nthr] = plant.thrusters.thrust[:nthr]
            self._truth_buf.append(row)
            if len(self._truth_buf) >= 100:
                self._flush_truth()

    def _flush_truth(self) -> None:
        if self._truth_fh is not None and self._truth_buf:
            try:
                self._truth_fh.write(np.asarray(self._truth_buf).tobytes())
                self._truth_fh.flush()
            except OSError as exc:  # a full disk: the vehicle goes on, its truth log ends
                log.error("truth log %s: %s; the simulation goes on without it",
                          self.truth_path, exc)  # (it ended the plant's task: the
                with contextlib.suppress(OSError):  # instruments fell silent, session 25)
                    self._truth_fh.close()
                self._truth_fh = None
        self._truth_buf.clear()

    def place(self, H: np.ndarray | None = None, hold: bool | None = None) -> None:
        """Put the vehicle back at ``H`` (the start pose by default), at rest."""
        with self.can.lock:
            self.plant.H = np.array(self.H0 if H is None else H, dtype=float)
            self.plant.v = np.zeros(6)
            self.plant.thrusters.reset()
            if hold is not None:
                self.hold = hold
            self.held = self.hold
            self.released_at_ns = None
            self.emulators.set_epoch(None if self.held else self.clock())

    async def _plant_loop(self, t0: int) -> None:
        """Plant steps on absolute deadlines t0 + k·dt, each followed by the instruments'
        frames that fell due, sampled from the state at that instant — as lockstep simulation
        samples them: a command that arrives within a step acts from the step's start, so a
        cycle run on a frame (and answered within the step) meets lockstep's timing."""
        period = int(round(1e9 * self.plant.dt))
        k = 0
        self.emulators.step(0)  # the frames of t = 0
        while not self._stop.is_set():
            k += 1
            target = t0 + k * period
            delay = (target - self.clock()) * 1e-9
            if delay > 0:
                await asyncio.sleep(delay)
            else:
                self.counters["late_steps"] += 1
                behind = (self.clock() - target) // period
                if behind > 20:  # suspended: do not replay seconds of physics in a burst
                    k += behind
                    self.counters["skipped_steps"] += behind
                    target = t0 + k * period
                await asyncio.sleep(0)
            self._plant_step(target)
            self.emulators.step(target - t0)

    # -- control --
    def call(self, op: str, **kw) -> dict:
        """One control command; never raises (``{"ok": false, "error": …}``). With ``at_s``
        it is scheduled that many seconds from now instead (:meth:`run_due`). Either way it is
        checked now (:meth:`command_problem`)."""
        try:
            now = self.clock()
            raw = kw.pop("at_s", None)
            why = self.command_problem(op, kw)
            if why:
                raise ValueError(why)
            if raw is not None:
                try:
                    at_s = float(raw)
                except (TypeError, ValueError):
                    at_s = math.nan
                if not (math.isfinite(at_s) and at_s >= 0.0):
                    raise ValueError(f"at_s must be a finite number of seconds >= 0, not "
                                     f"{raw!r}")
                due = now + int(at_s * 1e9)
                with self._timed_lock:
                    self._timed.append((due, op, kw))
                    self._timed.sort(key=lambda x: x[0])
                return {"ok": True, "t_ns": now, "scheduled_ns": due}
            if op == "plant_fault":
                fault = PlantFault(**_plant_fault_args(kw))
                with self.can.lock if self.can is not None else contextlib.nullcontext():
                    self.plant.set_fault(fault)
                return {"ok": True, "t_ns": now, "fault": dataclasses.asdict(fault)}
            if op == "ping":
                return {"ok": True, "t_ns": now}
            if op == "sensor":
                t = self.faults.set(str(kw["name"]), str(kw.get("mode", "ok")),
                                    kw.get("seconds"))
                return {"ok": True, "t_ns": t,
                        "last_write_ns": self.emulators.ports[kw["name"]].last_write_end_ns
                        if kw["name"] in self.emulators.ports else 0}
            if op == "truth":
                H, v = self.plant.H.copy(), self.plant.v.copy()
                roll, pitch, heading = R_to_euler(H[:3, :3])
                return {"ok": True, "t_ns": now, "eta": [*H[:3, 3], roll, pitch, heading],
                        "v": v.tolist(), "held": self.held,
                        "thrust_command_n": self.thrust_commands().tolist()}
            if op == "writes":
                port = self.emulators.ports[str(kw.get("name", "ins"))]
                return {"ok": True, "t_ns": now, "write_end_ns": list(port.write_times)}
            if op == "release":
                self.held = False
                self.emulators.set_epoch(now)
                return {"ok": True, "t_ns": now}
            if op == "place":
                self.place(hold=kw.get("hold"))
                return {"ok": True, "t_ns": now}
            if op == "stats":
                return {"ok": True, "t_ns": now, **self.stats(bool(kw.get("history")))}
            if op == "leak":  # {"op": "leak", "wet": true} floods the leak input
                return {"ok": True, "t_ns": self.set_leak(bool(kw.get("wet", True))),
                        "wet": self.leak_wet}
            if op == "reset":
                for name in self.faults.mode:
                    self.faults.set(name, "ok")
                if self.leak_path is not None:
                    self.set_leak(False)
                ans = self.can.call("reset")
                return {**ans, "t_ns": now}
            ans = self.can.call(op, **kw)
            ans.setdefault("t_ns", now)
            return ans
        except (KeyError, ValueError, TypeError) as exc:
            return {"ok": False, "error": f"{op}: {exc}"}

    def command_problem(self, op: str, kw: dict) -> str | None:
        """Why :meth:`call` could not carry out ``op`` with ``kw``, or None — checked without
        carrying it out, so that one scheduled with ``at_s`` (``sim-bridge --at S JSON``) is
        refused when it is given, not when it comes due."""
        if op == "plant_fault":
            try:
                PlantFault(**_plant_fault_args(kw))
            except (TypeError, ValueError) as exc:
                return str(exc)
            return None
        if op == "sensor":
            seconds = kw.get("seconds")
            why = self.faults.problem(kw.get("name"), kw.get("mode", "ok"))
            if why:
                return why
            if kw.get("name") == "depth" and kw.get("mode") == "nan" \
                    and "depth" in self.emulators.ports:
                return ("depth: a Digiquartz line carries no NaN, so the instrument cannot "
                        "send one (use silence, garbage or stuck here; nan in a lockstep "
                        "scenario)")
            if seconds is not None and (isinstance(seconds, bool)
                                        or not isinstance(seconds, (int, float))
                                        or not (math.isfinite(seconds) and seconds >= 0.0)):
                return f"seconds must be a finite number >= 0 (or absent), not {seconds!r}"
            return None
        if op == "writes":
            name = kw.get("name", "ins")
            return None if name in self.emulators.ports else \
                f"no instrument port {name!r}; have {sorted(self.emulators.ports)}"
        if op in BRIDGE_OPS:  # the rest of the bridge's own: nothing to check
            return None
        from sim_bridge.amplifiers.emulators import OPS, command_problem
        if op not in OPS:  # named with the bridge's own commands, not only the emulators'
            return f"unknown op {op!r}; known: {', '.join(sorted({*OPS, *BRIDGE_OPS}))}"
        c = self.config.can  # the rest are the CAN emulators' (CanEmulators.call)
        return command_problem(op, kw, c.amplifiers.node_ids,
                               c.depth.node_id if c.depth.enabled else None)

    def run_due(self, t_ns: int) -> None:
        """Carry out the scheduled commands due by ``t_ns`` (the plant's loop calls it)."""
        while True:
            with self._timed_lock:
                if not (self._timed and self._timed[0][0] <= t_ns):
                    return
                due, op, kw = self._timed.pop(0)
                self._timed_running += 1
            try:
                ans = self.call(op, **kw)
                self.timed_results.append({"op": op, **kw, "due_ns": due, **ans})
            finally:
                # counted as scheduled until its result is in timed_results: a stats call
                # between the two saw nothing scheduled and nothing done (seen under load,
                # tests/test_sim_bridge_faults.py)
                with self._timed_lock:
                    self._timed_running -= 1
            (log.info if ans.get("ok") else log.warning)(
                "scheduled %s %s: %s", op, kw, ans)

    def stats(self, history: bool = False) -> dict:
        with self._timed_lock:
            scheduled = len(self._timed) + self._timed_running
        ports = {n: {"device": p.device, "frames_written": p.frames_written,
                     "frames_dropped": p.frames_dropped, "garbage": p.garbage_written}
                 for n, p in self.emulators.ports.items()}
        return {"counters": dict(self.counters), "ports": ports,
                "faults": dict(self.faults.mode), "held": self.held,
                "plant_fault": dataclasses.asdict(self.plant.fault),
                "thruster_health": self.plant.thrusters.health.tolist(),
                "timed": list(self.timed_results),
                "scheduled": scheduled,
                "leak_wet": self.leak_wet,
                "released_at_ns": self.released_at_ns,
                "can": self.can.stats(history) if self.can is not None else {}}

    # -- running --
    async def run(self, *, duration_s: float | None = None,
                  on_ready: Callable[[dict], None] | None = None,
                  stop: asyncio.Event | None = None) -> dict:
        """Run until ``stop`` is set or ``duration_s`` passed; returns the final stats."""
        self._stop = stop or asyncio.Event()
        claims = self._claim()
        try:
            return await self._run(duration_s, on_ready)
        finally:
            for c in claims:
                c.close()

    def _claim(self) -> list:
        """Hold this vehicle's bus and instrument links for this process
        (:func:`uvd.claims.claim`), before anything is opened: a second sim-bridge of the
        same configuration (one forgotten in another terminal) answered as the same CAN nodes
        beside the first — every node id twice on the bus — and took its links over."""
        from uvd.claims import Taken, bus_name, claim
        from uvd.errors import TransportError
        b = self.config.can.bus
        wanted = [("sim-link", str(Path(p).absolute())) for p in self._links.values()]
        if b.interface != "virtual":  # a bus within one process: nobody else's
            wanted.insert(0, ("sim-can", bus_name(b)))
        held: list = []
        try:
            for kind, where in wanted:
                held.append(claim(kind, where))
        except Taken as exc:
            for c in held:
                c.close()
            what = ("emulates the drives on" if kind == "sim-can" else "serves the instrument "
                    "link")
            raise TransportError(f"another sim-bridge ({exc.holder}) already {what} {where}: "
                                 "stop it first (two would answer as the same vehicle)") from None
        return held

    async def _run(self, duration_s: float | None, on_ready) -> dict:
        await asyncio.to_thread(self._open_can)
        if self.truth_path is not None:
            self.truth_path.parent.mkdir(parents=True, exist_ok=True)
            self._truth_fh = self.truth_path.open("wb")
        try:
            t0 = self.clock()
            self.emulators.start(t0_ns=t0)  # sampled by the plant loop, after each step
            plant_task = asyncio.get_running_loop().create_task(self._plant_loop(t0),
                                                                name="plant")
            import gc
            gc.collect()
            gc.freeze()  # a full collection of this heap stalls every thread for ~70 ms
            if on_ready is not None:
                on_ready(self.ready_info())
            stopped = asyncio.get_running_loop().create_task(self._stop.wait())
            await asyncio.wait({plant_task, stopped}, timeout=duration_s,
                               return_when=asyncio.FIRST_COMPLETED)
            stopped.cancel()
            self._stop.set()
            if plant_task.done() and not plant_task.cancelled() \
                    and plant_task.exception() is not None:
                # a simulator whose vehicle stopped must not run on silent, answering its
                # control channel as if alive (session 26: a depth NaN ended the plant's task
                # unseen, and every instrument fell silent for good)
                exc = plant_task.exception()
                log.error("the plant's task ended", exc_info=exc)
                raise PlantStopped(f"the simulated vehicle stopped at plant step "
                                   f"{self.counters['plant_steps']}: {type(exc).__name__}: "
                                   f"{exc}") from exc
            plant_task.cancel()
            await asyncio.wait({plant_task}, timeout=1.0)
            return self.stats(history=False)
        finally:
            await self.emulators.stop()
            await asyncio.to_thread(self.can.close)
            self._flush_truth()
            if self._truth_fh is not None:
                self._truth_fh.close()
                self._truth_fh = None

    def ready_info(self) -> dict:
        b = self.config.can.bus
        roll, pitch, heading = R_to_euler(self.H0[:3, :3])
        return {"event": "ready", "pid": os.getpid(),
                "ports": {n: {"link": str(p.link), "device": p.device}
                          for n, p in self.emulators.ports.items()},
                "can": {"interface": b.interface, "channel": b.channel, "port": b.port,
                        "nodes": list(self.config.can.amplifiers.node_ids),
                        "pressure_node": self.config.can.depth.node_id
                        if self.config.can.depth.enabled else None},
                "start_eta": [*self.H0[:3, 3], roll, pitch, heading], "held": self.held}


def _plant_fault_args(kw: dict) -> dict:
    """The :class:`PlantFault` arguments of a ``plant_fault`` command (unknown names are
    refused by name)."""
    known = {"drag_scale", "mass_scale", "g_delta", "b_delta"}
    unknown = sorted(set(kw) - known)
    if unknown:
        raise ValueError(f"unknown argument(s) {', '.join(unknown)} (known: "
                         f"{', '.join(sorted(known))})")
    out = {k: float(v) for k, v in kw.items() if k != "b_delta"}
    if "b_delta" in kw:
        b = tuple(float(x) for x in kw["b_delta"])
        if len(b) != 3:
            raise ValueError(f"b_delta must be 3 numbers (N m), not {kw['b_delta']!r}")
        out["b_delta"] = b
    return out


def read_truth(path: str | Path) -> np.ndarray:
    """The truth log as an (n, len(TRUTH_COLUMNS)) array."""
    raw = np.fromfile(path, dtype=np.float64)
    n = raw.size // len(TRUTH_COLUMNS)
    return raw[:n * len(TRUTH_COLUMNS)].reshape(n, len(TRUTH_COLUMNS))


# ----------------------------------------------------------------------------- local setup

def merge_tables(dst: dict, src: dict) -> None:
    """``src`` merged into ``dst`` table by table: a table of both merged, anything else
    replaced."""
    for k, v in src.items():
        if isinstance(v, dict) and isinstance(dst.get(k), dict):
            merge_tables(dst[k], v)
        else:
            dst[k] = v


def write_local_config(run_dir: str | Path, *, base: str | Path | None = None,
                       changes: dict | None = None) -> Path:
    """A configuration for one local simulated run, isolated from any other.

    Takes ``base`` (a file or a shipped configuration's name; the embedded ``config/sim.toml``
    by default), points the instruments at
    pseudo-terminal links in ``run_dir``, picks a fresh interface-local multicast group and
    a free UDP port for the CAN bus, records telemetry to ``run_dir/telemetry.jsonl``, keeps
    the MAVLink link's parameters and signing timestamp in ``run_dir``, and
    applies ``changes`` (``{"loop": {"rate_hz": 100.0}, …}``, merged table by table).
    Returns the path of the written ``run_dir/uvd.toml``; a ``base`` that cannot be read as TOML
    is a :class:`~uvd.io.toml.TomlFileError` naming it. Every path it writes is absolute (a
    device's port must be; before session 32, ``uvd demo --record rec`` wrote ``rec/ins`` and
    its own configuration was refused).
    """
    from uvd.io.toml import read_toml
    from uvd.shipped import DEFAULT_CONFIG, config_path
    run_dir = Path(run_dir).absolute()
    run_dir.mkdir(parents=True, exist_ok=True)
    base = config_path(base) if base is not None else DEFAULT_CONFIG
    data = read_toml(base)
    vehicle = data.get("vehicle", {}).get("name")
    if vehicle and vehicle.endswith(".toml") and not Path(vehicle).is_absolute():
        data["vehicle"]["name"] = str((base.parent / vehicle).resolve())
    sensors = data.setdefault("sensors", {})
    for name in ("ins", "dvl", "depth"):
        sensors.setdefault(name, {})["port"] = str(run_dir / name)
    if sensors.get("leak", {}).get("enabled"):
        sensors["leak"]["path"] = str(run_dir / "leak")
    a, b = (int(x) for x in np.random.default_rng().integers(1, 0xFFFF, 2))
    can = data.setdefault("can", {})
    can.update(interface="udp_multicast", channel=f"ff11::7576:{a:x}:{b:x}",
               port=free_port("udp", "::1"), loopback_only=True)
    tel = data.setdefault("telemetry", {})
    tel.setdefault("jsonl", {}).update(enabled=True, path=str(run_dir / "telemetry.jsonl"))
    if "mavlink" in data:  # what the link keeps stays with the run
        data["mavlink"].update(params_file=str(run_dir / "mavlink-params.toml"),
                               signing_timestamp_file=str(run_dir / "mavlink-signing.ts"))
    merge_tables(data, changes or {})
    path = run_dir / "uvd.toml"
    path.write_text(f"# generated by sim_bridge.bridge.write_local_config from {base}\n"
                    + dump_toml(data), encoding="utf-8")
    return path


def hil_scheduling() -> tuple[list[str], dict]:
    """Scheduling of a local HIL run: the daemon's loop at SCHED_FIFO 50, the emulated devices
    above it (60: separate hardware is never late because the vehicle computer is busy), and
    neither pinned to a CPU. Returns (sim-bridge arguments, configuration changes for the
    daemon).

    Not pinned because pinning made the loop late on a shared machine (2 CPUs, a campaign at
    nice 19 and other work beside it; ``uvd demo --fault thruster:4:0.5@20``, the loop's
    lateness max): alone, pinned (sim-bridge on CPU 0, the loop on CPU 1) 65 and 45 ms against
    0.5 and 1.2 ms unpinned; two demos at once, pinned 128 and 99 ms — both loops at FIFO 50 on
    one CPU, where equal FIFO priorities do not share time, and one daemon's drives timed out
    (every amplifier ``command_timeout`` → disarm) — against 2.1 and 0.8 ms unpinned, both
    accommodating the fault. A vehicle computer with isolated CPUs can still pin:
    ``[loop] cpu_affinity`` and sim-bridge's ``--cpu``."""
    return ["--realtime", "60"], {"loop": {"sched_fifo_priority": 50}}


def _emulator_process_base():
    from sim_bridge.amplifiers.process import EmulatorProcess
    return EmulatorProcess


class BridgeProcess(_emulator_process_base()):
    """``sim-bridge --control`` as a second process, with the JSON control channel.

    The same interface as :class:`sim_bridge.amplifiers.process.EmulatorProcess` (``start``,
    ``call``, ``stop``, ``kill``): the child exits when its standard input closes, and is
    bounded by ``duration_s`` anyway.
    """

    def __init__(self, config_path: str | Path, *, duration_s: float = 120.0, seed: int = 0,
                 hold: bool = True, truth_log: str | Path | None = None,
                 extra: list[str] | None = None) -> None:
        import sys
        super().__init__("unused", 0, duration_s=duration_s)
        self.argv = [sys.executable, "-m", "uvd", "sim-bridge", "--config", str(config_path),
                     "--control", "--duration", str(duration_s), "--seed", str(seed),
                     *(["--hold"] if hold else []),
                     *(["--truth-log", str(truth_log)] if truth_log is not None else []),
                     *(extra or [])]

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc is not None else None
