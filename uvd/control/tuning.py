"""Per-axis PD tuning from a vehicle's mass matrix, and the sampled closed loop it gives.

The PD law (5.11), u = −(k_p A⁻ᵀ(Δψ)Δψ + k_d Δv), decouples near the reference (A⁻ᵀ ≈ I,
the vehicle's M nearly diagonal) into one loop per degree of freedom i::

    m_i ẍ + (k_d,i + c_i) ẋ + (k_p,i + s_i) x = 0

with m_i = M_ii of (2.44), s_i the hydrostatic stiffness (b₃ in roll and pitch, G(R) of
(2.44)) and c_i the quadratic drag |d_i| ẋ|ẋ| linearised at a speed amplitude V by its
describing function, c_i = 8|d_i|V/(3π) (:func:`equivalent_damping`; zero at rest, the worst
case). **The rule** (docs/tuning.md): choose a bandwidth ω and a damping ratio ζ per axis and
set

    k_p,i = m_i ω_i²,    k_d,i = 2 ζ_i ω_i m_i

so that every axis has the same natural frequency and damping whatever its mass: a 20 kg
translation and a 0.4 kg m² rotation get gains 50× apart, as they must. The bandwidth is limited
by what the loop delays: the cycle's zero-order hold (dt/2), the age of the frame it uses
(``delay_cycles`` whole periods), and the propeller lag τ. The default
ω = ``DELAY_MARGIN`` / (dt (delay_cycles + ½) + τ) keeps the phase those delays cost at the
crossover near 17°.

:func:`closed_loop` gives the figures of such a loop as the daemon runs it: the plant
(m ẍ = f − s x, τ ḟ = u − f) sampled with a zero-order hold at dt, the PD on a measurement
``delay_cycles`` periods old; the poles of that discrete loop, their largest modulus (< 1:
stable) and the smallest equivalent damping −Re(ln z)/|ln z|.

**Adaptation gains** (:func:`scaled_adaptation_gains`). The update law (5.28) changes m̂ᵢ at a
rate proportional to γ_m,i; the *relative* rate (dm̂ᵢ/dt)/mᵢ is what decides how fast a model
is learnt against how much noise it picks up. Scaling the thesis's gains for the JHU ROV
(γ_m = 1000, γ_d = 5000, §5.3.2) by mᵢ/mᵢ^JHU and |dᵢ|/|dᵢ^JHU| per axis keeps those relative
rates on any vehicle; the robust projection's floor m̂ᵢ ≥ mᵢ/10 keeps M̂ positive without
holding it far above a small vehicle's own masses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

__all__ = ["AxisLoop", "pd_gains_for", "delay_limited_bandwidth", "closed_loop",
           "equivalent_damping", "scaled_adaptation_gains", "DELAY_MARGIN"]

#: ω (dt (n + ½) + τ) of the default bandwidth: the phase (rad) the loop's delays cost at ω
DELAY_MARGIN = 0.3


def delay_limited_bandwidth(dt: float, lag_s: float, delay_cycles: int = 1) -> float:
    """The default bandwidth ω (rad/s) of a loop at period ``dt`` (s) whose frames are
    ``delay_cycles`` periods old and whose thrusters lag by ``lag_s`` (s)."""
    return DELAY_MARGIN / (dt * (delay_cycles + 0.5) + lag_s)


def equivalent_damping(d: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """c = 8|d|V/(3π): the linear damping with the same first harmonic as the quadratic drag
    d ẋ|ẋ| (d < 0, (2.44) decoupled) at a sinusoidal speed of amplitude V."""
    return 8.0 * np.abs(np.asarray(d, dtype=float)) * np.abs(speed) / (3.0 * np.pi)


def pd_gains_for(m: np.ndarray, omega, zeta) -> tuple[np.ndarray, np.ndarray]:
    """k_p = m ω², k_d = 2 ζ ω m per axis (the rule of the module docstring).

    Parameters
    ----------
    m : (6,) array
        Diagonal of M (kg, kg m²).
    omega, zeta : float or (6,) array
        Bandwidth (rad/s) and damping ratio per axis.
    """
    m = np.asarray(m, dtype=float)
    w = np.broadcast_to(np.asarray(omega, dtype=float), m.shape)
    z = np.broadcast_to(np.asarray(zeta, dtype=float), m.shape)
    if np.any(m <= 0) or np.any(w <= 0) or np.any(z <= 0):
        raise ValueError("masses, bandwidths and damping ratios must be > 0")
    return m * w ** 2, 2.0 * z * w * m


def scaled_adaptation_gains(m: np.ndarray, d: np.ndarray, m_ref: np.ndarray,
                            d_ref: np.ndarray, gamma_m_ref: float = 1000.0,
                            gamma_d_ref: float = 5000.0) -> dict[str, np.ndarray]:
    """γ_m,i = γ_m^ref mᵢ/mᵢ^ref, γ_d,i = γ_d^ref |dᵢ|/|dᵢ^ref| and the mass floor mᵢ/10
    (module docstring); ``m``, ``d``: the decoupled masses and drags (6,) of the vehicle,
    ``m_ref``, ``d_ref`` those of the vehicle the reference gains were tuned on."""
    m, d = np.asarray(m, dtype=float), np.abs(np.asarray(d, dtype=float))
    m_ref, d_ref = np.asarray(m_ref, dtype=float), np.abs(np.asarray(d_ref, dtype=float))
    if np.any(m <= 0) or np.any(m_ref <= 0) or np.any(d_ref <= 0):
        raise ValueError("masses and reference drags must be non-zero")
    return {"gamma_m": gamma_m_ref * m / m_ref, "gamma_d": gamma_d_ref * d / d_ref,
            "mass_floor": m / 10.0}


@dataclass(frozen=True)
class AxisLoop:
    """Closed-loop figures of one axis (see :func:`closed_loop`).

    Attributes
    ----------
    m, kp, kd, stiffness, damping : the axis's mass, gains, hydrostatic stiffness and linear(ised)
        damping.
    omega_n, zeta : continuous natural frequency (rad/s) and damping ratio, no delays.
    pole_radius : largest |z| of the sampled loop's poles (< 1: stable).
    zeta_sampled : smallest equivalent damping ratio of those poles (z ≠ 0).
    """

    m: float
    kp: float
    kd: float
    stiffness: float
    damping: float
    omega_n: float
    zeta: float
    pole_radius: float
    zeta_sampled: float

    @property
    def stable(self) -> bool:
        return self.pole_radius < 1.0


def closed_loop(m: float, kp: float, kd: float, dt: float, lag_s: float = 0.0,
                delay_cycles: int = 1, stiffness: float = 0.0, damping: float = 0.0
                ) -> AxisLoop:
    """The sampled PD loop of one axis (module docstring).

    Parameters
    ----------
    m : float
        Mass (kg) or inertia (kg m²) of the axis, M_ii.
    kp, kd : float
        The PD gains of the axis.
    dt : float
        Control period (s).
    lag_s : float
        First-order lag of the thrust (s); 0 for none.
    delay_cycles : int
        Age of the measurement the cycle uses, in whole periods (1: the fixed-rate cycle on a
        frame up to one period old; 0: a cycle run on the frame as it arrives).
    stiffness : float
        Hydrostatic stiffness s (N/m, N m/rad), b₃ in roll and pitch.
    damping : float
        Linear(ised) hydrodynamic damping c (N s/m, N m s/rad), see :func:`equivalent_damping`.
    """
    if m <= 0 or dt <= 0 or lag_s < 0 or delay_cycles < 0:
        raise ValueError("m and dt must be > 0, lag_s and delay_cycles >= 0")
    if lag_s > 0:
        A = np.array([[0.0, 1.0, 0.0], [-stiffness / m, -damping / m, 1.0 / m],
                      [0.0, 0.0, -1.0 / lag_s]])
        B = np.array([0.0, 0.0, 1.0 / lag_s])
    else:
        A = np.array([[0.0, 1.0], [-stiffness / m, -damping / m]])
        B = np.array([0.0, 1.0 / m])
    n = A.shape[0]
    aug = np.zeros((n + 1, n + 1))
    aug[:n, :n], aug[:n, n] = A, B
    E = expm(aug * dt)                       # exact zero-order-hold sampling
    Ad, Bd = E[:n, :n], E[:n, n]
    K = np.zeros(n)
    K[:2] = (kp, kd)                          # u = −K s on the plant's state [x, v, (f)]
    N = n * (delay_cycles + 1)                # the plant's state and its delayed copies
    Acl = np.zeros((N, N))
    Acl[:n, :n] = Ad
    Acl[:n, N - n:] -= np.outer(Bd, K)        # the command uses the oldest copy
    for j in range(delay_cycles):            # copy j+1 is copy j one cycle later
        Acl[n * (j + 1):n * (j + 2), n * j:n * (j + 1)] = np.eye(n)
    z = np.linalg.eigvals(Acl)
    nz = z[np.abs(z) > 1e-9]
    s = np.log(nz.astype(complex)) / dt
    zeta_s = float(np.min(-s.real / np.abs(s))) if nz.size else 1.0
    k_tot, c_tot = kp + stiffness, kd + damping
    return AxisLoop(m=float(m), kp=float(kp), kd=float(kd), stiffness=float(stiffness),
                    damping=float(damping),
                    omega_n=float(np.sqrt(k_tot / m)) if k_tot > 0 else 0.0,
                    zeta=float(c_tot / (2.0 * np.sqrt(k_tot * m))) if k_tot > 0
                    else float("inf"),
                    pole_radius=float(np.max(np.abs(z))), zeta_sampled=zeta_s)
