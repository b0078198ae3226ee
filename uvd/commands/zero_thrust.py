"""``uvd zero-thrust --config FILE``: command zero current to every amplifier, then disable them.

The unit's ``ExecStopPost=``: it runs after the daemon has exited — however it exited (clean
stop, crash, watchdog kill) — so the bus is free. It opens the ``[can]`` bus of the
configuration with the CAN driver (:class:`drivers.can.CanBus`), builds the
:class:`drivers.can.AmplifierGroup` of ``[can.amplifiers]`` for the configured vehicle, and
runs its shutdown: ``--cycles`` command cycles of zero target torque with the controlword
"disable voltage" (RPDO + SYNC each), then NMT pre-operational to every node. It does not wait
for SDO answers (so a dead node cannot make it hang) and is bounded by ``--cycles`` ×
``--period`` plus the bus opening: at most 100 cycles 1 s apart, and an option out of its
range (or NaN) is refused before anything is sent (exit 2), as a wrong configuration is.

The amplifiers' own command timeout (``command_timeout_ms``, 300 ms by default) zeroes their
output whatever happens to the daemon; this command makes the stop explicit and immediate.

Exit code 0 when every frame was accepted by the bus, 1 when some were dropped, 2 when the
configuration is invalid or the bus cannot be opened.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

from uvd.cliargs import float_in, int_in


def register(sub) -> None:
    p = sub.add_parser("zero-thrust", help="command zero current to every amplifier and "
                                           "disable them (systemd ExecStopPost)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="configuration (default: the embedded config/sim.toml)")
    p.add_argument("--cycles", type=int_in(1, 100), default=5,
                   help="zero-command cycles, 1..100 (default 5)")
    p.add_argument("--period", type=float_in(0.0, 1.0), default=0.01,
                   help="seconds between cycles, 0..1 (default 0.01)")
    p.set_defaults(handler=_run)


def zero_amplifiers(config, *, cycles: int = 5, period_s: float = 0.01) -> dict[str, Any]:
    """Zero and disable every amplifier of ``config`` (a validated :class:`Config`).

    Returns
    -------
    dict
        ``frames_sent``, ``frames_dropped``, ``nodes``, ``duration_s``.

    Raises
    ------
    drivers.can.BusOpenError
        The bus cannot be opened.
    """
    from drivers.can import AmplifierGroup, CanBus

    t0 = time.monotonic()
    vehicle = config.load_vehicle()
    bus = CanBus(config.can.bus).open()
    try:
        group = AmplifierGroup.from_config(bus, config.can.amplifiers, vehicle.thrusters)
        sent0 = bus.status().counters.get("tx_frames", 0)
        group.shutdown(cycles=max(1, cycles), period_s=max(0.0, period_s),
                       release_consumer=False)
        counters = bus.status().counters
        stats = group.stats()
    finally:
        bus.close()
    return {"nodes": list(config.can.amplifiers.node_ids),
            "cycles": max(1, cycles),
            "frames_sent": counters.get("tx_frames", 0) - sent0,
            "send_failed_cycles": stats.get("send_failed_cycles", 0),
            "duration_s": time.monotonic() - t0}


def _run(args) -> int:
    from drivers.can import BusOpenError
    from uvd.commands import checked_config

    cfg = checked_config(args.config, "zero-thrust", "nothing sent")
    if cfg is None:
        return 2
    try:
        res = zero_amplifiers(cfg, cycles=args.cycles, period_s=args.period)
    except BusOpenError as exc:
        print(f"uvd zero-thrust: {exc}", file=sys.stderr)
        return 2
    b = cfg.can.bus
    print(f"uvd zero-thrust: {res['cycles']} zero-current cycles to nodes "
          f"{', '.join(map(str, res['nodes']))} on {b.interface}:{b.channel} "
          f"({res['frames_sent']} frames sent, {res['send_failed_cycles']} cycles with a "
          f"dropped frame, {res['duration_s'] * 1e3:.0f} ms), each with \"disable voltage\", "
          "then NMT pre-operational (sent; no answer is waited for)")
    return 0 if res["send_failed_cycles"] == 0 else 1
