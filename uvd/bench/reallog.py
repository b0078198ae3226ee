"""``uvd bench real-log [--log FILE] [--profile NAME] [--method M] [--repeat N]``: reading and
identifying one real recording at its native rates, on one core.

Default: the 2016 LiU BlueROV's ``all_2`` (61.6 s; 13 k EKF states at 210 Hz, 673 pressure and
276 thruster messages), profile ``bluerov-exjobb-april``, ``ls-consistent``. Times the whole of
what ``uvd identify --log FILE --profile …`` does after start-up — read and decode the topics
(rosbags), clean, put on one clock, map thrust, reduce and solve — as CPU seconds of this
process (one BLAS thread) and wall seconds, after one untimed warm-up run (imports, compiled
kernels, solver set-up). The target is ≤ 2 s for a 60 s recording (issue 34).
"""

from __future__ import annotations

import time
from pathlib import Path

from uvd.bench import Bench
from uvd.cliargs import positive_int

_DEFAULT = (Path(__file__).resolve().parents[2].parent / "shared" / "data" / "bluerov-exjobb"
            / "all_2_2016-04-18-14-56-58.bag")


def _add(p) -> None:
    p.add_argument("--log", type=Path, default=_DEFAULT, help="recording (default: all_2 of "
                                                              "../shared/data/bluerov-exjobb)")
    p.add_argument("--profile", default="bluerov-exjobb-april")
    p.add_argument("--vehicle", default=None, help="vehicle file (default: the profile's)")
    p.add_argument("--method", default="ls-consistent", choices=("aid", "ls", "ls-consistent"))
    p.add_argument("--repeat", type=positive_int, default=3, help="timed repetitions (default 3)")


def _run(args) -> dict:
    import numpy as np

    from uvd.errors import ExperimentError
    from uvd.estimation.aid import scaled_aid_gains
    from uvd.estimation.realdata import identify_rotational, rot_of
    from uvd.io.logprofile import load_profile
    from uvd.io.logrun import load_log_runs
    from uvd.io.vehicle import load_vehicle

    if not Path(args.log).exists():
        raise ExperimentError(f"{args.log}: recording not present")
    profile = load_profile(args.profile)
    vehicle = load_vehicle(args.vehicle or profile.vehicle)
    theta0 = rot_of(vehicle.params)
    gains = scaled_aid_gains(np.diag(vehicle.params.M), rotational=True)

    def once():
        c0, w0 = time.process_time(), time.perf_counter()
        runs, _reps = load_log_runs([args.log], profile, vehicle, quiet=True)
        c1 = time.process_time()
        identify_rotational(runs, args.method, theta0=theta0, gains=gains, window_s=1.0)
        c2, w2 = time.process_time(), time.perf_counter()
        return runs, (c1 - c0, c2 - c1, c2 - c0, w2 - w0)

    runs, _ = once()  # warm-up
    times = np.array([once()[1] for _ in range(max(1, args.repeat))])
    dur = sum(len(r) * r.dt for r in runs)
    med = np.median(times, axis=0)
    return {"log": str(args.log), "profile": profile.name, "method": args.method,
            "recording_s": float(dur), "samples_on_clock": int(sum(len(r) for r in runs)),
            "read_cpu_s": float(med[0]), "identify_cpu_s": float(med[1]),
            "total_cpu_s": float(med[2]), "total_wall_s": float(med[3]),
            "cpu_s_per_60s_recording": float(med[2] * 60.0 / dur), "target_s": 2.0}


BENCH = Bench("real-log", "read + identify one real recording at its native rates (one core)",
              _run, _add)
