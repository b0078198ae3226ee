"""``uvd demo``: the main job on the embedded default, the simulated ``jhu-rov``.

Until the daemon exists this is a closed-loop lockstep simulation: the PD part of (5.11)
(k_p = 300, k_d = 100, §5.3.5.1) tracking RefTraj1 (Table 5.1) for 120 simulated seconds with
thruster dynamics and Table A.1 sensor noise on; it prints a per-DOF tracking-error table.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uvd.jsonio import write_json


def register(sub) -> None:
    p = sub.add_parser("demo", help="run the simulated vehicle closed loop, print tracking errors")
    p.add_argument("--duration", type=float, default=120.0, help="simulated seconds (default 120)")
    p.add_argument("--vehicle", default="jhu-rov", help="built-in vehicle or TOML file")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, metavar="OUT", help="write the figures to this file")
    p.set_defaults(handler=_run)


def pd_reftraj1_lockstep(vehicle_name: str, seed: int, kp: float = 300.0, kd: float = 100.0):
    """The demo's simulation: PDC on RefTraj1, plant started on the reference."""
    from uvd import core
    from uvd.control.allocation import Allocator
    from uvd.control.pdc import PDGains, PDState, pdc_step
    from uvd.control.trajectory import reftraj1
    from uvd.estimation.navigation import NavConfig
    from uvd.experiments.lockstep import Lockstep, LockstepConfig
    from uvd.model.vehicle import load_vehicle

    vehicle = load_vehicle(vehicle_name)
    traj = reftraj1()
    ref0 = traj.at(0.0)
    cfg = core.CoreConfig(
        nav=NavConfig(),
        controller=core.ControllerSpec("pdc", pdc_step, PDGains(kp=kp, kd=kd), PDState()),
        reference=traj, allocator=Allocator.from_vehicle(vehicle), k_thrust=vehicle.k_thrust)
    return Lockstep(vehicle, cfg, LockstepConfig(seed=seed), H0=ref0.H,
                    v0=ref0.v)


def _run(args) -> int:
    import time

    from uvd.experiments.lockstep import format_tracking_table, run, tracking_errors

    t0 = time.perf_counter()
    run(pd_reftraj1_lockstep(args.vehicle, args.seed), 0.5)  # compiles/loads the numeric kernels
    warm = time.perf_counter() - t0
    if warm > 2.0:
        print(f"(compiled the numeric kernels in {warm:.0f} s; they are cached for later runs)")
    sim = pd_reftraj1_lockstep(args.vehicle, args.seed)
    print(f"uvd demo: PD control (k_p=300, k_d=100) tracking RefTraj1 on '{args.vehicle}' for "
          f"{args.duration:.0f} simulated s (lockstep, thruster dynamics and Table A.1 noise on)")
    log = run(sim, args.duration)
    errs = tracking_errors(log)
    print(format_tracking_table(errs, title="Tracking error (true state vs reference):"))
    sat = float(np.mean(log.saturated.any(axis=1)))
    bad = sum(s != "ok" for s in log.status)
    rtf = args.duration / max(log.wall_s, 1e-9)
    print(f"cycles not ok: {bad}; cycles with a saturated thruster: {100 * sat:.1f} %; "
          f"peak |thrust| {np.abs(log.thrust).max():.0f} N; "
          f"{log.wall_s:.2f} s wall ({rtf:.0f}x real time)")
    if args.json:
        write_json(args.json, {"tracking": errs, "cycles_not_ok": bad,
                               "saturated_fraction": sat, "wall_s": log.wall_s})
    return 0 if bad == 0 else 1
