"""Thruster dynamics of the simulated plant (App. A.1, §5.3.3–5.3.4).

Each thruster receives a thrust command (N). Effects, each switchable:

* **saturation** — the command is clipped to ±max_thrust_n;
* **lag** — the propeller speed ω follows the steady-state speed of the command,
  ω* = sign(f) √(|f|/k), with a first-order lag of time constant τ (exact discretisation);
* **stiction** — after the command changes sign the thrust stays zero (propeller stopped)
  until |command| ≥ stiction_n (5 N on the JHU ROV, §5.3.4).

The thrust produced is the steady-state law f = k ω|ω| (App. A.1) of the current propeller
speed; ``omega`` is what a propeller-speed sensor (an amplifier's velocity feedback) reads.
``health`` scales each thruster's thrust (1 healthy, 0.5 weak, 0 dead) for fault injection.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uvd.model.thrusters import ThrusterSpec, speed_from_thrust, thrust_from_speed


@dataclass(frozen=True)
class ThrusterEffects:
    lag: bool = True
    stiction: bool = True
    saturation: bool = True


class ThrusterBank:
    """The N thrusters of a vehicle; state is the propeller speeds and reversal latches."""

    def __init__(self, specs: tuple[ThrusterSpec, ...] | list[ThrusterSpec],
                 effects: ThrusterEffects = ThrusterEffects()) -> None:
        self.specs = tuple(specs)
        self.effects = effects
        n = len(self.specs)
        self.k = np.array([s.k_thrust for s in self.specs])
        self.max_thrust = np.array([s.max_thrust_n for s in self.specs])
        self.tau = np.array([s.time_constant_s for s in self.specs])
        self.stiction = np.array([s.stiction_n for s in self.specs])
        self.health = np.ones(n)
        self.omega = np.zeros(n)
        self.thrust = np.zeros(n)
        self._last_sign = np.zeros(n)  # sign of the last command that produced thrust
        self._stuck = np.zeros(n, dtype=bool)
        self._alpha_cache: tuple[float, np.ndarray] | None = None

    def reset(self) -> None:
        self.omega[:] = 0.0
        self.thrust[:] = 0.0
        self._last_sign[:] = 0.0
        self._stuck[:] = False

    def _alpha(self, dt: float) -> np.ndarray:
        if self._alpha_cache is None or self._alpha_cache[0] != dt:
            with np.errstate(divide="ignore"):
                a = np.where(self.tau > 0.0, 1.0 - np.exp(-dt / np.maximum(self.tau, 1e-300)), 1.0)
            self._alpha_cache = (dt, a)
        return self._alpha_cache[1]

    def step(self, command_n: np.ndarray, dt: float) -> np.ndarray:
        """Advance by dt with the thrust commands held; return the thrust produced (N)."""
        cmd = np.asarray(command_n, dtype=float)
        cmd = np.where(np.isfinite(cmd), cmd, 0.0)  # a non-finite command is no command
        if self.effects.saturation:
            cmd = np.clip(cmd, -self.max_thrust, self.max_thrust)
        if self.effects.stiction:
            sign = np.sign(cmd)
            reversed_ = (sign != 0.0) & (self._last_sign != 0.0) & (sign != self._last_sign)
            self._stuck |= reversed_
            self._stuck &= ~(np.abs(cmd) >= self.stiction)
            cmd = np.where(self._stuck, 0.0, cmd)
            self._last_sign = np.where(cmd != 0.0, np.sign(cmd), self._last_sign)
        target = speed_from_thrust(cmd, self.k)
        if self.effects.lag:
            self.omega += self._alpha(dt) * (target - self.omega)
            if self.effects.stiction:
                self.omega = np.where(self._stuck, 0.0, self.omega)
        else:
            self.omega = target
        self.thrust = self.health * thrust_from_speed(self.omega, self.k)
        return self.thrust
