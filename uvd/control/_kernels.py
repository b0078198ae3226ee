"""Compiled kernels of the controllers (numba, ``cache=True``): error coordinates, the PD term,
the MBC regressor product W_MBC θ of (5.12) and its transpose product W_MBCᵀ s of (5.28).

Nothing here builds the 6 × 241 regressor: with α = Ad_{ΔH⁻¹} ᵈv̇_d − ad_{Δv} ᵃv_d and v = ᵃvₐ,

    W_MBC θ = M α − ad_vᵀ(M v) − Σᵢ|vᵢ|Dᵢ v − G(R)                                  (5.12)

which is W_UV(v, α, R) θ of (2.49), so both products are written entry by entry:

* W_MBCᵀ s, mass block: ∂/∂M of sᵀ(Mα − ad_vᵀ(Mv)) is dM = s αᵀ − (ad_v s) vᵀ, folded onto the
  21 unique entries of (2.45) (dM_ij + dM_ji off the diagonal);
* drag block of Dᵢ (column-stacked, (2.8)): −|vᵢ| s_row v_col;
* gravity g: −(Rᵀe₃)·s_f; buoyancy b: s_τ × Rᵀe₃.

The decoupled 16-parameter model of §5.3.1 (θ = [m, d, g, b]) is the projection of the same
formulas onto M = diag(m), Dᵢ = dᵢ eᵢeᵢᵀ. ``tests/test_control_ambc.py`` checks both products
against the kron-built :func:`uvd.model.regressors.W_UV`.

The SE(3) maps are the compiled kernels of :mod:`uvd.model.lie`.
"""

from __future__ import annotations

import numba
import numpy as np

from uvd.model.integrate import _ad
from uvd.model.lie import _A_inv_se3_blocks, _inv_H, _log_se3
from uvd.model.spd import cholesky

_jit = numba.njit(cache=True)

# unique-entry index (2.45) of M[i, j], row-wise over the upper triangle
_MIDX = np.zeros((6, 6), dtype=np.int64)
_k = 0
for _i in range(6):
    for _j in range(_i, 6):
        _MIDX[_i, _j] = _k
        _MIDX[_j, _i] = _k
        _k += 1
del _i, _j, _k

MODEL_FULL = 0
MODEL_DECOUPLED = 1


@_jit
def _cross(a, b, out, o):
    out[o] = a[1] * b[2] - a[2] * b[1]
    out[o + 1] = a[2] * b[0] - a[0] * b[2]
    out[o + 2] = a[0] * b[1] - a[1] * b[0]


@_jit
def ad_mul(x, y):
    """ad_x y = [ω_x × ν_y + ν_x × ω_y; ω_x × ω_y] (2.4) — the integrator's kernel, returned."""
    out = np.empty(6)
    _ad(x, y, out)
    return out


@_jit
def adT_mul(v, x):
    """ad_vᵀ x for v = [ν; ω], x = [p; h]: [p × ω; p × ν + h × ω]."""
    out = np.empty(6)
    n1, n2, n3, w1, w2, w3 = v[0], v[1], v[2], v[3], v[4], v[5]
    p1, p2, p3, h1, h2, h3 = x[0], x[1], x[2], x[3], x[4], x[5]
    out[0] = p2 * w3 - p3 * w2
    out[1] = p3 * w1 - p1 * w3
    out[2] = p1 * w2 - p2 * w1
    out[3] = p2 * n3 - p3 * n2 + h2 * w3 - h3 * w2
    out[4] = p3 * n1 - p1 * n3 + h3 * w1 - h1 * w3
    out[5] = p1 * n2 - p2 * n1 + h1 * w2 - h2 * w1
    return out


@_jit
def _Ad_mul(H, x):
    """Ad_H x = [R ν + p × (R ω); R ω] (2.5)."""
    out = np.empty(6)
    for i in range(3):
        out[i] = H[i, 0] * x[0] + H[i, 1] * x[1] + H[i, 2] * x[2]
        out[3 + i] = H[i, 0] * x[3] + H[i, 1] * x[4] + H[i, 2] * x[5]
    p0, p1, p2 = H[0, 3], H[1, 3], H[2, 3]
    r0, r1, r2 = out[3], out[4], out[5]
    out[0] += p1 * r2 - p2 * r1
    out[1] += p2 * r0 - p0 * r2
    out[2] += p0 * r1 - p1 * r0
    return out


@_jit
def _mm4(A, B):
    out = np.zeros((4, 4))
    for i in range(4):
        for j in range(4):
            s = 0.0
            for k in range(4):
                s += A[i, k] * B[k, j]
            out[i, j] = s
    return out


@_jit
def error_state(H_a, v_a, H_d, v_d, vdot_d, out):
    """Error coordinates of §5.2.3 and the MBC acceleration term, into ``out`` (5 × 6).

    out[0] = Δψ = log(ʷ_dH⁻¹ ʷₐH) (5.2)–(5.3); out[1] = Δv = ᵃvₐ − ᵃv_d (5.4) with
    ᵃv_d = Ad_{ΔH⁻¹} ᵈv_d (out[2]); out[3] = Ad_{ΔH⁻¹} ᵈv̇_d; out[4] = α = out[3] − ad_{Δv} ᵃv_d,
    the acceleration multiplying M in (5.12) (from (5.10)).
    """
    dH = _mm4(_inv_H(H_d), H_a)
    dpsi = _log_se3(dH)
    dHinv = _inv_H(dH)
    avd = _Ad_mul(dHinv, v_d)
    aad = _Ad_mul(dHinv, vdot_d)
    dv = np.empty(6)
    for i in range(6):
        dv[i] = v_a[i] - avd[i]
    adv = ad_mul(dv, avd)
    for i in range(6):
        out[0, i] = dpsi[i]
        out[1, i] = dv[i]
        out[2, i] = avd[i]
        out[3, i] = aad[i]
        out[4, i] = aad[i] - adv[i]


@_jit
def pd_term(dpsi, dv, kp, kd):
    """k_p A⁻ᵀ(Δψ) Δψ + k_d Δv, the PD part of (5.11) (k_p, k_d per DOF, shape (6,))."""
    Ai = _A_inv_se3_blocks(dpsi)
    out = np.empty(6)
    for j in range(6):
        s = 0.0
        for i in range(6):
            s += Ai[i, j] * dpsi[i]
        out[j] = kp[j] * s + kd[j] * dv[j]
    return out


@_jit
def w_theta(model, theta, v, alpha, r):
    """W_MBC θ of (5.12): M α − ad_vᵀ(M v) − Σᵢ|vᵢ|Dᵢ v − G(R); r = Rᵀe₃ (third row of R)."""
    Ma = np.zeros(6)
    Mv = np.zeros(6)
    drag = np.zeros(6)
    if model == MODEL_FULL:
        for i in range(6):
            for j in range(6):
                m = theta[_MIDX[i, j]]
                Ma[i] += m * alpha[j]
                Mv[i] += m * v[j]
        for k in range(6):
            ak = abs(v[k])
            if ak == 0.0:
                continue
            base = 21 + 36 * k
            for col in range(6):
                c = ak * v[col]
                for row in range(6):
                    drag[row] += theta[base + col * 6 + row] * c
        g = theta[237]
        b0, b1, b2 = theta[238], theta[239], theta[240]
    else:
        for i in range(6):
            Ma[i] = theta[i] * alpha[i]
            Mv[i] = theta[i] * v[i]
            drag[i] = theta[6 + i] * abs(v[i]) * v[i]
        g = theta[12]
        b0, b1, b2 = theta[13], theta[14], theta[15]
    c = adT_mul(v, Mv)
    out = np.empty(6)
    for i in range(6):
        out[i] = Ma[i] - c[i] - drag[i]
    # − G(R) = −[g r; b × r]
    out[0] -= g * r[0]
    out[1] -= g * r[1]
    out[2] -= g * r[2]
    out[3] -= b1 * r[2] - b2 * r[1]
    out[4] -= b2 * r[0] - b0 * r[2]
    out[5] -= b0 * r[1] - b1 * r[0]
    return out


@_jit
def wT_s(model, n, v, alpha, r, s):
    """W_MBCᵀ s (length n = 241 or 16), the gradient in the update law (5.28)."""
    out = np.zeros(n)
    ads = ad_mul(v, s)
    if model == MODEL_FULL:
        for i in range(6):
            for j in range(i, 6):
                d = s[i] * alpha[j] - ads[i] * v[j]
                if i != j:
                    d += s[j] * alpha[i] - ads[j] * v[i]
                out[_MIDX[i, j]] = d
        for k in range(6):
            ak = abs(v[k])
            base = 21 + 36 * k
            for col in range(6):
                c = -ak * v[col]
                for row in range(6):
                    out[base + col * 6 + row] = c * s[row]
        ig = 237
    else:
        for i in range(6):
            out[i] = s[i] * alpha[i] - ads[i] * v[i]
            out[6 + i] = -s[i] * abs(v[i]) * v[i]
        ig = 12
    out[ig] = -(r[0] * s[0] + r[1] * s[1] + r[2] * s[2])
    # s_τ × r
    out[ig + 1] = s[4] * r[2] - s[5] * r[1]
    out[ig + 2] = s[5] * r[0] - s[3] * r[2]
    out[ig + 3] = s[3] * r[1] - s[4] * r[0]
    return out


@_jit
def _pd_above(S, floor):
    """True when S − floor·I is positive definite (S symmetric), by Cholesky; False when S has
    a non-finite entry."""
    n = S.shape[0]
    return cholesky(S, floor, n, np.zeros((n, n)))


@_jit
def _sym_inside(A, sign, floor, S):
    """True when :func:`_sym_eig_clip_min` (sign·A, floor) would leave its matrix unchanged:
    the same test as there (:func:`_pd_above` at the floor less its tolerance) on
    sym(sign·A) = ½(sign·A + (sign·A)ᵀ) formed entry by entry into the n × n scratch ``S``
    (sign = ±1, so every entry is bit-identical) instead of as four temporary matrices — the
    projection's common case, every cycle."""
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            S[i, j] = 0.5 * (sign * A[i, j] + sign * A[j, i])
    return _pd_above(S, floor - 1e-9 * max(1.0, abs(floor)))


@_jit
def _sym_eig_clip_min(A, floor):
    """Symmetric part of A with its eigenvalues raised to at least ``floor`` (Frobenius
    projection onto {S = Sᵀ : S ⪰ floor·I}); returns (S, clipped?)."""
    S = 0.5 * (A + A.T)
    if _pd_above(S, floor - 1e-9 * max(1.0, abs(floor))):  # at the floor counts as inside
        return S, False
    if not np.isfinite(S).all():  # left as it is (the eigendecomposition would raise)
        return S, False
    w, V = np.linalg.eigh(S)
    for i in range(w.shape[0]):
        if w[i] < floor:
            w[i] = floor
    return (V * w) @ V.T, True


@_jit
def project(model, theta, mass_floor, drag_ceiling):
    """Parameter projection of the robust adaptation (in place); returns how many blocks moved.

    Decoupled: mᵢ ≥ mass_floor[i], dᵢ ≤ −drag_ceiling[i]. Full: M̂ symmetric with eigenvalues
    ≥ min(mass_floor) and each D̂ᵢ with symmetric part ⪯ −min(drag_ceiling)·I (which makes
    vᵀ(Σ|vᵢ|D̂ᵢ)v < 0, i.e. dissipative, §2.6); the skew part of D̂ᵢ is kept. A block with a
    non-finite entry is left as it is: the command computed from it is not finite either, and
    the core zeroes it.
    """
    moved = 0
    if model == MODEL_DECOUPLED:
        for i in range(6):
            if theta[i] < mass_floor[i]:
                theta[i] = mass_floor[i]
                moved += 1
            if theta[6 + i] > -drag_ceiling[i]:
                theta[6 + i] = -drag_ceiling[i]
                moved += 1
        return moved
    mf = mass_floor.min()
    M = np.empty((6, 6))
    for i in range(6):
        for j in range(6):
            M[i, j] = theta[_MIDX[i, j]]
    L = np.empty((6, 6))  # scratch of the tests
    clipped = False
    if not _sym_inside(M, 1.0, mf, L):
        S, clipped = _sym_eig_clip_min(M, mf)
    if clipped:
        moved += 1
        for i in range(6):
            for j in range(i, 6):
                theta[_MIDX[i, j]] = S[i, j]
    dc = drag_ceiling.min()
    D = np.empty((6, 6))
    for k in range(6):
        base = 21 + 36 * k
        for col in range(6):
            for row in range(6):
                D[row, col] = theta[base + col * 6 + row]
        # sym(D) ⪯ −dc I  ⇔  sym(−D) ⪰ dc I
        if _sym_inside(D, -1.0, dc, L):
            continue
        S, clipped = _sym_eig_clip_min(-D, dc)
        if clipped:
            moved += 1
            K = 0.5 * (D - D.T)
            for col in range(6):
                for row in range(6):
                    theta[base + col * 6 + row] = K[row, col] - S[row, col]
    return moved


@_jit
def ff_increment(model, theta, H_d, v_d, vdot_d, H_p, v_p, vdot_p):
    """Feed-forward preview increment W_d(t+δ)θ̂ − W_d(t)θ̂, where W_d is W_MBC of (5.12)
    evaluated on the reference alone (ᵃvₐ = ᵈv_d, Δv = 0, ᵃv̇_d = ᵈv̇_d, R = R_d):
    W_d θ = M ᵈv̇_d − ad_{v_d}ᵀ(M ᵈv_d) − Σᵢ|v_d,ᵢ|Dᵢ ᵈv_d − G(R_d). ``_p`` is the reference
    at t + δ. Identical inputs give exactly zero."""
    r_d = np.empty(3)
    r_p = np.empty(3)
    for i in range(3):
        r_d[i] = H_d[2, i]
        r_p[i] = H_p[2, i]
    wp = w_theta(model, theta, v_p, vdot_p, r_p)
    wd = w_theta(model, theta, v_d, vdot_d, r_d)
    out = np.empty(6)
    for i in range(6):
        out[i] = wp[i] - wd[i]
    return out


#: layout of the AMBC's packed parameters (:func:`pack_ambc_params`): scalars first, then
#: the gains (k_p, k_d, mass floor, drag ceiling: 4 × 6), K_θ (n), B⁺ (N × 6) and f_max (N)
P_MODEL, P_EPS, P_ADAPT, P_ROBUST, P_DEAD_ZONE, P_FREEZE_SAT, P_HOLD_S, P_BAND, P_N, P_NTHR = \
    range(10)
P_GAINS = 10
P_K = P_GAINS + 24


def pack_ambc_params(model, K, kp, kd, mass_floor, drag_ceiling, eps, robust, dead_zone,
                     freeze_on_saturation, hold_s, band, B_pinv, f_max):
    """The constant parameters of :func:`ambc_step_kernel` as one float64 vector (its packed
    structure: one array crosses into the kernel instead of fourteen values). ``adapt`` is
    K ≠ 0; flags are 1.0 / 0.0; gains are (6,) each; B_pinv (N × 6), f_max (N,)."""
    K = np.ascontiguousarray(K, dtype=np.float64).reshape(-1)
    B_pinv = np.ascontiguousarray(B_pinv, dtype=np.float64).reshape(-1, 6)
    f_max = np.ascontiguousarray(f_max, dtype=np.float64).reshape(-1)
    head = np.array([model, eps, bool(np.any(K > 0)), bool(robust), dead_zone,
                     bool(freeze_on_saturation), hold_s, band, K.shape[0], B_pinv.shape[0]],
                    dtype=np.float64)
    gains = np.concatenate([np.broadcast_to(np.asarray(g, dtype=np.float64), (6,))
                            for g in (kp, kd, mass_floor, drag_ceiling)])
    return np.ascontiguousarray(np.concatenate([head, gains, K, B_pinv.reshape(-1), f_max]))


@_jit
def ambc_step_kernel(P, H_a, v_a, H_d, v_d, vdot_d, mask, ff, use_ff, theta, dt, t, last_f,
                     hold_until, out):
    """One AMBC step: the control law (5.27) with θ̂_k and the Euler step of the update law
    (5.28), θ̂_{k+1} = θ̂_k + dt θ̂̇ with θ̂̇ = −K_θ W_MBCᵀ(εΔψ + Δv).

    ``P``: the constant parameters packed by :func:`pack_ambc_params` (model, ε, k_p, k_d,
    K_θ, the robust adaptation's settings, B⁺, f_max). The rest is this cycle's: actual and
    desired state, the DOF mask, the preview increment, θ̂_k, dt, the controller's clock t,
    the last per-thruster command and the reversal hold.

    With ``use_ff`` the feed-forward preview increment ``ff`` (:func:`ff_increment`) is added
    to the command (before the mask); the update law keeps the regressor at t.

    With robust adaptation: θ̂̇ is scaled by the dead zone max(0, 1 − δ/‖εΔψ + Δv‖) (δ > 0),
    zeroed while the command saturates a thruster (freeze on saturation) and until
    ``hold_until`` (set to t + dt + hold_s whenever a thruster command changes sign or lies in
    the stiction band, when hold_s > 0); θ̂_{k+1} is then projected (:func:`project`).

    Output: ``out`` = [u (6), err (5 × 6, :func:`error_state`), θ̂_{k+1} (n), θ̂̇ (n),
    f = B⁺u (N)]. Returns (saturated, frozen, projected, hold_until).
    """
    model = int(P[P_MODEL])
    eps = P[P_EPS]
    adapt = P[P_ADAPT] != 0.0
    robust = P[P_ROBUST] != 0.0
    dead_zone = P[P_DEAD_ZONE]
    freeze_on_saturation = P[P_FREEZE_SAT] != 0.0
    hold_s = P[P_HOLD_S]
    band = P[P_BAND]
    n = int(P[P_N])
    nthr = int(P[P_NTHR])
    kp = P[P_GAINS:P_GAINS + 6]
    kd = P[P_GAINS + 6:P_GAINS + 12]
    mass_floor = P[P_GAINS + 12:P_GAINS + 18]
    drag_ceiling = P[P_GAINS + 18:P_GAINS + 24]
    K = P[P_K:P_K + n]
    B_pinv = P[P_K + n:P_K + n + 6 * nthr].reshape((nthr, 6))
    f_max = P[P_K + n + 6 * nthr:P_K + n + 7 * nthr]
    err = out[6:36].reshape((5, 6))
    theta_out = out[36:36 + n]
    rate_out = out[36 + n:36 + 2 * n]
    f_out = out[36 + 2 * n:]
    error_state(H_a, v_a, H_d, v_d, vdot_d, err)
    dpsi = err[0].copy()
    dv = err[1].copy()
    alpha = err[4].copy()
    r = np.empty(3)
    r[0], r[1], r[2] = H_a[2, 0], H_a[2, 1], H_a[2, 2]
    fb = pd_term(dpsi, dv, kp, kd)
    wt = w_theta(model, theta, v_a, alpha, r)
    for i in range(6):
        x = wt[i] - fb[i]
        if use_ff:
            x += ff[i]
        out[i] = x * mask[i]
    for i in range(n):
        theta_out[i] = theta[i]
        rate_out[i] = 0.0
    saturated = False
    reversal = False
    for j in range(nthr):
        f = 0.0
        for i in range(6):
            f += B_pinv[j, i] * out[i]
        f_out[j] = f
        if abs(f) > f_max[j]:
            saturated = True
        if abs(f) < band or f * last_f[j] < 0.0:
            reversal = True
    if robust and hold_s > 0.0 and reversal:
        hold_until = t + dt + hold_s
    if not adapt:
        return saturated, False, False, hold_until
    if robust and ((saturated and freeze_on_saturation) or t < hold_until):
        return saturated, True, False, hold_until
    s = np.empty(6)
    ns = 0.0
    for i in range(6):
        s[i] = (eps * dpsi[i] + dv[i]) * mask[i]
        ns += s[i] * s[i]
    scale = 1.0
    if robust and dead_zone > 0.0:
        ns = np.sqrt(ns)
        if ns <= dead_zone:
            return saturated, True, False, hold_until
        scale = 1.0 - dead_zone / ns
    g = wT_s(model, n, v_a, alpha, r, s)
    for i in range(n):
        rate_out[i] = -K[i] * g[i] * scale
        theta_out[i] = theta[i] + dt * rate_out[i]
    projected = False
    if robust:
        projected = project(model, theta_out, mass_floor, drag_ceiling) > 0
    return saturated, False, projected, hold_until
