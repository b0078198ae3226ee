"""Adaptive identification (AID) of UV plant parameters: Theorems 4.2.1 (3-DOF) and 4.3.1 (6-DOF).

The estimators take only the accessible signals of the problem statements of §4.1 — attitude R,
body velocity v = [ν; ω] and the applied wrench u = [f; τ] — and never assume a controller, so
they identify a vehicle under our control, a manufacturer's controller, open-loop commands or a
pilot alike. Each is a frozen state object plus a pure step function with the estimator
signature of :mod:`uvd.core`::

    state = aid6_step(VehicleState(H, v), u_applied, params, state, dt)

6-DOF UV AID, Theorem 4.3.1, on the 241-parameter model (2.44); ∆x = x̂ − x (4.5)–(4.9)::

    v̂̇ = M̂⁻¹(ad_vᵀ(M̂v) + Σ|vᵢ|D̂ᵢ v + Ĝ(R) + u) − a∆v          (4.23)   ψ₂ = v̂̇ + a∆v (4.28)
    M̂̇ = ½γ₁(−ψ₁vᵀ − vψ₁ᵀ + ∆vψ₂ᵀ + ψ₂∆vᵀ),  ψ₁ = ad_v(∆v)        (4.24)
    D̂̇ᵢ = −γ₂|vᵢ| ∆v vᵀ                                           (4.25)
    ĝ̇ = −γ₃ ∆νᵀRᵀe₃                                               (4.26)
    b̂̇ = γ₄ J(∆ω) Rᵀe₃                                             (4.27)

3-DOF UV rotational AID, Theorem 4.2.1, on the 36-parameter model (2.40)::

    ω̂̇ = Î⁻¹(J(Îω)ω + Σ|ωᵢ|Ĉᵢω + J(b̂)Rᵀe₃ + τ) − a∆ω            (4.10)   ψ₃ = ω̂̇ + a∆ω
    Î̇ = −½γ₁(ψ₄ωᵀ + ωψ₄ᵀ − ∆ωψ₃ᵀ − ψ₃∆ωᵀ),  ψ₄ = J(ω)∆ω        (4.11)
    Ĉ̇ᵢ = −γ₂|ωᵢ| ∆ω ωᵀ                                           (4.12)
    b̂̇ = −γ₃ J(Rᵀe₃) ∆ω                                            (4.13)

The signs were re-derived from the Lyapunov functions (4.15), (4.31): with these laws
V̇ = −a∆vᵀM∆v (4.33) exactly (the extracted text of (4.14) lost a sign; (4.30) is right).

**Discretisation.** Explicit Euler at the loop period ``dt`` (§4.5–4.6: 100 ms). The core calls
an estimator at cycle k with (R_k, v_k) and u_k, the wrench produced during the *previous*
cycle [t_{k−1}, t_k]; so the step integrates that interval from the stored (v_{k−1}, R_{k−1},
v̂_{k−1}) with that interval's wrench — ``input_interp="linear"`` (u_k is the instantaneous
wrench at t_k, e.g. from measured propeller speeds, f = kω|ω|, App. A.1; the interval uses
½(u_{k−1} + u_k)) or ``"hold"`` (u_k was held over the interval: ideal actuators, wrench =
previous command). Where the exogenous signals (v, R) are sampled is ``sampling``:

* ``"midpoint"`` (default): the right-hand sides of (4.23)/(4.10) and the regressor terms of the
  parameter laws use the interval's mid signals ½(v_{k−1} + v_k), ½(r_{k−1} + r_k); v̂ is
  propagated with ∆v_{k−1}, and the parameter laws use the fresh error ∆v_k = v̂_k − v_k.
  This is Euler for v̂ and θ̂ with signals that are second-order accurate over the step;
* ``"euler"``: the thesis-literal scheme, every signal at the interval start and the laws
  driven by ∆v_{k−1}.

At 10 Hz the start-of-interval sampling biases θ̂ by O(dt), as much as the damping itself
(noise-free, at the true θ, the one-step ∆v is ≈50× larger with ``"euler"``); at the daemon's
1 kHz both schemes agree. ∆v_k = v̂_k − v_k is reported either way. v̂(t₀) = v(t₀) on the first
call, as both theorems require.

**Symmetry and definiteness.** M̂ (and Î) are never stored as matrices: θ̂ holds θ_M, the 21
unique entries (2.45), and M̂ = unstack(P_M θ_M) (2.46)–(2.47) is symmetric by construction;
(4.24) is symmetric, so only its upper triangle is integrated. The theorems keep M̂ positive
definite only inside their (conservative) domain of attraction (4.29), (4.36). Every step
checks the new M̂: if its smallest eigenvalue falls to ``pd_floor``·(largest) or below (or
anything becomes non-finite), the update is discarded, the estimator **freezes** (θ̂ kept at the
last positive-definite value, ``frozen=True`` and ``freeze_reason`` set) and from then on only
propagates v̂ with the frozen θ̂. :func:`aid_unfreeze` resumes adaptation explicitly.

Hot loop: one compiled (numba) kernel per step, no regressor matrix is formed — the blocks of
W_UVᵀ∆v are the structured products above (the drag block is −|vᵢ|(v ⊗ ∆v)); ~15 µs median per
6-DOF step including the Python state bookkeeping (``uvd bench estimation``).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace

import numba
import numpy as np

from uvd.control.types import Diagnostics, EstimatorSpec
from uvd.model.params import (
    N_THETA_UV,
    N_THETA_UVR,
    RotParams,
    UVParams,
    params_from_theta,
)
from uvd.model.spd import cholesky, min_max_eig

__all__ = [
    "AID6Gains", "AID6Params", "AID6State", "aid6_init", "aid6_step", "aid6_params",
    "aid6_estimator",
    "AID3Gains", "AID3Params", "AID3State", "aid3_init", "aid3_step", "aid3_params",
    "aid3_estimator",
    "aid_unfreeze", "aid_hold_dofs", "held_indices", "INITP_6DOF", "INITP_ROT",
    "DECOUPLED_NAMES", "decoupled_gains", "decoupled_excitation", "excitation_gain_scale",
    "entry_scale_of",
]

_INTERP = ("linear", "hold")
_SAMPLING = ("euler", "midpoint")


# ---------------------------------------------------------------------------------------------
# compiled kernels
# ---------------------------------------------------------------------------------------------
@numba.njit(cache=True)
def _sym_from_upper(th, n, out):
    """Symmetric n×n matrix from its unique entries run row-wise over the upper triangle."""
    k = 0
    for i in range(n):
        for j in range(i, n):
            out[i, j] = th[k]
            out[j, i] = th[k]
            k += 1


@numba.njit(cache=True)
def _chol_solve(A, b, n, x):
    """x = A⁻¹b by Cholesky; False (x untouched) if A is not positive definite or not finite."""
    L = np.zeros((n, n))
    if not cholesky(A, 0.0, n, L):
        return False
    y = np.empty(n)
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    return True


@numba.njit(cache=True)
def _add_drag(theta, base0, n, v, rhs):
    """rhs += Σᵢ |vᵢ| D̂ᵢ v, D̂ᵢ stored column-major from θ[base0 + n²i] ((2.40), (2.44))."""
    for i in range(n):
        avi = abs(v[i])
        if avi != 0.0:
            base = base0 + n * n * i
            for c in range(n):
                s = avi * v[c]
                off = base + n * c
                for row in range(n):
                    rhs[row] += theta[off + row] * s


@numba.njit(cache=True)
def _observer(vhat, v_prev, psi, dt, a, n, v_now, fresh, vhat_out):
    """v̂⁺ = v̂ + dt(ψ − a∆v) with ∆v = v̂ − v_prev ((4.23), (4.10)); returns the ∆v the
    parameter laws use: that one, or with ``fresh`` the new error v̂⁺ − v_now."""
    dv = vhat - v_prev
    for i in range(n):
        vhat_out[i] = vhat[i] + dt * (psi[i] - a * dv[i])
    if fresh:
        dv = vhat_out - v_now
    return dv


@numba.njit(cache=True)
def _inertia_law(theta_out, n, hg, s, psi_a, v, dv, psi_b):
    """θ_M += hg √(sᵢsⱼ)(−ψ_a vᵀ − v ψ_aᵀ + ∆v ψ_bᵀ + ψ_b ∆vᵀ)ᵢⱼ on the upper triangle: (4.24)
    with hg = γ₁dt/2, ψ_a = ψ₁, ψ_b = ψ₂; (4.11) with ψ_a = ψ₄, ψ_b = ψ₃; ``s`` the per-DOF
    gain scales (ones: the thesis's scalar γ₁)."""
    k = 0
    for i in range(n):
        for j in range(i, n):
            theta_out[k] += hg * math.sqrt(s[i] * s[j]) * (
                -psi_a[i] * v[j] - v[i] * psi_a[j] + dv[i] * psi_b[j] + psi_b[i] * dv[j])
            k += 1


@numba.njit(cache=True)
def _drag_law(theta_out, base0, n, g2dt, s, v, dv):
    """D̂ᵢ += −γ₂ dt |vᵢ| diag(s) ∆v vᵀ ((4.25), (4.12); row r of every D̂ᵢ at s_r γ₂)."""
    for i in range(n):
        avi = abs(v[i])
        if avi != 0.0:
            sc = -g2dt * avi
            base = base0 + n * n * i
            for c in range(n):
                x = sc * v[c]
                off = base + n * c
                for row in range(n):
                    theta_out[off + row] += x * s[row] * dv[row]


@numba.njit(cache=True)
def _entry_scale(theta, w, theta_out):
    """θ̂⁺ = θ̂ + diag(w)(θ̂⁺ − θ̂): each entry's update times its own gain multiplier wₖ > 0
    (:class:`AID6Gains` ``entry_scale``; an entry with wₖ = 1 is left bit for bit as the law
    wrote it, so the default gives the same bits as without this step)."""
    for k in range(theta.shape[0]):
        if w[k] != 1.0:
            theta_out[k] = theta[k] + w[k] * (theta_out[k] - theta[k])


@numba.njit(cache=True)
def _aid6_kernel(theta, vhat, v_prev, v, r, u, v_now, fresh, dt, a, g1, g2, g3, g4, s, w,
                 adapt, theta_out, vhat_out, diag):
    """One Euler step of (4.23)–(4.27).

    The model and regressor terms use the signals (v, Rᵀe₃ = r, u); v̂ is propagated with
    ∆v = v̂ − v_prev; the parameter laws use that ∆v, or with ``fresh`` the new error
    v̂⁺ − v_now. Writes θ̂⁺ and v̂⁺; ``diag`` receives [λ_min(M̂⁺), λ_max(M̂⁺)] (of M̂ if not
    adapting). Returns 0 on success, 1 if M̂ itself is not positive definite (nothing written).
    """
    M = np.empty((6, 6))
    _sym_from_upper(theta, 6, M)
    # right-hand side ad_vᵀ(M̂v) + Σ|vᵢ|D̂ᵢv + Ĝ(R) + u
    x = M @ v
    p1, p2, p3, h1, h2, h3 = x[0], x[1], x[2], x[3], x[4], x[5]
    n1, n2, n3, w1, w2, w3 = v[0], v[1], v[2], v[3], v[4], v[5]
    r1, r2, r3 = r[0], r[1], r[2]
    g = theta[237]
    b1, b2, b3 = theta[238], theta[239], theta[240]
    rhs = np.empty(6)
    rhs[0] = p2 * w3 - p3 * w2 + g * r1 + u[0]
    rhs[1] = p3 * w1 - p1 * w3 + g * r2 + u[1]
    rhs[2] = p1 * w2 - p2 * w1 + g * r3 + u[2]
    rhs[3] = p2 * n3 - p3 * n2 + h2 * w3 - h3 * w2 + b2 * r3 - b3 * r2 + u[3]
    rhs[4] = p3 * n1 - p1 * n3 + h3 * w1 - h1 * w3 + b3 * r1 - b1 * r3 + u[4]
    rhs[5] = p1 * n2 - p2 * n1 + h1 * w2 - h2 * w1 + b1 * r2 - b2 * r1 + u[5]
    _add_drag(theta, 21, 6, v, rhs)
    # ψ₂ = M̂⁻¹ rhs by Cholesky (fails ⇔ M̂ not positive definite)
    psi2 = np.empty(6)
    if not _chol_solve(M, rhs, 6, psi2):
        return 1
    dv = _observer(vhat, v_prev, psi2, dt, a, 6, v_now, fresh, vhat_out)
    for i in range(N_THETA_UV):
        theta_out[i] = theta[i]
    if not adapt:
        lo, hi = min_max_eig(M)
        diag[0], diag[1] = lo, hi
        return 0
    # ψ₁ = ad_v(∆v) = [ω × ∆ν + ν × ∆ω; ω × ∆ω]
    d1, d2, d3, e1, e2, e3 = dv[0], dv[1], dv[2], dv[3], dv[4], dv[5]
    psi1 = np.empty(6)
    psi1[0] = w2 * d3 - w3 * d2 + n2 * e3 - n3 * e2
    psi1[1] = w3 * d1 - w1 * d3 + n3 * e1 - n1 * e3
    psi1[2] = w1 * d2 - w2 * d1 + n1 * e2 - n2 * e1
    psi1[3] = w2 * e3 - w3 * e2
    psi1[4] = w3 * e1 - w1 * e3
    psi1[5] = w1 * e2 - w2 * e1
    # (4.24) on the upper triangle (θ_M of (2.45)); (4.25): D̂ᵢˢ += −γ₂ dt |vᵢ| (v ⊗ ∆v)
    _inertia_law(theta_out, 6, 0.5 * g1 * dt, s, psi1, v, dv, psi2)
    _drag_law(theta_out, 21, 6, g2 * dt, s, v, dv)
    # (4.26), (4.27); ĝ acts on surge, sway and heave: at their mean scale, b̂ₖ at roll's,
    # pitch's and yaw's
    sg = (s[0] + s[1] + s[2]) / 3.0
    theta_out[237] -= g3 * sg * dt * (d1 * r1 + d2 * r2 + d3 * r3)
    theta_out[238] += g4 * s[3] * dt * (e2 * r3 - e3 * r2)
    theta_out[239] += g4 * s[4] * dt * (e3 * r1 - e1 * r3)
    theta_out[240] += g4 * s[5] * dt * (e1 * r2 - e2 * r1)
    _entry_scale(theta, w, theta_out)
    _sym_from_upper(theta_out, 6, M)
    lo, hi = min_max_eig(M)
    diag[0], diag[1] = lo, hi
    return 0


@numba.njit(cache=True)
def _aid3_kernel(theta, what, w_prev, w, r, tau, w_now, fresh, dt, a, g1, g2, g3, s, ws,
                 adapt, theta_out, what_out, diag):
    """One Euler step of (4.10)–(4.13); the 3-DOF analogue of :func:`_aid6_kernel`."""
    I = np.empty((3, 3))
    _sym_from_upper(theta, 3, I)
    w1, w2, w3 = w[0], w[1], w[2]
    h = I @ w
    r1, r2, r3 = r[0], r[1], r[2]
    b1, b2, b3 = theta[33], theta[34], theta[35]
    rhs = np.empty(3)
    # J(Îω)ω = h × ω ;  J(b̂)Rᵀe₃ = b × r
    rhs[0] = h[1] * w3 - h[2] * w2 + b2 * r3 - b3 * r2 + tau[0]
    rhs[1] = h[2] * w1 - h[0] * w3 + b3 * r1 - b1 * r3 + tau[1]
    rhs[2] = h[0] * w2 - h[1] * w1 + b1 * r2 - b2 * r1 + tau[2]
    _add_drag(theta, 6, 3, w, rhs)
    psi3 = np.empty(3)
    if not _chol_solve(I, rhs, 3, psi3):
        return 1
    dw = _observer(what, w_prev, psi3, dt, a, 3, w_now, fresh, what_out)
    for i in range(N_THETA_UVR):
        theta_out[i] = theta[i]
    if not adapt:
        lo, hi = min_max_eig(I)
        diag[0], diag[1] = lo, hi
        return 0
    e1, e2, e3 = dw[0], dw[1], dw[2]
    psi4 = np.empty(3)  # J(ω)∆ω
    psi4[0] = w2 * e3 - w3 * e2
    psi4[1] = w3 * e1 - w1 * e3
    psi4[2] = w1 * e2 - w2 * e1
    # (4.11) (the same symmetric form as (4.24)) and (4.12)
    _inertia_law(theta_out, 3, 0.5 * g1 * dt, s, psi4, w, dw, psi3)
    _drag_law(theta_out, 6, 3, g2 * dt, s, w, dw)
    # (4.13): b̂̇ = −γ₃ J(r)∆ω = −γ₃ r × ∆ω (b̂ₖ at DOF k's scale)
    theta_out[33] -= g3 * s[0] * dt * (r2 * e3 - r3 * e2)
    theta_out[34] -= g3 * s[1] * dt * (r3 * e1 - r1 * e3)
    theta_out[35] -= g3 * s[2] * dt * (r1 * e2 - r2 * e1)
    _entry_scale(theta, ws, theta_out)
    _sym_from_upper(theta_out, 3, I)
    lo, hi = min_max_eig(I)
    diag[0], diag[1] = lo, hi
    return 0


@numba.njit(cache=True)
def _finite(x):
    for i in range(x.shape[0]):
        if not np.isfinite(x[i]):
            return False
    return True


@numba.njit(cache=True)
def _drive(n_v, theta, vhat, v_prev, r_prev, u_prev, H, v_in, u_in, cfg, dt, adapt, out):
    """Everything numeric of one AID step (n_v = 6: Theorem 4.3.1, 3: Theorem 4.2.1).

    ``vhat, v_prev, r_prev, u_prev``: the previous step's v̂ and sample (zeros at t₀ or after a
    gap, where dt = 0), ``cfg`` = [a, γ₁, γ₂, γ₃, γ₄, pd_floor, linear, midpoint]
    (:func:`_cfg_template`), ``dt`` the step, ``adapt`` whether θ̂ is updated. ``out`` receives
    [θ̂⁺, v̂⁺, v, r, u, ∆v, λ_min, λ_max] (θ̂⁺ first, as many entries as θ̂; v, r = Rᵀe₃, u: the
    new sample) — one buffer, so one array crosses into the kernel and back. With dt = 0 only
    the sample is copied (t₀ or a gap: v̂ = v). Returns 0 adapted, 4 propagated only (frozen),
    2 non-finite input (nothing done), 1 M̂ not positive definite, 3 update rejected: M̂⁺ lost
    positive definiteness or something became non-finite (θ̂ kept, v̂ propagated if finite
    else reset to v).
    """
    n = n_v
    p = theta.shape[0]
    theta_out = out[0:p]
    vhat_out = out[p:p + n]
    v_out = out[p + n:p + 2 * n]
    r_out = out[p + 2 * n:p + 2 * n + 3]
    u_out = out[p + 2 * n + 3:p + 3 * n + 3]
    dv_out = out[p + 3 * n + 3:p + 4 * n + 3]
    diag = out[p + 4 * n + 3:p + 4 * n + 5]
    off = 6 - n
    for i in range(n):
        v_out[i] = v_in[off + i]
        u_out[i] = u_in[off + i]
    for i in range(3):
        r_out[i] = H[2, i]
    if not (_finite(v_out) and _finite(r_out) and _finite(u_out)):
        return 2
    if dt == 0.0:
        for i in range(n):
            vhat_out[i] = v_out[i]
            dv_out[i] = 0.0
        return 4
    linear, midpoint = cfg[6] != 0.0, cfg[7] != 0.0
    u = np.empty(n)
    vs = np.empty(n)
    rs = np.empty(3)
    for i in range(n):
        u[i] = 0.5 * (u_prev[i] + u_out[i]) if linear else u_out[i]
        vs[i] = 0.5 * (v_prev[i] + v_out[i]) if midpoint else v_prev[i]
    for i in range(3):
        rs[i] = 0.5 * (r_prev[i] + r_out[i]) if midpoint else r_prev[i]
    sc = cfg[8:8 + n]
    we = cfg[8 + n:8 + n + p]
    if n == 6:
        status = _aid6_kernel(theta, vhat, v_prev, vs, rs, u, v_out, midpoint, dt, cfg[0],
                              cfg[1], cfg[2], cfg[3], cfg[4], sc, we, adapt, theta_out,
                              vhat_out, diag)
    else:
        status = _aid3_kernel(theta, vhat, v_prev, vs, rs, u, v_out, midpoint, dt, cfg[0],
                              cfg[1], cfg[2], cfg[3], sc, we, adapt, theta_out, vhat_out, diag)
    if status != 0:
        for i in range(n):
            vhat_out[i] = v_out[i]
            dv_out[i] = 0.0
        return 1
    ok = _finite(theta_out) and _finite(vhat_out) and diag[0] > cfg[5] * diag[1]
    if not ok:
        for i in range(theta.shape[0]):
            theta_out[i] = theta[i]
        if not _finite(vhat_out):
            for i in range(n):
                vhat_out[i] = v_out[i]
    for i in range(n):
        dv_out[i] = vhat_out[i] - v_out[i]
    if not ok:
        return 3
    return 0 if adapt else 4


def _cfg_template(params, n_v: int) -> np.ndarray:
    """[a, γ₁, γ₂, γ₃, γ₄, pd_floor, linear, midpoint, s₁ … s_n, w₁ … w_p]: :func:`_drive`'s
    ``cfg`` (s: the gains' per-DOF scales, w: the per-entry multipliers, ones when not given),
    built once per parameter set (writable like every array handed to the kernel — one
    compiled specialisation — and never written)."""
    gn = params.gains
    p = N_THETA_UV if n_v == 6 else N_THETA_UVR
    w = gn.entry_scale if gn.entry_scale else (1.0,) * p
    return np.array([gn.a, gn.gamma1, gn.gamma2, gn.gamma3, gn.gamma4 if n_v == 6 else 0.0,
                     params.pd_floor, params.input_interp == "linear",
                     params.sampling == "midpoint", *gn.dof_scale, *w], dtype=float)


# inputs of the gap step (dt = 0: only the sample is copied); never written by the kernel, and
# writable like the arrays of the normal step so both share one compiled specialisation
_ZEROS = {6: np.zeros(6), 3: np.zeros(3)}
_GAP_CFG = np.zeros(14 + N_THETA_UV)


def _step(n_v, vs, u_applied, params, st, dt, state_cls, what):
    """The Python side of :func:`aid6_step`/:func:`aid3_step` (state bookkeeping only).

    The new state's arrays are views of the kernel's one output buffer (see :func:`_drive`);
    states are built positionally, in the field order of :class:`AID6State`."""
    n = n_v
    p = st.theta.shape[0]
    out = np.empty(p + 4 * n + 5)
    gap = st.v_prev is None or not (0.0 < dt <= params.max_dt)  # t₀ (v̂ = v) or a gap
    if gap:
        z = _ZEROS[n]
        status = _drive(n, st.theta, z, z, _ZEROS[3], z, vs.H, vs.v, u_applied, _GAP_CFG,
                        0.0, False, out)
    else:
        status = _drive(n, st.theta, st.v_hat, st.v_prev, st.r_prev, st.u_prev, vs.H, vs.v,
                        u_applied, params._cfg, dt, not st.frozen, out)
    if status == 2:
        return replace(st, skipped=st.skipped + 1)
    vhat_out, v_out = out[p:p + n], out[p + n:p + 2 * n]
    r_out, u_out = out[p + 2 * n:p + 2 * n + 3], out[p + 2 * n + 3:p + 3 * n + 3]
    dv = out[p + 3 * n + 3:p + 4 * n + 3]
    if gap:
        return state_cls(st.theta, vhat_out, dv, v_out, r_out, u_out, st.m_min_eig,
                         st.m_max_eig, st.frozen, st.freeze_reason, st.steps, st.skipped,
                         st.resyncs + (st.v_prev is not None), st.t_s)
    t_s = st.t_s + dt
    frozen, reason, steps = st.frozen, st.freeze_reason, st.steps
    lo, hi = float(out[p + 4 * n + 3]), float(out[p + 4 * n + 4])
    theta_new = st.theta
    if status == 0:
        steps += 1
        theta_new = out[0:p]
        theta_new.setflags(write=False)
    elif status in (1, 3):
        frozen = True
        cause = "lost positive definiteness" if lo == lo else "update was not finite"
        reason = (f"t={t_s:.1f}s after {steps} steps: {what} {cause} "
                  f"(λ_min {lo:.4g}, λ_max {hi:.4g}); θ̂ frozen at its last PD value")
        lo, hi = st.m_min_eig, st.m_max_eig
    return state_cls(theta_new, vhat_out, dv, v_out, r_out, u_out, lo, hi, frozen, reason,
                     steps, st.skipped, st.resyncs, t_s)


# ---------------------------------------------------------------------------------------------
# 6-DOF UV AID, Theorem 4.3.1
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AID6Gains:
    """Gains of Theorem 4.3.1: a (1/s) and γ₁…γ₄ (> 0); defaults are §4.6's.

    ``dof_scale`` (6 numbers > 0, default ones: the thesis's scalar gains) makes the gain
    matrix diagonal per DOF, as Chapter 5's K_θ (γ_mi, γ_di, γ_bi): M̂ᵢⱼ adapts at
    γ₁√(sᵢsⱼ), row r of every D̂ᵢ at γ₂s_r, ĝ at γ₃ times the mean of s₁…s₃, b̂ₖ at γ₄s₃₊ₖ.
    Any positive diagonal gain keeps V̇ = −a∆vᵀM∆v of (4.33): V's parameter terms are
    weighted by the inverse gains, which cancel entry by entry.

    ``entry_scale`` (241 numbers > 0 in the order of θ_UV (2.48), or empty: ones) multiplies
    each entry's rate once more — the most general diagonal gain, so each parameter can be
    given a rate for its own excitation (:func:`excitation_entry_scale`); V̇ is unchanged
    by the same argument.
    """

    a: float = 10.0
    gamma1: float = 5000.0
    gamma2: float = 20000.0
    gamma3: float = 2000.0
    gamma4: float = 2000.0
    dof_scale: tuple[float, ...] = (1.0,) * 6
    entry_scale: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        _check_gains(self, ("a", "gamma1", "gamma2", "gamma3", "gamma4"), 6, N_THETA_UV)


def observer_problem(a: float, dt: float) -> str | None:
    """Why the velocity observer of (4.23) / (4.10) diverges at gain ``a`` and step ``dt``
    (s), or None. Its Euler step leaves the estimate's error (1 − a·dt) times itself plus the
    model's part, which grows unless a·dt < 2 (a > 0 is :class:`AID6Gains`' own check):
    ``uvd identify --gains 1e308,…`` froze at its first step, "RMS error inf %"."""
    if a * dt < 2.0:
        return None
    return (f"the observer gain a = {a:g} at a step of {dt:g} s makes a·dt = {a * dt:g} ≥ 2: "
            f"AID's velocity estimate ((4.10), (4.23)) diverges; a must stay under 2/dt = "
            f"{2.0 / dt:g}")


def _check_gains(g, names, n: int, p: int) -> None:
    """Every gain of ``names``, each of the ``n`` per-DOF scales and each of the ``p``
    per-entry scales (if given) finite and > 0."""
    for name in names:
        x = getattr(g, name)
        if not (math.isfinite(x) and x > 0.0):
            raise ValueError(f"AID gain {name} must be finite and > 0, got {x!r}")
    sc = tuple(float(x) for x in g.dof_scale)
    if len(sc) != n or not all(math.isfinite(x) and x > 0.0 for x in sc):
        raise ValueError(f"AID dof_scale must be {n} finite numbers > 0, got {g.dof_scale!r}")
    object.__setattr__(g, "dof_scale", sc)
    we = tuple(float(x) for x in g.entry_scale)
    if we and (len(we) != p or not all(math.isfinite(x) and x > 0.0 for x in we)):
        raise ValueError(f"AID entry_scale must be empty or {p} finite numbers > 0, got "
                         f"{len(we)} numbers")
    object.__setattr__(g, "entry_scale", we)


def _check_params(p) -> None:
    """Checks shared by :class:`AID6Params` and :class:`AID3Params` (errors name the field)."""
    if p.input_interp not in _INTERP:
        raise ValueError(f"input_interp must be one of {_INTERP}, got {p.input_interp!r}")
    if p.sampling not in _SAMPLING:
        raise ValueError(f"sampling must be one of {_SAMPLING}, got {p.sampling!r}")
    if not (0.0 <= p.pd_floor < 1.0):
        raise ValueError(f"pd_floor must be in [0, 1), got {p.pd_floor!r}")
    if not p.max_dt > 0.0:
        raise ValueError(f"max_dt must be > 0, got {p.max_dt!r}")


@dataclass(frozen=True)
class AID6Params:
    """Constant configuration of :func:`aid6_step`.

    Attributes
    ----------
    gains : AID6Gains
    input_interp : {"linear", "hold"}
        How the wrench u_k handed over at cycle k covers [t_{k−1}, t_k]: "linear" — u_k is the
        instantaneous wrench at t_k (measured propeller speeds); the interval uses
        ½(u_{k−1} + u_k). "hold" — u_k was held over the interval (ideal actuators).
    sampling : {"midpoint", "euler"}
        Where (v, R) enter the right-hand sides over a step (module docstring).
    pd_floor : float
        M̂ counts as no longer positive definite when λ_min(M̂) ≤ pd_floor · λ_max(M̂)
        (a condition number above 1/pd_floor); the estimator then freezes.
    max_dt : float
        A period longer than this (s), or ≤ 0, is a gap: v̂ is re-synchronised to v
        (v̂ = v as at t₀) and θ̂ is not updated.
    """

    gains: AID6Gains = field(default_factory=AID6Gains)
    input_interp: str = "linear"
    sampling: str = "midpoint"
    pd_floor: float = 1e-9
    max_dt: float = 1.0

    def __post_init__(self) -> None:
        _check_params(self)
        object.__setattr__(self, "_cfg", _cfg_template(self, 6))


@dataclass(frozen=True)
class _AIDState:
    """The fields of :class:`AID6State` and :class:`AID3State` (documented there)."""

    theta: np.ndarray
    v_hat: np.ndarray
    dv: np.ndarray
    v_prev: np.ndarray | None = None
    r_prev: np.ndarray | None = None
    u_prev: np.ndarray | None = None
    m_min_eig: float = float("nan")
    m_max_eig: float = float("nan")
    frozen: bool = False
    freeze_reason: str = ""
    steps: int = 0
    skipped: int = 0
    resyncs: int = 0
    t_s: float = 0.0
    hold_reason: str = ""


def aid_diagnostics(st: _AIDState) -> Diagnostics:
    """The diagnostics hook of AID's spec: θ̂ (a copy), M̂'s extreme eigenvalues (the health
    of Theorem 4.3.1's (4.36)), the freeze and its reason, the counters, ‖v̂ − v‖ and the
    DOFs held (:func:`aid_hold_dofs`)."""
    return Diagnostics(theta=np.array(st.theta, dtype=float), m_min_eig=float(st.m_min_eig),
                       m_max_eig=float(st.m_max_eig), frozen=bool(st.frozen),
                       freeze_reason=st.freeze_reason, steps=st.steps, skipped=st.skipped,
                       resyncs=st.resyncs, velocity_error=float(np.linalg.norm(st.dv)),
                       hold_reason=st.hold_reason)


_DOFS = ("surge", "sway", "heave", "roll", "pitch", "yaw")


@functools.cache
def held_indices(n_v: int, given_up: tuple[int, ...]) -> np.ndarray:
    """The entries of θ̂ that the model's rows ``given_up`` (DOF indices 0…5) own.

    6-DOF (n_v 6, θ_UV of (2.48)): row and column j of M̂ — the θ_M entries (i, k), i ≤ k,
    of (2.45) with i = j or k = j, since M̂ is symmetric and (4.24) moves both — row j of
    every D̂ᵢ (4.25), ĝ when a translational row is given up (4.26: ĝ̇ sums ∆ν over those
    rows) and b̂ when a rotational one is (4.27: ∆ω). 3-DOF (n_v 3, θ_UVR of (2.41)): the same
    for Î (4.11), Ĉᵢ (4.12) and b̂ (4.13), on the rotational DOFs only (roll, pitch, yaw are
    its rows 0, 1, 2; a translational DOF given up holds nothing there)."""
    rows = [j for j in given_up if j < 6] if n_v == 6 else [j - 3 for j in given_up if j >= 3]
    if not rows:
        return np.zeros(0, dtype=np.int64)
    n = n_v
    n_m = n * (n + 1) // 2
    idx = []
    k = 0
    for i in range(n):
        for j in range(i, n):  # θ_M's upper triangle, as _inertia_law walks it
            if i in rows or j in rows:
                idx.append(k)
            k += 1
    for i in range(n):  # D̂ᵢ (Ĉᵢ) stored column-major: entry (r, c) at n_m + n²i + n c + r
        for c in range(n):
            idx.extend(n_m + n * n * i + n * c + r for r in rows)
    tail = n_m + n ** 3
    if n == 6:
        if any(r < 3 for r in rows):
            idx.append(tail)                     # ĝ
        if any(r >= 3 for r in rows):
            idx.extend((tail + 1, tail + 2, tail + 3))  # b̂
    else:
        idx.extend((tail, tail + 1, tail + 2))   # b̂
    out = np.array(sorted(set(idx)), dtype=np.int64)
    out.setflags(write=False)
    return out


def aid_hold_dofs(new: _AIDState, old: _AIDState, actuated: np.ndarray | None
                  ) -> _AIDState:
    """AID's ``hold_dofs`` hook (:class:`~uvd.control.types.EstimatorSpec`): the parameters
    of the DOFs not ``actuated`` ((6,) bool; the core's allocation gave them up) stay at
    ``old``'s — their laws (4.24)–(4.27) ((4.11)–(4.13) for 3-DOF) are not integrated on
    those rows (:func:`held_indices`) — while the other rows adapt; v̂ (4.23) still runs on
    the whole model. ``hold_reason`` names them ("" when every DOF is actuated: ``actuated``
    all true, or None)."""
    if actuated is None or actuated.all():
        return new if not new.hold_reason else replace(new, hold_reason="")
    given_up = tuple(int(j) for j in np.flatnonzero(~np.asarray(actuated, dtype=bool)))
    n_v = 6 if new.theta.shape[0] == N_THETA_UV else 3
    idx = held_indices(n_v, given_up)
    theta = new.theta
    if idx.size and new.theta is not old.theta:
        theta = np.array(new.theta)
        theta[idx] = old.theta[idx]
        theta.setflags(write=False)
    names = ", ".join(_DOFS[j] for j in given_up)
    them = "it" if len(given_up) == 1 else "them"
    reason = (f"{names} given up (no thruster reaches {them}): rows held, "
              f"{idx.size} of {theta.shape[0]} parameters of θ̂")
    return replace(new, theta=theta, hold_reason=reason)


@dataclass(frozen=True)
class AID6State(_AIDState):
    """State of 6-DOF AID. Read θ̂ as ``theta`` (order of (2.48)) or :func:`aid6_params`.

    Attributes
    ----------
    theta : (241,) θ̂_UV = [θ_M, D₁ˢ…D₆ˢ, g, b] (2.48).
    v_hat : (6,) v̂ at the last sample time (m/s, rad/s).
    dv : (6,) ∆v = v̂ − v at the last sample (zeros before the second call).
    v_prev, r_prev, u_prev : last sample's v, Rᵀe₃ and wrench (None before the first call).
    m_min_eig, m_max_eig : extreme eigenvalues of M̂ (health of Theorem 4.3.1's (4.36)).
    frozen : True once M̂ lost positive definiteness; ``freeze_reason`` says why and when.
    steps : adaptation steps taken; ``skipped`` : calls ignored (non-finite input);
    ``resyncs`` : gaps after which v̂ was re-synchronised.
    """


def _check_theta(theta, n: int, what: str) -> np.ndarray:
    th = np.array(theta, dtype=float).reshape(-1)
    if th.shape != (n,):
        raise ValueError(f"{what} must have {n} entries, got {th.shape[0]}")
    if not np.all(np.isfinite(th)):
        raise ValueError(f"{what} has a non-finite entry")
    return th


def aid6_init(theta0: np.ndarray | UVParams) -> AID6State:
    """Initial state from θ̂(t₀) (e.g. INITP of Tables 4.6–4.7, :data:`INITP_6DOF`).

    M̂(t₀) must be positive definite (Theorem 4.3.1); v̂(t₀) = v(t₀) is set on the first step.
    """
    th = theta0.theta if isinstance(theta0, UVParams) else theta0
    th = _check_theta(th, N_THETA_UV, "θ̂_UV(t₀)")
    M = params_from_theta(th).M
    lam = np.linalg.eigvalsh(M)
    if not lam[0] > 0.0:
        raise ValueError(f"M̂(t₀) must be positive definite (min eigenvalue {lam[0]:.4g})")
    th.setflags(write=False)
    return AID6State(theta=th, v_hat=np.zeros(6), dv=np.zeros(6), m_min_eig=float(lam[0]),
                     m_max_eig=float(lam[-1]))


def aid6_step(vs, u_applied: np.ndarray, params: AID6Params, st: AID6State,
              dt: float) -> AID6State:
    """One Euler step of Theorem 4.3.1 (4.23)–(4.27); returns the new state.

    Parameters
    ----------
    vs : object with ``H`` (4×4 pose, body→world) and ``v`` (6,) body velocity [ν; ω]
        (:class:`uvd.control.types.VehicleState`).
    u_applied : (6,) wrench [f; τ] (N, N m) produced over the last period (see module note).
    params : AID6Params
    st : AID6State
    dt : float, period since the previous call (s).

    Never raises on bad data: a non-finite input is counted in ``skipped`` and ignored.
    """
    return _step(6, vs, np.asarray(u_applied, dtype=float), params, st, float(dt), AID6State,
                 "M̂")


def aid6_params(st: AID6State) -> UVParams:
    """θ̂ as :class:`UVParams` (M̂ symmetric by construction; may not be valid physically)."""
    return params_from_theta(st.theta)


def aid_unfreeze(st: AID6State | AID3State) -> AID6State | AID3State:
    """Resume adaptation (6-DOF or 3-DOF AID) after a freeze; θ̂ is the last
    positive-definite estimate."""
    return replace(st, frozen=False, freeze_reason="")


def aid6_estimator(theta0: np.ndarray | UVParams | None = None,
                   params: AID6Params | None = None, name: str = "aid6"):
    """An :class:`~uvd.control.types.EstimatorSpec` running 6-DOF AID (INITP of §4.6 by
    default)."""
    theta0 = INITP_6DOF.theta if theta0 is None else theta0
    return EstimatorSpec(name=name, step=aid6_step, params=params or AID6Params(),
                         init_state=aid6_init(theta0), diagnostics=aid_diagnostics,
                         hold_dofs=aid_hold_dofs)


# ---------------------------------------------------------------------------------------------
# 3-DOF UV rotational AID, Theorem 4.2.1
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AID3Gains:
    """Gains of Theorem 4.2.1: a (1/s), γ₁, γ₂, γ₃ (> 0); defaults are §4.5's.
    ``dof_scale``: per roll, pitch, yaw, as :class:`AID6Gains`'s (b̂ₖ at γ₃sₖ);
    ``entry_scale``: 36 per-entry multipliers in the order of θ_UVR (2.41), or empty."""

    a: float = 10.0
    gamma1: float = 5000.0
    gamma2: float = 10000.0
    gamma3: float = 1000.0
    dof_scale: tuple[float, ...] = (1.0,) * 3
    entry_scale: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        _check_gains(self, ("a", "gamma1", "gamma2", "gamma3"), 3, N_THETA_UVR)


@dataclass(frozen=True)
class AID3Params:
    """Constant configuration of :func:`aid3_step` (fields as :class:`AID6Params`)."""

    gains: AID3Gains = field(default_factory=AID3Gains)
    input_interp: str = "linear"
    sampling: str = "midpoint"
    pd_floor: float = 1e-9
    max_dt: float = 1.0

    def __post_init__(self) -> None:
        _check_params(self)
        object.__setattr__(self, "_cfg", _cfg_template(self, 3))


@dataclass(frozen=True)
class AID3State(_AIDState):
    """State of rotational AID: θ̂_UVR ∈ R³⁶ (2.41), ω̂, ∆ω; fields as :class:`AID6State`
    (``m_min_eig``/``m_max_eig`` are the extreme eigenvalues of Î)."""


def aid3_init(theta0: np.ndarray | RotParams) -> AID3State:
    """Initial state from θ̂_UVR(t₀) (e.g. INITP of Table 4.2, :data:`INITP_ROT`)."""
    th = theta0.theta if isinstance(theta0, RotParams) else theta0
    th = _check_theta(th, N_THETA_UVR, "θ̂_UVR(t₀)")
    lam = np.linalg.eigvalsh(RotParams.from_theta(th).I)
    if not lam[0] > 0.0:
        raise ValueError(f"Î(t₀) must be positive definite (min eigenvalue {lam[0]:.4g})")
    th.setflags(write=False)
    return AID3State(theta=th, v_hat=np.zeros(3), dv=np.zeros(3), m_min_eig=float(lam[0]),
                     m_max_eig=float(lam[-1]))


def aid3_step(vs, u_applied: np.ndarray, params: AID3Params, st: AID3State,
              dt: float) -> AID3State:
    """One Euler step of Theorem 4.2.1 (4.10)–(4.13) on ω = v[3:], τ = u[3:].

    Same contract as :func:`aid6_step`; ``v_hat``/``dv`` are ω̂ and ∆ω (rad/s).
    """
    return _step(3, vs, np.asarray(u_applied, dtype=float), params, st, float(dt), AID3State,
                 "Î")


def aid3_params(st: AID3State) -> RotParams:
    """θ̂_UVR as :class:`RotParams` (Î symmetric by construction)."""
    return RotParams.from_theta(st.theta)


def aid3_estimator(theta0: np.ndarray | RotParams | None = None,
                   params: AID3Params | None = None, name: str = "aid3"):
    """An :class:`~uvd.control.types.EstimatorSpec` running rotational AID (INITP of §4.5 by
    default)."""
    theta0 = INITP_ROT.theta if theta0 is None else theta0
    return EstimatorSpec(name=name, step=aid3_step, params=params or AID3Params(),
                         init_state=aid3_init(theta0), diagnostics=aid_diagnostics,
                         hold_dofs=aid_hold_dofs)


# ---------------------------------------------------------------------------------------------
# initialisation parameter sets (INITP)
# ---------------------------------------------------------------------------------------------
INITP_6DOF = UVParams(M=100.0 * np.eye(6), D=np.stack([-100.0 * np.eye(6)] * 6), g=0.0,
                      b=np.array([0.0, 0.0, 100.0]))
"""INITP of Tables 4.6–4.7: M̂ = 100 I, D̂ᵢ = −100 I, ĝ = 0, b̂ = [0, 0, 100]."""

INITP_ROT = RotParams(I=100.0 * np.eye(3), C=np.stack([-100.0 * np.eye(3)] * 3),
                      b=np.array([0.0, 0.0, 100.0]))
"""INITP of Table 4.2: Î = 100 I, Ĉᵢ = −100 I, b̂ = [0, 0, 100]."""


# ---------------------------------------------------------------------------------------------
# gains scaled to the vehicle
# ---------------------------------------------------------------------------------------------
#: the JHU ROV's decoupled model (Tables 5.4–5.5, uvd/vehicles/jhu-rov.toml): the vehicle
#: §4.5's and §4.6's gains and INITP were chosen for — masses, quadratic drags, b₃
JHU_MASSES = np.array([628.0, 791.0, 1043.0, 95.7, 145.3, 110.2])
JHU_DRAGS = np.array([-1259.0, -1429.0, -3083.0, -727.1, -783.4, -465.6])
JHU_B3 = 300.0


def _positive(x, n: int, what: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.shape != (n,) or np.any(~(a > 0)) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: {n} positive finite numbers needed, got {x!r}")
    return a


def scaled_aid_gains(masses: np.ndarray, *, rotational: bool = False,
                     base: AID6Gains | AID3Gains | None = None,
                     factors: tuple[float, float] = (1.0, 1.0)) -> AID6Gains | AID3Gains:
    """AID's gains for another vehicle: §4.6's (6-DOF) or §4.5's (rotational) γ's with a
    diagonal gain per DOF, ``dof_scale`` sⱼ = mⱼ / mⱼᴶᴴᵁ (times ``factors`` = (translation,
    rotation)).

    In (4.10)–(4.13) / (4.23)–(4.27) each parameter's update is γ times its regressor times
    ∆v, and the observer error is ∆v ≈ M̂⁻¹ 𝒲 θ̃ / a: a parameter of DOF j's equation moves
    at a relative rate ≈ γ E[𝒲ⱼ²] / (a mⱼ). With γⱼ ∝ mⱼ it moves, for the same motion, as
    fast as on the JHU ROV (where sⱼ = 1: §4.6's gains exactly) — whichever DOF: one mean-mass
    ratio for all six (the previous rule, 0.026 on a BlueROV2 Heavy) made its rotation 5–10×
    faster than the JHU ROV's (inertia ratios 0.0025–0.0054), its translation about as fast.
    Any positive diagonal gain keeps Theorem 4.3.1's V̇ (:class:`AID6Gains`; Chapter 5's K_θ
    is diagonal per DOF too). ``factors`` multiply the
    translational and rotational sⱼ: the thesis ran 22–35 min of data (Tables 4.1, 4.5), a
    2-minute run needs faster rates, chosen as §4.5 chose its gains — a logarithmic sweep in
    simulation (``uvd tune --aid-sweep``, :mod:`uvd.experiments.aid_gains`). ``base``: the
    gains to scale (default §4.6's / §4.5's). ``masses``: the vehicle's M diagonal (6).
    """
    m = _positive(masses, 6, "scaled_aid_gains: the diagonal of M")
    k = _positive(factors, 2, "scaled_aid_gains: factors (translation, rotation)")
    s = m / JHU_MASSES * np.repeat(k, 3)
    if rotational:
        g3 = base or AID3Gains()
        return replace(g3, dof_scale=tuple(float(x) for x in s[3:]))
    return replace(base or AID6Gains(), dof_scale=tuple(float(x) for x in s))


def scaled_initp(params: UVParams) -> UVParams:
    """INITP of Tables 4.6–4.7 (M̂ = 100 I, D̂ᵢ = −100 I, ĝ = 0, b̂ = [0, 0, 100]) carried to
    another vehicle entry by entry: M̂ⱼⱼ = 100 mⱼ/mⱼᴶᴴᵁ, every D̂ᵢ's (j, j) = −100 dⱼ/dⱼᴶᴴᵁ,
    b̂₃ = 100 b₃/b₃ᴶᴴᵁ, from the vehicle file's first guess ``params`` (M's and every Dᵢ's
    diagonal, b₃; a b₃ ≤ 0 takes the mean inertia ratio instead). Each first guess is as far
    from the vehicle's as the thesis's INITP was from the JHU ROV's (masses ×0.1–1,
    drags ×0.03–0.2, b₃ ×⅓) — not the vehicle file's values, which a simulation's plant
    shares. On the JHU ROV itself: INITP exactly."""
    m = _positive(np.diag(params.M), 6, "scaled_initp: the diagonal of M")
    d = np.array([params.D[i][i, i] for i in range(6)], dtype=float)
    if not np.all(d < 0):
        raise ValueError(f"scaled_initp: the drags D_i[i, i] must be < 0, got {d.tolist()}")
    b3 = float(params.b[2])
    rb = b3 / JHU_B3 if b3 > 0 else float(np.mean(m[3:] / JHU_MASSES[3:]))
    D = np.stack([np.diag(-100.0 * d / JHU_DRAGS)] * 6)
    return UVParams(M=np.diag(100.0 * m / JHU_MASSES), D=D, g=0.0,
                    b=np.array([0.0, 0.0, 100.0 * rb]))


# ---------------------------------------------------------------------------------------------
# a gain per decoupled parameter from its excitation
# ---------------------------------------------------------------------------------------------
#: the 16 decoupled parameters of §5.3.1 (θ_UV[DECOUPLED_INDEX]), named as in the tables
DECOUPLED_NAMES = ("m1", "m2", "m3", "m4", "m5", "m6", "d1", "d2", "d3", "d4", "d5", "d6",
                   "g", "b1", "b2", "b3")


def decoupled_gains(gains: AID6Gains) -> np.ndarray:
    """The rate γₖ each of the 16 decoupled parameters adapts at under ``gains`` (without
    ``entry_scale``): M̂ⱼⱼ at γ₁sⱼ (4.24), D̂ⱼ(j, j) at γ₂sⱼ (4.25), ĝ at γ₃ mean(s₁…s₃)
    (4.26), b̂ₖ at γ₄s₃₊ₖ (4.27) — as the compiled kernel applies them."""
    s = np.asarray(gains.dof_scale, dtype=float)
    return np.r_[gains.gamma1 * s, gains.gamma2 * s, gains.gamma3 * s[:3].mean(),
                 gains.gamma4 * s[3:]]


def decoupled_excitation(H: np.ndarray, v: np.ndarray, dt: np.ndarray, M: np.ndarray,
                         window_s: float = 0.5) -> np.ndarray:
    """Excitation of each decoupled parameter over a run: eₖ = mean over the samples of
    𝒲ₖᵀ M⁻¹ 𝒲ₖ, 𝒲ₖ the column of W_UV (2.49) that multiplies θₖ (θ_UV[DECOUPLED_INDEX]).

    Near θ̂ = θ the observer error of (4.23) is ∆v ≈ M⁻¹𝒲θ̃/a (a ≫ the motion's
    frequencies), so (4.24)–(4.27) move θ̃ₖ alone at the rate γₖeₖ/a (1/s): eₖ says how
    strongly the run excites θₖ. v̇ is a Savitzky–Golay derivative of v over ``window_s``
    (a plain difference of a 50 Hz noisy rate is mostly noise).

    Parameters
    ----------
    H : (n, 4, 4) poses; v : (n, 6) body velocities [ν; ω]; dt : (n,) periods (s, the first
        is ignored); M : (6, 6) the inertia used for M⁻¹ (the vehicle file's first guess).
    Returns (16,) in the order of :data:`DECOUPLED_NAMES`.
    """
    from scipy.signal import savgol_filter

    from uvd.model.params import DECOUPLED_INDEX
    from uvd.model.regressors import W_UV

    v = np.asarray(v, dtype=float)
    step = float(np.median(np.asarray(dt, dtype=float)[1:]))
    win = max(5, int(round(window_s / step)) | 1)
    if v.shape[0] < win:
        raise ValueError(f"decoupled_excitation: {v.shape[0]} samples, fewer than the "
                         f"{win} of the derivative's window")
    vd = savgol_filter(v, win, 2, deriv=1, delta=step, axis=0)
    Minv = np.linalg.inv(np.asarray(M, dtype=float))
    e = np.zeros(DECOUPLED_INDEX.shape[0])
    for k in range(v.shape[0]):
        W = W_UV(v[k], vd[k], np.asarray(H[k])[:3, :3])[:, DECOUPLED_INDEX]
        e += np.einsum("ik,ij,jk->k", W, Minv, W)
    return e / v.shape[0]


def excitation_gain_scale(excitation: np.ndarray, gains: AID6Gains,
                          band: tuple[float, float]) -> np.ndarray:
    """Multipliers wₖ of the 16 decoupled parameters' gains that bring each one's rate for
    its own excitation, ρₖ = γₖeₖ/a (1/s; :func:`decoupled_excitation`,
    :func:`decoupled_gains`), into ``band`` = (ρ_lo, ρ_hi): wₖ = clip(ρₖ, ρ_lo, ρ_hi)/ρₖ;
    1 where eₖ = 0 (not excited at all: nothing to scale by).

    Why (measured on a BlueROV2 Heavy under RefTraj1, docs/real-vehicles.md): §4.6's gains,
    even scaled per DOF, give parameters with a large regressor a rate far above the motion's
    frequencies — b̂₁, b̂₂ (regressor r₃ = cos φ cos θ ≈ 1) 1–2.5 /s against b̂₃'s 0.03 /s
    (r₁, r₂ ≈ 0.08) — so they follow b̂₃'s torque error as a time-varying signal within a
    second and b̂₃ does not converge; and parameters with a small regressor (the drags)
    0.00001–0.001 /s, hours. ρ_hi below the motion's frequencies keeps the first from
    following the motion, ρ_lo gives the second a rate a run can show. A diagonal Γ keeps
    V̇ = −a∆vᵀM∆v (4.33)."""
    lo, hi = (float(x) for x in band)
    if not (0.0 < lo <= hi and math.isfinite(hi)):
        raise ValueError(f"excitation_gain_scale: band must be 0 < lo <= hi, got {band!r}")
    e = np.asarray(excitation, dtype=float)
    rate = decoupled_gains(gains) * e / gains.a
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(rate > 0, np.clip(rate, lo, hi) / rate, 1.0)


def entry_scale_of(decoupled_scale) -> tuple[float, ...]:
    """``entry_scale`` (241) of :class:`AID6Gains` from multipliers of the 16 decoupled
    parameters (every other entry 1)."""
    from uvd.model.params import DECOUPLED_INDEX

    w = np.ones(N_THETA_UV)
    w[DECOUPLED_INDEX] = _positive(decoupled_scale, DECOUPLED_INDEX.shape[0],
                                   "decoupled gain scale")
    return tuple(float(x) for x in w)
