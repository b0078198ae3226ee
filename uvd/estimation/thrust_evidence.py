"""The daemon's own evidence of a weak thruster: commanded vs realised wrench over a window.
Pure: numbers in, numbers out (no clock, no I/O).

What it is for. A fault sample of uvd-fdc ("thruster i at efficiency η", over Zenoh) is, by
default, acted on only when the daemon's own evidence confirms it (``[faults.fdc] accept =
"confirm"``, :mod:`uvd.runtime.fdc_source`). This module is that evidence, computed by the
cycle from what the cycle has: its navigation (v, R), the thrust each thruster was told to
give (or, with the amplifiers' speed feedback, k ω|ω|), and the configured vehicle model.

The residual. The plant model (2.44), M v̇ = ad_vᵀ(Mv) + (Σᵢ|vᵢ|Dᵢ)v + G(R) + u, integrated over
a segment [t₀, t₁] of ``segment_s`` (trapezoids between cycles; no derivative of a noisy
velocity) gives the wrench the vehicle really received,

    ∫u dt = M (v(t₁) − v(t₀)) − ∫ (ad_vᵀ(Mv) + (Σᵢ|vᵢ|Dᵢ)v + G(R)) dt,

and the segment's residual is that minus the commanded wrench, e = ∫u dt − B ∫f dt. A thruster
i at efficiency ηᵢ leaves e = −Bᵢ (1 − ηᵢ) ∫fᵢ dt (its column of B times its missing
impulse) plus model error and noise. :func:`thruster_fit` fits δ = 1 − ηᵢ by least squares to
the segments kept since a given time (at most ``window_s``), with its standard error from the
fit's residual. The same residual, on uvd-fdc's side, names the thruster
(:mod:`uvd.fdc.residual`); here it is the daemon's independent check of that claim, on its own
navigation at its own rate.

State. :class:`Evidence` is one immutable value (the cycle carries it in its state): the open
segment's running integrals, and the last ``window_s / segment_s`` closed segments' e and ∫f.
A gap between samples longer than ``max_gap_s`` (or time going backwards) restarts the open
segment: a trapezoid across a gap would guess.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from uvd.model.dynamics import _ad_T_list, _gravity_list, drag_wrench

__all__ = ["EvidenceConfig", "Evidence", "ThrusterFit", "evidence_init", "evidence_step",
           "thruster_fit"]


@dataclass(frozen=True)
class EvidenceConfig:
    """The vehicle model the residual is computed with and the window's shape.

    Attributes
    ----------
    M : ndarray (6, 6)
        Mass matrix (symmetrised).
    D_flat : ndarray (6, 36)
        [D₁ … D₆] of (2.44).
    g : float
        Net buoyancy (N).
    b : ndarray (3,)
        Buoyancy torque vector (N m).
    B : ndarray (6, N)
        Thruster matrix, u = B f.
    segment_s : float
        Length of one segment (s).
    window_s : float
        How far back the closed segments are kept (s).
    max_gap_s : float
        A longer gap between two samples restarts the open segment (s).
    """

    M: np.ndarray
    D_flat: np.ndarray
    g: float
    b: np.ndarray
    B: np.ndarray
    segment_s: float = 1.0
    window_s: float = 120.0
    max_gap_s: float = 0.5

    @classmethod
    def from_params(cls, params, B, **kw) -> EvidenceConfig:
        """From :class:`uvd.model.params.UVParams` and the thruster matrix B (6 × N)."""
        M = np.asarray(params.M, dtype=float)
        return cls(M=0.5 * (M + M.T), D_flat=np.hstack([np.asarray(d, float) for d in params.D]),
                   g=float(params.g), b=np.asarray(params.b, dtype=float).copy(),
                   B=np.asarray(B, dtype=float), **kw)

    @property
    def n_segments(self) -> int:
        return max(1, int(math.ceil(self.window_s / self.segment_s)))


class Evidence(NamedTuple):
    """The evidence carried from one cycle to the next (module docstring, "State").

    ``t0``, ``v0``: the open segment's start (s, body velocity); ``t_prev``, ``prev``: the last
    sample's time and integrand [ad_vᵀ(Mv); drag; G(R); f] (18 + N); ``acc``: its integral since
    ``t0``; ``seg_t`` (K, 2) the closed segments' [t₀, t₁], ``seg_e`` (K, 6) their residuals,
    ``seg_F`` (K, N) their ∫f dt — oldest first, at most ``n_segments``."""

    t0: float | None
    v0: np.ndarray | None
    t_prev: float | None
    prev: np.ndarray | None
    acc: np.ndarray | None
    seg_t: np.ndarray
    seg_e: np.ndarray
    seg_F: np.ndarray


def evidence_init(cfg: EvidenceConfig) -> Evidence:
    """No sample yet, no segment."""
    n = cfg.B.shape[1]
    return Evidence(None, None, None, None, None, np.zeros((0, 2)), np.zeros((0, 6)),
                    np.zeros((0, n)))


def _integrand(cfg: EvidenceConfig, v: np.ndarray, R: np.ndarray, f: np.ndarray) -> np.ndarray:
    vl = v.tolist()
    ad = _ad_T_list(vl, (cfg.M @ v).tolist())
    grav = _gravity_list(cfg.g, cfg.b.tolist(), R[2].tolist())
    return np.concatenate([ad, drag_wrench(cfg.D_flat, v), grav, f])


def evidence_step(cfg: EvidenceConfig, ev: Evidence, t_s: float, v: np.ndarray,
                  R: np.ndarray, f: np.ndarray) -> Evidence:
    """Take one sample: time ``t_s`` (s), body velocity ``v`` (6,), attitude ``R`` (3, 3), the
    thrust ``f`` (N,) the thrusters were told to give over the interval ending at ``t_s``.
    Returns the new evidence (``ev`` is not modified). A sample with a non-finite number
    restarts the open segment."""
    v = np.asarray(v, dtype=float)
    f = np.asarray(f, dtype=float)
    if not (np.isfinite(v).all() and np.isfinite(f).all() and np.isfinite(R).all()
            and math.isfinite(t_s)):
        return ev._replace(t0=None, v0=None, t_prev=None, prev=None, acc=None)
    cur = _integrand(cfg, v, R, f)
    if ev.t_prev is None or not 0.0 < t_s - ev.t_prev <= cfg.max_gap_s:
        return ev._replace(t0=t_s, v0=v, t_prev=t_s, prev=cur, acc=np.zeros_like(cur))
    acc = ev.acc + 0.5 * (t_s - ev.t_prev) * (ev.prev + cur)
    if t_s - ev.t0 < cfg.segment_s - 1e-9:
        return ev._replace(t_prev=t_s, prev=cur, acc=acc)
    F = acc[18:]
    e = cfg.M @ (v - ev.v0) - acc[:6] - acc[6:12] - acc[12:18] - cfg.B @ F
    k = cfg.n_segments
    return Evidence(t_s, v, t_s, cur, np.zeros_like(cur),
                    np.vstack([ev.seg_t, [[ev.t0, t_s]]])[-k:],
                    np.vstack([ev.seg_e, e[None, :]])[-k:],
                    np.vstack([ev.seg_F, F[None, :]])[-k:])


class ThrusterFit(NamedTuple):
    """The fit of one thruster's efficiency: ``eta`` η̂ᵢ = 1 − δ̂, ``se`` its standard error,
    ``segments`` how many were fitted over ``seconds``, ``impulse_n_s`` Σ|∫fᵢ dt| over them.
    ``eta`` and ``se`` are NaN when nothing could be fitted (no segment, or the thruster was
    never commanded)."""

    eta: float
    se: float
    segments: int
    seconds: float
    impulse_n_s: float


def thruster_fit(cfg: EvidenceConfig, ev: Evidence, thruster: int,
                 since_s: float | None = None) -> ThrusterFit:
    """Least squares of δ = 1 − ηᵢ over the closed segments that start at or after
    ``since_s`` (all kept: None), ``thruster`` 1-based (module docstring).

    e_k = −Bᵢ ∫fᵢ dt|_k · δ + noise, so δ̂ = −Σ_k x_kᵀe_k / Σ_k x_kᵀx_k with x_k = Bᵢ ∫fᵢ dt|_k,
    and se(δ̂) = √(RSS / (6K − 1) / Σ_k x_kᵀx_k).
    """
    i = int(thruster) - 1
    keep = np.ones(len(ev.seg_t), dtype=bool) if since_s is None else ev.seg_t[:, 0] >= since_s
    K = int(keep.sum())
    if K == 0:
        return ThrusterFit(math.nan, math.nan, 0, 0.0, 0.0)
    Fi = ev.seg_F[keep, i]
    X = Fi[:, None] * cfg.B[:, i][None, :]  # (K, 6): x_k = Bᵢ ∫fᵢ dt
    E = ev.seg_e[keep]
    seconds = float(np.sum(ev.seg_t[keep, 1] - ev.seg_t[keep, 0]))
    impulse = float(np.sum(np.abs(Fi)))
    xx = float(np.sum(X * X))
    if xx <= 0.0:
        return ThrusterFit(math.nan, math.nan, K, seconds, impulse)
    delta = -float(np.sum(X * E)) / xx
    rss = float(np.sum((E + delta * X) ** 2))
    se = math.sqrt(rss / max(6 * K - 1, 1) / xx)
    return ThrusterFit(1.0 - delta, se, K, seconds, impulse)
