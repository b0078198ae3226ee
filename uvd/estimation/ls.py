"""Least-squares identification (LS, §4.4) of the UV models from a recorded run (R, v, u).

From (4.40) u(tᵢ) = W_UV(v(tᵢ), v̇(tᵢ), R(tᵢ)) θ_UV for every sample; stacking gives F = 𝒲 θ
(4.41)–(4.42), and likewise τ = W_UVR(ω, ω̇, R) θ_UVR (4.39) for the rotational model (2.40).

**Acceleration.** v̇ is not measured; it comes from numerical differentiation of v with a
Savitzky–Golay filter (local least-squares polynomial, :func:`scipy.signal.savgol_filter`;
default: cubic over a 2.1 s window, i.e. 21 samples at 10 Hz — the JHU ROV's motions vary over
seconds, §4.5, while DVL noise (0.003 m/s at 6 Hz, Table A.1) and the zero-order hold of the
6 Hz DVL samples live above 1 Hz). The same filter (derivative order 0) smooths v and u, so
both sides of the regression see the same low-pass and the same (zero) phase.

**Solver.** The thesis used one Moore–Penrose pseudo-inverse (4.43); we never form it. The
rows are reduced chunk by chunk with Householder QR ([R; 𝒲_chunk] = Q R', the tall-skinny
QR, so a 35-minute run never builds its 120 000 × 241 matrix at once); the columns are
equilibrated (unit 2-norm) and the triangular system is solved by SVD-based
:func:`scipy.linalg.lstsq` (LAPACK gelsd), which gives the numerical **rank** and the
**condition number** (of the equilibrated regressor) that :class:`LSResult` reports.

**Physically consistent variant** (``consistent=True``). Unconstrained LS can return a model
no vehicle has: the thesis's own LS drag D₄ (Table 4.11) has a symmetric part with an
eigenvalue ≈ +1034, i.e. drag that *feeds* energy in some directions. With ``consistent=True``
the same objective ‖𝒲θ − F‖ is minimised over the convex set

* M ⪰ ε_M I (M symmetric by construction through θ_M and P_M, (2.46)), and
* ½(Dᵢ + Dᵢᵀ) ⪯ −ε_D I for every i — a convex *sufficient* condition for dissipative drag:
  vᵀ(Σ|vᵢ|Dᵢ)v = Σ|vᵢ| vᵀ Dᵢˢʸᵐ v ≤ −ε_D ‖v‖₁‖v‖² < 0 for v ≠ 0 (§2.6)

(for the rotational model: I ⪰ ε_M I and ½(Cᵢ + Cᵢᵀ) ⪯ −ε_D I). It is a second-order-cone
program with linear matrix inequalities, solved by **cvxpy** with the Clarabel interior-point
solver (SCS as fall-back). A final eigenvalue projection onto the same set guards against
solver tolerance (and is the whole answer, applied to the unconstrained solution, if no solver
succeeds), so the result *always* has M positive definite and dissipative drag and passes
:meth:`UVParams.validate`; :class:`LSResult` says whether the projection moved anything.

**Linear damping** (model ``"rot-lin"``). (2.40) has quadratic rotational damping only; a real
vehicle's is also linear at low rates (the published model of the LiU BlueROV, whose recordings
docs/real-vehicles.md identifies, has K_p p, M_q q, N_r r beside its quadratic terms). With
``"rot-lin"`` θ is θ_UVR followed by the diagonal D_L = diag(d_p, d_q, d_r) (N m s/rad) of a
torque D_L ω on the side of the drag, τ = W_UVR θ_UVR − D_L ω, so d ≤ 0 is dissipative; the
consistent fit constrains d ≤ −ε_D. Outside the thesis's θ_UVR: :attr:`LSResult.linear_damping`
carries it apart, and :func:`uvd.estimation.xval.rot_xval_windows` simulates it.

**Admissible is not identified.** The margins ε_M = ε_D = 10⁻³ are far below any vehicle's
figures (the JHU ROV's smallest mass eigenvalue is 261.6 kg, its least dissipative drag
eigenvalue −30.2). A consistent fit that ends on (or within ten times) a margin was decided by
the constraint, not by the data — typically a run too short or too poorly excited for 241
parameters: admissible, but no model of the vehicle (its forward simulation can diverge at
once). :func:`active_bounds` names those blocks and :class:`LSResult` carries them
(``active_bounds``) so that ``uvd identify`` can say so.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from uvd.errors import ParameterError
from uvd.model.params import (
    N_THETA_UV,
    N_THETA_UVR,
    P_I,
    P_M,
    RotParams,
    UVParams,
    params_from_theta,
)

__all__ = ["DiffFilter", "LSResult", "differentiate", "regressor_uv_batch",
           "regressor_uvr_batch", "ls_reduce", "ls_reduce_runs", "ls_identify", "ls_solve",
           "project_consistent", "consistency_margins", "active_bounds", "unobserved_drag",
           "equation_error_rms"]

_UPPER6 = [(i, j) for i in range(6) for j in range(i, 6)]
_UPPER3 = [(i, j) for i in range(3) for j in range(i, 3)]


@dataclass(frozen=True)
class DiffFilter:
    """Savitzky–Golay smoothing/differentiation: polynomial order and window length (s)."""

    window_s: float = 2.1
    polyorder: int = 3

    def samples(self, dt: float) -> int:
        n = int(round(self.window_s / dt))
        n += 1 - n % 2  # odd
        return max(n, self.polyorder + 2 + (self.polyorder + 1) % 2)

    def describe(self, dt: float) -> str:
        return (f"Savitzky-Golay, order {self.polyorder}, window {self.samples(dt)} samples "
                f"({self.samples(dt) * dt:.2f} s)")


def differentiate(t: np.ndarray, x: np.ndarray, filt: DiffFilter = DiffFilter()
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(smoothed x, ẋ) of uniformly sampled x (n, k) by the Savitzky–Golay filter ``filt``."""
    t = np.asarray(t, dtype=float)
    dt = float((t[-1] - t[0]) / (len(t) - 1))
    w = filt.samples(dt)
    if len(t) < w:
        raise ValueError(f"run of {len(t)} samples is shorter than the {w}-sample "
                         "differentiation window")
    # imported here: scipy.signal costs ~1-2 s of start-up to every ``uvd`` command (the
    # experiment registry imports this module), and only identification differentiates
    from scipy.signal import savgol_filter
    xs = savgol_filter(x, w, filt.polyorder, deriv=0, axis=0, mode="interp")
    xd = savgol_filter(x, w, filt.polyorder, deriv=1, delta=dt, axis=0, mode="interp")
    return xs, xd


# ---------------------------------------------------------------------------------------------
# batched regressors (n samples at once; equal to uvd.model.regressors per sample — tested)
# ---------------------------------------------------------------------------------------------
def _adT(v: np.ndarray, x: np.ndarray) -> np.ndarray:
    """ad_vᵀ x row by row: [p × ω; p × ν + h × ω] for v = [ν; ω], x = [p; h]."""
    nu, om = v[:, :3], v[:, 3:]
    p, h = x[:, :3], x[:, 3:]
    return np.concatenate([np.cross(p, om), np.cross(p, nu) + np.cross(h, om)], axis=1)


def _cross_mat_rows(r: np.ndarray) -> np.ndarray:
    """(n, 3, 3) stack of J(r)."""
    n = r.shape[0]
    Jr = np.zeros((n, 3, 3))
    Jr[:, 0, 1], Jr[:, 0, 2] = -r[:, 2], r[:, 1]
    Jr[:, 1, 0], Jr[:, 1, 2] = r[:, 2], -r[:, 0]
    Jr[:, 2, 0], Jr[:, 2, 1] = -r[:, 1], r[:, 0]
    return Jr


def regressor_uv_batch_mass(v: np.ndarray, vdot: np.ndarray) -> np.ndarray:
    """W_M of (2.49) for n samples: (n, 6, 21), W_M θ_M = M v̇ − ad_vᵀ(Mv)."""
    n = v.shape[0]
    W = np.zeros((n, 6, 21))
    for k, (i, j) in enumerate(_UPPER6):  # E_k v̇ − ad_vᵀ(E_k v), E_k the basis of θ_M
        Ev = np.zeros((n, 6))
        Ea = np.zeros((n, 6))
        Ev[:, i] = v[:, j]
        Ea[:, i] = vdot[:, j]
        if i != j:
            Ev[:, j] = v[:, i]
            Ea[:, j] = vdot[:, i]
        W[:, :, k] = Ea - _adT(v, Ev)
    return W


def _inertia_batch(w: np.ndarray, wdot: np.ndarray) -> np.ndarray:
    """W_I of (2.39) for n samples: (n, 3, 6), W_I θ_I = Iω̇ − J(Iω)ω = Iω̇ + ω × (Iω)."""
    n = w.shape[0]
    W = np.zeros((n, 3, 6))
    for k, (i, j) in enumerate(_UPPER3):
        Ew = np.zeros((n, 3))
        Ea = np.zeros((n, 3))
        Ew[:, i] = w[:, j]
        Ea[:, i] = wdot[:, j]
        if i != j:
            Ew[:, j] = w[:, i]
            Ea[:, j] = wdot[:, i]
        W[:, :, k] = Ea + np.cross(w, Ew)
    return W


#: θ's length by model: θ_UV, θ_UVR, θ_UVR and the diagonal linear damping
N_THETA = {"6dof": N_THETA_UV, "rot": N_THETA_UVR, "rot-lin": N_THETA_UVR + 3}


def _check_model(model: str) -> None:
    if model not in N_THETA:
        raise ValueError(f"model must be one of {', '.join(map(repr, N_THETA))}, got {model!r}")


def _regressor_batch(model: str, n_theta: int, v, vdot, r) -> np.ndarray:
    Phi, A, drag, shared = _features(model, v, vdot, r)
    rows = A.shape[1]
    W = np.zeros((v.shape[0], rows, n_theta))
    for row in range(rows):
        W[:, row, drag[row]] = Phi
        W[:, row, shared] = A[:, row, :]
    return W


def regressor_uv_batch(v: np.ndarray, vdot: np.ndarray, r: np.ndarray) -> np.ndarray:
    """W_UV of (2.49) for n samples: (n, 6, 241), u = W_UV θ_UV; r = Rᵀe₃ (n, 3)."""
    return _regressor_batch("6dof", N_THETA_UV, v, vdot, r)


def regressor_uvr_batch(w: np.ndarray, wdot: np.ndarray, r: np.ndarray) -> np.ndarray:
    """W_UVR of (2.42) for n samples: (n, 3, 36), τ = W_UVR θ_UVR."""
    return _regressor_batch("rot", N_THETA_UVR, w, wdot, r)


# ---------------------------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LSResult:
    """An LS identification.

    Attributes
    ----------
    params : UVParams (model "6dof") or RotParams (models "rot", "rot-lin").
    theta : θ_UV (241,), θ_UVR (36,), or θ_UVR and D_L's diagonal (39,) ("rot-lin").
    rank : numerical rank of the equilibrated regressor (of ``n_params``).
    condition : its 2-norm condition number σ_max/σ_min (inf if rank deficient).
    residual_rms : RMS of u − 𝒲θ per wrench component (N, N m).
    consistent : whether the physically consistent variant was asked for.
    solver, solver_status : "lstsq/gelsd" or the cvxpy solver and its status.
    projected : the final projection onto {M ⪰ ε_M I, sym Dᵢ ⪯ −ε_D I} changed the solution.
    active_bounds : consistent fits only: the blocks that rest on their bound
        (:func:`active_bounds`) — set by the constraint, not identified by the data.
    unobserved : the drag blocks without data (:func:`unobserved_drag`): 0 from ``ls``, −ε_D I
        from the consistent fit.
    linear_damping : model "rot-lin": D_L (3 × 3, diagonal, N m s/rad); else None.
    """

    model: str
    params: UVParams | RotParams
    theta: np.ndarray
    rank: int
    n_params: int
    condition: float
    singular_values: np.ndarray
    residual_rms: np.ndarray
    n_samples: int
    filter: str
    consistent: bool = False
    solver: str = "scipy.linalg.lstsq (gelsd)"
    solver_status: str = "optimal"
    projected: bool = False
    mass_min_eig: float = float("nan")
    drag_max_sym_eig: float = float("nan")
    active_bounds: tuple[str, ...] = ()
    unobserved: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)
    linear_damping: np.ndarray | None = None

    def summary(self) -> dict:
        """The figures as plain values; ``linear_damping`` (its diagonal) only for "rot-lin"."""
        lin = {} if self.linear_damping is None else {
            "linear_damping": np.diag(self.linear_damping).tolist()}
        return {"model": self.model, "rank": self.rank, "n_params": self.n_params,
                "condition": self.condition, "n_samples": self.n_samples,
                "residual_rms": self.residual_rms.tolist(), "filter": self.filter,
                "consistent": self.consistent, "solver": self.solver,
                "solver_status": self.solver_status, "projected": self.projected,
                "mass_min_eig": self.mass_min_eig, "drag_max_sym_eig": self.drag_max_sym_eig,
                "active_bounds": list(self.active_bounds), "unobserved": list(self.unobserved),
                "notes": list(self.notes), **lin}


def runs_dt(run) -> float:
    """The period of a run, or of the first of several."""
    return run[0].dt if isinstance(run, (list, tuple)) else run.dt


# ---------------------------------------------------------------------------------------------
# reduction and solution
# ---------------------------------------------------------------------------------------------
def _features(model: str, x: np.ndarray, xd: np.ndarray, r: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The regressor in its block form: (Φ, A, drag index, shared index).

    Row ``row`` of W_UV (W_UVR) is Φ on the drag columns ``drag[row]`` (the same n × 36 (9)
    features −|vᵢ|v_c for every row) plus A[:, row, :] on the shared mass/gravity columns.
    """
    if model == "6dof":
        W_sh = np.zeros((x.shape[0], 6, 25))
        W_sh[:, :, :21] = regressor_uv_batch_mass(x, xd)
        W_sh[:, :3, 21] = -r
        W_sh[:, 3:, 22:25] = _cross_mat_rows(r)
        k, base0 = 6, 21
        shared = np.r_[0:21, 237:241]
    else:
        lin = model == "rot-lin"
        W_sh = np.zeros((x.shape[0], 3, 12 if lin else 9))
        W_sh[:, :, :6] = _inertia_batch(x, xd)
        W_sh[:, :, 6:9] = _cross_mat_rows(r)
        shared = np.r_[0:6, 33:36]
        if lin:  # row i: −d_i ω_i (the drag's sign: its features are −|ωᵢ|ω_c)
            for i in range(3):
                W_sh[:, i, 9 + i] = -x[:, i]
            shared = np.r_[shared, 36:39]
        k, base0 = 3, 6
    ax = np.abs(x)
    Phi = -(ax[:, :, None] * x[:, None, :]).reshape(x.shape[0], k * k)  # column k·i + c
    drag = np.array([[base0 + k * k * i + k * c + row for i in range(k) for c in range(k)]
                     for row in range(k)])
    return Phi, W_sh, drag, shared


def _reduce(model: str, run, filt: DiffFilter):
    """Reduce the stacked LS problem of a run to a square triangular one.

    Every wrench component (row) of 𝒲 is [Φ on its drag columns | A_row on the shared columns]
    with the *same* Φ. Level 1: Φ = Q₁R₁; each row block [A_row | F_row] splits orthogonally into
    Q₁ᵀ(·) = [Y | f] and its complement. Level 2: Householder QR (R only) of the stacked
    complements gives [[T, g], [0, ρ]]. With R assembled from R₁, Y and T (columns in θ order),
    ‖𝒲θ − F‖² = ‖Rθ − z‖² + ρ² exactly, and R has the singular values of 𝒲.
    Returns (R, z, residual², n, features…).
    """
    t = run.t
    p = N_THETA[model]
    if model == "6dof":
        x = run.v
        k = 6
    else:
        x = run.v[:, 3:]
        k = 3
    xs, xd = differentiate(t, x, filt)
    u = np.asarray(run.u, dtype=float)
    if run.input_interp == "hold":  # the wrench switches at t_k: take the mean of both sides
        u = np.vstack([0.5 * (u[:-1] + u[1:]), u[-1:]])
    us, _ = differentiate(t, u, filt)
    us = us[:, 6 - k:]
    r = run.R[:, 2, :]  # Rᵀe₃ = third row of R
    Phi, A, drag, shared = _features(model, xs, xd, r)
    nd, ns = Phi.shape[1], A.shape[2]
    n = len(t)
    # level 1: Φ = Q₁R₁ (Householder, so Q₁ has orthonormal columns even if Φ is rank
    # deficient); every row block's [A_row | F_row] splits into Q₁ᵀ(·) and (I − Q₁Q₁ᵀ)(·)
    # ("twice is enough" re-projection keeps the split orthogonal to working precision).
    C = np.concatenate([np.concatenate([A[:, row, :], us[:, row:row + 1]], axis=1)
                        for row in range(k)], axis=1)  # n × k(ns + 1)
    if n >= nd:
        Q1, R1 = scipy.linalg.qr(Phi, mode="economic", check_finite=False)
        Y = Q1.T @ C
        C = C - Q1 @ Y
        Y2 = Q1.T @ C
        C -= Q1 @ Y2
        Y += Y2
    else:  # fewer samples than drag features: no split, everything goes to level 2
        Q1, R1 = np.zeros((n, 0)), np.zeros((0, nd))
        Y = np.zeros((0, C.shape[1]))
    R = np.zeros((p, p))
    z = np.zeros(p)
    m1 = R1.shape[0]
    level2 = []
    w = ns + 1
    for row in range(k):
        Yr = Y[:, row * w:(row + 1) * w]
        R[np.ix_(drag[row][:m1], drag[row])] = R1
        R[np.ix_(drag[row][:m1], shared)] = Yr[:, :ns]
        z[drag[row][:m1]] = Yr[:, ns]
        level2.append(C[:, row * w:(row + 1) * w] if n >= nd
                      else np.hstack([np.zeros((n, 0)), C[:, row * w:(row + 1) * w]]))
    if n < nd:  # no level-1 split: reduce the full rows of every block together
        B = np.zeros((k * n, p + 1))
        for row in range(k):
            B[row * n:(row + 1) * n, drag[row]] = Phi
            B[row * n:(row + 1) * n, shared] = A[:, row, :]
            B[row * n:(row + 1) * n, p] = us[:, row]
        Rb = scipy.linalg.qr(B, mode="r", check_finite=False)[0]
        m = min(Rb.shape[0], p + 1)
        Rf = np.zeros((p + 1, p + 1))
        Rf[:m] = Rb[:m]
        return Rf[:p, :p], Rf[:p, p], float(Rf[p, p] ** 2), n, Phi, A, drag, shared, us
    # level 2: the projected shared columns of all rows, stacked
    Rb = scipy.linalg.qr(np.vstack(level2), mode="r", check_finite=False)[0]
    m = min(Rb.shape[0], w)
    Rb_full = np.zeros((w, w))
    Rb_full[:m] = Rb[:m]
    R[np.ix_(shared, shared)] = Rb_full[:ns, :ns]
    z[shared] = Rb_full[:ns, ns]
    resid2 = float(Rb_full[ns, ns] ** 2)
    return R, z, resid2, n, Phi, A, drag, shared, us


def _params_of(model: str, theta: np.ndarray) -> UVParams | RotParams:
    if model == "6dof":
        return params_from_theta(theta)
    return RotParams.from_theta(theta[:N_THETA_UVR])


def _blocks(model: str, theta: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """(mass matrix, drag matrices) of θ for either model."""
    p = _params_of(model, theta)
    if model == "6dof":
        return p.M, list(p.D)
    return p.I, list(p.C)


def consistency_margins(model: str, theta: np.ndarray) -> tuple[float, float]:
    """(λ_min(M), max_i λ_max(½(Dᵢ + Dᵢᵀ))) — positive and negative respectively when the
    sufficient conditions of the module docstring hold."""
    M, Ds = _blocks(model, theta)
    lam_m = float(np.linalg.eigvalsh(M)[0])
    lam_d = float(max(np.linalg.eigvalsh(0.5 * (D + D.T))[-1] for D in Ds))
    return lam_m, lam_d


def unobserved_drag(model: str, colnorm: np.ndarray) -> tuple[int, ...]:
    """Indices i (from 0) of the drag blocks Dᵢ (Cᵢ) the data say nothing about: every column of
    the block is zero in the regressor, i.e. |vᵢ| = 0 (|ωᵢ| = 0) on the whole run."""
    n, d0 = (6, 21) if model == "6dof" else (3, 6)
    return tuple(i for i in range(n)
                 if not np.any(colnorm[d0 + n * n * i: d0 + n * n * (i + 1)] > 0.0))


def active_bounds(model: str, theta: np.ndarray, eps_mass: float, eps_drag: float,
                  within: float = 10.0) -> tuple[str, ...]:
    """The consistency bounds θ rests on: ``"M"`` (``"I"``) when λ_min ≤ within·ε_M, ``"D<i>"``
    (``"C<i>"``, i from 1) when λ_max(½(Dᵢ + Dᵢᵀ)) ≥ −within·ε_D. See "Admissible is not
    identified" in the module docstring."""
    M, Ds = _blocks(model, theta)
    m_name, d_name = ("M", "D") if model == "6dof" else ("I", "C")
    out = [m_name] if np.linalg.eigvalsh(M)[0] <= within * eps_mass else []
    out += [f"{d_name}{i + 1}" for i, D in enumerate(Ds)
            if np.linalg.eigvalsh(0.5 * (D + D.T))[-1] >= -within * eps_drag]
    return tuple(out)


def project_consistent(model: str, theta: np.ndarray, eps_mass: float, eps_drag: float
                       ) -> tuple[np.ndarray, bool]:
    """Nearest (Frobenius) θ with M ⪰ ε_M I and sym(Dᵢ) ⪯ −ε_D I: eigenvalue clipping of M and
    of each Dᵢ's symmetric part (skew parts kept). Returns (θ, changed)."""
    theta = np.array(theta, dtype=float)
    n = 6 if model == "6dof" else 3
    M, Ds = _blocks(model, theta)
    changed = False
    lam, V = np.linalg.eigh(M)
    if lam[0] < eps_mass:
        M = (V * np.maximum(lam, eps_mass)) @ V.T
        M = 0.5 * (M + M.T)
        changed = True
    newD = []
    for D in Ds:
        S, K = 0.5 * (D + D.T), 0.5 * (D - D.T)
        lam, V = np.linalg.eigh(S)
        if lam[-1] > -eps_drag:
            S = (V * np.minimum(lam, -eps_drag)) @ V.T
            S = 0.5 * (S + S.T)
            changed = True
        newD.append(S + K)
    iu = np.triu_indices(n)
    if model == "6dof":
        theta[:21] = M[iu]
        theta[21:237] = np.concatenate([D.reshape(-1, order="F") for D in newD])
    else:
        theta[:6] = M[iu]
        theta[6:33] = np.concatenate([D.reshape(-1, order="F") for D in newD])
    if model == "rot-lin" and np.any(theta[36:39] > -eps_drag):
        theta[36:39] = np.minimum(theta[36:39], -eps_drag)
        changed = True
    return theta, changed


def _solve_consistent(model: str, Rs: np.ndarray, z: np.ndarray, c: np.ndarray,
                      eps_mass: float, eps_drag: float, empty: tuple[int, ...] = ()
                      ) -> tuple[np.ndarray | None, str, str]:
    """min ‖Rs x − z‖ (+ a 1e-7 ridge for strict convexity) over the consistent set with
    θ = c ∘ x (column equilibration), by cvxpy; returns (θ or None, solver, status).

    The drag blocks ``empty`` (no data, :func:`unobserved_drag`) are fixed at −ε_D I, the
    consistent value of smallest norm — what gelsd's minimum-norm zero becomes after the
    projection. Left to the solver, such a block takes whatever value the interior-point method
    stops at (≈ −4·10⁵ I on a random run without sway, roll or pitch rate): the ridge is too
    weak to steer it."""
    import cvxpy as cp

    p = N_THETA[model]
    if model == "6dof":
        n, P, n_m, d0 = 6, P_M, 21, 21
    else:
        n, P, n_m, d0 = 3, P_I, 6, 6
    scale = float(np.linalg.norm(Rs, 2)) or 1.0
    x = cp.Variable(p, name="x")
    theta = cp.multiply(c, x)
    M = cp.reshape(P @ theta[:n_m], (n, n), order="F")
    I_n = np.eye(n)
    cons = [0.5 * (M + M.T) - eps_mass * I_n >> 0]
    for i in range(n):
        block = slice(d0 + n * n * i, d0 + n * n * (i + 1))
        if i in empty:
            cons.append(theta[block] == (-eps_drag * I_n).reshape(-1, order="F"))
            continue
        D = cp.reshape(theta[block], (n, n), order="F")
        cons.append(-0.5 * (D + D.T) - eps_drag * I_n >> 0)
    if model == "rot-lin":
        cons.append(theta[36:39] <= -eps_drag)
    obj = cp.Minimize(cp.norm(cp.hstack([(Rs / scale) @ x - z / scale, 1e-7 * x]), 2))
    prob = cp.Problem(obj, cons)
    last = "not run"
    for solver in ("CLARABEL", "SCS"):
        if solver not in cp.installed_solvers():
            continue
        try:
            with warnings.catch_warnings():  # the status says it; no stderr noise
                warnings.simplefilter("ignore", UserWarning)
                prob.solve(solver=solver)
        except (cp.error.SolverError, ValueError, ArithmeticError) as exc:
            last = f"{solver}: {type(exc).__name__}: {exc}"
            continue
        last = f"{solver}: {prob.status}"
        if prob.status in ("optimal", "optimal_inaccurate") and x.value is not None \
                and np.all(np.isfinite(x.value)):
            return c * np.asarray(x.value), solver, prob.status
    return None, "none", last


def ls_solve(model: str, Rfac: np.ndarray, z: np.ndarray, colnorm: np.ndarray, *,
             consistent: bool = False, eps_mass: float = 1e-3, eps_drag: float = 1e-3,
             rcond: float = 1e-10):
    """Solve the reduced problem ‖R θ − z‖ → (θ, rank, cond, sv, solver, status, projected)."""
    c = np.where(colnorm > 0.0, 1.0 / np.where(colnorm > 0.0, colnorm, 1.0), 1.0)
    Rs = Rfac * c[None, :]
    xs, _, rank, sv = scipy.linalg.lstsq(Rs, z, cond=rcond, lapack_driver="gelsd",
                                         check_finite=False)
    theta = c * xs
    sv = np.asarray(sv)
    full = int(rank) == Rfac.shape[1] and sv.size and sv[-1] > 0
    cond = float(sv[0] / sv[-1]) if full else math.inf  # rank deficient: singular
    solver, status, projected = "scipy.linalg.lstsq (gelsd)", "optimal", False
    if consistent:
        th_c, solver, status = _solve_consistent(model, Rs, z, c, eps_mass, eps_drag,
                                                 unobserved_drag(model, colnorm))
        if th_c is None:
            th_c, status = theta, f"solver failed ({status}); projected the LS solution"
        theta, projected = project_consistent(model, th_c, eps_mass, eps_drag)
    return theta, int(rank), cond, sv, solver, status, projected


def ls_reduce(run, model: str = "6dof", filt: DiffFilter = DiffFilter()) -> tuple:
    """The reduced problem of a run (opaque; pass it to :func:`ls_identify` as ``reduced`` to
    solve the same data twice, e.g. unconstrained and consistent, for the price of one
    reduction)."""
    _check_model(model)
    return (model, filt, _reduce(model, run, filt))


def ls_reduce_runs(runs, model: str = "6dof", filt: DiffFilter = DiffFilter(),
                   progress=None) -> tuple:
    """The reduced problem of several runs at once (e.g. recordings, or the uninterrupted
    stretches of one): ‖𝒲θ − F‖² summed over the runs is ‖Rθ − z‖² + ρ² with [R z] the
    triangular factor of the runs' factors stacked. Each run is differentiated on its own (no
    filter window spans two runs). ``progress(done, total)`` after each run."""
    _check_model(model)
    runs = list(runs)
    if not runs:
        raise ValueError("no runs")
    parts = []
    for i, run in enumerate(runs):
        parts.append(_reduce(model, run, filt))
        if progress is not None:
            progress(i + 1, len(runs))
    if len(parts) == 1:
        return (model, filt, parts[0])
    p = parts[0][0].shape[0]
    stack = np.vstack([np.column_stack([q[0], q[1]]) for q in parts])
    Rb = scipy.linalg.qr(stack, mode="r", check_finite=False)[0]
    Rf = np.zeros((p + 1, p + 1))
    m = min(Rb.shape[0], p + 1)
    Rf[:m] = Rb[:m]
    resid2 = float(Rf[p, p] ** 2) + sum(q[2] for q in parts)
    n = sum(q[3] for q in parts)
    Phi = np.vstack([q[4] for q in parts])
    A = np.concatenate([q[5] for q in parts])
    us = np.vstack([q[8] for q in parts])
    return (model, filt, (Rf[:p, :p], Rf[:p, p], resid2, n, Phi, A, parts[0][6], parts[0][7],
                          us))


def equation_error_rms(run, model: str, theta: np.ndarray, filt: DiffFilter = DiffFilter()
                       ) -> np.ndarray:
    """RMS of the equation error u − 𝒲θ per wrench component (N, N m) of ``theta`` on ``run``:
    the criterion LS minimises, with the same differentiation and smoothing — so any estimate
    (another method's, or one identified elsewhere) can be judged by it on data it was not
    fitted to."""
    _check_model(model)
    theta = np.asarray(theta, dtype=float)
    if theta.shape != (N_THETA[model],):
        raise ValueError(f"theta of model {model!r} has {N_THETA[model]} entries, got "
                         f"{theta.shape}")
    _R, _z, _r2, n, Phi, A, drag, shared, us = _reduce(model, run, filt)
    k = 6 if model == "6dof" else 3
    return np.array([np.sqrt(np.mean((us[:, row] - Phi @ theta[drag[row]]
                                      - A[:, row, :] @ theta[shared]) ** 2))
                     for row in range(k)])


def ls_identify(run, model: str = "6dof", *, filt: DiffFilter = DiffFilter(),
                consistent: bool = False, eps_mass: float = 1e-3, eps_drag: float = 1e-3,
                rcond: float = 1e-10, reduced: tuple | None = None) -> LSResult:
    """Least-squares identification (§4.4) of the 6-DOF (2.44) or rotational (2.40) model.

    Parameters
    ----------
    run : :class:`uvd.estimation.runlog.RunLog` (or anything with t, R, v, u, input_interp).
    model : "6dof" (θ_UV ∈ R²⁴¹), "rot" (θ_UVR ∈ R³⁶; uses ω and τ only) or "rot-lin"
        (θ_UVR and a diagonal linear damping, module docstring).
    filt : the differentiation filter.
    consistent : constrain M ⪰ ε_M I and sym(Dᵢ) ⪯ −ε_D I (see the module docstring).
    eps_mass, eps_drag : the margins ε_M (kg, kg m²) and ε_D (N s²/m², N m s²).
    rcond : relative singular-value cut-off of the rank decision.
    reduced : the result of :func:`ls_reduce` for this run, model and filter (optional).

    Returns
    -------
    LSResult
    """
    if reduced is None:
        reduced = ls_reduce(run, model, filt)
    if reduced[0] != model or reduced[1] != filt:
        raise ValueError("reduced problem was made for another model or filter")
    Rfac, z, _resid2, n, Phi, A, drag, shared, us = reduced[2]
    colnorm = np.linalg.norm(Rfac, axis=0)
    theta, rank, cond, sv, solver, status, projected = ls_solve(
        model, Rfac, z, colnorm, consistent=consistent, eps_mass=eps_mass, eps_drag=eps_drag,
        rcond=rcond)
    # residual per wrench component, in chunks
    k = 6 if model == "6dof" else 3
    ss = np.array([np.sum((us[:, row] - Phi @ theta[drag[row]] - A[:, row, :] @ theta[shared])
                          ** 2) for row in range(k)])
    params = _params_of(model, theta)
    lam_m, lam_d = consistency_margins(model, theta)
    notes = []
    if consistent and model == "6dof":
        try:
            params.validate(where="ls-consistent")
        except ParameterError as exc:  # must not happen: the projection guarantees it
            notes.append(f"validate failed: {exc}")
    active = active_bounds(model, theta, eps_mass, eps_drag) if consistent else ()
    d_name = "D" if model == "6dof" else "C"
    unobserved = tuple(f"{d_name}{i + 1}" for i in unobserved_drag(model, colnorm))
    return LSResult(model=model, params=params, theta=theta, rank=rank, n_params=theta.size,
                    condition=cond, singular_values=sv, residual_rms=np.sqrt(ss / n),
                    n_samples=n, filter=filt.describe(runs_dt(run)), consistent=consistent,
                    solver=solver, solver_status=status, projected=projected,
                    mass_min_eig=lam_m, drag_max_sym_eig=lam_d, active_bounds=active,
                    unobserved=unobserved, notes=tuple(notes),
                    linear_damping=(np.diag(theta[36:39]) if model == "rot-lin" else None))
