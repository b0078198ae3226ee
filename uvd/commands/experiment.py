"""``uvd experiment NAME --json OUT [--plots DIR] [--record DIR] [--hours H] [--seed S]``."""

from __future__ import annotations

import json
import sys
import time

from uvd import experiments
from uvd.cliargs import nonnegative_int, output_file, output_folder, simulated_hours
from uvd.jsonio import write_json
from uvd.progress import Progress


def register(sub) -> None:
    p = sub.add_parser(
        "experiment",
        help="run a lockstep (simulated-clock) experiment from the thesis",
        description="Run a lockstep experiment; `uvd experiment list` lists them.",
    )
    p.add_argument("name", help="experiment name, or 'list'")
    p.add_argument("--json", type=output_file, metavar="OUT",
                   help="write results to this JSON file")
    p.add_argument("--plots", type=output_folder, metavar="DIR",
                   help="write figures into this folder")
    p.add_argument("--record", type=output_folder, metavar="DIR",
                   help="write each control run to MCAP in DIR/<run>/ as the daemon records "
                        "(uvd report draws it; docs/recording.md)")
    p.add_argument("--hours", type=simulated_hours, help="override the simulated duration (hours)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seed of every random generator")
    p.add_argument("--quiet", action="store_true", help="no progress")
    p.set_defaults(handler=_run)


def _run(args) -> int:
    if args.name == "list":
        for name, exp in sorted(experiments.registry().items()):
            print(f"{name:24s} {exp.summary}")
        return 0
    exp = experiments.get(args.name)
    t0 = time.perf_counter()
    with Progress(exp.name, unit="s simulated", quiet=args.quiet) as p:
        opts = experiments.ExperimentOptions(
            seed=args.seed, hours=args.hours, plots=args.plots, record=args.record,
            progress=p.note, advance=lambda done, total, label: p.update(done, total, label))
        result = exp.run(opts)
    result.setdefault("experiment", exp.name)
    result.setdefault("seed", args.seed)
    result["wall_seconds"] = round(time.perf_counter() - t0, 3)
    if args.record is not None:
        files = sorted(args.record.glob("*/*.mcap"))
        result["recordings"] = [str(f) for f in files]
        if not files:
            print(f"uvd experiment: {exp.name} wrote no recording: --record covers the control "
                  "experiments (their lockstep control runs), not identification or fdc",
                  file=sys.stderr)
    if args.json:
        write_json(args.json, result)
    summary = result.get("summary")
    if summary:
        print(summary)
    else:
        print(json.dumps(result, indent=2, default=float)[:4000])
    print(f"[{exp.name}] finished in {result['wall_seconds']:.1f} s wall"
          + (f"; results in {args.json}" if args.json else ""))
    return 0
