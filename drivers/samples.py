"""Sensor samples in SI units and the body/world frames of uvd (thesis App. A).

These are what every instrument source — a hardware codec, an emulator, or the simulated
instruments of a lockstep run — delivers to navigation. World frame north-east-down, body frame
x bow, y starboard, z keel; angles in radians; the Euler sequence of App. A: heading about z,
then pitch about the new y, then roll about the new x (R = Rz(heading) Ry(pitch) Rx(roll)).
``t_ns`` is the monotonic receive (or simulated) time in nanoseconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, slots=True)
class InsSample:
    """Attitude and body angular rate from an INS (PHINS)."""

    t_ns: int
    roll: float
    pitch: float
    heading: float
    omega_body: np.ndarray  # (3,) rad/s, body frame
    rates_valid: bool = True  # False when rates were derived from attitude (degraded)
    valid: bool = True
    source: str = "ins"


@dataclass(frozen=True, slots=True)
class DvlSample:
    """Vehicle velocity over ground in the body frame, from a bottom-lock DVL."""

    t_ns: int
    velocity_body: np.ndarray  # (3,) m/s, vehicle motion (not the bottom's), body frame
    bottom_lock: bool
    altitude_m: float = float("nan")
    good_beams: int = 4
    source: str = "dvl"


@dataclass(frozen=True, slots=True)
class DepthSample:
    """Depth of the vehicle origin below the surface (world z), metres, positive down."""

    t_ns: int
    depth_m: float
    pressure_pa: float = float("nan")
    valid: bool = True
    source: str = "depth"


@dataclass(frozen=True, slots=True)
class PositionSample:
    """Horizontal position (north, east) in metres, e.g. from an external DVLNAV or USBL."""

    t_ns: int
    north_m: float
    east_m: float
    source: str = "position"
    extra: dict = field(default_factory=dict)
