"""``uvd bench estimation``: per-cycle compute time of the online estimators.

Times :func:`uvd.estimation.aid.aid6_step` (6-DOF AID, Theorem 4.3.1, 241 parameters) and
:func:`uvd.estimation.aid.aid3_step` (rotational AID, Theorem 4.2.1) call by call, exactly as
the core calls them (new frozen state per call), on a smooth synthetic trajectory at 1 kHz —
the daemon's loop rate, where AID must fit together with AMBC into 0.3 ms p99. Also times the
least-squares reduction and both solves on a 10-minute synthetic run, for reference.
"""

from __future__ import annotations

import time

import numpy as np

from uvd.bench import Bench, percentiles
from uvd.cliargs import positive_float, positive_int

# the numeric modules (numba's) are imported when the bench runs: ``uvd``'s command line
# registers every bench, and a command as light as ``uvd watch`` should not load them

BUDGET_US = 300.0


def _add(p) -> None:
    p.add_argument("--cycles", type=positive_int, default=20000, help="timed calls (default 20000)")
    p.add_argument("--rate", type=positive_float, default=1000.0,
                   help="loop rate, Hz (default 1000)")


def _inputs(n: int, dt: float):
    from uvd.control.types import VehicleState
    from uvd.model.lie import exp_so3, make_H
    t = np.arange(n) * dt
    v = np.column_stack([0.2 * np.cos((0.2 + 0.07 * i) * t + i) for i in range(6)])
    u = np.column_stack([60.0 * np.cos((0.25 + 0.05 * i) * t + 2 * i) for i in range(6)])
    Hs = [make_H(exp_so3(np.array([0.1 * np.sin(0.3 * s), 0.1 * np.cos(0.4 * s), 0.5 * s])),
                 np.zeros(3)) for s in t]
    return [VehicleState(H=H, v=v[k]) for k, H in enumerate(Hs)], u


def _time_steps(step, prm, st, states, u, dt, warm: int) -> tuple[np.ndarray, object]:
    for k in range(warm):
        st = step(states[k], u[k], prm, st, dt)
    n = len(states) - warm
    per = np.empty(n)
    clock = time.perf_counter_ns
    for i in range(n):
        k = warm + i
        t0 = clock()
        st = step(states[k], u[k], prm, st, dt)
        per[i] = clock() - t0
    return per * 1e-9, st


def _run(args) -> dict:
    from uvd.estimation.aid import (
        INITP_6DOF,
        INITP_ROT,
        AID3Params,
        AID6Params,
        aid3_init,
        aid3_step,
        aid6_init,
        aid6_step,
    )
    dt = 1.0 / args.rate
    warm = 2000
    states, u = _inputs(args.cycles + warm, dt)
    per6, st6 = _time_steps(aid6_step, AID6Params(), aid6_init(INITP_6DOF), states, u, dt, warm)
    per3, _ = _time_steps(aid3_step, AID3Params(), aid3_init(INITP_ROT), states, u, dt, warm)
    p6 = percentiles(per6)
    out = {
        "aid6_step_us": p6,
        "aid3_step_us": percentiles(per3),
        "loop_rate_hz": args.rate,
        "budget_us_p99_aid_plus_ambc": BUDGET_US,
        "aid6_p99_fraction_of_budget": p6["p99"] / BUDGET_US,
        "aid6_frozen_during_bench": bool(st6.frozen),
    }
    # least squares on a 10-minute, 10 Hz synthetic run (reduction + both solves)
    from uvd.estimation.ls import ls_identify, ls_reduce
    from uvd.estimation.runlog import RunLog

    n = 6000
    sts, uu = _inputs(n, 0.1)
    run = RunLog(t=np.arange(n) * 0.1, R=np.stack([s.H[:3, :3] for s in sts]),
                 p=np.zeros((n, 3)), v=np.stack([s.v for s in sts]), u=uu)
    t0 = time.perf_counter()
    red = ls_reduce(run)
    t1 = time.perf_counter()
    ls_identify(run, reduced=red)
    t2 = time.perf_counter()
    ls_identify(run, reduced=red, consistent=True)
    t3 = time.perf_counter()
    out["ls_10min_s"] = {"reduce": t1 - t0, "lstsq": t2 - t1, "consistent_socp": t3 - t2}
    return out


BENCH = Bench(name="estimation",
              summary="per-cycle time of 6-DOF and rotational AID (median, p99) at the loop rate; "
                      "LS timings",
              run=_run, add_arguments=_add)
