"""Injected instrument faults, applied to the instrument models' samples — shared by the
real-time bridge (its control channel sets them) and lockstep simulation (a scenario sets them
on the simulated clock), so both see the very same faulty samples.

Modes per instrument (:data:`SENSOR_MODES`): ``silence`` (no samples), ``nan`` (NaN attitude,
depth or velocity in otherwise valid samples), ``stuck`` (the value frozen, the time stamp
advancing); ``garbage`` (random bytes instead of each frame) acts on the wire, in the bridge's
ports.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from sim_bridge.instruments.models import InstrumentConfig, Instruments

__all__ = ["SENSOR_MODES", "SensorFaults", "FaultyInstruments"]

SENSOR_MODES = ("ok", "silence", "garbage", "nan", "stuck")


class SensorFaults:
    """The injected fault of each instrument: a mode and when it ends (monotonic ns, 0 =
    until cleared). Written by the control channel, read by the emulators (plain attribute
    swaps, safe across threads)."""

    def __init__(self, clock: Callable[[], int] = time.monotonic_ns) -> None:
        self.clock = clock
        self.mode: dict[str, str] = {"ins": "ok", "dvl": "ok", "depth": "ok"}
        self.until: dict[str, int] = {"ins": 0, "dvl": 0, "depth": 0}
        self.since: dict[str, int] = {"ins": 0, "dvl": 0, "depth": 0}
        self.stuck_value: dict[str, Any] = {}

    def problem(self, name: str, mode: str) -> str | None:
        """Why instrument ``name`` cannot be put in ``mode``, or None."""
        if name not in self.mode:
            return f"unknown instrument {name!r}; have {sorted(self.mode)}"
        if mode not in SENSOR_MODES:
            return f"unknown mode {mode!r}; known: {', '.join(SENSOR_MODES)}"
        return None

    def set(self, name: str, mode: str, seconds: float | None = None) -> int:
        why = self.problem(name, mode)
        if why:
            raise ValueError(why)
        now = self.clock()
        self.stuck_value.pop(name, None)
        self.until[name] = now + int(seconds * 1e9) if seconds else 0
        self.since[name] = now
        self.mode[name] = mode
        return now

    def get(self, name: str) -> str:
        m = self.mode[name]
        if m != "ok" and self.until[name] and self.clock() >= self.until[name]:
            self.mode[name] = m = "ok"
            self.stuck_value.pop(name, None)
        return m


class FaultyInstruments(Instruments):
    """The instrument models with the injected faults applied to their samples."""

    def __init__(self, config: InstrumentConfig, rng: np.random.Generator,
                 faults: SensorFaults, *, frame_seed: int | None = None) -> None:
        super().__init__(config, rng, frame_seed=frame_seed)
        self.faults = faults

    @property
    def can_sample_trace(self) -> bool:
        """:meth:`sample_trace` makes what :meth:`sample` would: the noise is the one stream
        and no fault is injected (one may end within a period; none can begin there)."""
        mode = self.faults.mode
        return super().can_sample_trace and mode["ins"] == mode["dvl"] == mode["depth"] == "ok"

    def sample(self, t_ns, H, v):
        got = ins, dvl, depth = super().sample(t_ns, H, v)
        mode = self.faults.mode
        if mode["ins"] == mode["dvl"] == mode["depth"] == "ok":
            return got  # no fault injected: the samples as made
        f = self.faults
        out = []
        for name, s in (("ins", ins), ("dvl", dvl), ("depth", depth)):
            mode = f.get(name) if s is not None else "ok"
            if mode == "silence":
                s = None
            elif mode == "nan":
                if name == "ins":
                    s = replace(s, heading=float("nan"))
                elif name == "depth":
                    s = replace(s, depth_m=float("nan"))
                else:
                    s = replace(s, velocity_body=np.full(3, np.nan))
            elif mode == "stuck":
                held = f.stuck_value.setdefault(name, s)
                s = replace(held, t_ns=s.t_ns)
            out.append(s)
        return tuple(out)
