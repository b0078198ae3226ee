"""A command of the operator's sent to a running daemon from a shell, as any ground station
sends it (docs/mavlink.md): what ``uvd eta`` and ``uvd reset-failsafe`` share.

pymavlink over UDP to ``[mavlink] listen`` of ``--config`` (or ``--to``), signed with
``signing_key_file`` when the configuration has one, as system ``--system`` (one of
``gcs_system_ids``): :func:`send_command` sends its HEARTBEAT, waits for the vehicle's, sends
one COMMAND_LONG, waits for its COMMAND_ACK and gathers the daemon's STATUSTEXTs about it, on a
:class:`~uvd.links.mavlink.station.GroundStation`.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from uvd.cliargs import int_in, positive_float_upto
from uvd.links.mavlink.station import GroundStation

#: how long texts are gathered after the COMMAND_ACK, at most, and how long a quiet spell
#: after the last text ends it
TEXTS_S, QUIET_S = 2.0, 0.3


def add_station_options(p: argparse.ArgumentParser, timeout_s: float = 5.0) -> None:
    """``--config``, ``--to``, ``--system``, ``--timeout`` (default ``timeout_s``)."""
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="the daemon's configuration: its [mavlink] listen address and signing "
                        "key (default: the embedded config/sim.toml)")
    p.add_argument("--to", type=_udp_address, default=None, metavar="HOST:PORT",
                   help="the link's UDP address (default: [mavlink] listen)")
    p.add_argument("--system", type=int_in(1, 255), default=255,
                   help="this station's MAVLink system id (default 255)")
    # select() takes no wait past the platform's time_t: 1e308 was an OverflowError traceback
    p.add_argument("--timeout", type=positive_float_upto(3600.0), default=timeout_s,
                   help=f"seconds to wait for each answer, at most 3600 (default "
                        f"{timeout_s:g})")


def _udp_address(text: str) -> str:
    """``--to``: ADDRESS:PORT as the configuration's [mavlink] listen is written."""
    from uvd.runtime.config import check_udp_address
    bad = check_udp_address(text, "--to")
    if bad:
        raise argparse.ArgumentTypeError(bad[0][1])
    return text


def station_of(args) -> tuple[str, int, bytes | None]:
    """The daemon's (host, port, signing key or None) from ``--config`` / ``--to``. Raises
    ValueError (or a UvdError of the configuration) when there is none."""
    from uvd.runtime.config import load_config
    cfg = load_config(args.config).mavlink
    addr = args.to or cfg.listen
    if not addr:
        raise ValueError("no address: [mavlink] listen is empty and --to is not given")
    host, _, port = addr.rpartition(":")
    key = None
    if cfg.signing_key_file:
        from uvd.links.mavlink.signing import load_key
        key = load_key(cfg.signing_key_file)
    return host, int(port), key


def send_command(host: str, port: int, command: int, params: Sequence[float],
                 about: Callable[[str], bool], *, name: str, system: int = 255,
                 key: bytes | None = None, timeout_s: float = 5.0) -> tuple[str, list[str]]:
    """Send COMMAND_LONG ``command`` (``params``: param1…) and wait for its answer:
    (``"accepted"``/``"denied"``/…, the daemon's STATUSTEXTs for which ``about(text)`` holds,
    whole — chunks of one id joined — in the order they came). Raises TimeoutError when the
    vehicle's heartbeat or the COMMAND_ACK does not come within ``timeout_s``; ``name``: the
    command's in that message."""
    if ":" in host:
        raise ValueError(f"{host}:{port}: uvd {name} speaks IPv4 only (pymavlink's UDP "
                         "connection); reach the daemon on an IPv4 address ([mavlink] listen)")
    with GroundStation(host, port, system, key) as st:
        def answer(m, what):
            if m is None:
                bad = st.conn.mav.signing.badsig_count if key is not None else 0
                raise TimeoutError(f"no {what} from {host}:{port} within {timeout_s:g} s" + (
                    f" that this station's key verifies: {bad} message(s) came signed with "
                    "another key (the --config's [mavlink] signing_key_file is not the "
                    "daemon's)" if bad else ""))
            return m

        answer(st.vehicle(timeout_s), "vehicle heartbeat")
        ack = answer(st.command(command, *params, timeout_s=timeout_s), "COMMAND_ACK")
        result = st.mav.enums["MAV_RESULT"][ack.result].name.removeprefix("MAV_RESULT_").lower()
        # the link's own refusal of the command ("COMMAND_LONG refused: unsigned"), said too
        texts = _texts(st, lambda t: about(t) or t.startswith("COMMAND_LONG refused"),
                       min(timeout_s, TEXTS_S))
        if key is None and any(t == "COMMAND_LONG refused: unsigned" for t in texts):
            texts.append("the daemon's link is signed: give the --config that holds its "
                         "[mavlink] signing_key_file")
        return result, texts


def _texts(st: GroundStation, about: Callable[[str], bool], within_s: float) -> list[str]:
    """The whole STATUSTEXTs ``about`` picks, up to ``within_s``, or :data:`QUIET_S` after the
    last such text was whole (STATUSTEXT chunks: 50 characters, the last one shorter)."""
    texts: list[str] = []
    parts: dict[int, str] = {}
    end = time.monotonic() + within_s
    quiet_end = end
    while (left := min(end, quiet_end) - time.monotonic()) > 0:
        m = st.wait("STATUSTEXT", None, left)
        if m is None:
            break
        text = parts.pop(m.id, "") + m.text
        if m.id and len(m.text) == 50:
            parts[m.id] = text  # more chunks to come
            continue
        if about(text):
            texts.append(text)
            quiet_end = time.monotonic() + QUIET_S
    return texts
