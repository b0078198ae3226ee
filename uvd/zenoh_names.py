"""What Zenoh takes as a vehicle's key and as an endpoint, checked before a session opens.

The daemon's configuration (``[telemetry.zenoh]``: ``key``, ``listen``, ``connect``),
``uvd watch`` and ``uvd-fdc`` (``--vehicle``, ``--connect``) check them here, so that a bad one
is named where it was written — not a ``zenoh.ZError`` from inside the session (``uvd watch
--connect garbage`` and ``--vehicle ''`` were tracebacks), a client waiting for ever on a port
that cannot exist (``tcp/127.0.0.1:99999``), nor a ``check-config`` that says OK to a
configuration the daemon then refuses. A vehicle's key is one key chunk: ``*`` would make the
daemon's key space ``uvd/*/…`` and its fault subscription every vehicle's.

Pure string rules; importing nothing, so uvd-fdc (which speaks only the wire contract) may use
them as the daemon does.
"""

from __future__ import annotations

import re

#: characters a vehicle's key chunk may not hold: the separator, zenoh's wildcards and
#: DSL, the selector's and fragment's marks (and, ours, spaces)
NOT_IN_A_KEY = "/*$?# "

#: <protocol>/<address>[?<metadata>][#<config>], zenoh's endpoint form
_ENDPOINT = re.compile(r"(?P<proto>[A-Za-z][A-Za-z0-9+.-]*)/(?P<addr>[^?#\s]+)"
                       r"(\?[^#\s]*)?(#\S*)?")
#: protocols whose address ends in :PORT
_PORTED = ("tcp", "udp", "tls", "quic", "ws")


def vehicle_key_problem(key: str) -> str | None:
    """Why ``key`` cannot be a vehicle's ``<vehicle>`` of ``uvd/<vehicle>/…``, or None."""
    if not isinstance(key, str) or not key:
        return "is empty: a vehicle's key is one non-empty key chunk"
    if any(c in NOT_IN_A_KEY or c.isspace() for c in key):
        return ("is not a single key chunk (no '/', '*', '$', '?', '#' or spaces: one "
                "vehicle, never a pattern)")
    return None


def endpoint_address(text: str) -> tuple[str, str, int] | None:
    """``(protocol, host, port)`` of an endpoint whose protocol has a port and that carries
    no metadata or configuration (``udp/127.0.0.1:7447`` → ``("udp", "127.0.0.1", 7447)``;
    an IPv6 host keeps its brackets), else None."""
    m = _ENDPOINT.fullmatch(text) if isinstance(text, str) else None
    if m is None or m.group("proto") not in _PORTED or m.group(3) or m.group(4):
        return None
    host, sep, port = m.group("addr").rpartition(":")
    return (m.group("proto"), host, int(port)) if sep and host and port.isdigit() else None


def endpoint_problem(text: str) -> str | None:
    """Why ``text`` is not a Zenoh endpoint (``tcp/127.0.0.1:7447``), or None."""
    m = _ENDPOINT.fullmatch(text) if isinstance(text, str) else None
    if m is None:
        return "is not <protocol>/<address>[?<metadata>][#<config>] (e.g. tcp/127.0.0.1:7447)"
    if m.group("proto") in _PORTED:
        host, sep, port = m.group("addr").rpartition(":")
        if not (sep and host and port.isdigit() and 1 <= int(port) <= 65535):
            return f"has no port 1-65535 after its address ({m.group('proto')}/HOST:PORT)"
    return None
