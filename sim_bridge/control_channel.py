"""The JSON-lines control channel of the emulator processes (``sim-bridge --control``,
``python -m sim_bridge.amplifiers --control``).

One JSON object per line both ways: commands on standard input
(``{"op": "fault", "node": 2, "id": 7}``), one answer per command on standard output carrying
the command's ``id``, plus the process' own events (``{"event": "ready", …}``). A malformed
line is answered with ``{"ok": false, "error": …}`` naming it and skipped; ``{"op": "quit"}``
or the end of standard input (the parent gone) ends the channel.
"""

from __future__ import annotations

import json
import sys
import threading
from collections.abc import Callable
from typing import TextIO


class JsonLines:
    """Writes one JSON object per line, whole lines only (callable from any thread)."""

    def __init__(self, out: TextIO | None = None) -> None:
        self._out = out if out is not None else sys.stdout
        self._lock = threading.Lock()

    def __call__(self, obj: dict) -> None:
        with self._lock:
            self._out.write(json.dumps(obj, default=float) + "\n")
            self._out.flush()


def serve_commands(call: Callable[..., dict], emit: Callable[[dict], None],
                   on_end: Callable[[], None], lines: TextIO | None = None) -> None:
    """Answer each command line with ``call(op, **args)`` until ``quit`` or end of input,
    then ``on_end()`` (run it in a thread: it blocks on the input)."""
    for line in (lines if lines is not None else sys.stdin):
        line = line.strip()
        if not line:
            continue
        try:
            cmd = json.loads(line)
            op = cmd.pop("op")
            rid = cmd.pop("id", None)
        except (ValueError, KeyError, AttributeError, TypeError) as exc:
            emit({"ok": False, "error": f"bad command {line[:80]!r}: {exc}"})
            continue
        if op == "quit":
            emit({"id": rid, "ok": True})
            break
        emit({"id": rid, **call(op, **cmd)})
    on_end()
