"""Thruster dynamics of the simulated plant (App. A.1, §5.3.3–5.3.4).

Each thruster receives a thrust command (N). Effects, each switchable:

* **saturation** — the command is clipped to ±max_thrust_n;
* **lag** — the propeller speed ω follows the steady-state speed of the command,
  ω* = sign(f) √(|f|/k), with a first-order lag of time constant τ (exact discretisation);
* **stiction** — after the command changes sign the thrust stays zero (propeller stopped)
  until |command| ≥ stiction_n (5 N on the JHU ROV, §5.3.4).

Two more effects of real thrusters, off by default (every vehicle and experiment runs without
them unless it asks; ``ambc-6dof-unstable`` turns them on to reproduce §5.3.2):

* **dead band** (``dead_band_n`` > 0) — a command with |command| < dead_band_n turns nothing
  (the amplifier's dead band; the propeller spins down to zero);
* **asymmetry** (``reverse_ratio`` ≠ 1) — for negative propeller speed the thrust is
  reverse_ratio · k ω|ω|: a propeller shaped for forward thrust delivers less in reverse. The
  speed ω (what the amplifier reports) is unchanged, so a controller that estimates thrust as
  k ω|ω| (App. A.1) does not see it.

The thrust produced is the steady-state law f = k ω|ω| (App. A.1) of the current propeller
speed; ``omega`` is what a propeller-speed sensor (an amplifier's velocity feedback) reads.
``health`` scales each thruster's thrust (1 healthy, 0.5 weak, 0 dead) for fault injection.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from uvd.model.thrusters import ThrusterSpec


@dataclass(frozen=True)
class ThrusterEffects:
    """Which thruster effects the plant applies (module docstring).

    ``dead_band_n`` (N, 0: off) and ``reverse_ratio`` (thrust in reverse over thrust forward at
    the same propeller speed, 1: symmetric) are off by default.
    """

    lag: bool = True
    stiction: bool = True
    saturation: bool = True
    dead_band_n: float = 0.0
    reverse_ratio: float = 1.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.dead_band_n) and self.dead_band_n >= 0.0):
            raise ValueError(f"ThrusterEffects.dead_band_n must be finite and >= 0, "
                             f"got {self.dead_band_n!r}")
        if not (np.isfinite(self.reverse_ratio) and self.reverse_ratio > 0.0):
            raise ValueError(f"ThrusterEffects.reverse_ratio must be finite and > 0, "
                             f"got {self.reverse_ratio!r}")


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
            a = np.ones_like(self.tau)
            pos = self.tau > 0.0
            a[pos] = 1.0 - np.exp(-dt / self.tau[pos])
            self._alpha_cache = (dt, a)
        return self._alpha_cache[1]

    def step(self, command_n: np.ndarray, dt: float) -> np.ndarray:
        """Advance by dt with the thrust commands held; return the thrust produced (N)."""
        _thruster_step(*self.kernel_args(command_n, dt))
        return self.thrust

    def kernel_args(self, command_n: np.ndarray, dt: float) -> tuple:
        """Arguments of :func:`_thruster_step` (the plant fuses it with its integrator)."""
        e = self.effects
        return (np.asarray(command_n, dtype=float), self._alpha(dt), self.k, self.max_thrust,
                self.stiction, self.health, e.saturation, e.stiction, e.lag,
                float(e.dead_band_n), float(e.reverse_ratio), self.omega,
                self._last_sign, self._stuck, self.thrust)


@numba.njit(cache=True)
def _thruster_step(cmd_in, alpha, k, max_thrust, stiction, health, saturate, stick, lag,
                   dead_band, reverse_ratio, omega, last_sign, stuck, thrust_out):
    """The per-thruster effects of the module docstring, in place (compiled: ~1 µs for six)."""
    for i in range(cmd_in.shape[0]):
        c = cmd_in[i]
        if not np.isfinite(c):  # a non-finite command is no command
            c = 0.0
        if saturate:
            c = min(max(c, -max_thrust[i]), max_thrust[i])
        if dead_band > 0.0 and abs(c) < dead_band:
            c = 0.0
        if stick:
            s = np.sign(c)
            if s != 0.0 and last_sign[i] != 0.0 and s != last_sign[i]:
                stuck[i] = True
            if abs(c) >= stiction[i]:
                stuck[i] = False
            if stuck[i]:
                c = 0.0
            if c != 0.0:
                last_sign[i] = np.sign(c)
        target = np.sign(c) * np.sqrt(abs(c) / k[i])
        if lag:
            omega[i] += alpha[i] * (target - omega[i])
            if stick and stuck[i]:
                omega[i] = 0.0
        else:
            omega[i] = target
        thrust_out[i] = health[i] * k[i] * omega[i] * abs(omega[i])
        if reverse_ratio != 1.0 and omega[i] < 0.0:
            thrust_out[i] *= reverse_ratio
