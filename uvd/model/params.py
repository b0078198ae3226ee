"""UV parameters: θ_UV ∈ R²⁴¹ (2.48), θ_UVR ∈ R³⁶ (2.41), the decoupled 16-parameter view (§5.3.1).

θ_UV = [θ_Mᵀ, (D₁ˢ)ᵀ, …, (D₆ˢ)ᵀ, g, bᵀ]ᵀ where θ_M holds the 21 unique entries m₁…m₂₁ of the
symmetric mass matrix M numbered row by row over the upper triangle (2.45), so that
Mˢ = P_M θ_M (2.46)–(2.47); ·ˢ is the column stack (2.8). The rotational parameter vector
θ_UVR = [θ_Iᵀ, (C₁ˢ)ᵀ, (C₂ˢ)ᵀ, (C₃ˢ)ᵀ, bᵀ]ᵀ with Iˢ = P_I θ_I (2.35)–(2.37). The decoupled view
(m_i, d_i, g, b) of §5.3.1 is M = diag(m), D_i = d_i e_i e_iᵀ, so Σ|v_i|D_i v = diag(d ∘ |v|) v.

Units: M in kg (translational) and kg m² (rotational); D_i in N s²/m² or N m s²; g in N
(positive: net force toward +z world, i.e. heavier than water); b in N m.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uvd.errors import ParameterError
from uvd.model.lie import stack, unstack

N_THETA_UV = 241
N_THETA_UVR = 36
N_DECOUPLED = 16

# slices of θ_UV (2.48)
SL_M = slice(0, 21)
SL_D = slice(21, 21 + 216)
IDX_G = 237
SL_B = slice(238, 241)


def _sym_selector(n: int) -> np.ndarray:
    """P with stack(S) = P θ for symmetric n×n S whose unique entries θ run row-wise over the
    upper triangle (2.45): the P_I of (2.35) for n = 3 and the P_M of (2.46) for n = 6."""
    index = {}
    k = 0
    for i in range(n):
        for j in range(i, n):
            index[(i, j)] = k
            k += 1
    P = np.zeros((n * n, k))
    for col in range(n):  # column-stack order (2.8): row index runs fastest
        for row in range(n):
            i, j = min(row, col), max(row, col)
            P[col * n + row, index[(i, j)]] = 1.0
    return P


P_M = _sym_selector(6)  # (2.46), 36 × 21
P_I = _sym_selector(3)  # (2.35), 9 × 6
_UPPER6 = np.triu_indices(6)
_UPPER3 = np.triu_indices(3)


def theta_M_from(M: np.ndarray) -> np.ndarray:
    """The 21 unique entries of symmetric M, in the order of (2.45)."""
    return np.asarray(M, dtype=float)[_UPPER6].copy()


def M_from_theta(theta_M: np.ndarray) -> np.ndarray:
    """Symmetric 6×6 M from its 21 unique entries, Mˢ = P_M θ_M (2.47)."""
    return unstack(P_M @ theta_M, 6, 6)


@dataclass(frozen=True)
class UVParams:
    """The parameters of the 6-DOF UV model (2.44): M, D₁…D₆, g, b.

    Parameters
    ----------
    M : (6, 6) symmetric mass matrix (rigid body + added mass).
    D : (6, 6, 6) quadratic drag, ``D[i]`` is D_{i+1}.
    g : net buoyancy force (N), positive downward (heavy).
    b : (3,) buoyancy/gravity torque vector (N m).
    """

    M: np.ndarray
    D: np.ndarray
    g: float
    b: np.ndarray

    def __post_init__(self) -> None:
        M = np.array(self.M, dtype=float)
        D = np.array(self.D, dtype=float)
        b = np.array(self.b, dtype=float).reshape(-1)
        if M.shape != (6, 6):
            raise ParameterError(f"M must be 6x6, got shape {M.shape}")
        if D.shape != (6, 6, 6):
            raise ParameterError(f"D must be six 6x6 matrices (shape (6,6,6)), got {D.shape}")
        if b.shape != (3,):
            raise ParameterError(f"b must have 3 entries, got {b.shape}")
        for name, arr in (("M", M), ("D", D), ("b", b), ("g", np.array(self.g))):
            if not np.all(np.isfinite(arr)):
                raise ParameterError(f"{name} has a non-finite entry")
        for arr in (M, D, b):
            arr.setflags(write=False)
        object.__setattr__(self, "M", M)
        object.__setattr__(self, "D", D)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "g", float(self.g))

    # -- conversions -------------------------------------------------------------------------
    @property
    def theta(self) -> np.ndarray:
        """θ_UV ∈ R²⁴¹ in the order of (2.48) (uses the symmetric part of M)."""
        return theta_from(self)

    @classmethod
    def from_theta(cls, theta: np.ndarray) -> UVParams:
        return params_from_theta(theta)

    @classmethod
    def decoupled(cls, m, d, g: float, b) -> UVParams:
        """The decoupled model of §5.3.1: M = diag(m), D_i = d_i e_i e_iᵀ."""
        m = np.asarray(m, dtype=float).reshape(6)
        d = np.asarray(d, dtype=float).reshape(6)
        D = np.zeros((6, 6, 6))
        for i in range(6):
            D[i, i, i] = d[i]
        return cls(M=np.diag(m), D=D, g=g, b=b)

    def decoupled_view(self) -> np.ndarray:
        """The 16-parameter view [m₁…m₆, d₁…d₆, g, b₁, b₂, b₃] (§5.3.1): a projection of θ_UV
        that keeps diag(M) and the diagonal entry (i, i) of each D_i."""
        return decoupled_from_theta(self.theta)

    def rotational_view(self) -> np.ndarray:
        """θ_UVR ∈ R³⁶ (2.41): I = M[3:,3:], C_i = D_{3+i}[3:,3:], b."""
        return theta_uvr_from_theta(self.theta)

    # -- physical validity -------------------------------------------------------------------
    def mass_min_eigenvalue(self) -> float:
        return float(np.linalg.eigvalsh(0.5 * (self.M + self.M.T))[0])

    def drag_max_eigenvalue(self) -> float:
        """Largest eigenvalue of the symmetric part of any single D_i."""
        return float(max(np.linalg.eigvalsh(0.5 * (Di + Di.T))[-1] for Di in self.D))

    def drag_dissipativity_max(self) -> float:
        """max over ‖v‖ = 1 of vᵀ(Σ|v_i|D_i)v; the drag is dissipative (§2.6) iff this is < 0.

        See :func:`drag_dissipativity_max`.
        """
        return drag_dissipativity_max(self.D)

    def validate(self, *, where: str = "parameters") -> UVParams:
        """Raise :class:`ParameterError` unless M is symmetric positive definite and the drag
        is dissipative: vᵀ(Σ|v_i|D_i)v < 0 for every v ≠ 0 (§2.6)."""
        asym = float(np.max(np.abs(self.M - self.M.T)))
        if asym > 1e-9 * max(1.0, float(np.max(np.abs(self.M)))):
            raise ParameterError(f"{where}: M is not symmetric (max |M - Mᵀ| = {asym:.3g})")
        lam = _eigen_figure(self.mass_min_eigenvalue, self.M, f"{where}: M")
        if not lam > 0.0:  # nan too
            raise ParameterError(f"{where}: M is not positive definite (min eigenvalue {lam:.4g})")
        worst = _eigen_figure(self.drag_dissipativity_max, self.D, f"{where}: the drag")
        if not worst < 0.0:
            raise ParameterError(
                f"{where}: drag is not dissipative (max over unit v of vᵀ(Σ|v_i|D_i)v = "
                f"{worst:.4g} >= 0)")
        return self

    def is_decoupled(self) -> bool:
        off_M = self.M - np.diag(np.diag(self.M))
        D_diag = np.zeros_like(self.D)
        for i in range(6):
            D_diag[i, i, i] = self.D[i, i, i]
        return bool(np.all(off_M == 0.0) and np.all(self.D == D_diag))


def _eigen_figure(figure, entries: np.ndarray, what: str) -> float:
    """``figure()`` (an eigenvalue-based figure of ``entries``), or a ParameterError naming
    ``what`` when entries near the largest float make the eigenvalues overflow (a NaN or inf
    figure is returned, for the caller to refuse)."""
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            return figure()
    except np.linalg.LinAlgError as exc:
        raise ParameterError(f"{what}: the eigenvalues cannot be computed ({exc}; entries up "
                             f"to {float(np.max(np.abs(entries))):.3g})") from exc


def _drag_form(D: np.ndarray, v: np.ndarray) -> float:
    return float(v @ np.tensordot(np.abs(v), D, axes=1) @ v)


def drag_dissipativity_max(D: np.ndarray, *, samples: int = 4000, seed: int = 0) -> float:
    """max over the unit sphere of f(v) = vᵀ(Σ|v_i|D_i)v (negative ⇔ dissipative drag, §2.6).

    Exact fast paths: decoupled drag (D_i = d_i e_i e_iᵀ) gives f = Σ d_i|v_i|³, whose maximum
    over the sphere (Lagrange: |v_i| ∝ 1/|d_i|) is −(Σ d_i⁻²)^{-1/2} when every d_i < 0.
    If every D_i has a negative
    definite symmetric part, f(v) ≤ max_i λ_max(D_iˢ) Σ|v_i| ≤ max_i λ_max(D_iˢ) < 0 on the
    sphere, and that certified upper bound is returned. Otherwise f is searched on ``samples``
    deterministic random directions plus the axes and refined locally (f is positively
    homogeneous of degree 3, smooth inside each orthant).
    """
    D = np.asarray(D, dtype=float)
    diag_only = all(np.count_nonzero(D[i]) <= 1 and np.count_nonzero(D[i]) == np.count_nonzero(
        D[i][i, i]) for i in range(6))
    if diag_only:
        d = np.array([D[i][i, i] for i in range(6)])
        if np.all(d < 0.0):
            return float(-(np.sum(d**-2.0) ** -0.5))
        return float(np.max(d))  # f(e_i) = d_i
    Ds = 0.5 * (D + np.transpose(D, (0, 2, 1)))
    lam_max = float(np.max(np.linalg.eigvalsh(Ds)[:, -1]))
    if lam_max < 0.0:
        return lam_max
    rng = np.random.default_rng(seed)
    V = rng.normal(size=(samples, 6))
    V = np.vstack([np.eye(6), -np.eye(6), V / np.linalg.norm(V, axis=1, keepdims=True)])
    # f(v) = Σ_i |v_i| vᵀ D_i^s v, vectorised over the samples
    quad = np.einsum("nj,ijk,nk->ni", V, Ds, V)
    f = np.sum(np.abs(V) * quad, axis=1)
    best = float(np.max(f))
    from scipy.optimize import minimize  # local polish of the best few directions

    for k in np.argsort(f)[-8:]:
        res = minimize(lambda x: -_drag_form(Ds, x / np.linalg.norm(x)), V[k], method="Nelder-Mead",
                       options={"xatol": 1e-9, "fatol": 1e-12, "maxiter": 4000})
        x = res.x / np.linalg.norm(res.x)
        best = max(best, _drag_form(Ds, x))
    return best


def theta_from(p: UVParams) -> np.ndarray:
    th = np.empty(N_THETA_UV)
    th[SL_M] = theta_M_from(0.5 * (p.M + p.M.T))
    th[SL_D] = np.concatenate([stack(Di) for Di in p.D])
    th[IDX_G] = p.g
    th[SL_B] = p.b
    return th


def params_from_theta(theta: np.ndarray) -> UVParams:
    theta = np.asarray(theta, dtype=float).reshape(-1)
    if theta.shape != (N_THETA_UV,):
        raise ParameterError(f"θ_UV must have {N_THETA_UV} entries, got {theta.shape[0]}")
    D = np.stack([unstack(theta[21 + 36 * i: 21 + 36 * (i + 1)], 6, 6) for i in range(6)])
    return UVParams(M=M_from_theta(theta[SL_M]), D=D, g=theta[IDX_G], b=theta[SL_B])


# indices of the decoupled view inside θ_UV
_M_DIAG_IDX = np.array([0, 6, 11, 15, 18, 20])  # m1, m7, m12, m16, m19, m21 of (2.45)
_D_DIAG_IDX = np.array([21 + 36 * i + 7 * i for i in range(6)])  # (D_i)_{ii} in D_iˢ
DECOUPLED_INDEX = np.concatenate([_M_DIAG_IDX, _D_DIAG_IDX, [IDX_G], np.arange(238, 241)])
"""θ_dec = θ_UV[DECOUPLED_INDEX]: the 16 decoupled parameters as a projection of θ_UV."""


def decoupled_from_theta(theta: np.ndarray) -> np.ndarray:
    return np.asarray(theta, dtype=float)[DECOUPLED_INDEX].copy()


def theta_from_decoupled(theta_dec: np.ndarray) -> np.ndarray:
    """Embed the 16 decoupled parameters in θ_UV (every other entry zero)."""
    th = np.zeros(N_THETA_UV)
    th[DECOUPLED_INDEX] = np.asarray(theta_dec, dtype=float).reshape(N_DECOUPLED)
    return th


# rotational view (2.41): indices into θ_UV of θ_I, C₁ˢ, C₂ˢ, C₃ˢ, b
def _rot_index() -> np.ndarray:
    idx = []
    m_index = {}
    k = 0
    for i in range(6):
        for j in range(i, 6):
            m_index[(i, j)] = k
            k += 1
    for i in range(3, 6):
        for j in range(i, 6):
            idx.append(m_index[(i, j)])
    for c in range(3):  # C_{c+1} = D_{4+c}[3:, 3:], column-stacked
        base = 21 + 36 * (3 + c)
        for col in range(3, 6):
            for row in range(3, 6):
                idx.append(base + col * 6 + row)
    idx.extend([238, 239, 240])
    return np.array(idx)


ROTATIONAL_INDEX = _rot_index()
"""θ_UVR = θ_UV[ROTATIONAL_INDEX] (2.41)."""


def theta_uvr_from_theta(theta: np.ndarray) -> np.ndarray:
    return np.asarray(theta, dtype=float)[ROTATIONAL_INDEX].copy()


@dataclass(frozen=True)
class RotParams:
    """Parameters of the 3-DOF UV rotational model (2.40): I, C₁…C₃, b."""

    I: np.ndarray
    C: np.ndarray
    b: np.ndarray

    @property
    def theta(self) -> np.ndarray:
        """θ_UVR ∈ R³⁶ (2.41)."""
        I = 0.5 * (np.asarray(self.I) + np.asarray(self.I).T)
        return np.concatenate([np.asarray(I)[_UPPER3]] + [stack(Ci) for Ci in self.C]
                              + [np.asarray(self.b, dtype=float)])

    @classmethod
    def from_theta(cls, theta: np.ndarray) -> RotParams:
        theta = np.asarray(theta, dtype=float).reshape(-1)
        if theta.shape != (N_THETA_UVR,):
            raise ParameterError(f"θ_UVR must have {N_THETA_UVR} entries, got {theta.shape[0]}")
        I = unstack(P_I @ theta[:6], 3, 3)
        C = np.stack([unstack(theta[6 + 9 * i: 15 + 9 * i], 3, 3) for i in range(3)])
        return cls(I=I, C=C, b=theta[33:36].copy())
