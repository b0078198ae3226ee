"""``uvd eta THRUSTER ETA``: set (or ``clear``) one thruster's effectiveness η on a running
daemon, over its MAVLink link — the operator's source of η from a shell.

It speaks to the daemon as any ground station does (docs/mavlink.md): pymavlink over UDP to
``[mavlink] listen`` of ``--config`` (or ``--to``), signed with ``signing_key_file`` when the
configuration has one, as system ``--system`` (one of ``gcs_system_ids``). It sends its
HEARTBEAT, waits for the vehicle's, sends COMMAND_LONG ``MAV_CMD_USER_1`` (31010: param1 the
thruster, 1-based; param2 η ∈ [0, 1]) and prints the COMMAND_ACK and the daemon's STATUSTEXT
("thruster 4 eta 0 (mavlink 255/190); given up: pitch"). The cycle applies it at its next
start, records it and tells every station; η 1 (``clear``) gives the thruster back.

Exit code 0 when the daemon accepted it, 1 when it refused (the reason is in its STATUSTEXT),
2 when it did not answer within ``--timeout`` or the configuration is unusable.
"""

from __future__ import annotations

import math
import struct
import sys

from uvd.cliargs import positive_int
from uvd.commands._station import add_station_options, send_command, station_of


def register(sub) -> None:
    p = sub.add_parser("eta", help="set or clear a thruster's effectiveness on a running "
                                   "daemon (MAVLink)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("thruster", type=positive_int,
                   help="the thruster, 1-based, in the vehicle's order")
    p.add_argument("eta", help="its effectiveness in [0, 1] (0 dead, 0.5 weak), or 'clear' (1)")
    add_station_options(p)
    p.set_defaults(handler=_run)


def _eta(text: str) -> float:
    if text.strip().lower() == "clear":
        return 1.0
    try:
        e = float(text)
    except ValueError:
        raise ValueError(f"eta {text!r} is not a number nor 'clear'") from None
    if not (math.isfinite(e) and 0.0 <= e <= 1.0):
        raise ValueError(f"eta {text!r} is not in [0, 1]")
    # what COMMAND_LONG's param2 carries, a float32, and so what the echo says: "1e-320" was
    # echoed as 9.99989e-321 though 0 went out
    return struct.unpack("<f", struct.pack("<f", e))[0]


def _run(args) -> int:
    from uvd.errors import UvdError
    from uvd.links.mavlink.link import MAV_CMD_THRUSTER_ETA
    try:
        eta = _eta(args.eta)
        host, port, key = station_of(args)
        result, texts = send_command(
            host, port, MAV_CMD_THRUSTER_ETA, (args.thruster, eta),
            lambda t: t.startswith(f"thruster {args.thruster} eta")
            or "SetThrusterEta refused" in t, name="eta", system=args.system, key=key,
            timeout_s=args.timeout)
    except (UvdError, ValueError, OSError) as exc:
        print(f"uvd eta: {exc}", file=sys.stderr)
        return 2
    text = "; ".join(texts)
    print(f"thruster {args.thruster} eta {eta:g}: {result}" + (f" — {text}" if text else ""))
    return 0 if result == "accepted" else 1
