"""``uvd reset-failsafe``: reset the failsafe triggers of a running daemon whose condition no
longer holds — the latched ones above all — over its MAVLink link, from a shell, as a ground
station does with COMMAND_LONG ``MAV_CMD_USER_2`` (31011, param1 0).

A latched trigger (a leak, a drive's fault, a bus-off, a stuck depth sensor, a non-finite
command, a cycle that raised, diverged parameters) stays active once fired, and at
hold-depth or above the arming check refuses arming while it does: without a reset the
vehicle stays disarmed until the daemon restarts. The cycle applies the reset at its next
start and records it; each trigger reset is a failsafe event (``reset``, "operator reset")
told to every station, and a trigger whose condition still holds is refused by name ("leak:
condition still true: leak detected"). A trigger that clears by itself is cleared at once if
its condition is gone, and left to clear if not.
Disarmed, the daemon first brings the amplifiers back — drives that rebooted started again,
a fault reset to those in FAULT (uvd.runtime.recovery) — and answers once they are (at most
about 10 s).
It speaks to the daemon as ``uvd eta`` does (``--config``, ``--to``, ``--system``).

Exit code 0 when every latched trigger was reset (or none was latched), 1 when one was
refused (the reason is printed), 2 when the daemon did not answer within ``--timeout`` or the
configuration is unusable.
"""

from __future__ import annotations

import sys

from uvd.commands._station import add_station_options, send_command, station_of


def register(sub) -> None:
    p = sub.add_parser("reset-failsafe", help="reset the latched failsafe triggers of a "
                                              "running daemon (MAVLink)",
                       description=__doc__.split("\n\n")[0])
    add_station_options(p, timeout_s=15.0)  # a reset waits for the amplifiers' recovery
    p.set_defaults(handler=_run)


def _run(args) -> int:
    from uvd.errors import UvdError
    from uvd.links.mavlink.link import MAV_CMD_RESET_FAILSAFE
    try:
        host, port, key = station_of(args)
        result, texts = send_command(
            host, port, MAV_CMD_RESET_FAILSAFE, (0,),
            lambda t: t.startswith("failsafe reset:") or t.startswith("ResetFailsafe refused"),
            name="reset-failsafe", system=args.system, key=key, timeout_s=args.timeout)
    except (UvdError, ValueError, OSError) as exc:
        print(f"uvd reset-failsafe: {exc}", file=sys.stderr)
        return 2
    print(f"failsafe reset: {result}" + "".join(f"\n  {t}" for t in texts))
    return 0 if result == "accepted" else 1
