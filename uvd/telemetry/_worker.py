"""Blocking calls off the event loop, in *daemon* threads.

``asyncio.to_thread`` uses a ``ThreadPoolExecutor`` whose workers are joined when the event
loop and the interpreter shut down: one hung ``write`` or driver call would then keep the
daemon from exiting (systemd would have to kill it). These helpers run blocking calls in daemon
threads instead, so a call that never returns is abandoned at exit, never waited for.
"""

from __future__ import annotations

import asyncio
import contextlib
import queue
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["DaemonWorker", "run_in_daemon_thread"]


def _resolve(fut: asyncio.Future, result: Any, exc: BaseException | None) -> None:
    if fut.done():
        return
    if exc is not None:
        fut.set_exception(exc)
    else:
        fut.set_result(result)


def _deliver(loop: asyncio.AbstractEventLoop, fut: asyncio.Future, fn: Callable[..., Any],
             args: tuple) -> None:
    try:
        result, exc = fn(*args), None
    except BaseException as e:  # handed to the awaiting coroutine
        result, exc = None, e
    with contextlib.suppress(RuntimeError):  # the loop is already closed: nobody waits
        loop.call_soon_threadsafe(_resolve, fut, result, exc)


def run_in_daemon_thread(fn: Callable[..., Any], *args: Any,
                         name: str = "uvd-blocking") -> asyncio.Future:
    """Run ``fn(*args)`` in a new daemon thread; await the returned future for its result."""
    loop = asyncio.get_running_loop()
    fut = loop.create_future()
    threading.Thread(target=_deliver, args=(loop, fut, fn, args), name=name,
                     daemon=True).start()
    return fut


class DaemonWorker:
    """One daemon thread running submitted calls in order (e.g. a sink's file writes)."""

    def __init__(self, name: str = "uvd-worker") -> None:
        self.name = name
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._thread: threading.Thread | None = None

    def _run(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            _deliver(*item)

    def submit(self, fn: Callable[..., Any], *args: Any) -> asyncio.Future:
        """Queue ``fn(*args)``; await the returned future for its result."""
        loop = asyncio.get_running_loop()
        fut = loop.create_future()
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
            self._thread.start()
        self._q.put((loop, fut, fn, args))
        return fut

    def close(self) -> None:
        """Let the thread end after the calls already queued."""
        if self._thread is not None:
            self._q.put(None)
            self._thread = None
