"""``uvd bench campaign``: a campaign's throughput on a LocalCluster of 1 worker and of N
workers (runs per hour, and their ratio), each in a fresh folder so nothing is resumed, and
whether the two produced the same rows bit for bit (all but ``wall_s`` and ``worker``).

The campaign is a grid of short PDC runs (``--runs``, ``--minutes`` simulated each) unless
``--spec`` names a campaign file or a built-in one.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
from pathlib import Path

from uvd.bench import Bench
from uvd.cliargs import int_in, positive_float, positive_int


def _add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--workers", type=int_in(1, 64), nargs="+", default=[1, 2],
                   help="worker counts to compare, 1..64 (default 1 2; more than the "
                        "machine's cores measures them shared)")
    p.add_argument("--runs", type=positive_int, default=16, help="runs of the default grid (16)")
    p.add_argument("--minutes", type=positive_float, default=6.0,
                   help="simulated minutes per run of the default grid (6)")
    p.add_argument("--spec", help="a campaign file or built-in name instead of the grid")


def _spec(args):
    from uvd.campaign import builtin
    from uvd.campaign.runs import kind_axes
    from uvd.campaign.spec import parse
    if args.spec:
        return builtin.resolve(args.spec)
    return parse({"campaign": {"name": "bench", "kind": "control"},
                  "axes": {"controller": "pdc", "duration_h": args.minutes / 60.0,
                           "window_min": min(1.0, args.minutes), "seed": list(range(args.runs))}},
                 kind_axes(), source="uvd bench campaign")


def run(args: argparse.Namespace) -> dict:
    from uvd.campaign.execute import run_campaign
    from uvd.campaign.store import RUN_ENVIRONMENT, RowStore

    spec = _spec(args)
    out: dict = {"campaign": spec.name, "runs": len(spec.runs),
                 "simulated_minutes_per_run": None if args.spec else args.minutes,
                 "by_workers": {}}
    rows = {}
    with tempfile.TemporaryDirectory(prefix="uvd-bench-campaign-") as tmp:
        for n in args.workers:
            load0 = os.getloadavg()[0]
            res = run_campaign(spec, Path(tmp) / f"w{n}", workers=n)
            out["by_workers"][str(n)] = {
                "workers": res.workers, "wall_s": res.wall_s, "failed": res.failed,
                "runs_per_hour": 3600.0 * res.ran / res.wall_s,
                "load_average_before": load0, "load_average_after": os.getloadavg()[0]}
            stored = list(RowStore(Path(tmp) / f"w{n}").rows())
            # the runs' own wall times: what the cluster's start-up and close are set against
            out["by_workers"][str(n)]["run_wall_s_median"] = \
                statistics.median(r["wall_s"] for r in stored) if stored else None
            rows[n] = {r["key"]: {k: v for k, v in r.items()
                                  if k not in RUN_ENVIRONMENT + ("index",)}
                       for r in stored}
    # against the fewest workers, whichever ran first (--workers 2 1 measures the same ratio
    # as 1 2, in the other order: one key in the history for both)
    least = min(args.workers)
    base = out["by_workers"][str(least)]["runs_per_hour"]
    for n in sorted(set(args.workers) - {least}):
        out[f"throughput_{n}_over_{least}"] = out["by_workers"][str(n)]["runs_per_hour"] / base
    first = rows[args.workers[0]]
    out["rows_bit_identical"] = all(rows[n] == first for n in args.workers[1:])
    return out


BENCH = Bench("campaign", "a campaign's throughput on 1 vs N Dask workers (runs per hour, "
                          "ratio) and whether the rows are bit for bit the same", run,
              _add_arguments)
