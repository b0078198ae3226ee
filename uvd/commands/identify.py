"""``uvd identify --log RUN --method aid|ls|ls-consistent --out PARAMS.toml``.

Identifies the 6-DOF UV parameters θ_UV (2.48) of a recorded run (format:
:mod:`uvd.estimation.runlog`, ``docs/experiments-identification.md``) offline:

* ``aid`` — 6-DOF AID (Theorem 4.3.1) replayed over the run at its own period, from INITP
  (Tables 4.6–4.7) or ``--init PARAMS.toml``, gains of §4.6 unless given;
* ``ls`` — least squares (§4.4); ``ls-consistent`` — the constrained fit with M positive
  definite and dissipative drag.

Writes a ``[parameters]`` TOML (loadable by every ``--params`` option) and prints a summary:
for ``aid`` how far it got (velocity-estimate error over the last minute, how far θ̂ moved);
for ``ls-consistent`` a warning naming the blocks the constraint set rather than the data
(``LSResult.active_bounds``) and, for both LS methods, the drag blocks without data.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from uvd.cliargs import output_file, positive_float
from uvd.errors import ConfigError, ParameterError


def register(sub) -> None:
    p = sub.add_parser("identify", help="identify UV parameters from a recorded run (AID or LS)",
                       description="Identify the 241 UV parameters of (2.44) from a recorded run.")
    p.add_argument("--log", type=Path, required=True, metavar="FILE", nargs="+",
                   help="recorded run: .npz or uvd run's telemetry .jsonl "
                        "(docs/experiments-identification.md); with --profile one or more "
                        "recordings of another system (ROS bag, MCAP, .tlog, .BIN; "
                        "docs/real-vehicles.md)")
    p.add_argument("--profile", metavar="NAME",
                   help="log profile (built-in name or TOML file) mapping the recordings' "
                        "topics to signals: the recordings are another system's")
    p.add_argument("--vehicle", metavar="FILE",
                   help="with --profile: the vehicle file (thrusters, thrust curves, first "
                        "guess; default: the profile's vehicle)")
    p.add_argument("--method", choices=("aid", "ls", "ls-consistent"), required=True)
    p.add_argument("--out", type=output_file, required=True, metavar="PARAMS.toml",
                   help="where to write the identified parameters")
    p.add_argument("--init", type=Path, metavar="PARAMS.toml",
                   help="aid: initial parameters (default INITP of Tables 4.6-4.7)")
    p.add_argument("--gains", metavar="a,g1,g2,g3,g4",
                   help="aid: gains a, γ1..γ4 (default 10,5000,20000,2000,2000, §4.6; with "
                        "--profile a,γ1,γ2,γ3 of the rotational law, default §4.5's with each "
                        "DOF's scaled by its inertia over the JHU ROV's, "
                        "uvd.estimation.aid.scaled_aid_gains)")
    p.add_argument("--window", type=positive_float, default=None, metavar="S",
                   help="ls: Savitzky-Golay window in seconds (default 2.1; 1.0 with "
                        "--profile)")
    p.add_argument("--linear-damping", action="store_true",
                   help="with --profile and an LS method: also identify a linear rotational "
                        "damping diag(K_p, M_q, N_r) beside (2.40)'s quadratic one, written as "
                        "the parameter file's [linear_damping] (outside the thesis's model; "
                        "docs/real-vehicles.md)")
    p.add_argument("--json", type=output_file, metavar="OUT", help="also write a summary as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress")
    p.set_defaults(handler=_run)


def identify_aid(run, theta0, gains, progress=None):
    """Replay a run through 6-DOF AID; returns the final :class:`AID6State` and the
    velocity-estimate error ∆v = v̂ − v of every sample, (n, 6). ``progress(done, total)``
    every 1000 samples."""
    from uvd.control.types import VehicleState
    from uvd.errors import ConfigError
    from uvd.estimation.aid import AID6Params, aid6_init, aid6_step, observer_problem

    why = observer_problem(gains.a, run.dt)
    if why is not None:
        raise ConfigError(f"--gains: {why} (the run's sample period)")
    prm = AID6Params(gains=gains, input_interp=run.input_interp)
    st = aid6_init(theta0)
    H = run.H
    dt = run.dt
    dv = np.empty((len(run.t), 6))
    for k in range(len(run.t)):
        st = aid6_step(VehicleState(H=H[k], v=run.v[k]), run.u[k], prm, st, dt)
        dv[k] = st.dv
        if progress is not None and k % 1000 == 999:
            progress(k + 1, len(run.t))
    return st, dv


def _convergence(run, dv, theta0, theta) -> tuple[dict, str]:
    """How far offline AID got: the velocity-estimate RMS error over the run's last minute
    relative to the run's RMS velocity, translational and angular parts (the measure of the
    aid-6dof experiment), and how far θ̂ moved from its start."""
    n = len(run.t)
    last = slice(max(0, n - int(round(60.0 / run.dt))), n)
    span = (last.stop - last.start) * run.dt

    def rel(part):
        ref = np.sqrt(np.mean(np.sum(run.v[:, part] ** 2, axis=1)))
        err = np.sqrt(np.mean(np.sum(dv[last, part] ** 2, axis=1)))
        return float(err / ref) if ref > 0 else math.inf

    trans, ang = rel(slice(0, 3)), rel(slice(3, 6))
    moved = float(np.linalg.norm(theta - theta0) / np.linalg.norm(theta0))
    info = {"velocity_estimate_window_s": span,
            "velocity_estimate_translational_relative": trans,
            "velocity_estimate_angular_relative": ang, "theta_moved_relative": moved}
    text = (f"velocity estimate over the last {span:.0f} s: RMS error {100 * trans:.2f} % "
            f"(translational), {100 * ang:.2f} % (angular) of the run's RMS velocity (never below "
            f"the velocity sensor's own noise); θ̂ moved {100 * moved:.1f} % (‖θ̂−θ₀‖/‖θ₀‖) from "
            f"its start")
    return info, text


def _bounds_note(bounds, duration_s: float) -> str:
    """The warning for a consistent fit that rests on its bounds (uvd.estimation.ls,
    "Admissible is not identified")."""
    text = (f"WARNING: the fit rests on its consistency bound for {', '.join(bounds)} (smallest "
            f"mass eigenvalue or largest symmetric drag eigenvalue within 10x of the 1e-3 "
            f"margin): the constraint, not the data, set these parameters. They are admissible "
            f"but not identified by this run ({duration_s / 60:.1f} min; Chapter 4 identified "
            f"from 32-35 min runs that excite every DOF, Table 4.5).")
    if "M" in bounds:
        text += " With M on its bound, a simulation with these parameters may diverge."
    return text


_DOF = {"1": "surge u", "2": "sway v", "3": "heave w", "4": "roll rate p", "5": "pitch rate q",
        "6": "yaw rate r"}


def _unobserved_note(blocks) -> str:
    """The note for drag blocks without data (uvd.estimation.ls.unobserved_drag)."""
    dofs = ", ".join(_DOF[b[1:]] for b in blocks)
    return (f"WARNING: no data for {', '.join(blocks)}: {dofs} stayed exactly 0 throughout the "
            f"run. These blocks, and the columns of the other drag blocks that multiply these "
            f"velocities, are not identified (ls leaves the blocks 0, ls-consistent sets them "
            f"to -1e-3 I, the least dissipative admissible drag).")


def _parse_gains(text):
    from uvd.estimation.aid import AID6Gains

    if text is None:
        return AID6Gains()
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError as exc:
        raise ConfigError(f"--gains: not numbers: {text!r}") from exc
    if len(vals) != 5:
        raise ConfigError(f"--gains needs 5 values a,g1,g2,g3,g4; got {len(vals)}")
    try:
        return AID6Gains(*vals)
    except ValueError as exc:
        raise ConfigError(f"--gains: {exc}") from exc


def _run(args) -> int:
    from uvd.estimation.aid import INITP_6DOF, aid6_params
    from uvd.estimation.ls import DiffFilter, ls_identify
    from uvd.io.params import params_from_toml, save_params
    from uvd.jsonio import write_json
    from uvd.progress import Progress
    from uvd.telemetry.recording import load_run

    if args.linear_damping and (not args.profile or args.method == "aid"):
        raise ConfigError("--linear-damping: only with --profile (the rotational model of "
                          "another system's recordings) and --method ls or ls-consistent "
                          "(AID identifies the thesis's model, which has no linear damping)")
    if args.profile:
        return _run_logs(args)
    if len(args.log) != 1:
        raise ConfigError("--log: several recordings need --profile (another system's logs); "
                          "a uvd run log is identified one at a time")
    args.log = args.log[0]
    if args.window is None:
        args.window = 2.1
    run = load_run(args.log)
    if run.stretch_note():
        print(f"{args.log}: {run.stretch_note()}")
    summary: dict = {"log": str(args.log), "method": args.method, "samples": len(run.t),
                     "duration_s": float(len(run.t) * run.dt)}
    notes: list[str] = []
    if args.method == "aid":
        init = params_from_toml(args.init) if args.init else INITP_6DOF
        try:
            with Progress("aid", unit="samples", quiet=args.quiet) as p:
                st, dv = identify_aid(run, init.theta, _parse_gains(args.gains), p.update)
        except ValueError as exc:
            raise ConfigError(f"aid: {exc}") from exc
        params = aid6_params(st)
        summary.update(frozen=st.frozen, freeze_reason=st.freeze_reason, steps=st.steps,
                       M_min_eigenvalue=st.m_min_eig,
                       final_velocity_error=float(np.linalg.norm(st.dv)))
        info, text = _convergence(run, dv, init.theta, st.theta)
        summary.update(info)
        notes.append(text)
        title = (f"6-DOF AID (Theorem 4.3.1) on {args.log.name}, {st.steps} steps"
                 + (f"; FROZEN: {st.freeze_reason}" if st.frozen else ""))
    else:
        try:
            res = ls_identify(run, "6dof", filt=DiffFilter(window_s=args.window),
                              consistent=args.method == "ls-consistent")
        except ValueError as exc:
            raise ConfigError(f"{args.method}: {exc}") from exc
        params = res.params
        summary.update(res.summary())
        title = (f"{args.method} (§4.4) on {args.log.name}: rank {res.rank}/241, "
                 f"condition {res.condition:.3g}")
        if res.unobserved:
            notes.append(_unobserved_note(res.unobserved))
        bound = tuple(b for b in res.active_bounds if b not in res.unobserved)
        if bound:
            notes.append(_bounds_note(bound, summary["duration_s"]))
    lam = params.mass_min_eigenvalue()
    try:
        params.validate(where="identified parameters")
        valid = "valid (M positive definite, drag dissipative)"
    except ParameterError as exc:
        valid = f"NOT physically valid: {exc}"
    summary["validity"] = valid
    try:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        save_params(params, args.out, title=title)
    except OSError as exc:
        raise ConfigError(f"--out {args.out}: cannot write: {exc.strerror or exc}") from exc
    print(title)
    print(f"M min eigenvalue {lam:.4g}; g = {params.g:.4g} N; b = "
          f"{np.array2string(params.b, precision=4)} N m; {valid}")
    for note in notes:
        print(note)
    print(f"wrote {args.out}")
    if args.json:
        write_json(args.json, summary)
    return 0


# _run_logs is long (~105 lines): about half of it is the command's printed report (the
# physical checks, refusals and bounds); the identification itself is
# uvd.estimation.realdata.identify_rotational.
def _run_logs(args) -> int:
    """``uvd identify --log FILE… --profile NAME``: another system's recordings."""
    import time

    from uvd.commands.reallogs import parse_gains
    from uvd.estimation.aid import scaled_aid_gains
    from uvd.estimation.realdata import (
        embed_identified,
        identify_rotational,
        refused_dofs,
        rot_of,
    )
    from uvd.io.logprofile import load_profile
    from uvd.io.logrun import load_log_runs
    from uvd.io.params import linear_damping_toml, params_from_toml, save_params
    from uvd.io.vehicle import load_vehicle
    from uvd.jsonio import write_json
    from uvd.progress import Progress

    t_start = time.process_time()
    profile = load_profile(args.profile)
    vname = args.vehicle or profile.vehicle
    if vname is None:
        raise ConfigError(f"--vehicle: profile {profile.name!r} names no vehicle; give the "
                          "vehicle file (thrusters and their thrust curves)")
    vehicle = load_vehicle(vname)
    runs, reports = load_log_runs(args.log, profile, vehicle, quiet=args.quiet)
    for rep in reports:
        print(rep.text())
    refused = refused_dofs("linear_velocity" in profile.signals, runs,
                           f"profile {profile.name!r}")
    if any(d in refused for d in ("roll", "pitch", "yaw")):
        raise ConfigError("the rotational DOFs cannot be identified: " + "; ".join(
            f"{d}: {r}" for d, r in refused.items() if d in ("roll", "pitch", "yaw")))
    if "linear_velocity" in profile.signals:
        print("NOTE: the profile has a linear velocity; this version identifies the rotational "
              "model (2.40) from real recordings and keeps the vehicle file's translation")
    first = params_from_toml(args.init) if args.init else vehicle.params
    theta0 = rot_of(first)
    if args.method == "aid":
        gains = (parse_gains(args.gains, 3) if args.gains else
                 scaled_aid_gains(np.diag(first.M), rotational=True))
        from uvd.estimation.aid import observer_problem
        why = observer_problem(gains.a, max(r.dt for r in runs))
        if why is not None:
            raise ConfigError(f"--gains: {why} (the profile's grid)")
    else:
        gains = None
    window = 1.0 if args.window is None else args.window
    n = sum(len(r) for r in runs)
    with Progress(args.method, unit="samples" if args.method == "aid" else "runs",
                  quiet=args.quiet) as pr:
        try:
            res = identify_rotational(runs, args.method, theta0=theta0, gains=gains,
                                      window_s=window, progress=pr.update,
                                      linear_damping=args.linear_damping)
        except ValueError as exc:
            raise ConfigError(f"{args.method}: {exc}") from exc
    rot = res.pop("params")
    params = embed_identified(vehicle.params, rot)
    cpu_s = time.process_time() - t_start
    lam = np.linalg.eigvalsh(np.asarray(rot.I))
    sym = [np.linalg.eigvalsh(0.5 * (c + c.T)).max() for c in np.asarray(rot.C)]
    d_lin = res.get("linear_damping")
    phys = {"inertia_positive": bool(lam[0] > 0),
            "drag_dissipative": bool(max(sym) < 0) and (d_lin is None or max(d_lin) < 0),
            "restoring_b3_positive": bool(rot.b[2] > 0)}
    title = (f"{args.method} of the rotational model (2.40) from {len(args.log)} recording(s) "
             f"({n} samples, profile {profile.name}, vehicle {vehicle.name}); translation = the "
             f"vehicle file's first guess, NOT identified")
    extra = ["", "[identified]", f"method = {args.method!r}",
             f"profile = {profile.name!r}", f"vehicle = {vehicle.name!r}",
             "logs = [" + ", ".join(repr(str(p)) for p in args.log) + "]",
             'dofs = ["roll", "pitch", "yaw"]', "", "[refused]"]
    extra += [f"{d} = {r!r}" for d, r in refused.items()]
    text = "\n".join(extra) + "\n"
    if d_lin is not None:
        text += linear_damping_toml(d_lin, "K_p, M_q, N_r (N m s/rad), identified beside (2.40)'s "
                                    "quadratic damping (--linear-damping)")
    try:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        save_params(params, args.out, title=title, extra=text)
    except OSError as exc:
        raise ConfigError(f"--out {args.out}: cannot write: {exc.strerror or exc}") from exc
    print(title)
    print(f"I diag {np.array2string(np.diag(rot.I), precision=4)} kg m2, eigenvalues min "
          f"{lam[0]:.4g}; quadratic drag diag "
          f"{np.array2string(np.array([rot.C[i][i, i] for i in range(3)]), precision=4)}; "
          f"b {np.array2string(np.asarray(rot.b), precision=4)} N m")
    if d_lin is not None:
        print(f"linear damping K_p, M_q, N_r {np.array2string(np.asarray(d_lin), precision=4)} "
              "N m s/rad")
    print("physically meaningful: " + ", ".join(f"{k} {'yes' if v else 'NO'}"
                                                 for k, v in phys.items()))
    bound = [b for b in res.get("active_bounds", []) if b not in res.get("unobserved", [])]
    if bound:
        print(_bounds_note(tuple(bound), n * runs[0].dt).replace(
            "smallest mass eigenvalue", "smallest inertia eigenvalue"))
    reasons: dict[str, list[str]] = {}
    for d, r in refused.items():
        reasons.setdefault(r, []).append(d)
    for r, ds in reasons.items():
        print(f"REFUSED {', '.join(ds)}: {r}")
    if args.method == "aid":
        print(f"AID gains a, γ1..γ3 = {res['gains']}; "
              + (f"FROZEN: {res['freeze_reason']}" if res["frozen"] else
                 f"rate-estimate RMS error over the last quarter "
                 f"{100 * res['rate_estimate_error_last_quarter']:.1f} % of the RMS rate"))
    print(f"read + identified in {cpu_s:.2f} s CPU; wrote {args.out}")
    if args.json:
        write_json(args.json, {"logs": [str(p) for p in args.log], "profile": profile.name,
                               "vehicle": vehicle.name, "method": args.method, "samples": n,
                               "reports": [r.as_dict() for r in reports], "refused": refused,
                               "I": np.asarray(rot.I).tolist(), "C": np.asarray(rot.C).tolist(),
                               "b": np.asarray(rot.b).tolist(), "physical": phys,
                               "cpu_s": cpu_s, **{k: v for k, v in res.items()
                                                  if not isinstance(v, np.ndarray)}})
    return 0
