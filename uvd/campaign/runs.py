"""The run functions of campaigns, by kind: each is one lockstep experiment of
:mod:`uvd.experiments` with the run's inputs, returning its figures as a flat dict of numbers,
booleans and strings (one row of the campaign's table).

* ``fdc``: a vehicle of :class:`uvd.experiments.fdc.SimVehicle` (the demo's configuration of
  that vehicle, online 6-DOF AID) watched by uvd-fdc's detector
  (:func:`uvd.experiments.fdc.watch`), a fault injected into the plant at ``onset_min`` unless
  ``fault = "none"``;
* ``control``: :func:`uvd.experiments._control_runner.run_control` of PDC or the two-step AMBC
  of ``uvd experiment two-step`` on the JHU ROV, the plant's masses and drags off the vehicle
  file's by ``mass_error`` and ``drag_error`` (the model error the controller meets).

A run that raises is not lost: :func:`execute` returns its row with the error.
"""

from __future__ import annotations

import os
import socket
import time
import traceback
from dataclasses import replace

import numpy as np

from uvd.campaign.spec import Axis, within

#: the configuration of each vehicle an fdc run may take (its demo configuration)
FDC_VEHICLES = {"jhu-rov": "sim.toml", "bluerov2-heavy": "sim-bluerov2.toml"}
FAULT_KINDS = ("none", "thruster", "drag", "mass", "buoyancy")

#: what a fault's size must be, by its kind (buoyancy: any N added to g)
_FAULT_SIZES = {"thruster": within(0.0, 1.0), "drag": within(0.0, above=True),
                "mass": within(-1.0, above=True)}


def _fault_size_problem(size: float, run) -> str | None:
    check = _FAULT_SIZES.get(run["fault"])
    why = None if check is None else check(size, run)
    return None if why is None else f"{why} for a {run['fault']} fault"


def _onset_problem(onset: float, run) -> str | None:
    start = _monitored_from_min()
    if onset < start:
        return f"must be ≥ {start:g}: the detector learns its baseline until then"
    return within(hi=MAX_HOURS * 60.0)(onset, run)


#: the most simulated time a run may ask for: a slip such as ``after_min = 1e30`` is refused by
#: name instead of running for ever (1000 h is ~2 h of one core at the lockstep's speed)
MAX_HOURS = 1000.0

#: a random generator's seed (numpy takes no negative one)
SEED = Axis(int, 0, None, "the plant's and instruments' random generator", within(0))

FDC_AXES = {
    "vehicle": Axis(str, "jhu-rov", tuple(FDC_VEHICLES), "the vehicle and its demo config"),
    "seed": SEED,
    "fault": Axis(str, "none", FAULT_KINDS, "what fails at onset_min"),
    "fault_size": Axis(float, 0.0, None, "thruster: its remaining effectiveness η (0 dead); "
                                         "drag: D's scale; mass: M's relative increase; "
                                         "buoyancy: N added to g (the net buoyancy)",
                       _fault_size_problem),
    "fault_thruster": Axis(int, 0, None, "the failing thruster (index modulo the vehicle's "
                                         "count)"),
    "onset_min": Axis(float, 30.0, None, "simulated minutes before the fault (≥ 25: the "
                                         "detector learns its baseline from 5 to 25)",
                      _onset_problem),
    "after_min": Axis(float, 30.0, None, "simulated minutes after onset_min",
                      within(0.0, MAX_HOURS * 60.0, above=True)),
    "noise_scale": Axis(float, 1.0, None, "every instrument's noise σ times this",
                        within(0.0)),
    "reference": Axis(str, "reftraj1", ("reftraj1", "reftraj2"), "the trajectory tracked "
                                                                 "(Table 5.1)"),
}

CONTROL_AXES = {
    "controller": Axis(str, "two-step", ("pdc", "two-step"), "PDC or the two-step AMBC"),
    "seed": SEED,
    "duration_h": Axis(float, 1.0, None, "simulated hours (two-step: step 1 is 1/12 of it)",
                       within(0.0, MAX_HOURS, above=True)),
    "mass_error": Axis(float, 0.0, None, "the plant's M is the vehicle file's × (1 + this)",
                       within(-1.0, above=True)),
    "drag_error": Axis(float, 0.0, None, "the plant's D is the vehicle file's × (1 + this)",
                       within(-1.0, above=True)),
    "kp": Axis(float, 300.0, None, "k_p", within(0.0)),
    "kd": Axis(float, 100.0, None, "k_d (two-step: of step 1; step 2 keeps 1000)", within(0.0)),
    "window_min": Axis(float, 15.0, None, "the tracking figures' window: the run's last minutes",
                       within(0.0, MAX_HOURS * 60.0, above=True)),
}

#: minutes from the start before uvd-fdc judges (its warm-up and baseline,
#: :class:`uvd.fdc.detector.CusumSettings`)
def _monitored_from_min() -> float:
    from uvd.fdc.detector import CusumSettings
    s = CusumSettings()
    return (s.warmup_s + s.baseline_s) / 60.0


def _instruments(noise_scale: float):
    from sim_bridge.instruments.models import InstrumentConfig
    base = InstrumentConfig()
    if noise_scale == 1.0:
        return base
    return replace(base, **{k: getattr(base, k) * noise_scale for k in (
        "heading_std_rad", "roll_pitch_std_rad", "rate_std_rad_s", "dvl_std_m_s",
        "depth_std_m")})


def _fault_args(fault: str, size: float, thruster: int) -> tuple[dict | None, str | None]:
    if fault == "none":
        return None, None
    if fault == "thruster":
        return {"health": (thruster, size)}, "thruster"
    if fault == "drag":
        return {"drag_scale": size}, "entanglement"
    if fault == "mass":
        return {"mass_scale": 1.0 + size}, "flooding"
    return {"g_delta": size}, "buoyancy"


def run_fdc(inputs: dict) -> dict:
    """One vehicle under uvd-fdc's detector; figures: detected, delay, kind and thruster
    right, or (fault-free) the false alarms and the hours monitored."""
    from uvd.experiments.fdc import SimVehicle, watch
    from uvd.runtime.config import DEFAULT_CONFIG, load_config

    config = DEFAULT_CONFIG.parent / FDC_VEHICLES[inputs["vehicle"]]
    fault = inputs["fault"]
    onset, after = inputs["onset_min"], inputs["after_min"]
    start = _monitored_from_min()
    thruster = inputs["fault_thruster"] % load_config(config).load_vehicle().n_thrusters
    args, kind = _fault_args(fault, inputs["fault_size"], thruster)
    v = SimVehicle(None if fault == "none" else fault, onset, inputs["seed"], config=config,
                   fault_args=args, expected_kind=kind,
                   instruments=_instruments(inputs["noise_scale"]),
                   reference=inputs["reference"])
    # stopped at the first alarm: every figure below is the first alarm's (the detector then
    # holds the vehicle faulty), so the rest would be simulated for nothing
    r = watch(v, onset + after, until_first=True)
    first = r["detections"][0] if r["detections"] else None
    minutes = v.k / v.rate / 60.0  # what was simulated (watch ends within one batch of the end)
    out: dict = {"simulated_h": minutes / 60.0, "alarms": len(r["detections"]),
                 "first_kind": None if first is None else first["kind"],
                 "first_channel": None if first is None else first["channel"],
                 "first_t_s": None if first is None else first["t_ns"] * 1e-9,
                 "thruster_index": thruster if fault == "thruster" else None}
    if fault == "none":
        # hours at risk: from the end of the baseline to the first alarm (after it the
        # detector holds the vehicle faulty) or the end
        end = minutes if first is None else first["t_ns"] * 1e-9 / 60.0
        out["monitored_h"] = max(0.0, end - start) / 60.0
        out["false_alarms"] = int(first is not None)  # the hours at risk end with the first
        return out
    before = r["false_alarm_before_fault"]
    out["monitored_h"] = (r["injected_at_s"] / 60.0 - start) / 60.0 if before is False else \
        (first["t_ns"] * 1e-9 / 60.0 - start) / 60.0
    out["false_alarms"] = int(bool(before))
    out["detected"] = bool(r["detected"])
    out["right_kind"] = bool(r["detected"] and r["right_kind"])
    out["right_thruster"] = (bool(r["detected"] and first["channel"] == f"thruster{thruster + 1}")
                             if fault == "thruster" else None)
    out["delay_s"] = r["latency_s"]
    return out


def run_control(inputs: dict) -> dict:
    """PDC or the two-step AMBC on the JHU ROV over a plant off its model; figures: the
    measured and true tracking MNE and per-DOF MAE of the last ``window_min``, saturation,
    and (two-step) the masses' and drags' worst relative error against the plant's."""
    from sim_bridge.plant import PlantFault
    from uvd import core
    from uvd.control.allocation import Allocator
    from uvd.control.ambc import theta_of
    from uvd.control.pdc import PDGains, PDState, pdc_step
    from uvd.control.trajectory import reftraj1
    from uvd.control.twostep import (
        two_step_init,
        two_step_params,
        two_step_reference,
        two_step_step,
    )
    from uvd.experiments import _control_runner as cr
    from uvd.experiments import control as ctl
    from uvd.io.vehicle import load_vehicle

    veh = load_vehicle("jhu-rov")
    plant_params = PlantFault(mass_scale=1.0 + inputs["mass_error"],
                              drag_scale=1.0 + inputs["drag_error"]).apply(veh.params)
    plant_veh = replace(veh, params=plant_params)
    seconds = inputs["duration_h"] * 3600.0
    kp, kd = inputs["kp"], inputs["kd"]
    preview = ctl._preview_s(veh, ctl.FF_PREVIEW, ctl.LAG_COMPENSATION)
    if inputs["controller"] == "pdc":
        spec = core.ControllerSpec("pdc", pdc_step, PDGains(kp=kp, kd=kd), PDState())
        ref = reftraj1()
        start = 0.0
        preview = 0.0
    else:
        step1 = seconds / 12.0
        params = two_step_params("decoupled", kp=kp, kd1=kd, eps1=ctl.EPS_STEP1,
                                 kd2=ctl.KD_STEP2, eps2=ctl.EPS_STEP2,
                                 allocator=Allocator.from_vehicle(veh),
                                 step1_duration_s=step1)
        spec = core.ControllerSpec("two-step-ambc", two_step_step, params,
                                   two_step_init(params))
        ref = two_step_reference(step1_duration_s=step1)
        start = step1
    run = cr.run_control(plant_veh, spec, ref, seconds, seed=inputs["seed"],
                         theta_every_s=60.0, lag_compensation=ctl.LAG_COMPENSATION,
                         ff_preview_s=preview)
    end = run.t[-1] + 1e-9
    a = float(max(start, end - inputs["window_min"] * 60.0))
    st = cr.tracking_stats(run, a, end)
    out: dict = {"simulated_h": seconds / 3600.0, "window_start_s": a,
                 "position_mne": st["position_mne"], "velocity_mne": st["velocity_mne"],
                 "true_position_mne": st["true"]["position_mne"],
                 "true_velocity_mne": st["true"]["velocity_mne"],
                 "saturated_fraction": float(run.saturated.mean()),
                 "cycles_not_ok": int(run.not_ok)}
    for dof, e in st["position_mae"].items():
        out[f"mae_{dof}"] = e
    finite = bool(np.all(np.isfinite(run.eta_true)))
    out["finite"] = finite
    if inputs["controller"] != "pdc" and run.theta.size:
        truth = theta_of(plant_params, "decoupled")
        rel = np.abs(run.theta[-1][:12] - truth[:12]) / np.abs(truth[:12])
        out["worst_mass_drag_relative_error"] = float(rel.max())
    else:
        out["worst_mass_drag_relative_error"] = None
    return out


#: kind → (its axes, its run function)
KINDS = {"fdc": (FDC_AXES, run_fdc), "control": (CONTROL_AXES, run_control)}


def kind_axes() -> dict[str, dict[str, Axis]]:
    """The axes of every kind (what :func:`uvd.campaign.spec.parse` checks against)."""
    return {k: axes for k, (axes, _) in KINDS.items()}


def execute(kind: str, inputs: dict) -> dict:
    """Run one run in this process (a Dask worker): ``{"figures": …, "error": None}`` or,
    if it raised, ``{"figures": {}, "error": "<type>: <message> | <last frames>"}``; with the
    wall time and where it ran (host, process and BLAS kernels)."""
    t0 = time.perf_counter()
    try:
        figures, error = KINDS[kind][1](dict(inputs)), None
    except Exception as exc:  # a failing run is a row with its error, never the campaign's end
        tb = traceback.format_exception(exc)
        figures, error = {}, f"{type(exc).__name__}: {exc} | {''.join(tb[-3:]).strip()}"
    return {"figures": figures, "error": error, "wall_s": time.perf_counter() - t0,
            "worker": f"{socket.gethostname()}:{os.getpid()}{_blas()}"}


def _blas() -> str:
    """`` blas SkylakeX``: the BLAS kernels of this worker (rows are bit for bit the same on
    the same kernels, docs/campaigns.md), or nothing where they cannot be told."""
    from uvd.blas import kernel_names
    names = kernel_names()
    return f" blas {names}" if names else ""
