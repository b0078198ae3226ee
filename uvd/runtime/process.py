"""The daemon as a child process of a command (``uvd demo``, ``uvd replay --realtime``,
``uvd experiment fault-tolerance-hil``, ``uvd bench latency``): stopped as its unit file stops
it (config/uvd.service: SIGTERM, on which the amplifiers get zero thrust, then SIGKILL after
``TimeoutStopSec=5s``), and ended with the command however it ends (:func:`stop_with_parent`:
a SIGKILL of the command, which no ``finally`` sees)."""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys

#: config/uvd.service's ``TimeoutStopSec``
STOP_TIMEOUT_S = 5.0


def stop_daemon(proc: subprocess.Popen, timeout_s: float = STOP_TIMEOUT_S) -> int:
    """SIGTERM to ``proc`` unless it has ended, SIGKILL after ``timeout_s``; its exit code
    (negative: the signal that ended it). Raises ``subprocess.TimeoutExpired`` only if it
    outlives a SIGKILL by 5 s."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        return proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait(5.0)


_PR_SET_PDEATHSIG = 1


def stop_with_parent(parent_pid: int) -> bool:
    """In the daemon (``uvd run --stop-with-parent PID``): SIGTERM to itself when the thread
    that started it ends, as its process ends, however (Linux's ``PR_SET_PDEATHSIG``); the
    daemon then stops as on ``systemctl stop``. False when process ``parent_pid`` has already
    ended (the daemon does not start). Before (session 25), a command killed by SIGKILL (a
    tool's timeout) left its daemon running for the rest of its ``--duration``."""
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0) != 0:
            err = ctypes.get_errno()
            raise OSError(err, f"prctl(PR_SET_PDEATHSIG): {os.strerror(err)}")
    return os.getppid() == parent_pid
