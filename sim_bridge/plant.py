"""The simulated plant: rigid body (2.44) on SE(3), thrusters, and nothing else — no I/O.

Fixed-step RKMK4 (:mod:`uvd.model.integrate`) at ``rate_hz`` (default 100 Hz); the pose is kept
on SE(3) and updated through the exponential map, so there is no Euler-angle singularity
anywhere in the plant. Thrust commands go through :class:`sim_bridge.thrusters.ThrusterBank`
(saturation, propeller lag, reversal stiction), then u = B f.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from sim_bridge.thrusters import ThrusterBank, ThrusterEffects, _thruster_step
from uvd.model.dynamics import UVModel
from uvd.model.integrate import _rkmk4
from uvd.model.vehicle import Vehicle


@dataclass(frozen=True)
class PlantFault:
    """A change of the vehicle itself, for fault detection (thesis §6.2): the plant's true
    parameters become ``drag_scale``·D (entanglement: drag up), ``mass_scale``·M (flooding,
    a lost part), g + ``g_delta`` and b + ``b_delta`` (a lost float, a flooded housing);
    thruster faults are the bank's ``health`` (1 healthy, 0.5 weak, 0 dead)."""

    drag_scale: float = 1.0
    mass_scale: float = 1.0
    g_delta: float = 0.0
    b_delta: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        vals = (self.drag_scale, self.mass_scale, self.g_delta, *self.b_delta)
        if not all(math.isfinite(float(x)) for x in vals) or self.drag_scale <= 0.0 \
                or self.mass_scale <= 0.0:
            raise ValueError(f"PlantFault: scales must be finite and > 0, deltas finite; got "
                             f"{self!r}")

    def apply(self, p):
        """The parameters ``p`` (:class:`uvd.model.params.UVParams`) with this fault."""
        from uvd.model.params import UVParams
        return UVParams(M=np.asarray(p.M) * self.mass_scale,
                        D=np.asarray(p.D) * self.drag_scale, g=float(p.g) + self.g_delta,
                        b=np.asarray(p.b, dtype=float) + np.asarray(self.b_delta, dtype=float))


@dataclass(frozen=True)
class PlantConfig:
    rate_hz: float = 100.0
    thrusters: ThrusterEffects = field(default_factory=ThrusterEffects)


class Plant:
    """Simulated vehicle: state (t, H, v), advanced by :meth:`step` with thruster commands."""

    def __init__(self, vehicle: Vehicle, config: PlantConfig = PlantConfig(), *,
                 H0: np.ndarray | None = None, v0: np.ndarray | None = None) -> None:
        if not config.rate_hz > 0:
            raise ValueError(f"plant rate_hz must be > 0, got {config.rate_hz}")
        self.vehicle = vehicle
        self.config = config
        self.model = UVModel.from_params(vehicle.params)
        self.dt = 1.0 / config.rate_hz
        self.thrusters = ThrusterBank(vehicle.thrusters, config.thrusters)
        self.B = np.ascontiguousarray(vehicle.B)
        self.t = 0.0
        self.steps = 0
        self.H = np.eye(4) if H0 is None else np.array(H0, dtype=float)
        self.v = np.zeros(6) if v0 is None else np.array(v0, dtype=float)
        self.u = np.zeros(6)  # body wrench applied during the last step (u = B f)
        self.fault = PlantFault()  # none
        self._H_next = np.empty((4, 4))
        self._v_next = np.empty(6)
        self._no_trace = (np.empty((0, 4, 4)), np.empty((0, 6)))

    def set_fault(self, fault: PlantFault | None) -> None:
        """From now on the vehicle's true parameters are ``fault.apply(vehicle.params)``
        (None: the vehicle file's own again); the state carries on."""
        self.fault = fault if fault is not None else PlantFault()
        p = self.vehicle.params if fault is None else fault.apply(self.vehicle.params)
        self.model = UVModel.from_params(p)

    @property
    def R(self) -> np.ndarray:
        return self.H[:3, :3]

    @property
    def p(self) -> np.ndarray:
        return self.H[:3, 3]

    def step(self, thrust_command_n: np.ndarray) -> None:
        """Advance one step of 1/rate_hz with the thruster commands (N) held."""
        self.steps_held(thrust_command_n, 1)

    def steps_held(self, thrust_command_n: np.ndarray, n: int,
                   trace: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Advance ``n`` steps of 1/rate_hz with the thruster commands (N) held (zero-order
        hold): one compiled call, the very arithmetic of ``n`` calls of :meth:`step`.

        ``trace`` = (H (≥ n, 4, 4), v (≥ n, 6)): the state after step i + 1 is also written
        into ``H[i]``, ``v[i]`` (what the instruments sample inside the period, as
        :meth:`uvd.lockstep.Lockstep.advance` does)."""
        m = self.model
        H_trace, v_trace = self._no_trace if trace is None else trace
        _steps_held(n, self.thrusters.kernel_args(thrust_command_n, self.dt), self.B, m.M,
                    m.M_inv, m.D_flat, m.g, m.b, self.H, self.v, self.dt, self.u, self._H_next,
                    self._v_next, H_trace, v_trace)
        if n % 2:  # the state ended in the second pair of buffers
            self.H, self._H_next = self._H_next, self.H
            self.v, self._v_next = self._v_next, self.v
        self.steps += n
        self.t = self.steps * self.dt

    def step_wrench(self, u: np.ndarray) -> None:
        """Advance one step with the body wrench u = [f; τ] applied directly (ideal actuators)."""
        u = np.asarray(u, dtype=float)
        if not math.isfinite(float(u.sum())):  # a NaN/inf wrench is no wrench
            u = np.zeros(6)
        self.u[:] = u
        m = self.model
        _rkmk4(m.M, m.M_inv, m.D_flat, m.g, m.b, self.H, self.v, u, self.dt,
               self._H_next, self._v_next)
        self.H, self._H_next = self._H_next, self.H
        self.v, self._v_next = self._v_next, self.v
        self.steps += 1
        self.t = self.steps * self.dt


@numba.njit(cache=True)
def _thrusters_then_rigid_body(thr_args, B, M, M_inv, D_flat, g, b, H, v, dt, u, H_out, v_out):
    """One plant step in one compiled call: thruster effects, u = B f, then RKMK4 (2.44)."""
    _thruster_step(*thr_args)
    f = thr_args[-1]
    for i in range(6):
        acc = 0.0
        for j in range(f.shape[0]):
            acc += B[i, j] * f[j]
        u[i] = acc
    _rkmk4(M, M_inv, D_flat, g, b, H, v, u, dt, H_out, v_out)


@numba.njit(cache=True)
def _steps_held(n, thr_args, B, M, M_inv, D_flat, g, b, H, v, dt, u, H_next, v_next, H_trace,
                v_trace):
    """``n`` plant steps with the command held, alternating between the two state buffers
    (after an odd ``n`` the state is in ``H_next``, ``v_next``); the state after step i + 1
    also into ``H_trace[i]``, ``v_trace[i]`` for i below their length."""
    for i in range(n):
        if i % 2 == 0:
            _thrusters_then_rigid_body(thr_args, B, M, M_inv, D_flat, g, b, H, v, dt, u,
                                       H_next, v_next)
            H_new, v_new = H_next, v_next
        else:
            _thrusters_then_rigid_body(thr_args, B, M, M_inv, D_flat, g, b, H_next, v_next,
                                       dt, u, H, v)
            H_new, v_new = H, v
        if i < H_trace.shape[0]:
            H_trace[i] = H_new
            v_trace[i] = v_new
