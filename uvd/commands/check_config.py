"""``uvd check-config [FILE] [--shipped] [--doc-out MD] [--print]``: validate a configuration
(a file, the name of a shipped one, or with ``--shipped`` every shipped one), or write its
reference.

Validation is exactly what ``uvd run`` does at start (:func:`uvd.runtime.config.load_config`),
without opening a port or a bus: on success it prints a one-line summary and exits 0; on
failure every problem is printed as ``FILE: dotted.key: reason`` and it exits 2.
``--doc-out`` writes ``docs/config.md`` generated from the schema (and refreshes the MAVLink
parameter list in the ``mavlink.md`` beside it), each whole or not at all: a write that fails
(a full disk) leaves the old file as it was and names the file.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from uvd.cliargs import output_file
from uvd.jsonio import write_whole


def register(sub) -> None:
    p = sub.add_parser("check-config", help="validate a configuration file (or write its "
                                            "reference with --doc-out)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("file", nargs="?", type=Path, metavar="FILE",
                   help="TOML configuration to validate (or the name of a shipped one: sim, "
                        "sim-bluerov2, jhu-rov)")
    p.add_argument("--shipped", action="store_true",
                   help="validate every configuration shipped with the package")
    p.add_argument("--doc-out", type=output_file, metavar="MD",
                   help="write the configuration reference generated from the schema "
                        "(docs/config.md)")
    p.add_argument("--print", dest="dump", action="store_true",
                   help="print the validated configuration (defaults filled in) as JSON")
    p.set_defaults(handler=_run, parser=p)


def _run(args) -> int:
    from uvd.runtime.config import render_config_doc, shipped_configs

    if args.file is None and args.doc_out is None and not args.shipped:
        args.parser.print_usage(sys.stderr)
        print("uvd check-config: give a FILE to validate, --shipped and/or --doc-out MD",
              file=sys.stderr)
        return 2
    if args.doc_out is not None:
        args.doc_out.parent.mkdir(parents=True, exist_ok=True)
        _write_text(args.doc_out, render_config_doc() + "\n")
        print(f"uvd check-config: wrote {args.doc_out}")
        mav = args.doc_out.with_name("mavlink.md")  # its parameter list, from the same schema
        if mav.is_file():
            from uvd.links.mavlink.params import refresh_doc
            _write_text(mav, refresh_doc(mav.read_text(encoding="utf-8")))
            print(f"uvd check-config: refreshed the parameter list in {mav}")
    files = [args.file] if args.file is not None else []
    if args.shipped:
        files += shipped_configs()
    return max((_check(f, args.dump) for f in files), default=0)


def _write_text(path: Path, text: str) -> None:
    """``text`` in ``path``, whole or not at all (:func:`uvd.jsonio.write_whole`)."""
    write_whole(path, lambda tmp: tmp.write_text(text, encoding="utf-8"),
                path.with_suffix(path.suffix + ".tmp"))


def _check(file, dump: bool) -> int:
    """Validate one configuration: 0 and a one-line summary, or 2 and every error."""
    from uvd.runtime.config import ConfigValidationError, load_config
    from uvd.runtime.schema import as_dict

    try:
        cfg = load_config(file)
    except ConfigValidationError as exc:
        n = len(exc.errors)
        print(f"uvd check-config: {file}: {n} error{'s' if n != 1 else ''}",
              file=sys.stderr)
        print(str(exc), file=sys.stderr)
        return 2
    if dump:
        print(json.dumps(as_dict(cfg), indent=2, default=str))
    print(f"{file}: OK — vehicle {cfg.vehicle.name}, loop {cfg.loop.rate_hz:g} Hz, "
          f"controller {cfg.control.controller}, INS {cfg.sensors.ins.port}, "
          f"CAN {cfg.can.bus.interface}:{cfg.can.bus.channel} "
          f"(nodes {', '.join(map(str, cfg.can.amplifiers.node_ids))})"
          + _aid_summary(cfg.estimation))
    return 0


def _aid_summary(est) -> str:
    if not est.aid:
        return ""
    found = est.resume_path()
    start = f"the last run's {found}" if found else est.initial_params or "INITP"
    saved = f", saved to {est.save_path}" if est.save_path else ", not saved"
    resume = "; resume: later runs go on from it" if est.resume and not found else ""
    return f", AID on (from {start}{saved}{resume})"
