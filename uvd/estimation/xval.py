"""Cross-validation of identified parameter sets (thesis App. A.2).

A parameter set is judged by how well it *predicts* a run it was not identified from: the
model is simulated open loop from the run's first measured state, driven by the run's recorded
wrench, and its open-loop-stable states are compared with the measured ones. Velocities are
open-loop stable through hydrodynamic damping, roll and pitch through the buoyancy torque (the
COB above the COG), so these — and only these — are compared; the mean absolute error (MAE)
per state is reported in the units of Tables 4.3, 4.12 and 4.13:

==============  ==============================
state key       meaning
==============  ==============================
``roll_deg``    roll (deg)
``pitch_deg``   pitch (deg)
``u_mps`` …     body velocities ν (m/s): u, v, w
``p_degps`` …   angular velocities ω (deg/s): p, q, r
==============  ==============================

Simulation: the RKMK4 kernel of the plant (:mod:`uvd.model.integrate`, compiled) with
``substeps`` steps per recorded period (default 2: RK4 at 20 Hz, far finer than the
vehicle's time scales of seconds); over each period the wrench follows the run's
``input_interp`` — "linear" interpolation between the samples at both ends, or "hold" of the
sample that ends the period. A rotational parameter set (2.40) is simulated exactly by the same
kernel through an embedding whose translational part stays at rest (ν ≡ 0, see
:func:`embed_rotational`). A simulation that leaves any physical range (|v| > 100) is stopped
and reported as diverged (MAE = inf).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from uvd.geometry import euler_of_rotations
from uvd.model.dynamics import UVModel
from uvd.model.integrate import _rkmk4
from uvd.model.params import RotParams, UVParams

__all__ = ["STATES_6DOF", "STATES_ROT", "XvalResult", "embed_rotational", "simulate_run",
           "states_of", "mae", "cross_validate", "format_mae_table", "STATE_LABELS"]

STATES_6DOF = ("roll_deg", "pitch_deg", "u_mps", "v_mps", "w_mps", "p_degps", "q_degps",
               "r_degps")
STATES_ROT = ("roll_deg", "pitch_deg", "p_degps", "q_degps", "r_degps")
#: per state key: (label of the thesis figures, unit)
STATE_LABELS = {"roll_deg": ("Roll", "deg"), "pitch_deg": ("Pitch", "deg"),
                "u_mps": ("BodVelX", "m/s"), "v_mps": ("BodVelY", "m/s"),
                "w_mps": ("BodVelZ", "m/s"), "p_degps": ("AngVelX", "deg/s"),
                "q_degps": ("AngVelY", "deg/s"), "r_degps": ("AngVelZ", "deg/s")}
V_LIMIT = 100.0


def embed_rotational(p: RotParams) -> UVParams:
    """A 6-DOF parameter set whose rotational motion is exactly (2.40) with ``p``.

    M = blockdiag(I₃, I), D₁…D₃ = −e_i e_iᵀ, D_{3+i} = blockdiag(0, C_i), g = 0. With zero force
    and ν(0) = 0 the translation stays at rest (ad_vᵀ(Mv) = [0; Iω × ω] when ν = 0), so ω obeys
    I ω̇ = J(Iω)ω + Σ|ωᵢ|Cᵢω + J(b)Rᵀe₃ + τ.
    """
    M = np.eye(6)
    M[3:, 3:] = 0.5 * (np.asarray(p.I) + np.asarray(p.I).T)
    D = np.zeros((6, 6, 6))
    for i in range(3):
        D[i, i, i] = -1.0
        D[3 + i, 3:, 3:] = np.asarray(p.C)[i]
    return UVParams(M=M, D=D, g=0.0, b=np.asarray(p.b, dtype=float))


@numba.njit(cache=True)
def _simulate(M, M_inv, D_flat, g, b, H0, v0, U, substeps, dt, linear, vlim, Rs, vs):
    """Open-loop simulation over the run's periods; returns the index of divergence or −1."""
    n = U.shape[0]
    H = H0.copy()
    v = v0.copy()
    Hn = np.empty((4, 4))
    vn = np.empty(6)
    u = np.empty(6)
    h = dt / substeps
    for i in range(3):
        for j in range(3):
            Rs[0, i, j] = H[i, j]
    for i in range(6):
        vs[0, i] = v[i]
    for k in range(n - 1):
        for s in range(substeps):
            if linear:
                a = (s + 0.5) / substeps
                for i in range(6):
                    u[i] = (1.0 - a) * U[k, i] + a * U[k + 1, i]
            else:
                for i in range(6):
                    u[i] = U[k + 1, i]
            _rkmk4(M, M_inv, D_flat, g, b, H, v, u, h, Hn, vn)
            for i in range(4):
                for j in range(4):
                    H[i, j] = Hn[i, j]
            for i in range(6):
                v[i] = vn[i]
        bad = False
        for i in range(6):
            if not (abs(v[i]) <= vlim):
                bad = True
        if bad:
            for kk in range(k + 1, n):
                for i in range(3):
                    for j in range(3):
                        Rs[kk, i, j] = np.nan
                for i in range(6):
                    vs[kk, i] = np.nan
            return k + 1
        for i in range(3):
            for j in range(3):
                Rs[k + 1, i, j] = H[i, j]
        for i in range(6):
            vs[k + 1, i] = v[i]
    return -1


def simulate_run(params: UVParams | RotParams, run, *, substeps: int = 2
                 ) -> tuple[np.ndarray, np.ndarray, int | None]:
    """Simulate ``params`` open loop with the run's wrench from its first measured state.

    Returns (R (n, 3, 3), v (n, 6), index of divergence or None). For a :class:`RotParams`
    the translational velocity is held at zero and only the torque drives the model.
    """
    rot = isinstance(params, RotParams)
    p6 = embed_rotational(params) if rot else params
    model = UVModel.from_params(p6)
    U = np.ascontiguousarray(run.u, dtype=float).copy()
    H0 = np.ascontiguousarray(run.H[0])
    v0 = np.asarray(run.v[0], dtype=float).copy()
    if rot:
        U[:, :3] = 0.0
        v0[:3] = 0.0
    n = len(run.t)
    Rs = np.empty((n, 3, 3))
    vs = np.empty((n, 6))
    k = _simulate(model.M, model.M_inv, model.D_flat, model.g, model.b, H0, v0, U,
                  int(substeps), float(run.dt), run.input_interp == "linear", V_LIMIT, Rs, vs)
    return Rs, vs, (None if k < 0 else int(k))


def states_of(R: np.ndarray, v: np.ndarray) -> dict[str, np.ndarray]:
    """The compared states (units of the module table) of attitudes R and velocities v."""
    roll, pitch, _ = euler_of_rotations(R).T
    deg = 180.0 / math.pi
    return {"roll_deg": roll * deg, "pitch_deg": pitch * deg, "u_mps": v[:, 0],
            "v_mps": v[:, 1], "w_mps": v[:, 2], "p_degps": v[:, 3] * deg,
            "q_degps": v[:, 4] * deg, "r_degps": v[:, 5] * deg}


def mae(measured: dict[str, np.ndarray], simulated: dict[str, np.ndarray],
        states=STATES_6DOF, mask: np.ndarray | None = None) -> dict[str, float]:
    """Mean absolute error per state (inf where the simulation is not finite)."""
    out = {}
    for s in states:
        a, b = np.asarray(measured[s]), np.asarray(simulated[s])
        if mask is not None:
            a, b = a[mask], b[mask]
        d = b - a
        if s in ("roll_deg", "pitch_deg"):
            d = (d + 180.0) % 360.0 - 180.0
        out[s] = float(np.mean(np.abs(d))) if np.all(np.isfinite(d)) else math.inf
    return out


@dataclass(frozen=True)
class XvalResult:
    """MAE per state, the simulated trajectory and where (if) it diverged."""

    mae: dict
    R_sim: np.ndarray
    v_sim: np.ndarray
    diverged_at_s: float | None


def cross_validate(params: UVParams | RotParams, run, *, substeps: int = 2,
                   states=None) -> XvalResult:
    """App. A.2: simulate ``params`` with the run's inputs and return the MAE per state."""
    if states is None:
        states = STATES_ROT if isinstance(params, RotParams) else STATES_6DOF
    Rs, vs, k = simulate_run(params, run, substeps=substeps)
    meas = states_of(run.R, run.v)
    sim = states_of(Rs, vs)
    return XvalResult(mae=mae(meas, sim, states), R_sim=Rs, v_sim=vs,
                      diverged_at_s=None if k is None else float(run.t[k] - run.t[0]))


def format_mae_table(rows, states=STATES_6DOF, title: str = "") -> str:
    """A table in the layout of Tables 4.3/4.12/4.13: one row per (model, experiment).

    ``rows`` is an iterable of (model name, experiment name, {state: MAE}).
    """
    head = ["UV Model", "Exp"] + [f"{STATE_LABELS[s][0]} ({STATE_LABELS[s][1]})" for s in states]
    widths = [max(10, len(h)) for h in head]
    lines = [title] if title else []
    lines.append("  ".join(h.rjust(w) for h, w in zip(head, widths, strict=True)))
    for model, exp, vals in rows:
        cells = [model, exp]
        for s in states:
            x = vals.get(s, math.nan)
            if not math.isfinite(x):
                cells.append("diverged" if x == math.inf else "-")
            elif STATE_LABELS[s][1] == "m/s":
                cells.append(f"{x:.4f}")
            else:
                cells.append(f"{x:.3g}" if x >= 1 else f"{x:.3f}")
        lines.append("  ".join(c.rjust(w) for c, w in zip(cells, widths, strict=True)))
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# rotational cross-validation over windows, with an optional linear damping (real vehicles)
# ---------------------------------------------------------------------------------------------
@numba.njit(cache=True)
def _rot_f(I, I_inv, C, D_lin, b, R, w, tau, out):
    """ω̇ = I⁻¹(J(Iω)ω + Σ|ωᵢ|Cᵢω + D_lin ω + J(b)Rᵀe₃ + τ) — (2.40) plus a linear damping."""
    h = I @ w
    rhs = np.empty(3)
    rhs[0] = h[1] * w[2] - h[2] * w[1]
    rhs[1] = h[2] * w[0] - h[0] * w[2]
    rhs[2] = h[0] * w[1] - h[1] * w[0]
    r0, r1, r2 = R[2, 0], R[2, 1], R[2, 2]
    rhs[0] += b[1] * r2 - b[2] * r1
    rhs[1] += b[2] * r0 - b[0] * r2
    rhs[2] += b[0] * r1 - b[1] * r0
    for i in range(3):
        rhs[i] += tau[i]
        for c in range(3):
            rhs[i] += D_lin[i, c] * w[c]
            for k in range(3):
                rhs[i] += abs(w[k]) * C[k, i, c] * w[c]
    for i in range(3):
        out[i] = I_inv[i, 0] * rhs[0] + I_inv[i, 1] * rhs[1] + I_inv[i, 2] * rhs[2]


@numba.njit(cache=True)
def _rot_advance(R, w, h, out):
    """R exp(J(ω h)) (Rodrigues)."""
    q0, q1, q2 = w[0] * h, w[1] * h, w[2] * h
    th = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
    E = np.eye(3)
    if th > 1e-12:
        K = np.array([[0.0, -q2, q1], [q2, 0.0, -q0], [-q1, q0, 0.0]]) / th
        E = E + math.sin(th) * K + (1.0 - math.cos(th)) * (K @ K)
    out[:, :] = R @ E


@numba.njit(cache=True)
def _simulate_rot_windows(I, I_inv, C, D_lin, b, R_meas, w_meas, tau, dt, substeps, win, vlim,
                          Rs, ws):
    """Restart from the measured state every ``win`` samples; RK4 on ω with R advanced on the
    stage rates (Lie–Euler per stage); τ linear between samples. Writes Rs, ws; NaN after a
    window diverges (|ω| > vlim). Returns the number of diverged windows."""
    n = tau.shape[0]
    h = dt / substeps
    k1 = np.empty(3)
    k2 = np.empty(3)
    k3 = np.empty(3)
    k4 = np.empty(3)
    ta = np.empty(3)
    R2 = np.empty((3, 3))
    R3 = np.empty((3, 3))
    R4 = np.empty((3, 3))
    Rn = np.empty((3, 3))
    diverged = 0
    s = 0
    while s < n:
        e = min(s + win, n)
        R = R_meas[s].copy()
        w = w_meas[s].copy()
        Rs[s] = R
        ws[s] = w
        bad = False
        for k in range(s, e - 1):
            for j in range(substeps):
                a = (j + 0.5) / substeps
                for i in range(3):
                    ta[i] = (1.0 - a) * tau[k, i] + a * tau[k + 1, i]
                _rot_f(I, I_inv, C, D_lin, b, R, w, ta, k1)
                w2 = w + 0.5 * h * k1
                _rot_advance(R, w, 0.5 * h, R2)
                _rot_f(I, I_inv, C, D_lin, b, R2, w2, ta, k2)
                w3 = w + 0.5 * h * k2
                _rot_advance(R, w2, 0.5 * h, R3)
                _rot_f(I, I_inv, C, D_lin, b, R3, w3, ta, k3)
                w4 = w + h * k3
                _rot_advance(R, w3, h, R4)
                _rot_f(I, I_inv, C, D_lin, b, R4, w4, ta, k4)
                wm = (w + 2.0 * w2 + 2.0 * w3 + w4) / 6.0
                _rot_advance(R, wm, h, Rn)
                w = w + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
                R = Rn.copy()
            if not (abs(w[0]) <= vlim and abs(w[1]) <= vlim and abs(w[2]) <= vlim):
                bad = True
            if bad:
                for kk in range(k + 1, e):
                    Rs[kk, :, :] = np.nan
                    ws[kk, :] = np.nan
                diverged += 1
                break
            Rs[k + 1] = R
            ws[k + 1] = w
        s = e
    return diverged


@dataclass(frozen=True)
class WindowXval:
    """Windowed rotational cross-validation of one parameter set on one run."""

    mae: dict
    R_sim: np.ndarray
    w_sim: np.ndarray
    window_s: float
    windows: int
    diverged_windows: int


def rot_xval_windows(params: RotParams, run, *, window_s: float = 5.0,
                     linear_damping: np.ndarray | None = None,
                     substeps: int = 2) -> WindowXval:
    """App. A.2 on a real recording, in windows (the thesis's CROSS figures): every
    ``window_s`` the rotational model (2.40) — plus ``linear_damping`` D_L ω (3 × 3, N m s/rad)
    where a published model has one — restarts from the recorded attitude and rate and is
    driven by the recorded torque τ = u[3:]; roll, pitch (deg) and p, q, r (deg/s) are compared.

    Windows, because a real vehicle's attitude is kept by nothing but its restoring moment and
    a model error in a tumbling run compounds without bound: the window is the horizon over
    which the model is asked to predict.
    """
    I = 0.5 * (np.asarray(params.I, dtype=float) + np.asarray(params.I, dtype=float).T)
    C = np.ascontiguousarray(np.asarray(params.C, dtype=float))
    D_lin = np.zeros((3, 3)) if linear_damping is None else np.asarray(linear_damping, float)
    b = np.asarray(params.b, dtype=float).copy()
    win = max(2, int(round(window_s / run.dt)))
    n = len(run.t)
    Rs = np.empty((n, 3, 3))
    ws = np.empty((n, 3))
    tau = np.ascontiguousarray(run.u[:, 3:], dtype=float)
    R_meas = np.ascontiguousarray(run.R, dtype=float)
    w_meas = np.ascontiguousarray(run.v[:, 3:], dtype=float)
    ndiv = _simulate_rot_windows(I, np.linalg.inv(I), C, D_lin.copy(), b, R_meas, w_meas, tau,
                                 float(run.dt), int(substeps), win, V_LIMIT, Rs, ws)
    v_sim = np.zeros((n, 6))
    v_sim[:, 3:] = ws
    meas = states_of(run.R, run.v)
    sim = states_of(Rs, v_sim)
    return WindowXval(mae=mae(meas, sim, STATES_ROT), R_sim=Rs, w_sim=ws, window_s=win * run.dt,
                      windows=-(-n // win), diverged_windows=int(ndiv))


def rot_from_lumped(A_p: float, B_q: float, C_r: float, K_p: float, K_pp: float, M_q: float,
                    M_qq: float, N_r: float, N_rr: float, z_B: float, W: float
                    ) -> tuple[RotParams, np.ndarray]:
    """The lumped roll/pitch/yaw model of a BlueROV-type thesis (Aili & Ekelund 2016, eq.
    ``eq:quatModel``) as θ_UVR (2.41) plus a linear damping D_L.

        A_p ṗ = K + W z_B cosθ sinφ + (K_p + K_p|p| |p|) p + (B_q − C_r) q r   (and q, r alike)

    * I = diag(A_p, B_q, C_r): inertia including added inertia (kg m²), as (2.40)'s I — the
      gyroscopic term J(Iω)ω of (2.40) is exactly [(B_q−C_r)qr, (C_r−A_p)pr, (A_p−B_q)pq];
    * Cᵢ with the quadratic dampings on the diagonal: C₁[0,0] = K_p|p|, C₂[1,1] = M_q|q|,
      C₃[2,2] = N_r|r| (N m s²/rad², negative = dissipative, the sign convention of (2.40));
    * D_L = diag(K_p, M_q, N_r) (N m s/rad, negative): (2.40) has no linear damping, so it is
      carried beside θ_UVR (:func:`rot_xval_windows` ``linear_damping``);
    * b = (0, 0, −W z_B) (N m): J(b)Rᵀe₃ = (−b₃ cosθ sinφ, −b₃ sinθ, 0) equals the thesis's
      restoring moment (W z_B cosθ sinφ, W z_B sinθ, 0) for b₃ = −W z_B; with CB above CG
      (z_B < 0) b₃ > 0, the restoring sign of (2.40) (the JHU ROV's b₃ = 300 N m).
    """
    I = np.diag([A_p, B_q, C_r]).astype(float)
    C = np.zeros((3, 3, 3))
    C[0, 0, 0], C[1, 1, 1], C[2, 2, 2] = K_pp, M_qq, N_rr
    return (RotParams(I=I, C=C, b=np.array([0.0, 0.0, -W * z_B])),
            np.diag([K_p, M_q, N_r]).astype(float))
