"""Commanded vs realised wrench: the thrust residual that tells a weak thruster from a change
of the vehicle (thesis §6.2). Pure: numbers in, numbers out.

Why a residual. A thruster that turns but pushes less (a fouled propeller, a cracked blade)
leaves its amplifier's speed feedback that of a healthy thruster, and AID absorbs the missing
thrust into the parameters it has — the buoyancy torque b and the masses of the DOFs the
thruster drives (measured: thruster 4 at 0 % moves b₁ by +11 N m). The estimates alone cannot
tell it from a change of buoyancy. What can is *when* the missing wrench appears: a thruster's
missing wrench is proportional to that thruster's command, along its column of the thruster
matrix B; a buoyancy change is constant in the body frame (for a vehicle kept level); an
entanglement is proportional to the drag force, a flooding to the acceleration.

The residual. The plant model (2.44), M v̇ = ad_vᵀ(Mv) + (Σᵢ|vᵢ|Dᵢ)v + G(R) + u, is integrated
over a segment [t₀, t₁] instead of differentiated (no derivative of a noisy velocity):

    ∫u dt = M (v(t₁) − v(t₀)) − ∫ (ad_vᵀ(Mv) + (Σᵢ|vᵢ|Dᵢ)v + G(R)) dt,

with M, Dᵢ, g, b *frozen* at the baseline (the medians of AID's θ̂ before any fault, (2.48)),
so the model says what a healthy vehicle needed. The residual of the segment is that wrench
minus the commanded one, e = ∫u dt − B ∫f dt (f the per-thruster commands of the state
stream, trapezoids between samples). For a healthy vehicle e ≈ 0 (model error, sensor noise
and the thrusters' lag: learned at the baseline as a per-DOF mean rate and spread). For each
explanation the expected residual is linear in its unknown size, with one column per unknown:

==============  ===========================================  ===================================
explanation     column(s) of e                               coefficient
==============  ===========================================  ===================================
thruster i      −Bᵢ ∫fᵢ dt                                   δᵢ = 1 − ηᵢ (ηᵢ the efficiency)
buoyancy        [∫r dt; 0], [0; −J(∫r dt)] (r = Rᵀe₃)         Δg, Δb (G(R) of (2.44))
entanglement    ∫ (Σᵢ|vᵢ|Dᵢ) v dt                            drag scale − 1
flooding        −(M Δv − ∫ ad_vᵀ(Mv) dt)                     mass scale − 1
==============  ===========================================  ===================================

:func:`explain` fits each explanation by least squares to a window of segments, whitened by
the baseline spread, and returns its generalised likelihood ratio Λ = ‖ẽ‖² − RSS (twice the
log-likelihood ratio of a Gaussian residual, χ²ₚ for p unknowns when nothing changed). Scores
Λ − p ln n (Schwarz's penalty, n the number of residual components) compare explanations with
different numbers of unknowns: the four of buoyancy explain a thruster's constant part as well
(a vertical thruster's Bᵢ·const is a Δg, Δb), so only a thruster command that varies tells
them apart, and the penalty lets the one-unknown thruster win when it explains as much.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["FrozenModel", "Segment", "SegmentIntegrator", "Explanation", "explain",
           "explanations", "state_sample", "warm"]


@dataclass(frozen=True)
class FrozenModel:
    """The plant model (2.44) frozen at the baseline, and the thruster matrix.

    Attributes
    ----------
    M : ndarray (6, 6)
        Mass matrix (symmetrised).
    D_flat : ndarray (6, 36)
        [D₁ … D₆], so that (Σᵢ|vᵢ|Dᵢ)v = D_flat (|v| ⊗ v).
    g : float
        Net buoyancy (N). b : ndarray (3,) buoyancy torque vector (N m).
    B : ndarray (6, N)
        Thruster matrix, u = B f.
    """

    M: np.ndarray
    D_flat: np.ndarray
    g: float
    b: np.ndarray
    B: np.ndarray

    @classmethod
    def from_theta(cls, theta, B) -> FrozenModel:
        """From θ ∈ R²⁴¹ as the estimate payload documents it, in the order of (2.48): the 21
        entries of M's upper triangle row by row (2.45), D₁ˢ … D₆ˢ (each column-stacked, (2.8)),
        g, b — decoded here from that contract alone (uvd-fdc imports nothing of the daemon);
        and B (6 × N)."""
        theta = np.asarray(theta, dtype=float).reshape(-1)
        if theta.shape != (241,) or not np.isfinite(theta).all():
            raise ValueError(f"θ: 241 finite numbers expected, got {theta.shape[0]} entries")
        M = np.zeros((6, 6))
        M[np.triu_indices(6)] = theta[:21]
        M = M + np.triu(M, 1).T
        D = theta[21:237].reshape(6, 6, 6).transpose(0, 2, 1)  # Dᵢ from its column stack
        return cls(M=M, D_flat=np.hstack(list(D)), g=float(theta[237]),
                   b=theta[238:241].copy(), B=np.asarray(B, dtype=float))


@dataclass(frozen=True)
class Segment:
    """The integrals of one segment [t0, t1] (s); every array is an integral over it.

    ``e`` (6,) the residual ∫u dt − B∫f dt; ``F`` (N,) ∫f dt; ``r`` (3,) ∫Rᵀe₃ dt;
    ``drag`` (6,) ∫(Σ|vᵢ|Dᵢ)v dt; ``inertial`` (6,) M Δv − ∫ad_vᵀ(Mv) dt.
    """

    t0: float
    t1: float
    e: np.ndarray
    F: np.ndarray
    r: np.ndarray
    drag: np.ndarray
    inertial: np.ndarray

    @property
    def duration(self) -> float:
        return self.t1 - self.t0


_R = 21  # integrands before the thrust commands: ad (6), drag (6), gravity (6), r (3)


@numba.njit(cache=True)
def _finite(v, R, f) -> bool:
    """Every number of v, R and f is finite (one compiled call)."""
    for x in v:
        if not np.isfinite(x):
            return False
    for i in range(R.shape[0]):
        for j in range(R.shape[1]):
            if not np.isfinite(R[i, j]):
                return False
    for x in f:
        if not np.isfinite(x):
            return False
    return True


@numba.njit(cache=True)
def _integrands_into(out, M, D_flat, g, b, v, R, f):
    """The segment's integrands at one sample, into ``out`` (21 + N): ad_vᵀ(Mv) (6, the
    transpose of (2.4): [p × ω; p × ν + h × ω] for Mv = [p; h]), (Σᵢ|vᵢ|Dᵢ)v (6), G(R) (6:
    [g r; b × r], r = Rᵀe₃ the third row of R), r (3) and f (N). One compiled call: the
    formulas' own products, summed in index order."""
    mv = np.zeros(6)
    for i in range(6):
        acc = 0.0
        for j in range(6):
            acc += M[i, j] * v[j]
        mv[i] = acc
    nu0, nu1, nu2, w0, w1, w2 = v[0], v[1], v[2], v[3], v[4], v[5]
    p0, p1, p2, h0, h1, h2 = mv[0], mv[1], mv[2], mv[3], mv[4], mv[5]
    out[0] = p1 * w2 - p2 * w1
    out[1] = p2 * w0 - p0 * w2
    out[2] = p0 * w1 - p1 * w0
    out[3] = (p1 * nu2 - p2 * nu1) + (h1 * w2 - h2 * w1)
    out[4] = (p2 * nu0 - p0 * nu2) + (h2 * w0 - h0 * w2)
    out[5] = (p0 * nu1 - p1 * nu0) + (h0 * w1 - h1 * w0)
    for i in range(6):
        acc = 0.0
        for j in range(6):
            a = abs(v[j])
            for k in range(6):
                acc += D_flat[i, 6 * j + k] * (a * v[k])
        out[6 + i] = acc
    r0, r1, r2 = R[2, 0], R[2, 1], R[2, 2]
    out[12] = g * r0
    out[13] = g * r1
    out[14] = g * r2
    out[15] = b[1] * r2 - b[2] * r1
    out[16] = b[2] * r0 - b[0] * r2
    out[17] = b[0] * r1 - b[1] * r0
    out[18] = r0
    out[19] = r1
    out[20] = r2
    for i in range(f.shape[0]):
        out[_R + i] = f[i]


def warm() -> None:
    """Compile the kernels (or load them from numba's cache) for a state payload's arrays now,
    rather than inside the first sample's handling (~1.5 s without a cache)."""
    m = FrozenModel.from_theta(np.zeros(241), np.zeros((6, 1)))  # the arrays' own layouts
    v, R, f = state_sample([0.0] * 6, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                           [0.0], 1)
    _integrands_into(np.empty(_R + 1), m.M, m.D_flat, m.g, m.b, v, R, f)


def state_sample(v, R, f, n_thrusters: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A state payload's v (6), R (3 × 3 or 9 numbers) and per-thruster commands f (N) as
    finite arrays; a ValueError naming what is wrong otherwise."""
    try:
        v = np.asarray(v, dtype=float)
        R = np.asarray(R, dtype=float).reshape(3, 3)
        f = np.asarray(f, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"state sample: v, R or thrust is not numbers ({exc})") from exc
    if v.shape != (6,) or f.shape != (n_thrusters,) or not _finite(v, R, f):
        raise ValueError("state sample: v must be 6 finite numbers, R 3×3 finite, thrust "
                         f"{n_thrusters} finite numbers")
    return v, R, f


class SegmentIntegrator:
    """Turn a stream of state samples into :class:`Segment` s of ``length_s``.

    Feed (t, v, R, f) with :meth:`add`; it returns a segment when one is complete. A gap
    longer than ``max_gap_s`` between samples (lost samples, a pause) drops the partial
    segment and starts a new one at the next sample: a trapezoid across a gap would guess.
    """

    def __init__(self, model: FrozenModel, length_s: float = 10.0,
                 max_gap_s: float = 1.0) -> None:
        self.model = model
        self.length_s = length_s
        self.max_gap_s = max_gap_s
        self._start = None  # (t, v) at the segment's start
        self._prev = None   # (t, the integrands at t) of the previous sample
        self._acc = None

    def add(self, t: float, v, R, f) -> Segment | None:
        m = self.model
        v, R, f = state_sample(v, R, f, m.B.shape[1])
        cur = np.empty(_R + f.shape[0])
        _integrands_into(cur, m.M, m.D_flat, m.g, m.b, v, R, f)
        if self._prev is None or not 0.0 < t - self._prev[0] <= self.max_gap_s:
            self._start, self._prev = (t, v), (t, cur)
            self._acc = np.zeros_like(cur)
            return None
        self._acc += 0.5 * (t - self._prev[0]) * (self._prev[1] + cur)  # the trapezoid
        self._prev = (t, cur)
        if t - self._start[0] < self.length_s - 1e-9:
            return None
        acc = self._acc
        ad, drag, grav, r, F = acc[:6], acc[6:12], acc[12:18], acc[18:_R], acc[_R:]
        inertial = m.M @ (v - self._start[1]) - ad
        e = inertial - drag - grav - m.B @ F
        seg = Segment(self._start[0], t, e, F.copy(), r.copy(), drag.copy(), inertial)
        self._start = (t, v)
        self._acc = np.zeros_like(cur)
        return seg


def _J(x: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -x[2], x[1]], [x[2], 0.0, -x[0]], [-x[1], x[0], 0.0]])


def _columns(kind: str, s: Segment, model: FrozenModel) -> np.ndarray:
    """The (6, p) columns of one explanation for one segment (module docstring's table)."""
    if kind.startswith("thruster"):
        i = int(kind[len("thruster"):]) - 1
        return (-model.B[:, i] * s.F[i])[:, None]
    if kind == "buoyancy":
        out = np.zeros((6, 4))
        out[:3, 0] = s.r
        out[3:, 1:] = -_J(s.r)
        return out
    if kind == "entanglement":
        return s.drag[:, None]
    if kind == "flooding":
        return -s.inertial[:, None]
    raise ValueError(f"unknown explanation {kind!r}")


def explanations(n_thrusters: int) -> tuple[str, ...]:
    """The explanations :func:`explain` weighs: ``thruster1`` … and the vehicle's changes."""
    return (*(f"thruster{i + 1}" for i in range(n_thrusters)), "buoyancy", "entanglement",
            "flooding")


@dataclass(frozen=True)
class Explanation:
    """One explanation's best fit: ``coef`` (its unknowns), ``since`` (the change time, s),
    ``glr`` Λ = ‖ẽ‖² − RSS, ``score`` Λ − p ln n."""

    kind: str
    coef: np.ndarray
    since: float
    glr: float
    score: float


def explain(segments, model: FrozenModel, bias_rate: np.ndarray,
            sigma: np.ndarray) -> list[Explanation]:
    """Fit every explanation to a window of ``segments``, the change at the start of any one
    of them (its columns zero before: the GLR of an unknown change time, Willsky and Jones
    1976); best score first (module docstring).

    Parameters
    ----------
    segments : sequence of Segment
        Consecutive segments, oldest first.
    model : FrozenModel
    bias_rate : ndarray (6,)
        The healthy residual's mean per second (baseline), subtracted.
    sigma : ndarray (6,)
        The healthy residual's spread per DOF over one segment (baseline): the whitening.
    """
    if not segments:
        return []
    w = 1.0 / np.asarray(sigma, dtype=float)
    y = np.concatenate([(s.e - bias_rate * s.duration) * w for s in segments])
    n = y.size
    yy = float(y @ y)
    out = []
    for kind in explanations(model.B.shape[1]):
        X = np.concatenate([_columns(kind, s, model) * w[:, None] for s in segments])
        best = None
        for j in range(len(segments)):
            Xj = X[6 * j:]
            coef, *_ = np.linalg.lstsq(Xj, y[6 * j:], rcond=None)
            glr = yy - float(y[:6 * j] @ y[:6 * j]) - float(np.sum((y[6 * j:] - Xj @ coef) ** 2))
            if best is None or glr > best[0]:
                best = (glr, coef, segments[j].t0)
        glr, coef, since = best
        out.append(Explanation(kind, coef, since, glr, glr - X.shape[1] * math.log(n)))
    out.sort(key=lambda x: -x.score)
    return out
