"""``uvd bench NAME --json OUT [--report FILE]``: print figures, write them, optionally append."""

from __future__ import annotations

import datetime as _dt
import json
import platform
from pathlib import Path

from uvd import bench as benches
from uvd.jsonio import write_json


def register(sub) -> None:
    p = sub.add_parser("bench", help="run a benchmark and print its figures")
    bsub = p.add_subparsers(dest="bench", metavar="NAME")
    for name, b in sorted(benches.registry().items()):
        bp = bsub.add_parser(name, help=b.summary, description=b.summary)
        bp.add_argument("--json", type=Path, metavar="OUT", help="write the figures to this file")
        bp.add_argument("--report", type=Path, metavar="MD",
                        help="append the figures to this Markdown file "
                             "(make bench: docs/BENCHMARKS.md)")
        if b.add_arguments:
            b.add_arguments(bp)
        bp.set_defaults(handler=_run, bench_obj=b)
    p.set_defaults(handler=_usage, bench_parser=p)


def _usage(args) -> int:
    args.bench_parser.print_help()
    return 2


def _run(args) -> int:
    b = args.bench_obj
    figures = b.run(args)
    figures.setdefault("bench", b.name)
    figures.setdefault("machine", {"python": platform.python_version(),
                                   "processor": platform.machine(),
                                   "cpus": __import__("os").cpu_count()})
    text = json.dumps(figures, indent=2, default=float)
    print(text)
    if args.json:
        write_json(args.json, figures)
    if args.report:
        args.report.parent.mkdir(parents=True, exist_ok=True)
        stamp = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
        with args.report.open("a") as fh:
            fh.write(f"\n## `uvd bench {b.name}` — {stamp}\n\n{b.summary}\n\n"
                     f"```json\n{text}\n```\n")
    return 0
