"""The daemon as a child process of a command (``uvd demo``, ``uvd replay --realtime``,
``uvd experiment fault-tolerance-hil``, ``uvd bench latency``): stopped as its unit file stops
it (config/uvd.service: SIGTERM, on which the amplifiers get zero thrust, then SIGKILL after
``TimeoutStopSec=5s``)."""

from __future__ import annotations

import signal
import subprocess

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
