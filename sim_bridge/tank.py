"""The tank, not the model: effects a real vehicle has and the plant of :mod:`sim_bridge.plant`
does not — each a named option, every one off by default.

The thesis ran the real JHU ROV; our plant is the rigid-body model (2.44) with thruster lag,
reversal stiction and saturation (:mod:`sim_bridge.thrusters`). The options here are the
candidate causes of Fig. 5.1's selective drift (issue 32; ``uvd experiment fig51-hunt``). With
every option off nothing here runs: :func:`attach` leaves the plant and the instruments alone,
so every result that does not ask for an option stays bit-identical.

Plant (:class:`TankPlant`, applied every plant step):

* ``tether_n`` — a tether of constant tension (N) from ``tether_anchor_m`` (world, relative to
  the start position) pulling on the vehicle at ``tether_attach_m`` (body); force and torque
  r × f enter the wrench.
* ``buoyancy_n_per_m`` — buoyancy lost with depth (foam compressing): a downward force
  κ (z − z₀) at the centre of buoyancy ``buoyancy_centre_m``, i.e. Δg = κ Δz and Δb = κ Δz r_B
  in G(R) = [g Rᵀe₃; J(b) Rᵀe₃] of (2.44).
* ``advance_loss`` — thrust loss with advance speed, f = k ω|ω| − k_a |ω| u_a (the affine
  advance-speed model of Healey et al. 1995 / Fossen), u_a the water's speed along the
  thruster's axis at its position (body velocity ν + ω × r).
* ``reversal_band_scale`` — the reversal dead band (stiction, §5.3.4) ×scale: wider.
* ``reversal_hold_s`` — after a command changes sign its thruster gets no command for this
  long (the propeller must stop and start again): a longer reversal dead band, in time.
* ``hysteresis_n`` = (on, off) — a hysteretic dead band about zero: a stopped thruster starts
  only when |command| ≥ on, a running one stops when |command| < off.

Instruments (:class:`TankInstruments`, applied to the samples as they fall due):

* ``mounting_bias_rad`` = (roll, pitch, heading) — the INS is mounted rotated by R_b (the
  Euler angles of App. A): it reports R R_b and R_bᵀ ω.
* ``latency_samples`` = (INS, DVL, depth) — each instrument's frame carries the content of its
  frame N samples earlier (the first frame's content until N frames have passed), stamped when
  it arrives.

The instrument rates (DVL 6 Hz, depth 7 Hz, Table A.1) are :class:`InstrumentConfig`'s.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, fields, replace

import numpy as np

from drivers.samples import InsSample, R_to_euler, euler_to_R


def _finite(*xs: float) -> bool:
    return all(math.isfinite(float(x)) for x in xs)


@dataclass(frozen=True)
class TankEffects:
    """Which tank effects are on (module docstring); the defaults switch every one off."""

    tether_n: float = 0.0
    tether_anchor_m: tuple[float, float, float] = (-3.0, 0.0, -2.0)
    tether_attach_m: tuple[float, float, float] = (-0.5, 0.0, -0.3)
    buoyancy_n_per_m: float = 0.0
    buoyancy_centre_m: tuple[float, float, float] = (0.0, 0.0, -0.1)
    advance_loss: float = 0.0
    reversal_band_scale: float = 1.0
    reversal_hold_s: float = 0.0
    hysteresis_n: tuple[float, float] = (0.0, 0.0)
    mounting_bias_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    latency_samples: tuple[int, int, int] = (0, 0, 0)

    def __post_init__(self) -> None:
        vecs = (self.tether_anchor_m, self.tether_attach_m, self.buoyancy_centre_m,
                self.mounting_bias_rad)
        for name, v in zip(("tether_anchor_m", "tether_attach_m", "buoyancy_centre_m",
                            "mounting_bias_rad"), vecs, strict=True):
            if len(v) != 3 or not _finite(*v):
                raise ValueError(f"TankEffects.{name} needs 3 finite numbers, got {v!r}")
        if not _finite(self.tether_n, self.buoyancy_n_per_m, self.advance_loss,
                       self.reversal_band_scale, self.reversal_hold_s, *self.hysteresis_n):
            raise ValueError(f"TankEffects: every number must be finite, got {self!r}")
        if self.tether_n < 0 or self.advance_loss < 0 or self.reversal_hold_s < 0:
            raise ValueError("TankEffects: tether_n, advance_loss and reversal_hold_s must be "
                             f">= 0, got {self.tether_n}, {self.advance_loss}, "
                             f"{self.reversal_hold_s}")
        if self.reversal_band_scale <= 0:
            raise ValueError(f"TankEffects.reversal_band_scale must be > 0, got "
                             f"{self.reversal_band_scale}")
        on, off = self.hysteresis_n
        if len(self.hysteresis_n) != 2 or not 0 <= off <= on:
            raise ValueError(f"TankEffects.hysteresis_n must be (on, off) with 0 <= off <= on, "
                             f"got {self.hysteresis_n!r}")
        if len(self.latency_samples) != 3 or any(int(n) != n or n < 0
                                                 for n in self.latency_samples):
            raise ValueError(f"TankEffects.latency_samples must be 3 integers >= 0 (INS, DVL, "
                             f"depth), got {self.latency_samples!r}")

    @property
    def plant_on(self) -> bool:
        return (self.tether_n > 0 or self.buoyancy_n_per_m != 0 or self.advance_loss > 0
                or self.reversal_band_scale != 1.0 or self.reversal_hold_s > 0
                or self.hysteresis_n[0] > 0)

    @property
    def instruments_on(self) -> bool:
        return any(self.mounting_bias_rad) or any(self.latency_samples)

    def on(self) -> list[str]:
        """Names of the options that differ from the default (for tables)."""
        d = TankEffects()
        return [f.name for f in fields(self) if getattr(self, f.name) != getattr(d, f.name)
                and not f.name.endswith(("_anchor_m", "_attach_m", "_centre_m"))]


def tether_wrench(effects: TankEffects, H: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Body wrench [f; r × f] of the tether: tension ``tether_n`` from the attachment point
    toward the anchor ``origin + tether_anchor_m`` (world)."""
    R, p = H[:3, :3], H[:3, 3]
    r = np.asarray(effects.tether_attach_m)
    d = origin + np.asarray(effects.tether_anchor_m) - (p + R @ r)
    n = float(np.linalg.norm(d))
    if n == 0.0:
        return np.zeros(6)
    f = R.T @ (effects.tether_n * d / n)
    return np.r_[f, np.cross(r, f)]


def buoyancy_wrench(effects: TankEffects, H: np.ndarray, z0: float) -> np.ndarray:
    """[Δg Rᵀe₃; J(Δb) Rᵀe₃] with Δg = κ (z − z₀), Δb = Δg r_B: buoyancy lost with depth."""
    dg = effects.buoyancy_n_per_m * (float(H[2, 3]) - z0)
    down = H[2, :3]  # Rᵀe₃
    return np.r_[dg * down, np.cross(dg * np.asarray(effects.buoyancy_centre_m), down)]


def advance_speeds(positions: np.ndarray, directions: np.ndarray, v: np.ndarray) -> np.ndarray:
    """u_a of each thruster: the body's velocity at its position along its axis (m/s)."""
    vel = v[:3] + np.cross(v[3:], positions)
    return np.einsum("ij,ij->i", vel, directions)


class CommandShaper:
    """The command-side options: the reversal hold and the hysteretic dead band (per thruster,
    applied to the command before the thruster bank)."""

    def __init__(self, effects: TankEffects, n: int, dt: float) -> None:
        self.hold_steps = int(round(effects.reversal_hold_s / dt))
        self.on_n, self.off_n = effects.hysteresis_n
        self.last_sign = np.zeros(n)
        self.hold = np.zeros(n, dtype=int)
        self.running = np.zeros(n, dtype=bool)

    def __call__(self, command: np.ndarray) -> np.ndarray:
        c = np.array(command, dtype=float)
        c[~np.isfinite(c)] = 0.0
        if self.on_n > 0:
            a = np.abs(c)
            self.running = np.where(self.running, a >= self.off_n, a >= self.on_n)
            c[~self.running] = 0.0
        if self.hold_steps > 0:
            s = np.sign(c)
            flip = (s != 0) & (self.last_sign != 0) & (s != self.last_sign)
            self.hold[flip] = self.hold_steps
            self.last_sign[s != 0] = s[s != 0]
            held = self.hold > 0
            c[held] = 0.0
            self.hold[held] -= 1
        return c


class TankPlant:
    """A :class:`sim_bridge.plant.Plant` with the plant-side options: what the lockstep sees
    (``H``, ``v``, ``thrusters``, ``step``) is the wrapped plant's."""

    def __init__(self, plant, effects: TankEffects) -> None:
        self.plant = plant
        self.effects = effects
        self.origin = plant.H[:3, 3].copy()
        self.z0 = float(plant.H[2, 3])
        specs = plant.vehicle.thrusters
        self.positions = np.array([s.position_m for s in specs], dtype=float)
        self.directions = np.array([s.direction for s in specs], dtype=float)
        plant.thrusters.stiction = plant.thrusters.stiction * effects.reversal_band_scale
        self.shaper = CommandShaper(effects, len(specs), plant.dt)

    def __getattr__(self, name):  # H, v, u, t, thrusters, vehicle, … of the wrapped plant
        return getattr(self.plant, name)

    def step(self, thrust_command_n: np.ndarray) -> None:
        """One plant step: shaped command → thrusters (minus the advance-speed loss) → u = B f
        plus the tether's and the depth-dependent buoyancy's wrench → (2.44)."""
        p, e = self.plant, self.effects
        f = p.thrusters.step(self.shaper(thrust_command_n), p.dt).copy()
        if e.advance_loss > 0:
            ua = advance_speeds(self.positions, self.directions, p.v)
            f -= e.advance_loss * np.abs(p.thrusters.omega) * ua * p.thrusters.health
        u = p.B @ f
        if e.tether_n > 0:
            u += tether_wrench(e, p.H, self.origin)
        if e.buoyancy_n_per_m != 0:
            u += buoyancy_wrench(e, p.H, self.z0)
        p.step_wrench(u)


def mounted(ins: InsSample, R_b: np.ndarray) -> InsSample:
    """The INS sample as an INS mounted rotated by R_b reports it: attitude R R_b, rate R_bᵀ ω."""
    R = euler_to_R(ins.roll, ins.pitch, ins.heading) @ R_b
    roll, pitch, heading = R_to_euler(R)
    return replace(ins, roll=roll, pitch=pitch, heading=heading,
                   omega_body=R_b.T @ np.asarray(ins.omega_body))


class Delay:
    """N samples of latency: each call returns the content of the sample N calls earlier
    (the first sample's until N have passed), stamped as the one given."""

    def __init__(self, n: int) -> None:
        self.n = int(n)
        self.queue: deque = deque(maxlen=self.n + 1)

    def __call__(self, sample):
        if self.n == 0 or sample is None:
            return sample
        if not self.queue:
            self.queue.extend([sample] * self.n)
        self.queue.append(sample)
        return replace(self.queue[0], t_ns=sample.t_ns)


class TankInstruments:
    """Instruments (anything with ``sample(t_ns, H, v)``) with the instrument-side options."""

    def __init__(self, instruments, effects: TankEffects) -> None:
        self.instruments = instruments
        self.effects = effects
        self.R_b = euler_to_R(*effects.mounting_bias_rad)
        self.bias = any(effects.mounting_bias_rad)
        self.delays = [Delay(n) for n in effects.latency_samples]

    def __getattr__(self, name):
        return getattr(self.instruments, name)

    def sample(self, t_ns, H, v):
        ins, dvl, depth = self.instruments.sample(t_ns, H, v)
        if ins is not None and self.bias:
            ins = mounted(ins, self.R_b)
        return tuple(d(s) for d, s in zip(self.delays, (ins, dvl, depth), strict=True))


def attach(sim, effects: TankEffects | None) -> None:
    """Switch ``effects`` on in a lockstep simulation (anything with ``plant`` and
    ``instruments``) before its first cycle; with None or every option off, nothing changes.
    The frame the lockstep primed at construction (t = 0) is taken as it was made."""
    if effects is None:
        return
    if effects.plant_on:
        sim.plant = TankPlant(sim.plant, effects)
    if effects.instruments_on:
        sim.instruments = TankInstruments(sim.instruments, effects)
