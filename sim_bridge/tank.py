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

import numba
import numpy as np

from drivers.samples import InsSample
from sim_bridge.thrusters import _thruster_step
from uvd.geometry import R_to_euler, euler_to_R
from uvd.model.integrate import _rkmk4


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


@numba.njit(cache=True)
def _shape(c, last_sign, hold, running, hold_steps, on_n, off_n):
    """The command-side options in place: hysteretic dead band, then the reversal hold."""
    for i in range(c.shape[0]):
        x = c[i]
        if not np.isfinite(x):
            x = 0.0
        if on_n > 0.0:
            running[i] = abs(x) >= (off_n if running[i] else on_n)
            if not running[i]:
                x = 0.0
        if hold_steps > 0:
            s = np.sign(x)
            if s != 0.0 and last_sign[i] != 0.0 and s != last_sign[i]:
                hold[i] = hold_steps
            if s != 0.0:
                last_sign[i] = s
            if hold[i] > 0:
                x = 0.0
                hold[i] -= 1
        c[i] = x


class CommandShaper:
    """The command-side options: the reversal hold and the hysteretic dead band (per thruster,
    applied to the command before the thruster bank)."""

    def __init__(self, effects: TankEffects, n: int, dt: float) -> None:
        self.hold_steps = int(round(effects.reversal_hold_s / dt))
        self.on_n, self.off_n = (float(x) for x in effects.hysteresis_n)
        self.last_sign = np.zeros(n)
        self.hold = np.zeros(n, dtype=np.int64)
        self.running = np.zeros(n, dtype=np.bool_)

    def __call__(self, command: np.ndarray) -> np.ndarray:
        c = np.array(command, dtype=float)
        _shape(c, self.last_sign, self.hold, self.running, self.hold_steps, self.on_n,
               self.off_n)
        return c


@numba.njit(cache=True)
def _tank_step(thr_args, omega, health, pos, dirs, ka, B, M, M_inv, D_flat, g, b, H, v, dt,
               u, H_out, v_out, tether_n, anchor, attach_pt, kappa, z0, r_b):
    """One plant step with the plant-side options, compiled: thrusters, the advance-speed loss,
    u = B f + tether + buoyancy lost with depth, then RKMK4 (2.44) — as the functions above."""
    _thruster_step(*thr_args)
    f = thr_args[-1].copy()
    if ka > 0.0:
        for i in range(f.shape[0]):
            r0, r1, r2 = pos[i, 0], pos[i, 1], pos[i, 2]
            w0, w1, w2 = v[3], v[4], v[5]
            ua = ((v[0] + w1 * r2 - w2 * r1) * dirs[i, 0] + (v[1] + w2 * r0 - w0 * r2) * dirs[i, 1]
                  + (v[2] + w0 * r1 - w1 * r0) * dirs[i, 2])
            f[i] -= ka * abs(omega[i]) * ua * health[i]
    for i in range(6):
        acc = 0.0
        for j in range(f.shape[0]):
            acc += B[i, j] * f[j]
        u[i] = acc
    if tether_n > 0.0:
        d = np.empty(3)
        for i in range(3):
            d[i] = anchor[i] - H[i, 3] - (H[i, 0] * attach_pt[0] + H[i, 1] * attach_pt[1]
                                          + H[i, 2] * attach_pt[2])
        n = np.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        if n > 0.0:
            fb = np.empty(3)
            for i in range(3):
                fb[i] = tether_n * (H[0, i] * d[0] + H[1, i] * d[1] + H[2, i] * d[2]) / n
            u[0] += fb[0]
            u[1] += fb[1]
            u[2] += fb[2]
            u[3] += attach_pt[1] * fb[2] - attach_pt[2] * fb[1]
            u[4] += attach_pt[2] * fb[0] - attach_pt[0] * fb[2]
            u[5] += attach_pt[0] * fb[1] - attach_pt[1] * fb[0]
    if kappa != 0.0:
        dg = kappa * (H[2, 3] - z0)
        e0, e1, e2 = H[2, 0], H[2, 1], H[2, 2]
        u[0] += dg * e0
        u[1] += dg * e1
        u[2] += dg * e2
        u[3] += dg * (r_b[1] * e2 - r_b[2] * e1)
        u[4] += dg * (r_b[2] * e0 - r_b[0] * e2)
        u[5] += dg * (r_b[0] * e1 - r_b[1] * e0)
    _rkmk4(M, M_inv, D_flat, g, b, H, v, u, dt, H_out, v_out)


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
        self._anchor = self.origin + np.asarray(effects.tether_anchor_m, dtype=float)
        self._attach = np.asarray(effects.tether_attach_m, dtype=float)
        self._r_b = np.asarray(effects.buoyancy_centre_m, dtype=float)

    def __getattr__(self, name):  # H, v, u, t, thrusters, vehicle, … of the wrapped plant
        return getattr(self.plant, name)

    def step(self, thrust_command_n: np.ndarray) -> None:
        """One plant step: shaped command → thrusters (minus the advance-speed loss) → u = B f
        plus the tether's and the depth-dependent buoyancy's wrench → (2.44)."""
        p, e, m = self.plant, self.effects, self.plant.model
        bank = p.thrusters
        _tank_step(bank.kernel_args(self.shaper(thrust_command_n), p.dt), bank.omega,
                   bank.health, self.positions, self.directions, float(e.advance_loss), p.B,
                   m.M, m.M_inv, m.D_flat, m.g, m.b, p.H, p.v, p.dt, p.u, p._H_next,
                   p._v_next, float(e.tether_n), self._anchor, self._attach,
                   float(e.buoyancy_n_per_m), self.z0, self._r_b)
        p.H, p._H_next = p._H_next, p.H
        p.v, p._v_next = p._v_next, p.v
        p.steps += 1
        p.t = p.steps * p.dt

    def steps_held(self, thrust_command_n: np.ndarray, n: int,
                   trace: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """``n`` calls of :meth:`step` (the command shaper runs at every one); ``trace`` as
        :meth:`sim_bridge.plant.Plant.steps_held`'s."""
        p = self.plant
        for i in range(n):
            self.step(thrust_command_n)
            if trace is not None and i < trace[0].shape[0]:
                trace[0][i], trace[1][i] = p.H, p.v


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
