"""systemd notification (``sd_notify``) over the ``NOTIFY_SOCKET`` datagram socket.

The protocol is a few lines — one ``AF_UNIX`` datagram of newline-separated ``KEY=VALUE``
assignments to the path (or, with a leading ``@``, the abstract address) in
``$NOTIFY_SOCKET`` — so it is implemented here rather than pulled in as a dependency. Without
``NOTIFY_SOCKET`` (not started by systemd) every call is a cheap no-op.

What the daemon sends:

* ``READY=1`` once the drivers are up (``Type=notify`` waits for it);
* ``STATUS=…`` with the lifecycle state on every transition;
* ``WATCHDOG=1`` only from the control loop, after a completed cycle, at most every half
  ``WatchdogSec`` (:class:`WatchdogPinger` as a loop ``after_cycle`` hook) — so a hung loop
  trips the watchdog even while other threads and tasks are alive;
* ``RELOADING=1`` … ``READY=1`` around a ``SIGHUP`` reload, ``STOPPING=1`` on shutdown.

Sending never blocks and never raises: a full socket buffer or a vanished socket is counted
(:attr:`SdNotifier.errors`) and remembered (:attr:`SdNotifier.last_error`).
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable, Mapping

__all__ = ["SdNotifier", "WatchdogPinger", "watchdog_interval_ns"]


def watchdog_interval_ns(env: Mapping[str, str] | None = None, pid: int | None = None
                         ) -> int | None:
    """``WATCHDOG_USEC`` in ns when the watchdog is enabled for this process, else None.

    ``WATCHDOG_PID``, when set, must be this process (as ``sd_watchdog_enabled`` checks).
    """
    env = os.environ if env is None else env
    usec = env.get("WATCHDOG_USEC")
    if not usec:
        return None
    wpid = env.get("WATCHDOG_PID")
    if wpid and int(wpid) != (os.getpid() if pid is None else pid):
        return None
    try:
        n = int(usec)
    except ValueError:
        return None
    return n * 1000 if n > 0 else None


class SdNotifier:
    """Sends sd_notify messages; disabled (no-op) when there is no ``NOTIFY_SOCKET``.

    Parameters
    ----------
    address : str, optional
        Socket path, or ``@name`` for an abstract socket; ``$NOTIFY_SOCKET`` by default.
    env : mapping, optional
        Environment to read (tests).
    """

    def __init__(self, address: str | None = None, *,
                 env: Mapping[str, str] | None = None) -> None:
        env = os.environ if env is None else env
        self.address = address if address is not None else env.get("NOTIFY_SOCKET") or None
        self.sent = 0
        self.errors = 0
        self.last_error: str | None = None
        self._sock: socket.socket | None = None
        self._addr: str | bytes | None = None
        if self.address:
            addr = self.address
            self._addr = ("\0" + addr[1:]) if addr.startswith("@") else addr
            try:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                self._sock.setblocking(False)
            except OSError as exc:
                self.last_error = f"cannot create the notify socket: {exc}"
                self._sock = None

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, *assignments: str) -> bool:
        """Send ``KEY=VALUE`` assignments in one datagram; True if it was sent."""
        if self._sock is None:
            return False
        msg = "\n".join(a.replace("\n", " ") for a in assignments).encode()
        try:
            self._sock.sendto(msg, self._addr)
        except OSError as exc:  # BlockingIOError included: never wait
            self.errors += 1
            self.last_error = f"{type(exc).__name__}: {exc}"
            return False
        self.sent += 1
        return True

    def ready(self, status: str | None = None) -> bool:
        return self.notify("READY=1", *((f"STATUS={status}",) if status else ()))

    def reloading(self) -> bool:
        usec = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
        return self.notify("RELOADING=1", f"MONOTONIC_USEC={usec}")

    def stopping(self, status: str | None = None) -> bool:
        return self.notify("STOPPING=1", *((f"STATUS={status}",) if status else ()))

    def status(self, text: str) -> bool:
        return self.notify(f"STATUS={text}")

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


class WatchdogPinger:
    """A loop ``after_cycle`` hook: ``WATCHDOG=1`` at most every ``interval_ns``.

    Parameters
    ----------
    notifier : SdNotifier
    interval_ns : int
        Normally half of ``WATCHDOG_USEC`` (:meth:`from_env`).
    healthy : callable, optional
        Extra condition checked before each ping (e.g. "the loop is not stuck in errors");
        no ping while it returns False.
    """

    def __init__(self, notifier: SdNotifier, interval_ns: int,
                 healthy: Callable[[], bool] | None = None) -> None:
        self.notifier = notifier
        self.interval_ns = int(interval_ns)
        self.healthy = healthy
        self.last_ns: int | None = None
        self.pings = 0

    @classmethod
    def from_env(cls, notifier: SdNotifier, env: Mapping[str, str] | None = None,
                 **kw) -> WatchdogPinger | None:
        """A pinger at half ``WATCHDOG_USEC``, or None when the watchdog is off."""
        wd = watchdog_interval_ns(env)
        if wd is None or not notifier.enabled:
            return None
        return cls(notifier, wd // 2, **kw)

    def __call__(self, t_ns: int, ok: bool = True) -> None:
        if self.last_ns is not None and t_ns - self.last_ns < self.interval_ns:
            return
        if self.healthy is not None and not self.healthy():
            return
        if self.notifier.watchdog():
            self.pings += 1
        self.last_ns = t_ns
