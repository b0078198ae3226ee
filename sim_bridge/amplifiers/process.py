"""Start and talk to ``python -m sim_bridge.amplifiers`` as a second process.

Used by the contract tests and the benchmark to put the emulators in another process on
``udp_multicast``; the same :meth:`call` interface as the in-process
:meth:`sim_bridge.amplifiers.emulators.CanEmulators.call`. The child is started with
``--control``, so it exits when this side closes its standard input (or dies), and it is bounded
by ``--duration`` anyway; :meth:`EmulatorProcess.stop` kills it if it does not exit in time.

The child is the vehicle's hardware, so it runs in a session of its own: Ctrl-C in the
terminal (SIGINT to the terminal's whole process group) does not reach it. The command that
started it stops the daemon first — which still disables the amplifiers and sends its last
telemetry to them — and it last, as :mod:`uvd.commands.demo` does (before, the emulators ended
at the Ctrl-C with the daemon, whose shutdown then found no amplifier to disable).
"""

from __future__ import annotations

import itertools
import json
import os
import queue
import subprocess
import sys
import threading
import time

from uvd.errors import TransportError


class EmulatorProcess:
    """A running emulator process.

    Parameters
    ----------
    channel : str
        udp_multicast group (interface-local ``ff11::`` by default in the config).
    port : int
        UDP port; use a free, test-specific one so parallel runs do not hear each other.
    duration_s : float
        Hard upper bound on the child's life.
    interface : str
        python-can interface.
    extra : list of str
        More command-line arguments (``--pressure-node 32``...).
    """

    def __init__(self, channel: str, port: int, duration_s: float = 60.0,
                 interface: str = "udp_multicast", extra: list[str] | None = None) -> None:
        self.argv = [sys.executable, "-m", "sim_bridge.amplifiers", "--control",
                     "--interface", interface, "--channel", channel, "--port", str(port),
                     "--duration", str(duration_s), *(extra or [])]
        self.proc: subprocess.Popen | None = None
        self._lines: queue.Queue[dict | None] = queue.Queue()
        self._ids = itertools.count(1)
        self.ready: dict | None = None
        self.exit_stats: dict | None = None
        self._lock = threading.Lock()

    def start(self, timeout_s: float = 30.0) -> EmulatorProcess:
        """Start the child and wait (bounded) for its ready line."""
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(self.argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, env=env,
                                     start_new_session=True)
        threading.Thread(target=self._reader, daemon=True, name="emulator-stdout").start()
        threading.Thread(target=self._drain_err, daemon=True, name="emulator-stderr").start()
        msg = self._next(timeout_s, lambda m: m.get("event") in ("ready", "error"))
        if msg is None or msg.get("event") != "ready":
            err = self.stderr_tail()
            self.kill()
            raise TransportError(f"emulator process did not start: {msg or 'no answer'} {err}")
        self.ready = msg
        return self

    _err: list[str]

    def _drain_err(self) -> None:
        self._err = []
        for line in self.proc.stderr:
            self._err.append(line)
            del self._err[:-50]

    def stderr_tail(self) -> str:
        return "".join(getattr(self, "_err", [])[-20:])

    def _reader(self) -> None:
        for line in self.proc.stdout:
            try:
                self._lines.put(json.loads(line))
            except ValueError:
                continue
        self._lines.put(None)

    def _next(self, timeout_s: float, pred) -> dict | None:
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            try:
                msg = self._lines.get(timeout=left)
            except queue.Empty:
                return None
            if msg is None:
                return None
            if msg.get("event") == "exit":
                self.exit_stats = msg.get("stats")
            if pred(msg):
                return msg

    def call(self, op: str, timeout_s: float = 5.0, **kw) -> dict:
        """Send one control command and wait (bounded) for its answer."""
        with self._lock:
            rid = next(self._ids)
            try:
                self.proc.stdin.write(json.dumps({"op": op, "id": rid, **kw}) + "\n")
                self.proc.stdin.flush()
            except (OSError, ValueError, AttributeError) as exc:
                return {"ok": False, "error": f"emulator process gone: {exc}"}
            msg = self._next(timeout_s, lambda m: m.get("id") == rid)
        return msg if msg is not None else {"ok": False, "error": f"no answer to {op!r}"}

    def stop(self, timeout_s: float = 10.0) -> dict | None:
        """Ask the child to end, wait (bounded), kill it if needed; returns its exit stats."""
        if self.proc is None:
            return self.exit_stats
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        if self.exit_stats is None:
            self._next(timeout_s, lambda m: m.get("event") == "exit")
        try:
            self.proc.wait(timeout=max(1.0, timeout_s / 2))
        except subprocess.TimeoutExpired:
            self.kill()
        return self.exit_stats

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                pass

    def __enter__(self) -> EmulatorProcess:
        return self if self.proc is not None else self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
        self.kill()
