"""``sim-bridge --config FILE`` (also ``uvd sim-bridge``): the simulated vehicle on the daemon's
real wire protocols.

The process's entry point, here above both sides: it reads and validates the daemon's very
configuration file (its ``[sensors]`` ports and ``[can]`` bus are the contract between the two
processes) and hands :class:`sim_bridge.bridge.SimBridge` a configuration of its own
(:func:`bridge_config`) — sim_bridge imports nothing of uvd.runtime.

Runs :class:`sim_bridge.bridge.SimBridge` until SIGTERM/SIGINT, ``--duration`` or (with
``--control``) the end of standard input. With ``--control`` it reads JSON commands on
standard input, one per line (``{"op": "sensor", "name": "ins", "mode": "silence", "id": 1}``;
see :meth:`SimBridge.call`), and answers each with one JSON line on standard output; the
first line is ``{"event": "ready", …}`` once the pseudo-terminals and CAN nodes are up, the
last ``{"event": "exit", "stats": …}``.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import signal
import sys
import threading
from pathlib import Path

from uvd.blas import single_threaded_blas
from uvd.cliargs import cpu_number, int_in, nonnegative_int, output_file, positive_float


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sim-bridge", description=__doc__.split("\n\n")[0])
    _add_arguments(p)
    return p


def register(sub) -> None:
    p = sub.add_parser("sim-bridge", help="the simulated vehicle on the daemon's wire "
                                          "protocols (as the sim-bridge command)",
                       description=__doc__.split("\n\n")[0])
    _add_arguments(p)
    p.set_defaults(handler=_run, own_signals=True)  # SIGTERM and SIGINT end its run


def bridge_config(cfg):
    """The :class:`sim_bridge.config.BridgeConfig` of a validated daemon configuration
    (:class:`uvd.runtime.config.Config`): where the daemon expects the instruments and the
    CAN nodes, the vehicle it controls, its start pose, ``[simulation.instruments]``."""
    from sim_bridge.config import BridgeConfig
    from sim_bridge.instruments.models import instrument_config

    s = cfg.sensors
    ports = {name: Path(port) for name, port in (
        ("ins", s.ins.port), ("dvl", s.dvl.port),
        ("depth", s.depth.port if s.depth.source == "serial" else None)) if port is not None}
    leak = s.leak
    return BridgeConfig(
        vehicle=cfg.load_vehicle(), trajectory=cfg.control.reference,
        start_north_m=cfg.navigation.initial_north_m, start_east_m=cfg.navigation.initial_east_m,
        serial_ports=ports, ins_protocol="ascii" if s.ins.format == "phins-ascii" else "stdbin",
        depth=s.depth.conversion, instruments=instrument_config(cfg.simulation.instruments),
        leak_path=Path(leak.path) if leak.enabled and leak.path else None,
        leak_active_level=leak.active_level, can=cfg.can)


def _add_arguments(p) -> None:
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="the daemon's configuration, a file or a shipped one's name "
                        "(default: the embedded config/sim.toml)")
    p.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="end by itself after S seconds (default: until signalled)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seed of the instrument noise")
    p.add_argument("--hold", action="store_true",
                   help="keep the vehicle at its start pose until the first thrust command")
    p.add_argument("--truth-log", type=output_file, default=None, metavar="FILE",
                   help="write the true state at every plant step (float64 rows)")
    p.add_argument("--control", action="store_true",
                   help="JSON commands on stdin, answers on stdout; exit when stdin closes")
    p.add_argument("--at", nargs=2, action="append", default=[], metavar=("S", "JSON"),
                   help="carry out a control command S seconds after the start (repeatable),"
                        " e.g. --at 60 '{\"op\": \"plant_fault\", \"drag_scale\": 1.5}' or "
                        "--at 120 '{\"op\": \"health\", \"node\": 4, \"value\": 0}'")
    p.add_argument("--realtime", type=int_in(1, 99), nargs="?", const=10, default=0, metavar="PRIO",
                   help="SCHED_FIFO priority (10 without a value) if permitted: the emulated "
                        "devices answer on time whatever else the machine runs")
    p.add_argument("--cpu", type=cpu_number, action="append", default=[], metavar="N",
                   help="run on this CPU (repeatable): keep the emulated devices off the "
                        "daemon's CPU, as separate hardware would be")


def main(argv: list[str] | None = None) -> int:
    """The ``sim-bridge`` command."""
    single_threaded_blas()  # before the bridge's modules import numpy
    return _run(build_parser().parse_args(argv))


def _late_at(args) -> str | None:
    """The first ``--at S`` at or after ``--duration``: it would never be carried out (None:
    none; an S that is not a number is named by the bridge's own check)."""
    for seconds, text in args.at:
        try:
            late = args.duration is not None and float(seconds) >= args.duration
        except ValueError:
            late = False
        if late:
            return (f"sim-bridge: --at {seconds} {text}: {seconds} s is not within --duration "
                    f"{args.duration:g} s (it would never be carried out)")
    return None


def _schedule(bridge, at: list) -> str | None:
    """Give ``bridge`` each ``--at S JSON`` command; the first it refuses, named (None:
    every one taken)."""
    for seconds, text in at:
        try:
            try:
                cmd = json.loads(text)
            except ValueError as exc:
                raise ValueError(f"not JSON ({exc})") from None
            if not (isinstance(cmd, dict) and isinstance(cmd.get("op"), str)):
                raise ValueError('not a JSON object with an "op" (e.g. {"op": "plant_fault", '
                                 '"drag_scale": 1.5})')
            ans = bridge.call(cmd.pop("op"), at_s=seconds, **cmd)
        except (ValueError, KeyError, AttributeError, TypeError) as exc:
            ans = {"ok": False, "error": f"{exc}"}
        if not ans.get("ok"):
            return f"sim-bridge: --at {seconds} {text}: {ans.get('error')}"
    return None


def _run(args) -> int:
    from sim_bridge.control_channel import JsonLines, serve_commands

    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("canopen").setLevel(logging.WARNING)
    sys.setswitchinterval(0.0005)  # answer a SYNC promptly while other threads hold the GIL
    emit = JsonLines()
    if (msg := _late_at(args)) is not None:
        print(msg, file=sys.stderr)
        emit({"event": "error", "error": msg})
        return 2

    from uvd.errors import UvdError
    from uvd.runtime.config import ConfigValidationError, load_config
    try:
        cfg = load_config(args.config)
    except ConfigValidationError as exc:
        print(f"sim-bridge: invalid configuration:\n{exc}", file=sys.stderr)
        emit({"event": "error", "error": str(exc)})
        return 2
    if args.cpu:
        try:
            os.sched_setaffinity(0, set(args.cpu))
        except (OSError, ValueError) as exc:
            print(f"sim-bridge: CPU affinity {args.cpu} refused: {exc}", file=sys.stderr)
    from sim_bridge.bridge import SimBridge
    try:
        bridge = SimBridge(bridge_config(cfg), seed=args.seed, hold=args.hold,
                           truth_log=args.truth_log)
    except (UvdError, ValueError, OSError) as exc:
        emit({"event": "error", "error": str(exc)})
        return 2
    if (msg := _schedule(bridge, args.at)) is not None:
        print(msg, file=sys.stderr)
        emit({"event": "error", "error": msg})
        return 2
    import gc
    gc.collect()  # the heavy start-up work is done at normal priority…
    gc.freeze()
    realtime = False
    thread_msgs: list[str] = []
    if args.realtime:  # …the threads started from here on inherit the priority
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.realtime))
            realtime = args.realtime
        except (OSError, AttributeError) as exc:
            print(f"sim-bridge: SCHED_FIFO {args.realtime} refused ({exc}): running with "
                  "normal scheduling", file=sys.stderr)
    if realtime:
        # …and those started before (OpenBLAS workers of numpy and scipy, anything an import
        # started) one below it, on the same CPUs: a normally scheduled thread holding the
        # GIL while other load preempts it would hold up the plant and the emulators
        from uvd.rtthreads import promote_threads
        rep = promote_threads(max(1, realtime - 1), args.cpu,
                              exclude={threading.get_native_id()})
        thread_msgs = rep.messages
        for m in thread_msgs:
            print(f"sim-bridge: {m}", file=sys.stderr)

    async def run() -> dict:
        loop = asyncio.get_running_loop()
        stop = asyncio.Event()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, stop.set)

        def control() -> None:  # stdin closed or quit: the parent is gone or done
            serve_commands(bridge.call, emit, lambda: loop.call_soon_threadsafe(stop.set))

        def ready(info: dict) -> None:
            from uvd.rtthreads import thread_table
            info["realtime"] = realtime
            info["threads"] = [t.as_dict() for t in thread_table()]
            info["thread_messages"] = thread_msgs
            emit(info)
            if args.control:
                threading.Thread(target=control, name="control", daemon=True).start()

        return await bridge.run(duration_s=args.duration, on_ready=ready, stop=stop)

    from sim_bridge.bridge import PlantStopped
    try:
        stats = asyncio.run(run())
    except (UvdError, OSError) as exc:
        emit({"event": "error", "error": f"{type(exc).__name__}: {exc}"})
        return 2
    except PlantStopped as exc:  # its traceback is in the log
        emit({"event": "error", "error": str(exc)})
        return 1
    emit({"event": "exit", "stats": stats})
    return 0


if __name__ == "__main__":
    sys.exit(main())
