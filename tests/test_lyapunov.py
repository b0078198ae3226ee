"""Lyapunov functions of Theorems 5.2.1 and 5.2.2 along simulated closed loops.

V₁ = ½ xᵀM_εx (5.18) for MBC with the true parameters and V₂ = V₁ + ½ΔθᵀK_θ⁻¹Δθ (5.32) for
AMBC must not increase where the theorems' conditions hold: exact state (no sensor noise),
ideal actuators (no lag, no stiction, no saturation), 1 kHz so that the held command and the
Euler step of (5.28) approximate the continuous laws, k_p, k_d > 0, ε below the bound of
(5.21)/(5.25) and the initial condition inside the region of the theorems.
"""

import numpy as np
import pytest

from sim_bridge.plant import Plant, PlantConfig
from uvd.control.ambc import (
    MBCParams,
    MBCState,
    adaptation_gains,
    ambc_init,
    ambc_params,
    ambc_step,
    epsilon_bound,
    lyapunov_V1,
    lyapunov_V2,
    mbc_step,
    theta_of,
)
from uvd.control.trajectory import reftraj1
from uvd.control.types import VehicleState
from uvd.io.vehicle import load_vehicle
from uvd.model.lie import A_inv_se3, exp_se3

ROV = load_vehicle("jhu-rov")
COUPLED = load_vehicle("jhu-rov-coupled")
RATE = 1000.0
KP, KD = 300.0, 100.0
C_A = 2.0  # bound on ‖A⁻¹(Δψ)‖₂ used in (5.23); checked along every trajectory below

def _start(psi0, dv0):
    ref = reftraj1().at(0.0)
    return ref.H @ exp_se3(psi0), ref.v + dv0


def _eigs(M):
    lam = np.linalg.eigvalsh(M)
    return lam[-1], lam[0]


def _Meps_min_max(M, kp, eps):
    Me = np.block([[kp * np.eye(6), eps * M], [eps * M, M]])
    lam = np.linalg.eigvalsh(Me)
    return lam[0], lam[-1]


def _run(vehicle, step, params, ctrl, H0, v0, duration_s, record):
    plant = Plant(vehicle, PlantConfig(rate_hz=RATE), H0=H0, v0=v0)
    traj = reftraj1()
    dt = 1.0 / RATE
    out = []
    for k in range(int(duration_s * RATE)):
        ref = traj.at(k * dt)
        u, ctrl = step(VehicleState(plant.H, plant.v), ref, params, ctrl, dt)
        out.append(record(ctrl))
        plant.step_wrench(u)  # ideal actuators: no lag, stiction or saturation
    return np.array(out)


def _assert_non_increasing(V, rel=1e-6):
    dV = np.diff(V)
    assert V[-1] < V[0]
    assert dV.max() <= rel * V[0], f"V increased by {dV.max():.3g} (V0 = {V[0]:.3g})"


def _draw(seed, n=6):
    """Initial errors: a few seeded draws (each case is an 8 s simulation at 1 kHz, too slow
    for hypothesis's shrinking)."""
    return np.random.default_rng(seed).uniform(-1.0, 1.0, n)


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("vehicle", [ROV, COUPLED], ids=["jhu-rov", "jhu-rov-coupled"])
def test_V1_of_MBC_is_non_increasing(vehicle, seed):
    psi, dv = _draw(seed), _draw(seed + 100)
    M = vehicle.params.M
    eps = 0.9 * epsilon_bound(M, KP, KD, C_A)
    psi0, dv0 = 0.1 * psi, 0.05 * dv
    # initial condition of Theorem 5.2.1: ‖x(t₀)‖ < √(ελ₁₂/ελ₁) π
    lo, hi = _Meps_min_max(M, KP, eps)
    assert np.linalg.norm(np.concatenate([psi0, dv0])) < np.sqrt(lo / hi) * np.pi
    H0, v0 = _start(psi0, dv0)
    p = MBCParams.from_params(vehicle.params, KP, KD)
    rec = _run(vehicle, mbc_step, p, MBCState(), H0, v0, 8.0,
               lambda c: np.concatenate([c.dpsi, c.dv]))
    V = np.array([lyapunov_V1(x[:6], x[6:], M, KP, eps) for x in rec])
    assert max(np.linalg.norm(A_inv_se3(x[:6]), 2) for x in rec[::50]) <= C_A
    _assert_non_increasing(V)
    assert V[-1] < 0.5 * V[0]  # and it decays (ε ≈ 0.09 makes the Δψ part slow)


@pytest.mark.parametrize("seed", [0, 1])
def test_V2_of_decoupled_AMBC_is_non_increasing_inside_the_theorem_region(seed):
    """Every condition of Theorem 5.2.2, including the last one, which confines ‖Δθ(t₀)‖ to a
    few units with the thesis's γ_g = 0.5 (k_θ = 1/min eig K_θ = 2)."""
    psi, dv, dth = _draw(seed), _draw(seed + 100), _draw(seed + 200, 16)
    M = ROV.params.M
    eps = 0.9 * epsilon_bound(M, KP, KD, C_A)
    truth = theta_of(ROV.params, "decoupled")
    K = adaptation_gains("decoupled")  # the thesis's γ (§5.3.2)
    dtheta0 = dth * np.concatenate([np.full(12, 4.0), np.full(4, 0.2)])
    psi0, dv0 = 0.05 * psi, 0.02 * dv
    lo, hi = _Meps_min_max(M, KP, eps)
    x0 = np.concatenate([psi0, dv0])
    k_theta = 1.0 / K.min()
    assert np.sqrt((hi * x0 @ x0 + k_theta * dtheta0 @ dtheta0) / lo) < np.pi  # Theorem 5.2.2
    _check_V2(ROV, "decoupled", K, eps, truth, dtheta0, psi0, dv0)


@pytest.mark.parametrize("seed", [0, 1])
def test_V2_of_decoupled_AMBC_is_non_increasing_with_10_percent_errors(seed):
    """Larger parameter errors (10 % of every mass and drag): outside the theorem's sufficient
    initial-condition region, but the proof's actual requirement, ‖Δψ(t)‖ < π with ε below
    the bound, holds along the trajectory (checked), so V̇₂ = V̇₁ ≤ 0 (5.34) still applies."""
    psi, dv, dth = _draw(seed), _draw(seed + 100), _draw(seed + 200, 16)
    M = ROV.params.M
    eps = 0.9 * epsilon_bound(M, KP, KD, C_A)
    truth = theta_of(ROV.params, "decoupled")
    K = adaptation_gains("decoupled")
    dtheta0 = dth * np.concatenate([0.1 * np.abs(truth[:12]), np.full(4, 0.2)])
    _check_V2(ROV, "decoupled", K, eps, truth, dtheta0, 0.05 * psi, 0.02 * dv)


def _check_V2(vehicle, model, K, eps, truth, dtheta0, psi0, dv0):
    M = vehicle.params.M
    H0, v0 = _start(psi0, dv0)
    p = ambc_params(model, K=K, kp=KP, kd=KD, eps=eps)
    rec = _run(vehicle, ambc_step, p, ambc_init(p, truth + dtheta0), H0, v0, 8.0,
               lambda c: np.concatenate([c.dpsi, c.dv, c.theta]))
    assert np.linalg.norm(rec[:, :6], axis=1).max() < np.pi
    assert max(np.linalg.norm(A_inv_se3(r[:6]), 2) for r in rec[::50]) <= C_A
    V = np.array([lyapunov_V2(r[:6], r[6:12], M, KP, eps, r[12:] - truth, K) for r in rec])
    _assert_non_increasing(V)
    return V


def test_V2_of_full_AMBC_is_non_increasing():
    """The 241-parameter law on the coupled plant, 2 % errors on every parameter."""
    vehicle = COUPLED
    eps = 0.9 * epsilon_bound(vehicle.params.M, KP, KD, C_A)
    truth = theta_of(vehicle.params, "full")
    rng = np.random.default_rng(1)
    dtheta0 = 0.02 * np.abs(truth) * rng.normal(size=truth.size)
    _check_V2(vehicle, "full", adaptation_gains("full"), eps, truth, dtheta0,
              0.05 * rng.normal(size=6), 0.02 * rng.normal(size=6))


def test_V2_can_increase_when_the_update_law_has_the_wrong_sign():
    """The check above has teeth: flipping the sign of (5.28) breaks the cancellation in
    (5.33)–(5.34) and V₂ grows."""
    M = ROV.params.M
    eps = 0.9 * epsilon_bound(M, KP, KD, C_A)
    truth = theta_of(ROV.params, "decoupled")
    K = adaptation_gains("decoupled")
    H0, v0 = _start(np.full(6, 0.03), np.full(6, 0.01))
    p_bad = ambc_params("decoupled", K=K, kp=KP, kd=KD, eps=eps)
    bad = ambc_step

    def flipped(state, ref, params, ctrl, dt):
        u, nxt = bad(state, ref, params, ctrl, dt)
        theta = ctrl.theta - dt * nxt.theta_dot
        return u, type(nxt)(**{**{f: getattr(nxt, f) for f in nxt.__slots__}, "theta": theta})

    rec = _run(ROV, flipped, p_bad, ambc_init(p_bad, truth * 1.05), H0, v0, 8.0,
               lambda c: np.concatenate([c.dpsi, c.dv, c.theta]))
    V = np.array([lyapunov_V2(r[:6], r[6:12], M, KP, eps, r[12:] - truth, K) for r in rec])
    assert np.diff(V).max() > 1e-6 * V[0]
