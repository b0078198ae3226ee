"""Thruster geometry and the steady-state thruster law (App. A.1) — pure math.

A thruster at body position r with unit thrust direction d contributes the body wrench
[d; r × d] per newton, so u = B f with B = [[d₁ … d_N], [r₁×d₁ … r_N×d_N]] ∈ R⁶ˣᴺ.
Steady state, thrust and propeller speed obey f = k ω|ω| (App. A.1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uvd.errors import ParameterError


@dataclass(frozen=True)
class ThrusterSpec:
    """One thruster: geometry (body frame, m), f = k ω|ω| constant, limits and dynamics."""

    name: str
    position_m: tuple[float, float, float]
    direction: tuple[float, float, float]
    k_thrust: float = 0.0048
    max_thrust_n: float = 300.0
    time_constant_s: float = 0.15
    stiction_n: float = 5.0
    curve: ThrustCurve | None = None

    def __post_init__(self) -> None:
        """Every number finite (a NaN or infinite gain or limit would reach the loop, whose
        guard would then hold zero thrust for ever), the limits and constants of the right
        sign; a :class:`ParameterError` names the thruster and the field."""
        if not isinstance(self.name, str) or not self.name:
            raise ParameterError(f"thruster name must be a non-empty string, got {self.name!r}")
        position = _vector3(self.name, "position_m", self.position_m)
        d = _vector3(self.name, "direction", self.direction)
        with np.errstate(over="ignore"):  # a norm past the largest float is refused below
            n = float(np.linalg.norm(d))
        if not (math.isfinite(n) and n > 0.0):
            raise ParameterError(f"thruster {self.name!r}: direction must be a non-zero "
                                 f"vector of finite length, got {self.direction!r}")
        object.__setattr__(self, "direction", tuple(float(x) for x in d / n))
        object.__setattr__(self, "position_m", tuple(float(x) for x in position))
        for key, least, strict in (("k_thrust", 0.0, True), ("max_thrust_n", 0.0, True),
                                   ("time_constant_s", 0.0, False),
                                   ("stiction_n", 0.0, False)):
            x = _number(self.name, key, getattr(self, key))
            if x < least or (strict and x == least):
                raise ParameterError(f"thruster {self.name!r}: {key} must be "
                                     f"{'>' if strict else '>='} {least:g}, got {x!r}")
            object.__setattr__(self, key, x)


def _number(name: str, key: str, x) -> float:
    """``x`` as a float when it is a finite real number (not a bool, a string or a list)."""
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)) \
            or not math.isfinite(x):
        raise ParameterError(f"thruster {name!r}: {key} must be a finite number, got {x!r}")
    return float(x)


def _vector3(name: str, key: str, x) -> np.ndarray:
    """``x`` as three finite numbers."""
    if isinstance(x, (str, bytes)) or not hasattr(x, "__len__") or len(x) != 3:
        raise ParameterError(f"thruster {name!r}: {key} needs 3 entries, got {x!r}")
    return np.array([_number(name, key, e) for e in x])


def thruster_matrix(specs: tuple[ThrusterSpec, ...] | list[ThrusterSpec]) -> np.ndarray:
    """B ∈ R⁶ˣᴺ with u = [f; τ] = B f_thrusters."""
    B = np.zeros((6, len(specs)))
    for j, s in enumerate(specs):
        d = np.asarray(s.direction)
        r = np.asarray(s.position_m)
        B[:3, j] = d
        B[3:, j] = np.cross(r, d)
    return B


def thrust_from_commands(specs, commands: np.ndarray) -> np.ndarray:
    """Thrust (N) of every thruster, (n, N), from recorded commands (n, N) through each
    thruster's :class:`ThrustCurve`; raises :class:`ParameterError` naming a thruster without
    one."""
    commands = np.atleast_2d(np.asarray(commands, dtype=float))
    if commands.shape[1] != len(specs):
        raise ParameterError(f"{commands.shape[1]} thruster commands for {len(specs)} thrusters")
    out = np.empty_like(commands)
    for j, s in enumerate(specs):
        if s.curve is None:
            raise ParameterError(f"thruster {s.name!r}: no thrust curve (command -> thrust)")
        out[:, j] = s.curve.thrust(commands[:, j])
    return out


def thrust_from_speed(omega: np.ndarray, k: np.ndarray | float) -> np.ndarray:
    """Steady-state thrust f = k ω|ω| (App. A.1); ω in rad/s, f in N."""
    omega = np.asarray(omega, dtype=float)
    return k * omega * np.abs(omega)


def speed_from_thrust(f: np.ndarray, k: np.ndarray | float) -> np.ndarray:
    """Inverse of :func:`thrust_from_speed`: ω = sign(f) √(|f|/k)."""
    f = np.asarray(f, dtype=float)
    return np.sign(f) * np.sqrt(np.abs(f) / k)


@dataclass(frozen=True)
class ThrustCurve:
    """Steady-state thrust of one thruster as a function of its command: a table with linear
    interpolation, a dead band and separate forward and reverse branches.

    The command is what the log records: a PWM pulse width (µs) or a normalised command; the
    table is (command, thrust N) pairs, increasing in command. Within ``dead_band`` of
    ``neutral`` the thrust is 0; outside the table the end values hold (the ESC clamps). The
    table itself carries the asymmetry (e.g. T200: +49.95 N at u = +1, −40.08 N at u = −1),
    so forward and reverse are as measured, not mirrored.
    """

    command: tuple[float, ...]
    thrust_n: tuple[float, ...]
    neutral: float = 0.0
    dead_band: float = 0.0
    unit: str = "normalised"
    source: str = ""

    def __post_init__(self) -> None:
        c = np.asarray(self.command, dtype=float)
        f = np.asarray(self.thrust_n, dtype=float)
        if c.ndim != 1 or c.shape != f.shape or c.size < 2:
            raise ParameterError("thrust curve: command and thrust_n need the same length >= 2")
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(f))):
            raise ParameterError("thrust curve: non-finite entries")
        if not np.all(np.diff(c) > 0):
            raise ParameterError("thrust curve: command must increase strictly")
        if not np.all(np.diff(f) >= 0):
            raise ParameterError("thrust curve: thrust must not decrease with the command")
        if not (math.isfinite(self.neutral) and math.isfinite(self.dead_band)):
            raise ParameterError(f"thrust curve: neutral and dead_band must be finite, got "
                                 f"{self.neutral!r}, {self.dead_band!r}")
        if self.dead_band < 0:
            raise ParameterError("thrust curve: dead_band must be >= 0")
        if self.unit not in ("pwm_us", "normalised"):
            raise ParameterError(f"thrust curve: unit must be 'pwm_us' or 'normalised', "
                                 f"got {self.unit!r}")
        object.__setattr__(self, "command", tuple(float(x) for x in c))
        object.__setattr__(self, "thrust_n", tuple(float(x) for x in f))

    def thrust(self, cmd: np.ndarray) -> np.ndarray:
        """Thrust (N) of commands ``cmd`` (any shape, the curve's unit)."""
        cmd = np.asarray(cmd, dtype=float)
        f = np.interp(cmd, self.command, self.thrust_n)
        return np.where(np.abs(cmd - self.neutral) <= self.dead_band, 0.0, f)

    @property
    def max_forward_n(self) -> float:
        return float(self.thrust_n[-1])

    @property
    def max_reverse_n(self) -> float:
        return float(self.thrust_n[0])
