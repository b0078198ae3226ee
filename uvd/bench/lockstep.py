"""``uvd bench lockstep``: this checkout's lockstep speed against a previous version, side by
side on this machine in one run — the figure that travels between machines is the ratio
(docs/architecture.md: timings are ratios).

The previous version is a git revision (``--old-ref``, default the commit before the campaign
work, 88767d0), checked out with ``git worktree add`` into a temporary folder (or ``--old-path``,
a checkout already there). Each side runs ``uvd experiment EXPERIMENT --hours H --json …`` in its
own Python process, the same interpreter and virtual environment, only ``PYTHONPATH`` telling
which sources; the sides alternate (old, new, new, old, …) so that a change of the machine's
load falls on both alike. Figures: each side's CPU seconds (user + system of the run's process,
which a shared machine's load changes far less than the wall time) and wall seconds, the
medians of ``--repeats``; the ratio old/new of the CPU medians (> 1: this checkout is faster),
also net of each side's start-up (the CPU of its 0.01 h warm-up run: imports, loading the
kernels), which a 6 h run spreads over 200 000 cycles; the load average; and whether the two
sides' results are bit for bit the same (the JSON minus its wall times).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from uvd.bench import Bench
from uvd.cliargs import positive_int, simulated_hours
from uvd.errors import ExperimentError

ROOT = Path(__file__).resolve().parents[2]
#: the last commit before the campaign work (issue 31): "today's code" of the issue
DEFAULT_OLD_REF = "88767d0"
#: keys whose values are timings, left out of the bit-for-bit comparison
_TIMING_KEYS = {"wall_seconds", "sim_wall_s", "wall_s", "summary"}


def _add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--experiment", default="two-step",
                   help="the lockstep experiment timed (default two-step)")
    p.add_argument("--hours", type=simulated_hours, default=0.5,
                   help="simulated hours per run (default 0.5; the experiment's own: 6)")
    p.add_argument("--repeats", type=positive_int, default=2, help="runs of each side (default 2)")
    p.add_argument("--old-ref", default=DEFAULT_OLD_REF,
                   help=f"git revision of the previous version (default {DEFAULT_OLD_REF})")
    p.add_argument("--old-path", type=Path,
                   help="a checkout of the previous version (instead of --old-ref)")


def _strip(x):
    if isinstance(x, dict):
        return {k: _strip(v) for k, v in x.items() if k not in _TIMING_KEYS}
    if isinstance(x, list):
        return [_strip(v) for v in x]
    return x


def _one(src: Path, experiment: str, hours: float, out: Path, who: str = ""
         ) -> tuple[float, float]:
    """One run in its own process: (CPU seconds, wall seconds). ``who``: the side, named in
    the error of a run that fails (:class:`~uvd.errors.ExperimentError`)."""
    env = {**os.environ, "PYTHONPATH": str(src)}
    cmd = [sys.executable, "-c", "import sys; from uvd.cli import main; sys.exit(main())",
           "experiment", experiment, "--hours", str(hours), "--json", str(out), "--quiet"]
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=src, env=env, stdout=subprocess.DEVNULL,
                       stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:  # was CalledProcessError's traceback under the child's
        last = next((ln for ln in reversed(r.stderr.splitlines()) if ln.strip()), "no output")
        raise ExperimentError(f"{who or src}: uvd experiment {experiment} --hours {hours:g} "
                              f"ended with exit code {r.returncode}: {last}")
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime), wall


def run(args: argparse.Namespace) -> dict:
    with tempfile.TemporaryDirectory(prefix="uvd-bench-lockstep-") as tmp:
        tmp = Path(tmp)
        old = args.old_path
        made = False
        if old is None:
            old = tmp / "old"
            subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(old),
                            args.old_ref], check=True, capture_output=True)
            made = True
        try:
            sides = {"old": old.resolve(), "new": ROOT}
            who = {"old": f"the old side ({args.old_ref if args.old_path is None else old})",
                   "new": "this checkout"}
            # a warm-up run of each side: numba compiles (or loads) its kernels; the second
            # one's CPU is the side's start-up
            start: dict[str, float] = {}
            for name, src in [*sides.items(), *sides.items()]:
                start[name] = _one(src, args.experiment, 0.01, tmp / f"warm-{name}.json",
                                   who[name])[0]
            walls: dict[str, list[float]] = {"old": [], "new": []}
            cpus: dict[str, list[float]] = {"old": [], "new": []}
            order = []
            for i in range(args.repeats):
                order += ["old", "new"] if i % 2 == 0 else ["new", "old"]
            load0 = os.getloadavg()
            for j, name in enumerate(order):
                cpu, wall = _one(sides[name], args.experiment, args.hours,
                                 tmp / f"{name}-{j}.json", who[name])
                cpus[name].append(cpu)
                walls[name].append(wall)
            load1 = os.getloadavg()
            res = {n: _strip(json.loads((tmp / f"{n}-{order.index(n)}.json").read_text()))
                   for n in ("old", "new")}
        finally:
            if made:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force",
                                str(old)], capture_output=True)
    med = {n: statistics.median(w) for n, w in walls.items()}
    cpu = {n: statistics.median(c) for n, c in cpus.items()}
    net = {n: cpu[n] - start[n] for n in cpu}
    return {"experiment": args.experiment, "simulated_hours": args.hours,
            "old": {"source": args.old_ref if args.old_path is None else str(args.old_path),
                    "cpu_s": cpus["old"], "median_cpu_s": cpu["old"],
                    "startup_cpu_s": start["old"], "wall_s": walls["old"],
                    "median_s": med["old"]},
            "new": {"cpu_s": cpus["new"], "median_cpu_s": cpu["new"],
                    "startup_cpu_s": start["new"], "wall_s": walls["new"],
                    "median_s": med["new"]},
            "speed_ratio_old_over_new": cpu["old"] / cpu["new"],
            "speed_ratio_net_of_startup": net["old"] / net["new"] if net["new"] > 0 else None,
            "wall_ratio_old_over_new": med["old"] / med["new"],
            "results_bit_identical": res["old"] == res["new"],
            "load_average": {"before": list(load0), "after": list(load1)}}


BENCH = Bench("lockstep", "lockstep speed of this checkout vs a previous version, side by side "
                          "(uvd experiment two-step, ratio old/new; results compared bit for "
                          "bit)", run, _add_arguments)
