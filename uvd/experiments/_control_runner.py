"""Shared machinery of the control experiments (``uvd/experiments/control.py``).

:func:`run_control` drives :class:`uvd.lockstep.Lockstep` (plant + instruments +
the one core) for a duration and records, every control cycle, the true state and the measured
(navigation) state against the reference, the commands and the applied wrench, and, every
``theta_every_s``, the controller's parameter estimate. Two kinds of tracking error are kept:

* **measured** — navigation solution vs reference, what the thesis reports (§5.3.1: "error
  between the measured and reference values"); the controller acts on this;
* **true** — plant state vs reference. x and y of the true error also contain the drift of the
  dead-reckoned navigation (DVLNAV-like, Table A.1), which no controller can remove.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numba
import numpy as np

from sim_bridge.instruments.models import InstrumentConfig
from sim_bridge.plant import PlantConfig
from sim_bridge.tank import TankEffects, attach
from sim_bridge.thrusters import ThrusterEffects
from uvd import core
from uvd.control import _kernels
from uvd.control.allocation import Allocator
from uvd.estimation.navigation import NavConfig
from uvd.geometry import wrap_angles
from uvd.lockstep import DOF_NAMES, VEL_NAMES, Lockstep, LockstepConfig
from uvd.model.lie import R_euler
from uvd.model.vehicle import Vehicle
from uvd.runtime.cycle import unsupervised


@numba.njit(cache=True)
def _eta(H, out):
    """η = [x, y, z, roll, pitch, heading] of H into ``out`` (:func:`uvd.geometry.eta_of`)."""
    out[0], out[1], out[2] = H[0, 3], H[1, 3], H[2, 3]
    out[3], out[4], out[5] = R_euler(H[:3, :3])


#: the (n, 6) records of a run, in the order of ``_record``'s ``rows`` (ControlRun's fields)
_ROWS = ("eta_true", "eta_nav", "eta_ref", "v_true", "dpsi_true", "dv_true", "dpsi_meas",
         "dv_meas", "u_cmd", "u_applied")


@numba.njit(cache=True)
def _record(k, H, v, H_nav, H_ref, v_ref, vdot_ref, dpsi_meas, dv_meas, u_cmd, u_applied,
            thrust_n, saturated, err, rows, thrust, sat):
    """Cycle k's records into row k, in one compiled call: the true, measured and reference
    pose, the true velocity and error coordinates, the controller's (Δψ, Δv), the commanded
    and applied wrench into ``rows`` ((10, n, 6), the order of :data:`_ROWS`), the thrusts
    into ``thrust`` and whether any saturated into ``sat``."""
    _eta(H, rows[0, k])
    _eta(H_nav, rows[1, k])
    _eta(H_ref, rows[2, k])
    _kernels.error_state(H, v, H_ref, v_ref, vdot_ref, err)
    for i in range(6):
        rows[3, k, i] = v[i]
        rows[4, k, i] = err[0, i]
        rows[5, k, i] = err[1, i]
        rows[6, k, i] = dpsi_meas[i]
        rows[7, k, i] = dv_meas[i]
        rows[8, k, i] = u_cmd[i]
        rows[9, k, i] = u_applied[i]
    any_saturated = False
    for j in range(thrust_n.shape[0]):
        thrust[k, j] = thrust_n[j]
        any_saturated = any_saturated or saturated[j]
    sat[k] = any_saturated


def _inner(ctrl: Any) -> Any:
    """The adaptive controller's state inside a controller's (two-step AMBC's ``ambc``)."""
    return getattr(ctrl, "ambc", ctrl)


def theta_of_ctrl(ctrl: Any) -> np.ndarray | None:
    return getattr(_inner(ctrl), "theta", None)


def theta_dot_of_ctrl(ctrl: Any) -> np.ndarray | None:
    return getattr(_inner(ctrl), "theta_dot", None)


@dataclass
class ControlRun:
    """Per-cycle records of one run (arrays of length n_cycles unless said otherwise)."""

    t: np.ndarray
    eta_true: np.ndarray
    eta_nav: np.ndarray
    eta_ref: np.ndarray
    v_true: np.ndarray
    dpsi_true: np.ndarray
    dv_true: np.ndarray
    dpsi_meas: np.ndarray
    dv_meas: np.ndarray
    u_cmd: np.ndarray
    u_applied: np.ndarray
    thrust_cmd: np.ndarray
    saturated: np.ndarray       # any thruster saturated this cycle
    not_ok: int
    theta_t: np.ndarray         # times of the θ̂ samples
    theta: np.ndarray           # (n_samples, n_params) or (0, 0)
    rates: np.ndarray           # θ̂̇ of the selected indices, every cycle
    H0: np.ndarray
    v0: np.ndarray
    final_ctrl: Any = None
    wall_s: float = 0.0
    extra: dict = field(default_factory=dict)


def make_core(vehicle: Vehicle, controller: core.ControllerSpec, reference, *,
              lag_compensation: bool = False, ff_preview_s: float = 0.0) -> core.CoreConfig:
    return core.CoreConfig(nav=NavConfig(), controller=controller, reference=reference,
                           allocator=Allocator.from_vehicle(vehicle), k_thrust=vehicle.k_thrust,
                           lag_compensation=lag_compensation, ff_preview_s=ff_preview_s)


def lockstep_cycle_record(t_ns: int, dt: float, out: core.CoreOutputs,
                          inputs: dict | None = None) -> dict:
    """The ``"cycle"`` hub record of one lockstep cycle (armed, no failsafe), as the daemon's
    write phase publishes it: what its sinks (the MCAP recorder, Zenoh's state) take."""
    from uvd.telemetry.records import CycleRecord

    nav, ref = out.nav, out.reference
    return CycleRecord(
        t_ns=t_ns, dt=dt, state="ARMED", action="none", mode=out.mode, status=out.status,
        p=nav.H[:3, 3], R=nav.H[:3, :3], v=nav.v, nav_valid=nav.valid, u=out.u_applied,
        u_cmd=out.u_cmd, thrust=out.thrust_n, ages=(None,) * 4, inputs=inputs,
        p_ref=None if ref is None else ref.H[:3, 3],
        R_ref=None if ref is None else ref.H[:3, :3],
        v_ref=None if ref is None else np.asarray(ref.v)).to_dict()


class _BlackBox:
    """``--record DIR``: the run's cycles and θ̂ on the daemon's MCAP channels
    (docs/recording.md) — the files ``uvd report`` draws — in ``DIR/<label>/``, on the
    simulated clock. No raw channels: a lockstep run reads no bytes."""

    def __init__(self, directory: Path, vehicle: Vehicle, label: str, dt: float) -> None:
        from uvd import __version__
        from uvd.links.mcap import McapRecorder

        name = label.strip(": ").replace(" ", "-") or "run"
        self.rec = McapRecorder(Path(directory) / name, rotate_mb=0.0)
        self.rec.open_now(0)
        self.dt_ns = int(round(dt * 1e9))
        self.dt = dt
        # the vehicle as a configuration's text: the report takes k of f = k ω|ω| from it
        self.rec.write_now([{"type": "start", "t_ns": 0, "version": __version__,
                             "config_toml": f'[vehicle]\nname = "{vehicle.name}"\n'}])

    def cycle(self, k: int, out: core.CoreOutputs, omega: np.ndarray) -> None:
        self.rec.write_now([lockstep_cycle_record(k * self.dt_ns, self.dt, out, inputs={
            "actuators": {"omega_rad_s": omega, "enabled": True, "faults": [],
                          "bus_off": False}})])

    def estimate(self, k: int, theta: np.ndarray) -> None:
        self.rec.write_now([{"type": "estimate", "t_ns": k * self.dt_ns,
                             "estimator": "controller", "theta": theta}])

    def close(self) -> None:
        self.rec.close_now()


# run_control is long (~105 lines): it sets up one lockstep run and records a dozen per-cycle
# arrays in its loop; the set-up and the loop share them all.
def run_control(vehicle: Vehicle, controller: core.ControllerSpec, reference, duration_s: float,
                *, seed: int = 0, noise: bool = True,
                thrusters: ThrusterEffects | None = None, control_rate_hz: float = 10.0,
                plant_rate_hz: float = 100.0, theta_every_s: float = 10.0,
                rate_indices: tuple[int, ...] = (), H0: np.ndarray | None = None,
                v0: np.ndarray | None = None,
                progress: Callable[[str], None] | None = None, label: str = "",
                progress_every_s: float = 1800.0,
                on_theta: Callable[[float, np.ndarray], None] | None = None,
                lag_compensation: bool = False, ff_preview_s: float = 0.0,
                record: Path | None = None,
                advance: Callable[[float, float, str], None] | None = None,
                tank: TankEffects | None = None,
                instruments: InstrumentConfig | None = None) -> ControlRun:
    """Run ``duration_s`` simulated seconds of ``controller`` tracking ``reference``.

    The plant starts on the reference (zero initial error) unless H0/v0 are given. Thruster
    lag, reversal stiction (§5.3.4) and saturation are on, and Table A.1 sensor noise, unless
    ``thrusters``/``noise`` say otherwise. ``lag_compensation`` turns on the core's lead
    set-points from the measured propeller speeds (:func:`uvd.control.allocation.lag_compensate`);
    ``ff_preview_s`` > 0 the feed-forward preview (``CoreConfig.ff_preview_s``).
    ``record`` (a folder): every cycle and θ̂ to MCAP as the daemon records them (``_BlackBox``).
    ``advance(done_s, total_s, label)`` is called every 100 cycles (a progress bar).
    ``tank`` switches on effects of the real vehicle the plant lacks (:mod:`sim_bridge.tank`;
    None: none); ``instruments`` replaces Table A.1's rates (its ``noise`` is ``noise``'s).
    """
    thrusters = ThrusterEffects() if thrusters is None else thrusters
    cfg = make_core(vehicle, controller, reference, lag_compensation=lag_compensation,
                    ff_preview_s=ff_preview_s)
    if H0 is None or v0 is None:
        r0 = reference.at(0.0)
        H0 = r0.H if H0 is None else H0
        v0 = r0.v if v0 is None else v0
    sim = Lockstep(vehicle, unsupervised(cfg), LockstepConfig(
        plant_rate_hz=plant_rate_hz, control_rate_hz=control_rate_hz,
        plant=PlantConfig(rate_hz=plant_rate_hz, thrusters=thrusters),
        instruments=InstrumentConfig(noise=noise) if instruments is None else
        replace(instruments, noise=noise), seed=seed), H0=H0, v0=v0)
    attach(sim, tank)
    n = int(round(duration_s * control_rate_hz))
    nthr = vehicle.n_thrusters
    rows = np.empty((len(_ROWS), n, 6))  # each rows[i] a contiguous (n, 6) record
    thrust = np.empty((n, nthr))
    sat = np.zeros(n, dtype=bool)
    rates = np.zeros((n, len(rate_indices)))
    ridx = np.asarray(rate_indices, dtype=np.int64)
    theta_every = max(1, int(round(theta_every_s * control_rate_hz)))
    th_t: list[float] = []
    th: list[np.ndarray] = []
    err = np.empty((5, 6))
    not_ok = 0
    frozen = 0
    dt = 1.0 / control_rate_hz
    t_wall = time.perf_counter()
    next_report = progress_every_s
    plant = sim.plant
    box = None if record is None else _BlackBox(record, vehicle, label, dt)
    for k in range(n):
        H = plant.H.copy()
        v = plant.v.copy()
        if box is not None:
            omega = plant.thrusters.omega.copy()
        out = sim.advance()
        if box is not None:
            box.cycle(k, out, omega)
        ref = out.reference
        ctrl = sim.state.ctrl
        inner = _inner(ctrl)  # its (Δψ, Δv): what the controller saw (every state has them)
        _record(k, H, v, out.nav.H, ref.H, ref.v, ref.vdot, inner.dpsi, inner.dv, out.u_cmd,
                out.u_applied, out.thrust_n, out.saturated, err, rows, thrust, sat)
        if out.status != "ok":
            not_ok += 1
        if getattr(inner, "frozen", False):
            frozen += 1
        if ridx.size:
            td = theta_dot_of_ctrl(ctrl)
            if td is not None and td.shape[0] > ridx.max():
                rates[k] = td[ridx]
        if k % theta_every == 0 or k == n - 1:
            theta = theta_of_ctrl(ctrl)
            if theta is not None:
                th_t.append((k + 1) * dt)
                th.append(theta.copy())
                if box is not None:
                    box.estimate(k, theta)
                if on_theta is not None:
                    on_theta((k + 1) * dt, theta)
        if advance is not None and k % 100 == 99:
            advance((k + 1) * dt, duration_s, label.strip(": ") or "simulated")
        if progress is not None and (k + 1) * dt >= next_report:
            next_report += progress_every_s
            progress(f"  {label}simulated {(k + 1) * dt / 60:.0f} / {duration_s / 60:.0f} min "
                     f"({time.perf_counter() - t_wall:.0f} s wall)")
    if box is not None:
        box.close()
    return ControlRun(t=np.arange(n) * dt, thrust_cmd=thrust, saturated=sat, not_ok=not_ok,
                      theta_t=np.array(th_t), theta=np.array(th) if th else np.zeros((0, 0)),
                      rates=rates, H0=np.array(H0), v0=np.array(v0), final_ctrl=sim.state.ctrl,
                      wall_s=time.perf_counter() - t_wall,
                      extra={"frozen_fraction": frozen / max(n, 1)},
                      **dict(zip(_ROWS, rows, strict=True)))


# ---------------------------------------------------------------------------------------------
# statistics
# ---------------------------------------------------------------------------------------------
def tracking_stats(run: ControlRun, start_s: float = 0.0, end_s: float | None = None) -> dict:
    """Per-DOF MAE and the MNE of §5.3.1 over [start_s, end_s), measured and true.

    ``position_mae`` (m, rad) per DOF of [x, y, z, roll, pitch, heading] and ``velocity_mae``
    (m/s, rad/s) per body-velocity component of Δv; ``position_mne`` = mean ‖Δψ‖,
    ``velocity_mne`` = mean ‖Δv‖ — measured (navigation vs reference) at the top level, plant
    truth under ``true``.
    """
    sel = run.t >= start_s
    if end_s is not None:
        sel &= run.t < end_s

    def block(eta: np.ndarray, dpsi: np.ndarray, dv: np.ndarray) -> dict:
        e = eta[sel] - run.eta_ref[sel]
        e[:, 3:] = wrap_angles(e[:, 3:])
        return {
            "position_mae": {nm: float(np.mean(np.abs(e[:, i])))
                             for i, nm in enumerate(DOF_NAMES)},
            "velocity_mae": {nm: float(np.mean(np.abs(dv[sel, i])))
                             for i, nm in enumerate(VEL_NAMES)},
            "position_mne": float(np.mean(np.linalg.norm(dpsi[sel], axis=1))),
            "velocity_mne": float(np.mean(np.linalg.norm(dv[sel], axis=1))),
        }

    out = block(run.eta_nav, run.dpsi_meas, run.dv_meas)
    out["true"] = block(run.eta_true, run.dpsi_true, run.dv_true)
    out["samples"] = int(np.count_nonzero(sel))
    out["window_s"] = [float(start_s), float(end_s if end_s is not None else run.t[-1] + 1e-9)]
    return out


def windows(run: ControlRun, window_s: float = 900.0, start_s: float = 0.0,
            end_s: float | None = None) -> list[dict]:
    """:func:`tracking_stats` of consecutive windows (15 minutes: Table 5.6, Fig. 5.4)."""
    end = run.t[-1] + 1e-9 if end_s is None else end_s
    out = []
    a = start_s
    while a + window_s <= end + 1e-6:
        s = tracking_stats(run, a, a + window_s)
        s["start_min"] = (a - start_s) / 60.0
        s["end_min"] = (a - start_s + window_s) / 60.0
        out.append(s)
        a += window_s
    return out


def format_windows(rows: list[dict], title: str, *, pdc: dict | None = None) -> str:
    """Table 5.6 layout: one row per window, position MAE (m, rad) and velocity MAE."""
    hdr = (f"{'block (min)':>12} " + " ".join(f"{n:>7}" for n in ("PosX", "PosY", "PosZ", "Hea",
                                                                 "Pit", "Rol"))
           + " " + " ".join(f"{n:>8}" for n in ("BodVelX", "BodVelY", "BodVelZ", "AngVelX",
                                                "AngVelY", "AngVelZ"))
           + f" {'MNE psi':>8} {'MNE v':>8}")
    lines = [title, hdr]
    order = ("x", "y", "z", "heading", "pitch", "roll")

    def row(label: str, s: dict) -> str:
        pm, vm = s["position_mae"], s["velocity_mae"]
        return (f"{label:>12} " + " ".join(f"{pm[d]:7.4f}" for d in order) + " "
                + " ".join(f"{vm[d]:8.4f}" for d in VEL_NAMES)
                + f" {s['position_mne']:8.4f} {s['velocity_mne']:8.4f}")

    if pdc is not None:
        lines.append(row("PDC", pdc))
    for s in rows:
        lines.append(row(f"{s['start_min']:.0f}-{s['end_min'] - 1:.0f}", s))
    return "\n".join(lines)


def series_summary(t: np.ndarray, x: np.ndarray, names: list[str], every_s: float) -> dict:
    """A thinned time series {"t": [...], name: [...]} sampled every ``every_s``."""
    if t.size == 0:
        return {"t": []}
    step = max(1, int(round(every_s / max(float(t[1] - t[0]) if t.size > 1 else every_s,
                                          1e-9))))
    idx = np.arange(0, t.size, step)
    if idx[-1] != t.size - 1:
        idx = np.append(idx, t.size - 1)
    out = {"t": [round(float(v), 3) for v in t[idx]]}
    for j, nm in enumerate(names):
        out[nm] = [float(v) for v in x[idx, j]]
    return out
