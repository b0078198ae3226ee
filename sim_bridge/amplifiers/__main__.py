"""Run the emulated amplifiers (and pressure transmitter) as their own process.

    python -m sim_bridge.amplifiers --interface udp_multicast --channel ff11::7576:6463 \\
        --port 43113 --duration 60 [--control] [--pressure-node 32]

Prints one JSON line ``{"event": "ready", ...}`` once every node has booted, and
``{"event": "exit", "stats": {...}}`` when it ends: after ``--duration`` seconds, on SIGTERM or
SIGINT, or — with ``--control`` — when its standard input closes (so it never outlives the
process that started it). With ``--control`` it reads one JSON command per line on standard
input, ``{"op": "fault", "node": 3, "name": "overcurrent"}``, and answers each with one JSON
line (see :meth:`sim_bridge.amplifiers.emulators.CanEmulators.call`).
"""

from __future__ import annotations

import argparse
import gc
import os
import signal
import sys
import threading
import time

from drivers.can.config import DEFAULT_UDP_GROUP, DEFAULT_UDP_PORT, CanBusConfig, DepthConfig
from sim_bridge.amplifiers.emulators import CanEmulators
from sim_bridge.control_channel import JsonLines, serve_commands
from sim_bridge.thrusters import ThrusterEffects
from uvd.errors import UvdError
from uvd.io.vehicle import load_vehicle


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m sim_bridge.amplifiers",
                                description="Emulated CiA 402 thruster amplifiers on a CAN bus.")
    p.add_argument("--interface", default="udp_multicast", help="python-can interface")
    p.add_argument("--channel", default=DEFAULT_UDP_GROUP,
                   help="channel (udp_multicast: an interface-local ff11:: group)")
    p.add_argument("--port", type=int, default=DEFAULT_UDP_PORT, help="udp_multicast port")
    p.add_argument("--allow-network", action="store_true",
                   help="udp_multicast: allow a group whose datagrams may leave this machine")
    p.add_argument("--duration", type=float, default=60.0,
                   help="seconds to run (the process always ends by itself)")
    p.add_argument("--vehicle", default="jhu-rov", help="built-in vehicle or vehicle TOML file")
    p.add_argument("--nodes", default="1,2,3,4,5,6", help="amplifier node ids, thruster order")
    p.add_argument("--pressure-node", type=int, default=None,
                   help="also emulate the CiA 404 pressure transmitter on this node id")
    p.add_argument("--depth", type=float, default=1.0, help="transmitter depth (m)")
    p.add_argument("--no-dynamics", action="store_true",
                   help="thrusters without lag and stiction (steady state at once)")
    p.add_argument("--realtime", action="store_true",
                   help="run at SCHED_FIFO priority 10 if permitted (a drive answers on time)")
    p.add_argument("--control", action="store_true",
                   help="read JSON commands on stdin, answer on stdout; exit when stdin closes")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # answer a SYNC within ~1 ms even while the tick thread holds the GIL (default 5 ms)
    sys.setswitchinterval(0.0005)
    realtime = False
    if args.realtime:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
            realtime = True
        except (OSError, AttributeError):
            pass  # not permitted: normal priority, reported in the ready line
    emit = JsonLines()

    try:
        cfg = CanBusConfig(interface=args.interface, channel=args.channel, port=args.port,
                           loopback_only=not args.allow_network)
        vehicle = load_vehicle(args.vehicle)
        nodes = tuple(int(x) for x in args.nodes.split(",") if x.strip())
        effects = ThrusterEffects(lag=not args.no_dynamics, stiction=not args.no_dynamics)
        emu = CanEmulators(cfg, vehicle.thrusters, nodes, effects=effects,
                           pressure_node=args.pressure_node, depth_m=args.depth,
                           depth_cfg=DepthConfig())
        emu.open()
    except (UvdError, ValueError, KeyError) as exc:
        emit({"event": "error", "error": str(exc)})
        return 2
    gc.collect()
    gc.freeze()  # no ~50 ms full collection of the start-up objects while answering SYNCs
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())

    def control() -> None:  # stdin closed or quit: the parent is gone or done
        serve_commands(emu.call, emit, stop.set)

    if args.control:
        threading.Thread(target=control, name="control", daemon=True).start()
    emit({"event": "ready", "pid": os.getpid(), "interface": args.interface,
          "channel": args.channel, "port": args.port, "nodes": list(nodes),
          "pressure_node": args.pressure_node, "realtime": realtime})
    deadline = time.monotonic() + args.duration
    while not stop.is_set() and time.monotonic() < deadline:
        stop.wait(min(0.1, max(0.0, deadline - time.monotonic())))
    stats = emu.stats(history=True)
    emu.close()
    emit({"event": "exit", "stats": stats})
    return 0


if __name__ == "__main__":
    sys.exit(main())
