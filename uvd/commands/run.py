"""``uvd run --config FILE``: the daemon.

Validates the configuration (an error names the file, the key and the reason, exit 2 before
anything starts), then runs :class:`uvd.runtime.daemon.Daemon` until SIGTERM/SIGINT (exit 0
after the orderly shutdown) or a failure (exit 1). ``--arm`` arms as soon as the arming
checks pass (the demo and tests; an operator link does it otherwise). ``--duration`` bounds
the run; ``--summary-json`` writes loop statistics, failsafe events and counters at exit.
"""

from __future__ import annotations

import sys
from pathlib import Path

from uvd.cliargs import output_file, positive_float


def register(sub) -> None:
    p = sub.add_parser("run", help="run the control daemon",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="configuration (default: the embedded config/sim.toml)")
    p.add_argument("--arm", action="store_true",
                   help="arm as soon as the arming checks pass (once)")
    p.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="stop by itself after S seconds (default: run until signalled)")
    p.add_argument("--summary-json", type=output_file, default=None, metavar="OUT",
                   help="write the run's summary (loop statistics, failsafe events) at exit")
    p.add_argument("--stop-with-parent", type=int, default=None, metavar="PID",
                   help="stop as on SIGTERM when process PID, which started this one, ends "
                        "however it ends (a command that runs a daemon: uvd demo)")
    p.add_argument("--log-level", default="INFO",
                   choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    p.set_defaults(handler=_run, own_signals=True)  # SIGTERM stops, SIGHUP reloads


def _run(args) -> int:
    import asyncio
    import logging

    from uvd.commands import checked_config
    from uvd.jsonio import write_json
    from uvd.runtime.app import setup_logging
    from uvd.runtime.process import stop_with_parent

    if args.stop_with_parent is not None and not stop_with_parent(args.stop_with_parent):
        print(f"uvd run: process {args.stop_with_parent}, which started it, has ended: not "
              "starting", file=sys.stderr)
        return 1
    cfg = checked_config(args.config, "run", "nothing started")
    if cfg is None:
        return 2
    listener = setup_logging(getattr(logging, args.log_level))
    logging.getLogger("canopen").setLevel(max(logging.WARNING, getattr(logging, args.log_level)))
    _say_configuration(cfg, embedded=args.config is None)
    try:
        from uvd.runtime.daemon import Daemon
        try:
            daemon = Daemon(cfg, auto_arm=args.arm)
        except Exception as exc:  # noqa: BLE001 - a driver that cannot be built: say why
            logging.getLogger("uvd.daemon").error("cannot build the daemon: %s: %s",
                                                  type(exc).__name__, exc)
            return 2

        async def main() -> int:
            if args.duration is not None:
                asyncio.get_running_loop().call_later(
                    args.duration, daemon.stop, f"--duration {args.duration:g} s elapsed")
            return await daemon.run()

        code = asyncio.run(main())
        if args.summary_json is not None:
            try:
                write_json(args.summary_json, daemon.summary())
            except OSError as exc:
                print(f"uvd run: cannot write {args.summary_json}: {exc}", file=sys.stderr)
        return code
    finally:
        listener.stop()


def _say_configuration(cfg, *, embedded: bool) -> None:
    """The log's first line: which configuration runs which vehicle; with the embedded
    default, where its instruments come from (without ``uvd sim-bridge`` the start fails
    after 5 s on the missing ``/tmp/uvd-sim/ins``, which alone does not say why)."""
    import logging
    log = logging.getLogger("uvd.daemon")
    log.info("configuration %s: vehicle %s, %s at %g Hz", cfg.source, cfg.vehicle.name,
             cfg.control.controller, cfg.loop.rate_hz)
    if embedded:
        log.info("the embedded default is the simulated vehicle: its instruments and drives "
                 "are `uvd sim-bridge`'s (start that first; `uvd demo` runs both)")
