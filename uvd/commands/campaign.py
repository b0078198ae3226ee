"""``uvd campaign SPEC.toml|NAME [--out DIR] [--workers N | --scheduler tcp://HOST:PORT]
[--limit N] [--report] [--json SUMMARY] [--quiet]``: many lockstep experiments as one study on Dask
(:mod:`uvd.campaign`); ``uvd campaign list`` names the built-in campaigns."""

from __future__ import annotations

import sys
from pathlib import Path

from uvd.cliargs import output_file, output_folder, positive_int, workers_count


def register(sub) -> None:
    p = sub.add_parser(
        "campaign", help="run a Monte-Carlo campaign of lockstep experiments on Dask",
        description="Run every run of a campaign file (or a built-in campaign by name) not yet "
                    "in OUT, on a local Dask cluster or a scheduler; rows go to "
                    "OUT/rows/*.parquet as runs finish (a restart resumes), the whole table to "
                    "OUT/runs.parquet, the summary to stdout. `uvd campaign list` lists the "
                    "built-in campaigns.")
    p.add_argument("spec", metavar="SPEC.toml|NAME", help="campaign file, built-in name, or "
                                                          "'list'")
    p.add_argument("--out", type=output_folder, metavar="DIR",
                   help="where the rows go (default: campaigns/<name>)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=workers_count, metavar="N",
                       help="worker processes of the local Dask cluster, at most the "
                            "machine's cores (default: all of them)")
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="a running Dask scheduler instead of a local cluster")
    p.add_argument("--report", action="store_true",
                   help="run nothing: summarise the stored rows and draw figures in "
                        "OUT/figures")
    p.add_argument("--limit", type=positive_int, metavar="N",
                   help="run at most N of the runs not yet done, in run order (a first look, "
                        "or a campaign in instalments: the rest follows on the next call)")
    p.add_argument("--json", type=output_file, metavar="SUMMARY",
                   help="write the summary (with intervals) to this JSON file")
    p.add_argument("--quiet", action="store_true", help="no progress")
    p.set_defaults(handler=_run)


def _run(args) -> int:
    from uvd.campaign import builtin
    from uvd.campaign.execute import run_campaign
    from uvd.campaign.store import RowStore, code_version, run_key
    from uvd.campaign.summary import format_summary, summarize
    from uvd.jsonio import write_json
    from uvd.progress import Progress

    if args.spec == "list":
        for name, spec in builtin.campaigns().items():
            print(f"{name:20s} {len(spec.runs):5d} runs  {spec.description}")
        return 0
    spec = builtin.resolve(args.spec)
    out = args.out if args.out is not None else Path("campaigns") / spec.name
    if not args.report:
        from uvd.claims import Taken, claim
        try:  # held to the end: a second campaign into the folder ran every run again beside
            held = claim("campaign", str(Path(out).resolve()))  # it (session 34)
        except Taken as exc:
            print(f"uvd campaign: {out} is being filled by another campaign ({exc.holder}): "
                  "wait for it (its rows are kept, a later run skips them) or give another "
                  "--out", file=sys.stderr)
            return 2
        with held, Progress(spec.name, unit="runs", quiet=args.quiet, every_s=30.0) as p:
            def on_row(row: dict, done: int, todo: int) -> None:
                if row["error"] is not None:
                    p.note(f"  run {row['index']} failed: {row['error'][:300]}")
                p.update(done, todo)
            done = RowStore(out).done()
            n_done = sum(1 for i in spec.runs if run_key(spec.kind, i, code_version()) in done)
            p.note(f"campaign {spec.name}: {len(spec.runs)} runs, {n_done} already in {out}")
            res = run_campaign(spec, out, workers=args.workers, scheduler=args.scheduler,
                               on_row=on_row, limit=args.limit)
        print(f"campaign {spec.name}: ran {res.ran} ({res.failed} failed) on {res.workers} "
              f"worker(s) in {res.wall_s:.1f} s; {res.skipped} were done before")
    store = RowStore(out)
    keys = [run_key(spec.kind, i, code_version()) for i in spec.runs]
    rows = store.rows(keys)
    if len(rows) < len(keys):
        print(f"campaign {spec.name}: {len(rows)} of {len(keys)} runs in {out} (of this code "
              "version); the summary covers those", file=sys.stderr)
    summary = summarize(spec.kind, rows)
    print(format_summary(spec.kind, summary))
    if args.json:
        write_json(args.json, {"campaign": spec.name, "kind": spec.kind,
                               "description": spec.description, "summary": summary})
    if args.report:
        from uvd.campaign.report import write_figures
        files = write_figures(spec.kind, summary, rows, out / "figures")
        print(f"figures: {', '.join(str(f) for f in files)}")
    return 0
