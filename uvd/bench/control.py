"""``uvd bench control``: per-cycle compute time of the controllers, and lockstep throughput.

Each controller step — PDC (5.11), MBC (5.11)/(5.12), decoupled and full 241-parameter AMBC
(5.27)/(5.28) with and without robust adaptation, two-step AMBC — is timed one call at a time
along RefTraj1 with small tracking errors (what the daemon's 1 kHz loop pays per cycle), after a
warm-up that compiles the kernels. The lockstep figure times the whole simulated cycle (plant at
100 Hz, instruments, navigation, reference, two-step AMBC, allocation, recording) and
extrapolates to the 6 simulated hours of ``uvd experiment two-step``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from uvd.bench import Bench, percentiles
from uvd.cliargs import positive_float, positive_int


def _add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cycles", type=positive_int, default=20000,
                   help="timed calls per controller (default 20000)")
    p.add_argument("--lockstep-seconds", type=positive_float, default=600.0,
                   help="simulated seconds of two-step lockstep to time (default 600; "
                        "0 skips)")


def _states(n: int, seed: int = 0):
    from uvd.control.trajectory import reftraj1
    from uvd.control.types import VehicleState
    from uvd.model.lie import exp_se3

    rng = np.random.default_rng(seed)
    traj = reftraj1()
    out = []
    for k in range(n):
        ref = traj.at(0.1 * k)
        H = ref.H @ exp_se3(0.02 * rng.normal(size=6))
        out.append((VehicleState(np.ascontiguousarray(H), ref.v + 0.01 * rng.normal(size=6)),
                    ref))
    return out


def _time_controller(step, params, state0, cases, cycles: int, dt: float) -> dict:
    ctrl = state0
    for vs, ref in cases[:200]:  # warm-up (compiles)
        _, ctrl = step(vs, ref, params, ctrl, dt)
    ctrl = state0
    samples = np.empty(cycles)
    m = len(cases)
    clock = time.perf_counter_ns
    for k in range(cycles):
        vs, ref = cases[k % m]
        t0 = clock()
        _, ctrl = step(vs, ref, params, ctrl, dt)
        samples[k] = clock() - t0
    return percentiles(samples * 1e-9)


def run(args: argparse.Namespace) -> dict:
    from uvd import core
    from uvd.control.allocation import Allocator
    from uvd.control.ambc import (
        ROBUST_DAEMON_DEFAULT,
        MBCParams,
        MBCState,
        ambc_init,
        ambc_params,
        ambc_step,
        mbc_step,
        theta_of,
    )
    from uvd.control.pdc import PDGains, PDState, pdc_step
    from uvd.control.twostep import (
        two_step_init,
        two_step_params,
        two_step_reference,
        two_step_step,
    )
    from uvd.io.vehicle import load_vehicle

    cycles = int(getattr(args, "cycles", 20000))
    coupled = load_vehicle("jhu-rov-coupled")
    rov = load_vehicle("jhu-rov")
    cases = _states(2000)
    dt = 0.001
    figures: dict = {"unit": "microseconds per control cycle (one call of the step function)",
                     "cycles": cycles}
    alloc_c = Allocator.from_vehicle(coupled)
    alloc_r = Allocator.from_vehicle(rov)
    ctrls = {
        "pdc": (pdc_step, PDGains(kp=300.0, kd=100.0), PDState()),
        "mbc_full": (mbc_step, MBCParams.from_params(coupled.params), MBCState()),
    }
    for label, model, veh, alloc, robust in (
            ("ambc_full_241", "full", coupled, alloc_c, None),
            ("ambc_full_241_robust", "full", coupled, alloc_c, ROBUST_DAEMON_DEFAULT),
            ("ambc_decoupled_16", "decoupled", rov, alloc_r, None),
            ("ambc_decoupled_16_robust", "decoupled", rov, alloc_r, ROBUST_DAEMON_DEFAULT)):
        p = ambc_params(model, eps=1.0, allocator=alloc, robust=robust)
        ctrls[label] = (ambc_step, p, ambc_init(p, theta_of(veh.params, model)))
    tp = two_step_params("decoupled", eps=1.0, allocator=alloc_r, robust=ROBUST_DAEMON_DEFAULT)
    ctrls["two_step_decoupled_robust"] = (two_step_step, tp, two_step_init(tp))
    for label, (step, params, st0) in ctrls.items():
        figures[label] = _time_controller(step, params, st0, cases, cycles, dt)
    secs = float(getattr(args, "lockstep_seconds", 600.0))
    if secs > 0:
        from uvd.experiments._control_runner import run_control

        params = two_step_params("decoupled", eps=1.0, allocator=alloc_r, step1_duration_s=secs / 2)
        spec = core.ControllerSpec("two-step", two_step_step, params, two_step_init(params))
        ref = two_step_reference(step1_duration_s=secs / 2, blend_s=min(60.0, secs / 4))
        run_control(rov, spec, ref, 5.0)  # warm-up
        r = run_control(rov, spec, ref, secs, theta_every_s=10.0)
        per = r.wall_s / len(r.t)
        figures["lockstep_two_step"] = {
            "simulated_s": secs, "wall_s": r.wall_s, "us_per_control_cycle": per * 1e6,
            "real_time_factor": secs / r.wall_s,
            "extrapolated_wall_s_for_6_h": per * 6 * 3600 * 10,
        }
    return figures


BENCH = Bench(name="control", summary="per-cycle compute time of PDC, MBC and AMBC (full 241 "
              "and decoupled 16 parameters, robust on/off) and lockstep two-step throughput",
              run=run, add_arguments=_add_arguments)
