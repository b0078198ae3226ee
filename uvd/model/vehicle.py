"""A vehicle description: the UV parameters of (2.44) plus its thrusters.

Vehicle files (the built-in ``uvd/vehicles/*.toml`` or any other) are read by
:func:`uvd.io.vehicle.load_vehicle`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from uvd.model.params import UVParams
from uvd.model.thrusters import ThrusterSpec, thruster_matrix


@dataclass(frozen=True)
class Vehicle:
    name: str
    description: str
    params: UVParams
    thrusters: tuple[ThrusterSpec, ...]

    @cached_property
    def B(self) -> np.ndarray:
        """Thruster matrix, u = B f (6 × N)."""
        return thruster_matrix(self.thrusters)

    @property
    def n_thrusters(self) -> int:
        return len(self.thrusters)

    @property
    def k_thrust(self) -> np.ndarray:
        return np.array([t.k_thrust for t in self.thrusters])

    @property
    def max_thrust_n(self) -> np.ndarray:
        return np.array([t.max_thrust_n for t in self.thrusters])
