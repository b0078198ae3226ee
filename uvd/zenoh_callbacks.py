"""The Python callbacks of one Zenoh session, ended with it.

zenoh-python runs each callback given to ``declare_subscriber`` or ``declare_queryable`` on a
Python thread of its own (``zenoh.handlers.Callback``, ``indirect`` by default), and
``Session.close()`` returns without waiting for those threads. A process that exits while one
of them is still in a callback, or still winding down, aborts in Python's finalization
(``FATAL: exception not rethrown``, SIGABRT, exit −6): Python 3.11 ends a thread that wants
the GIL back during finalization with ``pthread_exit``, whose forced unwind cannot pass the
Rust frames on that thread's stack (PyO3 pull request 4874). Measured: the daemon of
tests/test_runtime_app.py, given SIGTERM beside two busy processes, aborted this way in 1 of
25 starts after an orderly shutdown — a systemd unit left ``failed`` with a core dump — with a
``(pyo3-closure)`` thread still alive at exit.

:class:`SessionCallbacks` hands zenoh each callback with a ``drop`` of its own (zenoh calls it
on the callback's thread, after the last call, when the subscriber or queryable goes) and
:meth:`SessionCallbacks.close` closes the session, then waits, bounded, until every such thread
has run its drop and ended.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

#: how long :meth:`SessionCallbacks.close` waits for the callbacks' threads, all together (s)
CLOSE_TIMEOUT_S = 2.0


class SessionCallbacks:
    """Wrap a session's callbacks (``callbacks(fn)`` where zenoh takes ``fn``); end them all
    with :meth:`close` (module docstring)."""

    def __init__(self) -> None:
        self._handlers: list[tuple[threading.Event, list[threading.Thread]]] = []

    def __call__(self, fn: Callable[[Any], Any]):
        import zenoh

        dropped = threading.Event()
        thread: list[threading.Thread] = []

        def drop() -> None:
            thread.append(threading.current_thread())
            dropped.set()

        self._handlers.append((dropped, thread))
        return zenoh.handlers.Callback(fn, drop)

    def close(self, session, timeout_s: float = CLOSE_TIMEOUT_S, *,
              warn: Callable[[str], Any] | None = None, who: str = "zenoh") -> int:
        """Close ``session`` (undeclaring everything it declared), then wait up to
        ``timeout_s`` in all for each callback's thread to run its drop and end. Returns how
        many were still running when the time ran out (0: all ended); if any were, ``warn``
        (a logger's ``warning``, a print) is told so, the message naming ``who``."""
        session.close()
        deadline = time.monotonic() + timeout_s
        running = 0
        for dropped, thread in self._handlers:
            if not dropped.wait(max(0.0, deadline - time.monotonic())):
                running += 1  # still inside a callback
                continue
            if thread[0] is not threading.current_thread():
                thread[0].join(max(0.0, deadline - time.monotonic()))
                running += thread[0].is_alive()
        self._handlers.clear()
        if running and warn is not None:
            warn(f"{who}: {running} callback(s) still running {timeout_s:g} s after the "
                 "session closed")
        return running
