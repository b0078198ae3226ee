"""The leak input: a digital input read from a file, polled off the loop's critical path.

A real vehicle's leak detector (a conductivity probe in each housing) ends in one digital
line: a GPIO of the vehicle computer (``/sys/class/gpio/gpioN/value`` with the sysfs
interface, or a file any GPIO daemon keeps up to date) holding ``0`` or ``1``. ``[sensors.leak]``
names the file and which level means water; :class:`LeakInput` reads it in its own thread
every ``poll_interval_s`` (a read of a file can block — a hung NFS mount, a driver — and must
never stall the cycle) and keeps the latest state; the cycle only reads that state
(:meth:`LeakInput.health`).

* ``leak``: the input at its active level for ``confirm_samples`` consecutive polls →
  ``Health.leak`` → the ``leak`` failsafe (DISARM, latched until an operator reset while dry).
* ``leak_sensor_fault``: the file cannot be read, holds something other than 0/1, or the
  newest good reading is older than ``stale_s`` (the poller is stuck) → a WARN trigger that
  clears when the input reads again: the operator learns that a leak would go unseen.

Fires within ``poll_interval_s × confirm_samples`` (plus the read's own time) and one cycle.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass
from typing import Any, Literal

from uvd.runtime import schema
from uvd.runtime.failsafe import Action, Health, Thresholds, TriggerDef
from uvd.runtime.schema import setting

__all__ = ["LeakSection", "LeakInput", "leak_sensor_fault_trigger", "read_level"]


@dataclass(frozen=True)
class LeakSection:
    """The leak detector's digital input (``[sensors.leak]``); absent = no leak sensor."""

    enabled: bool = setting(False, doc="read a leak input (trips the leak failsafe: disarm, "
                                       "latched)")
    path: str | None = setting(
        None, doc="file holding the input's level, 0 or 1 (a GPIO's "
                  "/sys/class/gpio/gpioN/value, or a file a GPIO daemon updates); required "
                  "when enabled")
    active_level: Literal[0, 1] = setting(1, doc="the level that means water")
    poll_interval_s: float = setting(0.1, unit="s", min=0.005, max=10.0,
                                     doc="how often the input is read (in its own thread)")
    confirm_samples: int = setting(
        1, min=1, max=100, doc="consecutive readings at the active level before a leak is "
                               "reported (debounce)")
    stale_s: float = setting(
        1.0, unit="s", gt=0.0, max=60.0,
        doc="no good reading for this long → leak_sensor_fault (warning)")

    def _check(self, ctx: schema.BuildContext) -> list[tuple[str, str]]:
        out: list[tuple[str, str]] = []
        if self.enabled and self.path is None:
            out.append(("path", "missing required key (needed when enabled = true)"))
        if self.path is not None and not self.path.startswith("/"):
            out.append(("path", f"{self.path!r} is not an absolute path"))
        if self.stale_s <= self.poll_interval_s:
            out.append(("stale_s", f"{self.stale_s} must be longer than poll_interval_s "
                                   f"{self.poll_interval_s}"))
        return out


def read_level(path: str) -> int:
    """The level in ``path`` (0 or 1). Raises OSError, or ValueError naming the content."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    try:
        raw = os.read(fd, 16)
    finally:
        os.close(fd)
    text = raw.strip()
    if text in (b"0", b"1"):
        return int(text)
    raise ValueError(f"expected 0 or 1, read {raw[:16]!r}")


class LeakInput:
    """Component polling a leak input file in a daemon thread (see the module docstring).

    ``start`` reads the input once and fails (naming the path) when it cannot, as a serial
    port that does not open; afterwards failure is data (``leak_sensor_fault``).
    """

    name = "leak"

    def __init__(self, cfg: LeakSection, *, clock=time.monotonic_ns) -> None:
        self.cfg = cfg
        self.path = str(cfg.path)
        self._clock = clock
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        # written by the poller only, read by the cycle (each a single reference swap)
        self.last_good_ns = 0
        self.active_count = 0
        self.error: str | None = None
        self.counters = {"reads": 0, "errors": 0, "active_reads": 0}

    # -- polling --

    def poll_once(self) -> None:
        try:
            level = read_level(self.path)
        except (OSError, ValueError) as exc:
            self.counters["errors"] += 1
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            self.error = f"leak input {self.path}: {reason}"
            return
        self.counters["reads"] += 1
        if level == self.cfg.active_level:
            self.counters["active_reads"] += 1
            self.active_count += 1
        else:
            self.active_count = 0
        self.error = None
        self.last_good_ns = self._clock()

    def _run(self) -> None:
        period = self.cfg.poll_interval_s
        while not self._stop.wait(period):
            self.poll_once()

    # -- the cycle's view --

    def health(self, t_ns: int) -> tuple[bool, str | None]:
        """(leak asserted, sensor fault reason or None) at ``t_ns``."""
        leak = self.active_count >= self.cfg.confirm_samples
        err = self.error
        if err is None and (t_ns - self.last_good_ns) * 1e-9 > self.cfg.stale_s:
            err = (f"leak input {self.path}: no reading for "
                   f"{(t_ns - self.last_good_ns) * 1e-9:.2f} s")
        return leak, err

    def read(self, t_ns: int, armed: bool, parts) -> None:
        """Its part of the cycle's inputs (:mod:`uvd.runtime.interfaces`): the leak, and the
        sensor's fault for the ``leak_sensor_fault`` trigger."""
        parts.leak, fault = self.health(t_ns)
        parts.signal("leak_sensor_fault", fault)

    def stats(self) -> dict[str, Any]:
        return {**self.counters, "error": self.error, "active_count": self.active_count}

    # -- Component --

    async def start(self) -> None:
        try:
            read_level(self.path)
        except (OSError, ValueError) as exc:
            raise OSError(f"leak input {self.path} cannot be read: "
                          f"{getattr(exc, 'strerror', None) or exc}") from exc
        self.poll_once()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="uvd-leak", daemon=True)
        self._thread.start()

    async def run(self) -> None:
        return None

    async def stop(self) -> None:
        self._stop.set()  # a daemon thread: a read that hangs is abandoned, never joined


def _leak_sensor_fault(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
    return (h.extra or {}).get("leak_sensor_fault"), mem


def leak_sensor_fault_trigger() -> TriggerDef:
    """WARN while the leak input cannot be read (clears when it reads again)."""
    return TriggerDef("leak_sensor_fault", Action.WARN, _leak_sensor_fault,
                      doc="the leak input cannot be read (a leak would go unseen)")
