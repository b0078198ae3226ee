"""``uvd report RUN.mcap --out DIR [--params PARAMS.toml] [--quiet]``: ``DIR/index.html`` with
PNG figures of a black-box recording — tracking per DOF, MNE in windows (Fig. 5.4), commanded
vs realised thrust (Fig. 5.2), estimates over time, the failsafe timeline, the loop's lateness
histogram, and with ``--params`` the cross-validation of that set on the run (Figs. 4.5–4.7)
(:mod:`uvd.telemetry.report`)."""

from __future__ import annotations

import sys
from pathlib import Path

from uvd.cliargs import output_folder


def register(sub) -> None:
    p = sub.add_parser("report", help="an HTML report with figures of a black-box recording",
                       description="Write DIR/index.html and PNG figures of RUN.mcap.")
    p.add_argument("recording", type=Path, metavar="RUN.mcap")
    p.add_argument("--out", type=output_folder, required=True, metavar="DIR")
    p.add_argument("--params", type=Path, metavar="PARAMS.toml",
                   help="also cross-validate this parameter set on the run (Figs. 4.5-4.7)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(handler=_run)


def _run(args) -> int:
    from uvd.errors import ConfigError
    from uvd.progress import Progress
    from uvd.telemetry.recording import RecordingError
    from uvd.telemetry.report import write_report

    try:
        with Progress("report", quiet=args.quiet) as p:
            summary = write_report(args.recording, args.out, params=args.params,
                                   progress=lambda m: p.note(f"  {m}"))
    except (RecordingError, ConfigError) as exc:
        print(f"uvd report: {exc}", file=sys.stderr)
        return 2
    files = len(summary["files"])
    print(f"uvd report: {args.out / 'index.html'} — {summary['cycles']} cycles "
          f"({summary['armed_cycles']} armed), {len(summary['figures'])} figures"
          + (f", from the run's {files} files" if files > 1 else ""))
    if summary.get("missing_file"):
        print(f"uvd report: {summary['missing_file']}", file=sys.stderr)
    if summary.get("unreadable_messages"):
        print(f"uvd report: {summary['unreadable_messages']} unreadable message(s) skipped "
              f"(first: {summary['first_unreadable']})", file=sys.stderr)
    if summary.get("malformed_records"):
        print(f"uvd report: {summary['malformed_records']} malformed record(s) skipped "
              f"(first: {summary['first_malformed']})", file=sys.stderr)
    return 0
