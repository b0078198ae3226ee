"""``uvd tune [--config FILE] [--bandwidth W] [--damping Z] [--json OUT]``: per-axis PD gains
from the vehicle's mass matrix, and the closed-loop figures of the configured gains and of the
suggestion (docs/tuning.md).

Each axis's loop is sampled as the daemon runs it (:func:`uvd.control.tuning.closed_loop`): the
configuration's period, the vehicle's propeller lag, the age of the frame the cycle uses (one
period on the fixed-rate schedule, none with ``[loop] trigger = "ins"``), the hydrostatic
stiffness b₃ in roll and pitch and the quadratic drag linearised at the reference's peak speed.
The suggestion is k_p = m ω², k_d = 2ζωm with one bandwidth ω and damping ratio ζ for every
axis (default ω: the delay-limited bandwidth, ζ = 0.8), printed as the ``[control]`` lines to
paste — with the AMBC adaptation gains and mass floor scaled from the thesis's on the JHU ROV
(:func:`uvd.control.tuning.scaled_adaptation_gains`) and AID's gains scaled likewise, per DOF
(:func:`uvd.estimation.aid.scaled_aid_gains`). ``--aid-sweep S`` also chooses AID's
``gain_factors`` and ``decoupled_gain_scale`` (a gain per decoupled parameter from its
excitation) as §4.5 chose its gains, by a logarithmic sweep over an S-second simulation of the
configuration (:mod:`uvd.experiments.aid_gains`; minutes).
"""

from __future__ import annotations

import sys
from pathlib import Path

from uvd.cliargs import output_file, positive_float, positive_float_upto
from uvd.runtime.schema import AXES

DEFAULT_ZETA = 0.8


def register(sub) -> None:
    p = sub.add_parser("tune", help="per-axis PD gains from the vehicle's M and the closed-loop "
                                    "figures of the configured ones",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="configuration (default: the embedded config/sim.toml)")
    p.add_argument("--bandwidth", type=positive_float, nargs="+", metavar="W",
                   help="ω in rad/s, one for every axis or six (default: delay-limited)")
    p.add_argument("--damping", type=positive_float, nargs="+", metavar="Z",
                   default=[DEFAULT_ZETA],
                   help=f"damping ratio ζ, one or six (default {DEFAULT_ZETA})")
    p.add_argument("--aid-sweep", type=positive_float_upto(86400.0), metavar="S", default=None,
                   help="choose AID's [estimation] gain_factors by a logarithmic sweep over an "
                        "S-second lockstep simulation of this configuration (seed 1; minutes; "
                        "S at most a day)")
    p.add_argument("--json", type=output_file, metavar="OUT", help="write the figures as JSON")
    p.set_defaults(handler=_run)


def tune_figures(cfg, omega=None, zeta=DEFAULT_ZETA) -> dict:
    """The figures ``uvd tune`` prints: the loop's delays, and per axis the configured and the
    suggested gains with their closed-loop figures."""
    import numpy as np

    from uvd.control.tuning import (
        closed_loop,
        delay_limited_bandwidth,
        equivalent_damping,
        pd_gains_for,
        scaled_adaptation_gains,
    )
    from uvd.runtime.build import make_reference, pd_gains

    vehicle = cfg.load_vehicle()
    p = vehicle.params
    m = np.diag(p.M).copy()
    d = np.array([p.D[i][i, i] for i in range(6)])
    stiff = np.array([0.0, 0.0, 0.0, p.b[2], p.b[2], 0.0])
    dt = 1.0 / cfg.loop.rate_hz
    lag = float(max(t.time_constant_s for t in vehicle.thrusters))
    # the frame the cycle uses: up to a period old on the fixed schedule, fresh on the INS's
    delay = 0 if cfg.loop.trigger == "ins" else 1
    traj = make_reference(cfg)
    speed = np.zeros(6) if traj is None else np.max(
        [np.abs(traj.at(t).v) for t in np.arange(0.0, 120.0, 0.1)], axis=0)
    c = equivalent_damping(d, speed)
    w = delay_limited_bandwidth(dt, lag, delay) if omega is None else omega
    kp_s, kd_s = pd_gains_for(m, w, zeta)
    g = pd_gains(cfg)

    def table(kp, kd):
        return [vars(closed_loop(m[i], kp[i], kd[i], dt, lag, delay, stiff[i], c[i]))
                | {"axis": AXES[i]} for i in range(6)]

    configured = table(g._kp, g._kd)
    suggested = table(kp_s, kd_s)
    from uvd.io.vehicle import load_vehicle
    ref = load_vehicle("jhu-rov").params
    adapt = scaled_adaptation_gains(m, d, np.diag(ref.M), [ref.D[i][i, i] for i in range(6)])
    from uvd.estimation.aid import scaled_aid_gains
    aid = scaled_aid_gains(m, factors=cfg.estimation.gain_factors)
    return {"vehicle": vehicle.name, "rate_hz": cfg.loop.rate_hz, "lag_s": lag,
            "delay_cycles": delay, "peak_speed": speed.tolist(),
            "bandwidth": np.broadcast_to(w, (6,)).tolist(),
            "damping_ratio": np.broadcast_to(zeta, (6,)).tolist(),
            "configured": configured, "suggested": suggested,
            "adaptation": {k: v.tolist() for k, v in adapt.items()},
            "aid_gains": [aid.a, aid.gamma1, aid.gamma2, aid.gamma3, aid.gamma4],
            "aid_dof_scale": list(aid.dof_scale),
            "stable": all(r["pole_radius"] < 1.0 for r in configured)}


def _fmt(rows) -> str:
    lines = [f"{'axis':>6} {'m':>8} {'kp':>9} {'kd':>9} {'ω_n':>6} {'ζ':>6} {'|z|max':>7} "
             f"{'ζ sampled':>9}"]
    for r in rows:
        flag = "" if r["pole_radius"] < 1.0 else "  UNSTABLE"
        lines.append(f"{r['axis']:>6} {r['m']:8.3f} {r['kp']:9.3f} {r['kd']:9.3f} "
                     f"{r['omega_n']:6.2f} {r['zeta']:6.2f} {r['pole_radius']:7.4f} "
                     f"{r['zeta_sampled']:9.3f}{flag}")
    return "\n".join(lines)


def _one_or_six(v):
    return v[0] if v is not None and len(v) == 1 else v


def _beyond_the_loop(cfg, bandwidth, damping) -> str | None:
    """Why a --bandwidth or --damping cannot be tuned for, or None: a bandwidth at or above the
    loop's Nyquist frequency, π × rate_hz (no sampled loop follows it), or a pair whose gains
    overflow (session 33: ``--bandwidth 1e308`` and ``--damping 1e308`` ended in numpy's
    LinAlgError traceback on the infinite gains)."""
    import math

    nyquist = math.pi * cfg.loop.rate_hz
    for w in bandwidth or ():
        if w >= nyquist:
            return (f"--bandwidth {w:g} rad/s is at or above the loop's Nyquist frequency "
                    f"(π × [loop] rate_hz {cfg.loop.rate_hz:g} = {nyquist:.3g} rad/s): no "
                    "sampled loop follows it")
    m = max(float(x) for x in cfg.load_vehicle().params.M.diagonal())
    for w in bandwidth or (nyquist,):
        for z in damping or ():
            if not math.isfinite(2.0 * z * w * m):
                return f"--damping {z:g}: its derivative gain 2ζωm overflows"
    return None


def _toml_list(xs) -> str:
    return "[" + ", ".join(f"{x:.4g}" for x in xs) + "]"


def _run(args) -> int:
    from uvd.jsonio import write_json
    from uvd.runtime.config import ConfigValidationError, load_config

    for name, v in (("--bandwidth", args.bandwidth), ("--damping", args.damping)):
        if v is not None and len(v) not in (1, 6):
            print(f"uvd tune: {name}: one value or six, got {len(v)}: {v}", file=sys.stderr)
            return 2
    try:
        cfg = load_config(args.config)
    except ConfigValidationError as exc:
        print(str(exc), file=sys.stderr)
        return 2
    why = _beyond_the_loop(cfg, args.bandwidth, args.damping)
    if why:
        print(f"uvd tune: {why}", file=sys.stderr)
        return 2
    f = tune_figures(cfg, _one_or_six(args.bandwidth), _one_or_six(args.damping))
    print(f"{f['vehicle']} at {f['rate_hz']:g} Hz: propeller lag {f['lag_s']:g} s, frame age "
          f"{f['delay_cycles']} period(s); drag linearised at the reference's peak speed; "
          "ω_n, ζ: continuous (drag and b₃ included), |z|max and ζ sampled: the sampled loop")
    print("configured gains:")
    print(_fmt(f["configured"]))
    print(f"suggested (k_p = m ω², k_d = 2ζωm; ω {_toml_list(f['bandwidth'])} rad/s, "
          f"ζ {_toml_list(f['damping_ratio'])}):")
    print(_fmt(f["suggested"]))
    print("[control]")
    print(f"kp = {_toml_list(r['kp'] for r in f['suggested'])}")
    print(f"kd = {_toml_list(r['kd'] for r in f['suggested'])}")
    print("# AMBC: the thesis's γ_m = 1000, γ_d = 5000 on the JHU ROV, scaled per axis by "
          "m_i and |d_i|")
    for k, v in f["adaptation"].items():
        print(f"{k} = {_toml_list(v)}")
    print("[estimation]")
    print("# AID: §4.6's gains [a, γ₁…γ₄], each DOF's scaled by its mass over the JHU ROV's "
          "(scale_to_vehicle = true, the default, applies it), per-DOF scale:")
    print(f"# {_toml_list(f['aid_dof_scale'])}")
    print(f"gains = {_toml_list(f['aid_gains'])}")
    if args.aid_sweep is not None:
        from uvd.experiments.aid_gains import sweep_gain_factors
        print(f"# gain_factors by §4.5's rule: a logarithmic sweep over a {args.aid_sweep:g} s "
              "lockstep run (seed 1) …", flush=True)
        sw = sweep_gain_factors(cfg, cfg.load_vehicle(), args.aid_sweep)
        f["aid_sweep"] = sw
        for r in sw["grid"]:
            b = r["band"]
            band = "§4.6 per DOF" if b is None else f"{b[0]:g}–{b[1]:g} /s"
            print(f"#   translation ×{r['translation']:<3g} rotation ×{r['rotation']:<3g} "
                  f"rates {band:<12} error {r['error']:.3f} (M, b₃: {r['mass_b3_error']:.3f})"
                  f"{'  frozen' if r['frozen'] else ''}")
        print(f"# mean |ln(estimate/truth)| of the decoupled parameters (M's, D's diagonals, g, "
              f"b₃) after {args.aid_sweep:g} s: {sw['best_error']:.3f} (×1, ×1 §4.6 per DOF: "
              f"{sw['error_at_1_1']:.3f}); {sw['record_cpu_s']:.0f} s + "
              f"{sw['replay_cpu_s']:.0f} s CPU")
        print(f"gain_factors = {_toml_list(sw['best'])}")
        if sw["best_scale"] is not None:
            lo, hi = sw["best_band"]
            print(f"# each decoupled parameter's rate for its excitation within {lo:g}–{hi:g} "
                  "/s (m1..m6, d1..d6, g, b1, b2, b3):")
            print(f"decoupled_gain_scale = {_toml_list(sw['best_scale'])}")
    if args.json is not None:
        write_json(args.json, f)
    return 0
