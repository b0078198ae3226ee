"""``uvd bench NAME [--json OUT] [--history FILE]``: print figures, write them, optionally record
them in the benchmark history (``make bench``: ``docs/bench/history.jsonl``, rendered as
``docs/BENCHMARKS.md`` by :mod:`uvd.bench.page`)."""

from __future__ import annotations

import json

from uvd import bench as benches
from uvd.bench.page import append_history, current_commit, new_record
from uvd.cliargs import output_file
from uvd.jsonio import write_json


def register(sub) -> None:
    p = sub.add_parser("bench", help="run a benchmark and print its figures")
    bsub = p.add_subparsers(dest="bench", metavar="NAME")
    for name, b in sorted(benches.registry().items()):
        bp = bsub.add_parser(name, help=b.summary, description=b.summary)
        bp.add_argument("--json", type=output_file, metavar="OUT",
                        help="write the figures to this file")
        bp.add_argument("--history", type=output_file, metavar="JSONL",
                        help="append the figures as one record to this benchmark history "
                             "(make bench: docs/bench/history.jsonl; python -m uvd.bench.page "
                             "renders docs/BENCHMARKS.md from it)")
        if b.add_arguments:
            b.add_arguments(bp)
        bp.set_defaults(handler=_run, bench_obj=b)
    p.set_defaults(handler=_usage, bench_parser=p)


def _usage(args) -> int:
    args.bench_parser.print_help()
    return 2


def _run(args) -> int:
    b = args.bench_obj
    figures = benches.run(b, args)
    print(json.dumps(figures, indent=2, default=float))
    if args.json:
        write_json(args.json, figures)
    if args.history:
        append_history(args.history, new_record(b.name, b.summary, figures,
                                                commit=current_commit()))
    return 0
