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
import os
import sys
import time
from pathlib import Path

from uvd.cliargs import int_in, positive_float, positive_int


def register(sub) -> None:
    p = sub.add_parser("eta", help="set or clear a thruster's effectiveness on a running "
                                   "daemon (MAVLink)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("thruster", type=positive_int,
                   help="the thruster, 1-based, in the vehicle's order")
    p.add_argument("eta", help="its effectiveness in [0, 1] (0 dead, 0.5 weak), or 'clear' (1)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="the daemon's configuration: its [mavlink] listen address and signing "
                        "key (default: the embedded config/sim.toml)")
    p.add_argument("--to", type=_udp_address, default=None, metavar="HOST:PORT",
                   help="the link's UDP address (default: [mavlink] listen)")
    p.add_argument("--system", type=int_in(1, 255), default=255,
                   help="this station's MAVLink system id (default 255)")
    p.add_argument("--timeout", type=positive_float, default=5.0,
                   help="seconds to wait for each answer (default 5)")
    p.set_defaults(handler=_run)


def _udp_address(text: str) -> str:
    """``--to``: ADDRESS:PORT as the configuration's [mavlink] listen is written."""
    import argparse

    from uvd.runtime.config import check_udp_address
    bad = check_udp_address(text, "--to")
    if bad:
        raise argparse.ArgumentTypeError(bad[0][1])
    return text


def _eta(text: str) -> float:
    if text.strip().lower() == "clear":
        return 1.0
    try:
        e = float(text)
    except ValueError:
        raise ValueError(f"eta {text!r} is not a number nor 'clear'") from None
    if not (math.isfinite(e) and 0.0 <= e <= 1.0):
        raise ValueError(f"eta {text!r} is not in [0, 1]")
    return e


def send_eta(host: str, port: int, thruster: int, eta: float, *, system: int = 255,
             key: bytes | None = None, timeout_s: float = 5.0) -> tuple[str, str]:
    """Send the command and wait for its answer: (``"accepted"``/``"denied"``/…, the
    daemon's STATUSTEXT, "" when none came). Raises TimeoutError when the vehicle's heartbeat
    or the COMMAND_ACK does not come within ``timeout_s``."""
    if ":" in host:
        raise ValueError(f"{host}:{port}: uvd eta speaks IPv4 only (pymavlink's UDP "
                         "connection); reach the daemon on an IPv4 address ([mavlink] listen)")
    os.environ.setdefault("MAVLINK20", "1")  # pymavlink's MAVLink 2 dialects
    from pymavlink import mavutil

    from uvd.links.mavlink.link import MAV_CMD_THRUSTER_ETA
    mav = mavutil.mavlink
    conn = mavutil.mavlink_connection(f"udpout:{host}:{port}", source_system=system,
                                      source_component=mav.MAV_COMP_ID_MISSIONPLANNER,
                                      dialect="ardupilotmega")
    conn.mav.WIRE_PROTOCOL_VERSION = "2.0"
    if key is not None:
        conn.setup_signing(key, sign_outgoing=True)
    try:
        def wait(kind, cond, what):
            deadline = time.monotonic() + timeout_s
            next_beat = 0.0
            while time.monotonic() < deadline:
                if time.monotonic() >= next_beat:  # a station the link hears
                    conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                    next_beat = time.monotonic() + 0.5
                m = conn.recv_match(type=kind, blocking=True, timeout=0.1)
                if m is not None and cond(m):
                    return m
            raise TimeoutError(f"no {what} from {host}:{port} within {timeout_s:g} s")

        hb = wait("HEARTBEAT", lambda m: m.get_srcSystem() != system
                  and m.type != mav.MAV_TYPE_GCS, "vehicle heartbeat")
        target = (hb.get_srcSystem(), hb.get_srcComponent())
        conn.mav.command_long_send(*target, MAV_CMD_THRUSTER_ETA, 0, float(thruster),
                                   float(eta), 0, 0, 0, 0, 0)
        ack = wait("COMMAND_ACK", lambda m: m.command == MAV_CMD_THRUSTER_ETA, "COMMAND_ACK")
        result = mav.enums["MAV_RESULT"][ack.result].name.removeprefix("MAV_RESULT_").lower()
        # the daemon's text, in 50-character chunks of one id
        text, sid = "", None
        deadline = time.monotonic() + min(timeout_s, 2.0)
        while time.monotonic() < deadline:
            m = conn.recv_match(type="STATUSTEXT", blocking=True, timeout=0.1)
            if m is None:
                continue
            if sid is None and (m.text.startswith(f"thruster {thruster} eta")
                                or "SetThrusterEta refused" in m.text):
                sid, text = m.id, m.text
                if not m.id:
                    break
            elif sid is not None and m.id == sid:
                text += m.text
            elif sid is not None:
                break
        return result, text
    finally:
        conn.close()


def _run(args) -> int:
    from uvd.errors import UvdError
    from uvd.runtime.config import load_config
    try:
        eta = _eta(args.eta)
        cfg = load_config(args.config).mavlink
        addr = args.to or cfg.listen
        if not addr:
            raise ValueError("no address: [mavlink] listen is empty and --to is not given")
        host, _, port = addr.rpartition(":")
        key = None
        if cfg.signing_key_file:
            from uvd.links.mavlink.signing import load_key
            key = load_key(cfg.signing_key_file)
        result, text = send_eta(host, int(port), args.thruster, eta, system=args.system,
                                key=key, timeout_s=args.timeout)
    except (UvdError, ValueError, OSError) as exc:
        print(f"uvd eta: {exc}", file=sys.stderr)
        return 2
    print(f"thruster {args.thruster} eta {eta:g}: {result}" + (f" — {text}" if text else ""))
    return 0 if result == "accepted" else 1
