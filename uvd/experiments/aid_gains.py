"""AID's gains for a vehicle by the thesis's own rule: a logarithmic sweep in simulation (§4.5).

§4.5 chose AID's gains "from simulations which sparsely covered a roughly logarithmic scaling
for a range of possible gains"; §4.6 took them over for the 6-DOF law. This module does the
same for the configured vehicle and reference: one lockstep run of the configuration (its
vehicle, controller, reference, instruments and their noise, failsafes; ``seed`` other than
the demo's so the gains are not chosen on the run they are judged on; an INS outage halfway,
:data:`OUTAGE_S`, so the run holds a failsafe and a re-arm) records what AID sees each cycle
(R, v = [ν; ω], the applied wrench u, dt), and the excitation of each of the 16 decoupled
parameters over it (:func:`uvd.estimation.aid.decoupled_excitation`); AID (Theorem 4.3.1) is
then replayed over that record for every pair of per-DOF gain factors (translation, rotation) on
a logarithmic grid, each with §4.6's per-DOF gains alone and with each band of rates
(:data:`BANDS`) the decoupled parameters' gains are scaled into for their excitation
(:func:`uvd.estimation.aid.excitation_gain_scale`), with the gains and INITP of
``[estimation] scale_to_vehicle`` (:func:`uvd.estimation.aid.scaled_aid_gains`,
:func:`~uvd.estimation.aid.scaled_initp`). Each is scored by how far the final decoupled
parameters are from the plant's (the vehicle file's) values: the mean of |ln(θ̂ᵢ/θᵢ)| over the
14 whose truth is not zero (:func:`decoupled_error`; ∞ when one has the wrong sign or AID
froze). The best gives ``[estimation] gain_factors`` and ``decoupled_gain_scale``. Used by
``uvd tune --aid-sweep S``.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

#: the logarithmic grid of per-DOF gain factors (translation and rotation each)
FACTORS = (1.0, 3.0, 10.0, 30.0, 100.0)

#: INS silence halfway through the sweep's run (s): longer than the configured ins_stale_s
#: of the shipped configurations (0.25 s), so the failsafe zeroes the thrust and, a second
#: later, the controller re-arms with a jump of wrench — what a HIL demo run on a loaded
#: machine met (docs/real-vehicles.md). Gains that only survive a smooth run are not chosen.
OUTAGE_S = 0.3


def record_aid_inputs(cfg, vehicle, duration_s: float, seed: int,
                      outage_s: float = OUTAGE_S) -> dict[str, np.ndarray]:
    """One lockstep run of ``cfg`` through the daemon's cycle (failsafes included;
    ``duration_s`` simulated, instrument noise ``seed``), the INS silent for ``outage_s``
    halfway; returns what the online AID sees each cycle: ``H`` (n, 4, 4), ``v`` (n, 6),
    ``u`` (n, 6), ``dt`` (n,)."""
    from uvd.estimation.aid import aid6_estimator
    from uvd.lockstep import Lockstep, lockstep_config
    from uvd.runtime.build import make_cycle, start_pose

    H, v, u, dts = [], [], [], []

    def step(vs, u_applied, params, st, dt):
        H.append(np.array(vs.H, dtype=float))
        v.append(np.array(vs.v, dtype=float))
        u.append(np.array(u_applied, dtype=float))
        dts.append(float(dt))
        return st

    spec = dataclasses.replace(aid6_estimator(), step=step, name="aid6-record")
    H0, v0 = start_pose(cfg)
    sim = Lockstep(vehicle, make_cycle(cfg, vehicle, estimators=(spec,)),
                   lockstep_config(cfg, seed), H0=H0, v0=v0)
    n = int(round(duration_s / sim.dt_control))
    for k in range(n):
        if outage_s > 0.0 and k == n // 2:
            sim.faults.set("ins", "silence", outage_s)
        sim.advance()
    return {"H": np.array(H), "v": np.array(v), "u": np.array(u), "dt": np.array(dts)}


def replay_aid(rec: dict[str, np.ndarray], theta0: np.ndarray, params):
    """AID (:func:`uvd.estimation.aid.aid6_step`) over a record of
    :func:`record_aid_inputs`; the final state."""
    from uvd.control.types import VehicleState
    from uvd.estimation.aid import aid6_init, aid6_step

    st = aid6_init(theta0)
    for k in range(rec["dt"].shape[0]):
        st = aid6_step(VehicleState(rec["H"][k], rec["v"][k]), rec["u"][k], params, st,
                       rec["dt"][k] if k else 0.0)
    return st


def convergence_error(theta: np.ndarray, truth) -> float:
    """Mean |ln(θ̂ᵢ/θᵢ)| over M̂'s diagonal and b̂₃ against ``truth`` (UVParams); ∞ if an
    estimate is ≤ 0."""
    from uvd.model.params import params_from_theta

    p = params_from_theta(theta)
    est = np.r_[np.diag(p.M), p.b[2]]
    ref = np.r_[np.diag(truth.M), truth.b[2]]
    if np.any(est <= 0) or np.any(ref <= 0):
        return float("inf")
    return float(np.mean(np.abs(np.log(est / ref))))


def decoupled_error(theta: np.ndarray, truth) -> float:
    """Mean |ln(θ̂ᵢ/θᵢ)| over every decoupled parameter whose true value is not zero (M's
    and the Dᵢ's diagonals, g, b₃ on a decoupled plant: 14 numbers); ∞ if one has the wrong
    sign (a drag that feeds energy in, a negative mass)."""
    from uvd.model.params import DECOUPLED_INDEX, theta_from

    ref = theta_from(truth)[DECOUPLED_INDEX]
    est = np.asarray(theta, dtype=float)[DECOUPLED_INDEX]
    keep = ref != 0
    r = est[keep] / ref[keep]
    if np.any(~(r > 0)):
        return float("inf")
    return float(np.mean(np.abs(np.log(r))))


#: bands (ρ_lo, ρ_hi) (1/s) each decoupled parameter's rate for its own excitation is brought
#: into (:func:`uvd.estimation.aid.excitation_gain_scale`); None: §4.6's per-DOF gains alone
BANDS = (None, (0.003, 0.1), (0.003, 0.3), (0.01, 0.1), (0.01, 0.3), (0.03, 0.1), (0.03, 0.3))

#: the gain factors swept with each band
SWEEP_FACTORS = (1.0, 3.0, 10.0)


def sweep_gain_factors(cfg, vehicle, duration_s: float = 120.0, seed: int = 1,
                       factors=SWEEP_FACTORS, bands=BANDS) -> dict:
    """The sweep of the module docstring; returns the grid's scores, the best pair, the best
    band and its 16 multipliers (``[estimation] decoupled_gain_scale``), the excitation, and
    the CPU seconds of the lockstep run and of the replays."""
    from dataclasses import replace

    from uvd.estimation.aid import (
        AID6Gains,
        AID6Params,
        decoupled_excitation,
        entry_scale_of,
        excitation_gain_scale,
        scaled_aid_gains,
        scaled_initp,
    )

    c0 = time.process_time()
    rec = record_aid_inputs(cfg, vehicle, duration_s, seed)
    c1 = time.process_time()
    exc = decoupled_excitation(rec["H"], rec["v"], rec["dt"], vehicle.params.M)
    theta0 = scaled_initp(vehicle.params).theta
    masses = np.diag(vehicle.params.M)
    base = AID6Gains(*cfg.estimation.gains)
    grid = []
    for kt in factors:
        for kr in factors:
            gains = scaled_aid_gains(masses, base=base, factors=(kt, kr))
            for band in bands:
                w = None if band is None else excitation_gain_scale(exc, gains, band)
                g = gains if w is None else replace(gains, entry_scale=entry_scale_of(w))
                st = replay_aid(rec, theta0, AID6Params(gains=g))
                bad = st.frozen
                grid.append({"translation": kt, "rotation": kr,
                             "band": None if band is None else list(band),
                             "error": float("inf") if bad else decoupled_error(st.theta,
                                                                               vehicle.params),
                             "mass_b3_error": float("inf") if bad else convergence_error(
                                 st.theta, vehicle.params),
                             "frozen": bool(st.frozen),
                             "scale": None if w is None else w.tolist()})
    best = min(grid, key=lambda r: r["error"])
    return {"duration_s": duration_s, "seed": seed, "cycles": int(rec["dt"].shape[0]),
            "excitation": exc.tolist(), "grid": grid,
            "best": [best["translation"], best["rotation"]], "best_band": best["band"],
            "best_scale": best["scale"], "best_error": best["error"],
            "error_at_1_1": next((r["error"] for r in grid if r["translation"] == 1.0
                                  and r["rotation"] == 1.0 and r["band"] is None), None),
            "record_cpu_s": c1 - c0, "replay_cpu_s": time.process_time() - c1}
