"""``uvd bench plant``: how much faster than real time the simulated plant runs.

The ``jhu-rov-coupled`` plant (241 parameters) at 100 Hz RKMK4 with every thruster effect
(saturation, propeller lag, reversal stiction) and every instrument model (Table A.1 rates and
noise, DVLNAV) on, driven by thrust commands that sweep and reverse. ``real_time_factor`` is
simulated seconds per wall second over the whole run; per-step times come from a second, timed
pass (timing each step costs a little itself).
"""

from __future__ import annotations

import time

import numpy as np

from uvd.bench import Bench, percentiles
from uvd.cliargs import positive_float

# the plant (numba's kernels) is imported when the bench runs: ``uvd``'s command line
# registers every bench, and a command as light as ``uvd watch`` should not load it


def _add(p) -> None:
    p.add_argument("--seconds", type=positive_float, default=600.0,
                   help="simulated seconds (default 600)")
    p.add_argument("--vehicle", default="jhu-rov-coupled")
    p.add_argument("--rate", type=positive_float, default=100.0,
                   help="plant rate, Hz (default 100)")


def _commands(n_steps: int, n_thr: int, dt: float) -> np.ndarray:
    t = np.arange(n_steps)[:, None] * dt
    phase = np.arange(n_thr)[None, :]
    return 120.0 * np.sin(0.3 * t + phase) + 40.0 * np.sin(2.1 * t + 2 * phase)


def _run(args) -> dict:
    from sim_bridge.instruments.models import InstrumentConfig, Instruments
    from sim_bridge.plant import Plant, PlantConfig
    from uvd.io.vehicle import load_vehicle
    vehicle = load_vehicle(args.vehicle)
    dt = 1.0 / args.rate
    n = int(round(args.seconds * args.rate))
    cmds = _commands(n, vehicle.n_thrusters, dt)

    def fresh():
        plant = Plant(vehicle, PlantConfig(rate_hz=args.rate))
        return plant, Instruments(InstrumentConfig(), np.random.default_rng(0))

    plant, inst = fresh()
    for k in range(200):  # warm-up: JIT compile/cache load is not the plant's speed
        plant.step(cmds[k])
    plant, inst = fresh()
    step_ns = int(round(1e9 * dt))
    samples = 0
    t0 = time.perf_counter()
    for k in range(n):
        plant.step(cmds[k])
        got = inst.sample((k + 1) * step_ns, plant.H, plant.v)
        samples += sum(s is not None for s in got)
    wall = time.perf_counter() - t0

    plant, inst = fresh()
    m = min(n, 20000)
    per = np.empty(m)
    clock = time.perf_counter_ns
    for k in range(m):
        a = clock()
        plant.step(cmds[k])
        inst.sample((k + 1) * step_ns, plant.H, plant.v)
        per[k] = (clock() - a) * 1e-9
    return {
        "vehicle": vehicle.name,
        "plant_rate_hz": args.rate,
        "simulated_s": args.seconds,
        "wall_s": wall,
        "real_time_factor": args.seconds / wall,
        "steps": n,
        "instrument_samples": samples,
        "step_us": percentiles(per),
        "effects": "thrusters: saturation, lag, stiction; instruments: INS, DVL, depth, DVLNAV",
    }


BENCH = Bench(name="plant", summary="Simulated plant speed (real-time factor) with every model on",
              run=_run, add_arguments=_add)
