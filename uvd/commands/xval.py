"""``uvd xval --params PARAMS.toml --log RUN [--json OUT] [--plots DIR]``.

Cross-validation (App. A.2): simulates the parameter set open loop with the wrench of a recorded
run, from the run's first measured state, and prints the mean absolute error of roll, pitch and
the six body velocities (layout of Tables 4.12–4.13).
"""

from __future__ import annotations

from pathlib import Path

from uvd.cliargs import int_in, output_file, output_folder, positive_float


def register(sub) -> None:
    p = sub.add_parser("xval", help="cross-validate a parameter set on a recorded run (App. A.2)",
                       description="Simulate PARAMS with the inputs of RUN; MAE per state.")
    p.add_argument("--params", type=Path, required=True, metavar="PARAMS.toml")
    p.add_argument("--log", type=Path, required=True, metavar="FILE", nargs="+",
                   help="recorded run: .npz or uvd run's telemetry .jsonl "
                        "(docs/experiments-identification.md); with --profile one or more "
                        "recordings of another system (docs/real-vehicles.md)")
    p.add_argument("--profile", metavar="NAME",
                   help="log profile of the recordings (built-in name or TOML file): "
                        "rotational cross-validation over windows")
    p.add_argument("--vehicle", metavar="FILE",
                   help="with --profile: vehicle file (default: the profile's)")
    p.add_argument("--window", type=positive_float, default=2.0, metavar="S",
                   help="with --profile: restart from the recorded state every S seconds "
                        "(default 2)")
    p.add_argument("--json", type=output_file, metavar="OUT", help="write the MAE to this file")
    p.add_argument("--plots", type=output_folder, metavar="DIR",
                   help="write figures in the style of Figs. 4.5-4.7 into this folder")
    # one compiled call integrates the whole run: its SIGTERM and Ctrl-C wait for it to end
    # (--substeps 1000000000 ran on for minutes after a SIGTERM, session 33)
    p.add_argument("--substeps", type=int_in(1, 1000), default=2,
                   help="integration steps per recorded period, 1..1000 (default 2)")
    p.set_defaults(handler=_run)


def _warn_if_not_physical(path, inertia, what: str) -> None:
    """A warning on stderr when ``inertia`` (M, or the rotational I of M for --profile) is not
    positive definite: the model is simulated as given, but it is not a physical one."""
    import sys

    import numpy as np

    lam = float(np.linalg.eigvalsh(0.5 * (inertia + inertia.T))[0])
    if not lam > 0.0:
        print(f"warning: {path}: {what} is not positive definite (smallest eigenvalue "
              f"{lam:.4g}): no physical vehicle has it, and its MAE below says little",
              file=sys.stderr)


def _run(args) -> int:
    from uvd.errors import ConfigError
    from uvd.estimation.xval import STATES_6DOF, cross_validate, format_mae_table
    from uvd.io.figures import write_xval_figures
    from uvd.io.params import params_from_toml
    from uvd.jsonio import write_json
    from uvd.telemetry.recording import load_run

    if args.profile:
        return _run_logs(args)
    if len(args.log) != 1:
        raise ConfigError("--log: several recordings need --profile")
    args.log = args.log[0]
    params = params_from_toml(args.params)
    _warn_if_not_physical(args.params, params.M, "M")
    run = load_run(args.log)
    if run.stretch_note():
        print(f"{args.log}: {run.stretch_note()}")
    res = cross_validate(params, run, substeps=args.substeps)
    name = args.params.stem
    print(format_mae_table([(name, run.name, res.mae)], STATES_6DOF,
                           title=f"MAE of {args.params} on {args.log} "
                                 f"({len(run.t)} samples, {len(run.t) * run.dt / 60:.1f} min)"))
    if res.diverged_at_s is not None:
        print(f"the simulation diverged at t = {res.diverged_at_s:.1f} s")
    if args.plots:
        files = write_xval_figures(args.plots, run, {name: (res.R_sim, res.v_sim)}, STATES_6DOF)
        print(f"wrote {len(files)} figure file(s) into {args.plots}")
    if args.json:
        write_json(args.json, {"params": str(args.params), "log": str(args.log),
                               "run": run.name, "samples": len(run.t), "mae": res.mae,
                               "diverged_at_s": res.diverged_at_s})
    return 0


def _run_logs(args) -> int:
    """``uvd xval --params P --log FILE… --profile NAME``: rotational cross-validation of P on
    another system's recordings, in windows (uvd.estimation.xval.rot_xval_windows)."""
    import numpy as np

    from uvd.errors import ConfigError
    from uvd.estimation.realdata import rot_of
    from uvd.estimation.xval import STATES_ROT, format_mae_table, rot_xval_windows
    from uvd.io.figures import write_xval_figures
    from uvd.io.logprofile import load_profile
    from uvd.io.logrun import load_log_runs
    from uvd.io.params import linear_damping_from_toml, params_from_toml
    from uvd.io.vehicle import load_vehicle
    from uvd.jsonio import write_json

    if not args.window > 0:
        raise ConfigError(f"--window must be > 0, got {args.window}")
    profile = load_profile(args.profile)
    vname = args.vehicle or profile.vehicle
    if vname is None:
        raise ConfigError(f"--vehicle: profile {profile.name!r} names no vehicle")
    vehicle = load_vehicle(vname)
    params = params_from_toml(args.params)
    _warn_if_not_physical(args.params, params.M[3:, 3:], "the rotational inertia I (M[3:, 3:])")
    rot = rot_of(params)
    d_lin = linear_damping_from_toml(args.params)
    runs, reports = load_log_runs(args.log, profile, vehicle, quiet=True)
    name = args.params.stem
    rows, out = [], []
    for run in runs:
        res = rot_xval_windows(rot, run, window_s=args.window, linear_damping=d_lin,
                               substeps=args.substeps)
        rows.append((name, run.name, res.mae))
        out.append({"run": run.name, "samples": len(run), "mae": res.mae,
                    "windows": res.windows, "diverged_windows": res.diverged_windows})
        if args.plots:
            v = np.zeros((len(run), 6))
            v[:, 3:] = res.w_sim
            write_xval_figures(args.plots, run, {name: (res.R_sim, v)}, STATES_ROT,
                               prefix=f"{run.name}-")
    print(format_mae_table(rows, STATES_ROT,
                           title=f"MAE of {args.params} over {args.window:g} s windows "
                                 f"(restarted from the recorded state), profile {profile.name}"
                                 + (", with its linear damping" if d_lin is not None else "")))
    if args.json:
        write_json(args.json, {"params": str(args.params), "profile": profile.name,
                               "window_s": args.window, "runs": out})
    return 0
