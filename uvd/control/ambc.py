"""Model-based control (MBC, Theorem 5.2.1) and adaptive model-based control (AMBC,
Theorem 5.2.2), for the full 241-parameter model (2.48) and the decoupled 16-parameter model of
§5.3.1, with optional robust adaptation.

Control law (5.11)/(5.27), with the regressor W_MBC of (5.12)::

    u = −(k_p A⁻ᵀ(Δψ)Δψ + k_d Δv) + W_MBC(ᵃv_d, Δv, ᵃv̇_d, ʷₐH) θ̂

    W_MBC θ = M α − ad_vᵀ(M v) − Σᵢ|vᵢ|Dᵢ v − G(R),   α = Ad_{ΔH⁻¹}ᵈv̇_d − ad_{Δv} ᵃv_d, v = ᵃvₐ

Update law (5.28)::

    θ̂̇ = −K_θ W_MBCᵀ (ε Δψ + Δv)

Discrete time as in §5.3.1: every cycle the command is recomputed from the latest state,
reference and θ̂_k and held; θ̂_{k+1} = θ̂_k + dt θ̂̇_k (Euler over the cycle). K_θ is diagonal
(the per-parameter gains γ of §5.3.1); a zero gain keeps that parameter at its initial value,
which is how §5.2.6 fixes known parameters.

**Robust adaptation** (:class:`RobustAdaptation`; off by default, so the thesis is reproduced
as published) goes beyond the thesis, whose single-step AMBC drifts under unmodelled thruster
dynamics (§5.3.2–5.3.4):

* *projection*: after each update M̂ is made symmetric with eigenvalues ≥ ``mass_floor`` and
  each D̂ᵢ gets a symmetric part ⪯ −``drag_ceiling``·I (decoupled: mᵢ ≥ floor, dᵢ ≤ −ceiling),
  so the model stays physical (M̂ ≻ 0, dissipative drag, §2.6). The projection is onto a convex
  set that contains the true parameters, so it never increases the distance to them in the
  metric of K_θ⁻¹ where K_θ is a multiple of I on each block (Frobenius projection);
* *dead zone*: the update is scaled by max(0, 1 − δ/‖εΔψ + Δv‖), so tracking errors below δ
  (noise) do not make parameters wander;
* *freeze on saturation*: no update while the commanded wrench saturates a thruster (the
  applied input is then not the one the law assumes);
* *freeze after reversal*: no update for ``reversal_hold_s`` after a thruster command changes
  sign or enters the stiction band |f| < ``stiction_band_n`` — the unmodelled thrust-reversal
  dynamics that §5.3.4 identifies as the cause of the drift.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from uvd.control import _kernels
from uvd.control.pdc import gain_vector
from uvd.control.types import ControllerSpec, Diagnostics, Reference, VehicleState
from uvd.model.params import (
    IDX_G,
    N_DECOUPLED,
    N_THETA_UV,
    SL_D,
    SL_M,
    UVParams,
    theta_from_decoupled,
)

MODELS = ("full", "decoupled")
_MODEL_CODE = {"full": _kernels.MODEL_FULL, "decoupled": _kernels.MODEL_DECOUPLED}
N_PARAMS = {"full": N_THETA_UV, "decoupled": N_DECOUPLED}

# positions of g and b, masses and drags inside each parameter vector
_DEC_M = np.arange(0, 6)
_DEC_D = np.arange(6, 12)
_DEC_GB = np.arange(12, 16)
_FULL_GB = np.arange(IDX_G, N_THETA_UV)
_FULL_M = np.arange(SL_M.start, SL_M.stop)
_FULL_D = np.arange(SL_D.start, SL_D.stop)


def mass_index(model: str) -> np.ndarray:
    """Indices of the mass parameters (m₁…m₆ or the 21 entries of M) in θ."""
    return _DEC_M if model == "decoupled" else _FULL_M


def drag_index(model: str) -> np.ndarray:
    return _DEC_D if model == "decoupled" else _FULL_D


def gravity_index(model: str) -> np.ndarray:
    """Indices of [g, b₁, b₂, b₃] in θ."""
    return _DEC_GB if model == "decoupled" else _FULL_GB


def _check_model(model: str) -> None:
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {model!r}")


# ---------------------------------------------------------------------------------------------
# parameter vectors and gains
# ---------------------------------------------------------------------------------------------
def theta_of(params: UVParams, model: str) -> np.ndarray:
    """θ of ``params`` for ``model``: θ_UV ∈ R²⁴¹ (2.48) or the decoupled view ∈ R¹⁶ (§5.3.1)."""
    _check_model(model)
    return params.theta if model == "full" else params.decoupled_view()


def params_of(theta: np.ndarray, model: str) -> UVParams:
    """The :class:`UVParams` that a parameter vector of ``model`` describes."""
    _check_model(model)
    theta = np.asarray(theta, dtype=float)
    if model == "decoupled":
        theta = theta_from_decoupled(theta)
    return UVParams.from_theta(theta)


def adaptation_gains(model: str, *, gamma_m: float | np.ndarray = 1000.0,
                     gamma_d: float | np.ndarray = 5000.0, gamma_g: float = 0.5,
                     gamma_b: float | np.ndarray = (0.5, 0.5, 10.0)) -> np.ndarray:
    """Diagonal of K_θ. Decoupled: [γ_m1…γ_m6, γ_d1…γ_d6, γ_g, γ_b1, γ_b2, γ_b3] (§5.3.1);
    defaults are the thesis's γ_mi = 1000, γ_di = 5000, γ_g = γ_b1 = γ_b2 = 0.5, γ_b3 = 10
    (§5.3.2). Full: γ_m on every one of the 21 mass entries (a (21,) array gives one each),
    γ_d on every one of the 216 drag entries, then γ_g and γ_b."""
    _check_model(model)
    n = N_PARAMS[model]
    K = np.empty(n)
    K[mass_index(model)] = gamma_m
    K[drag_index(model)] = gamma_d
    gi = gravity_index(model)
    K[gi[0]] = gamma_g
    K[gi[1:]] = gamma_b
    if not np.all(np.isfinite(K)) or np.any(K < 0):
        raise ValueError("adaptation gains must be finite and >= 0")
    return K


@dataclass(frozen=True)
class RobustAdaptation:
    """Robust modifications of the update law (module docstring); all off when not ``enabled``.

    Attributes
    ----------
    mass_floor : smallest allowed eigenvalue of M̂ (decoupled: per DOF, scalar or (6,));
        kg for translation, kg m² for rotation.
    drag_ceiling : dᵢ ≤ −drag_ceiling (decoupled), or sym(D̂ᵢ) ⪯ −drag_ceiling·I (full).
    dead_zone : δ on ‖εΔψ + Δv‖ (mixed units, as the update law's own error signal).
    freeze_on_saturation : no update while the command saturates a thruster (needs
        ``AMBCParams.B_pinv`` and ``f_max``, see :func:`ambc_params`).
    reversal_hold_s : no update for this long after a thruster command reverses or enters
        the stiction band (0 disables).
    stiction_band_n : |f| below which a thruster command counts as "in the stiction band".
    """

    enabled: bool = False
    mass_floor: float | np.ndarray = 10.0
    drag_ceiling: float | np.ndarray = 0.0
    dead_zone: float = 0.0
    freeze_on_saturation: bool = True
    reversal_hold_s: float = 0.0
    stiction_band_n: float = 5.0


ROBUST_DAEMON_DEFAULT = RobustAdaptation(enabled=True, mass_floor=10.0, drag_ceiling=0.0,
                                         dead_zone=0.002, freeze_on_saturation=True,
                                         reversal_hold_s=0.0, stiction_band_n=5.0)
"""The robust adaptation the daemon runs with (see ``docs/experiments.md``, ``ambc-robust``).

The reversal hold is off: in simulation (RefTraj1, 0.15 s propeller lag, 5 N stiction) a 1 s
hold froze 80 % of the cycles and made the lag bias of the remaining updates worse (m₅ +74 %
after 2 h instead of −2 %)."""


@dataclass(frozen=True)
class AMBCParams:
    """Constant configuration of :func:`ambc_step`.

    Attributes
    ----------
    model : "full" (θ_UV ∈ R²⁴¹, (2.48)) or "decoupled" (16 parameters, §5.3.1).
    K : diagonal of K_θ (n,), see :func:`adaptation_gains`; all zero ⇒ MBC (Theorem 5.2.1).
    kp, kd : PD gains (scalar or (6,)).
    eps : ε of the update law (5.28) (and of the Lyapunov function (5.18)/(5.32)).
    robust : :class:`RobustAdaptation`.
    B_pinv, f_max : allocation pseudo-inverse (N × 6) and thrust limits (N,), used only to
        detect saturation and reversals for the robust freezes (empty: not detected).
    """

    model: str
    K: np.ndarray
    kp: float | np.ndarray = 300.0
    kd: float | np.ndarray = 100.0
    eps: float = 0.1
    robust: RobustAdaptation = field(default_factory=RobustAdaptation)
    B_pinv: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    f_max: np.ndarray = field(default_factory=lambda: np.zeros(0))
    _c: tuple = field(default=(), init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        _check_model(self.model)
        K = np.ascontiguousarray(self.K, dtype=float).reshape(-1)
        if K.shape != (N_PARAMS[self.model],):
            raise ValueError(f"K must have {N_PARAMS[self.model]} entries for model "
                             f"{self.model!r}, got {K.shape[0]}")
        if not np.all(np.isfinite(K)) or np.any(K < 0):
            raise ValueError("K must be finite and >= 0")
        if not (np.isfinite(self.eps) and self.eps >= 0):
            raise ValueError(f"eps must be finite and >= 0, got {self.eps}")
        B_pinv = np.ascontiguousarray(self.B_pinv, dtype=float).reshape(-1, 6)
        f_max = np.ascontiguousarray(self.f_max, dtype=float).reshape(-1)
        if B_pinv.shape[0] != f_max.shape[0]:
            raise ValueError("B_pinv and f_max must describe the same thrusters")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "B_pinv", B_pinv)
        object.__setattr__(self, "f_max", f_max)
        rb = self.robust
        mf = np.broadcast_to(np.asarray(rb.mass_floor, dtype=float), (6,)).copy()
        dc = np.broadcast_to(np.asarray(rb.drag_ceiling, dtype=float), (6,)).copy()
        kp, kd = gain_vector(self.kp, "kp"), gain_vector(self.kd, "kd")
        object.__setattr__(self, "_c", (_MODEL_CODE[self.model], kp, kd, mf, dc,
                                        bool(np.any(K > 0))))
        # the kernel's packed parameters (_kernels.pack_ambc_params), packed once; its output
        # buffer's length; the last thruster commands before the first cycle
        object.__setattr__(self, "_hot", (
            _MODEL_CODE[self.model],
            _kernels.pack_ambc_params(_MODEL_CODE[self.model], K, kp, kd, mf, dc,
                                      float(self.eps), rb.enabled, float(rb.dead_zone),
                                      rb.freeze_on_saturation, float(rb.reversal_hold_s),
                                      float(rb.stiction_band_n), B_pinv, f_max),
            36 + 2 * K.shape[0] + B_pinv.shape[0], np.zeros(B_pinv.shape[0])))

    @property
    def n(self) -> int:
        return N_PARAMS[self.model]


@dataclass(frozen=True, slots=True)
class AMBCState:
    """Memory of the AMBC between cycles (immutable; each cycle returns a new one).

    Attributes
    ----------
    theta : θ̂_k, the estimate used by the next command.
    theta_dot : θ̂̇ of the last cycle (zero when frozen).
    t : seconds of control so far.
    dpsi, dv : last Δψ, Δv (5.3)–(5.4).
    saturated : the last command saturated a thruster.
    frozen : the last update was skipped (saturation, reversal hold, dead zone).
    hold_until : time until which the reversal hold freezes adaptation.
    last_f : last per-thruster command (N) of the controller's own allocation, for reversals.
    projections : number of cycles on which the projection moved θ̂ (diagnostic).
    """

    theta: np.ndarray
    theta_dot: np.ndarray
    t: float = 0.0
    dpsi: np.ndarray = field(default_factory=lambda: np.zeros(6))
    dv: np.ndarray = field(default_factory=lambda: np.zeros(6))
    saturated: bool = False
    frozen: bool = False
    hold_until: float = -1.0
    last_f: np.ndarray | None = None
    projections: int = 0


def ambc_init(params: AMBCParams, theta0: np.ndarray) -> AMBCState:
    """Initial state with θ̂(t₀) = theta0 (projected if robust adaptation is on)."""
    theta = np.array(theta0, dtype=float).reshape(-1)
    if theta.shape != (params.n,):
        raise ValueError(f"theta0 must have {params.n} entries, got {theta.shape[0]}")
    if not np.all(np.isfinite(theta)):
        raise ValueError("theta0 has a non-finite entry")
    code, _, _, mf, dc, _ = params._c
    if params.robust.enabled:
        _kernels.project(code, theta, mf, dc)
    return AMBCState(theta=theta, theta_dot=np.zeros(params.n))


_ONES = np.ones(6)


def _mask(reference: Reference) -> np.ndarray:
    if reference.closed_loop is None:
        return _ONES
    return np.asarray(reference.closed_loop, dtype=float)


def _ff(code: int, theta: np.ndarray, reference: Reference) -> tuple[np.ndarray, bool]:
    """(increment, on) of the feed-forward preview; off (zeros) without ``reference.preview``."""
    p = reference.preview
    if p is None:
        return _ZERO6, False
    return _kernels.ff_increment(code, theta, reference.H, reference.v, reference.vdot, p.H,
                                 p.v, p.vdot), True


def ambc_step(state: VehicleState, reference: Reference, params: AMBCParams, ctrl: AMBCState,
              dt: float) -> tuple[np.ndarray, AMBCState]:
    """One AMBC cycle: u by (5.27) with θ̂_k, then θ̂_{k+1} = θ̂_k + dt θ̂̇ by (5.28).

    **Feed-forward preview** (opt-in: only when ``reference.preview``, the desired state at
    t + δ, is set — the core does it when ``CoreConfig.ff_preview_s`` = δ > 0). The command the
    law computes at t reaches the vehicle as thrust about δ later (10 Hz hold + propeller,
    :func:`uvd.control.allocation.actuation_delay_s`); the update law (5.28), which assumes the
    input acts at once, turns that delay into bias of M̂ and D̂ (delayed Mv̇_d looks like drag,
    delayed drag like mass). The part of (5.27) that the reference alone determines is known in
    advance, so it is sent δ early:

        u = (5.27) at t  +  [W_d(t+δ) − W_d(t)] θ̂,
        W_d(t) θ̂ = W_MBC(ᵈv_d, 0, ᵈv̇_d, ʷ_dH)(t) θ̂ = M̂ ᵈv̇_d − ad_{v_d}ᵀ(M̂ ᵈv_d)
                    − Σᵢ|v_d,ᵢ| D̂ᵢ ᵈv_d − Ĝ(R_d)

    i.e. (5.12) with the actual state replaced by the desired one (Δψ = 0, Δv = 0). In (5.12)
    only M ᵃv̇_d is built from the reference; Coriolis, drag and G use the measured state, which
    on the reference equals the desired one — so the preview advances the whole regressor's
    reference part and leaves the state-error part (and the PD term) at t. The increment is
    formed in the desired body frame (first order in ΔH; ΔH ≈ I when tracking). The update law
    keeps W_MBC at t: after the delay the applied feed-forward is W_d(t)θ̂ again. With the
    preview equal to the reference (δ = 0) the increment is exactly zero and u is unchanged;
    a non-finite preview makes u non-finite, which the core turns into zero thrust.

    Parameters
    ----------
    state : actual pose ʷₐH and body velocity ᵃvₐ.
    reference : desired {ʷ_dH, ᵈv_d, ᵈv̇_d}; DOFs with ``closed_loop`` False get neither feedback
        nor feed-forward and do not drive the update.
    params : :class:`AMBCParams`. ctrl : :class:`AMBCState`. dt : cycle period (s).

    Returns
    -------
    u : (6,) body wrench [f; τ] (N, N m). ctrl : the next :class:`AMBCState`.
    """
    code, P, n_out, f0 = params._hot
    n = params.K.shape[0]
    out = np.empty(n_out)  # [u, err, θ̂⁺, θ̂̇, f]: the new state's arrays are views of it
    last_f = ctrl.last_f if ctrl.last_f is not None else f0
    ff, use_ff = _ff(code, ctrl.theta, reference)
    saturated, frozen, projected, hold_until = _kernels.ambc_step_kernel(
        P, state.H, state.v, reference.H, reference.v, reference.vdot, _mask(reference), ff,
        use_ff, ctrl.theta, float(dt), float(ctrl.t), last_f, float(ctrl.hold_until), out)
    # positional, in the field order of AMBCState (a frozen dataclass's keyword __init__ costs
    # twice as much, on every cycle)
    return out[0:6], AMBCState(out[36:36 + n], out[36 + n:36 + 2 * n], ctrl.t + dt, out[6:12],
                               out[12:18], saturated, frozen, hold_until, out[36 + 2 * n:],
                               ctrl.projections + int(projected))


def ambc_params(model: str, *, K: np.ndarray | None = None, kp: float = 300.0,
                kd: float = 100.0, eps: float = 0.1, robust: RobustAdaptation | None = None,
                allocator=None, **gammas) -> AMBCParams:
    """Convenience constructor: gains γ by name (see :func:`adaptation_gains`), and the
    allocator (:class:`uvd.control.allocation.Allocator`) whose B⁺ and thrust limits the
    robust freezes use."""
    if K is None:
        K = adaptation_gains(model, **gammas)
    elif gammas:
        raise TypeError("give either K or the gammas, not both")
    extra = {}
    if allocator is not None:
        extra = {"B_pinv": allocator.B_pinv, "f_max": allocator.max_thrust_n}
    return AMBCParams(model=model, K=K, kp=kp, kd=kd, eps=eps,
                      robust=robust if robust is not None else RobustAdaptation(), **extra)


# ---------------------------------------------------------------------------------------------
# MBC (Theorem 5.2.1): AMBC with K_θ = 0 and the true parameters
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MBCParams:
    """Constant configuration of :func:`mbc_step`: the known θ_UV, k_p, k_d."""

    theta: np.ndarray
    kp: float | np.ndarray = 300.0
    kd: float | np.ndarray = 100.0
    _ambc: AMBCParams = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        theta = np.ascontiguousarray(self.theta, dtype=float).reshape(-1)
        model = {N_THETA_UV: "full", N_DECOUPLED: "decoupled"}.get(theta.shape[0])
        if model is None:
            raise ValueError(f"theta must have {N_THETA_UV} or {N_DECOUPLED} entries")
        object.__setattr__(self, "theta", theta)
        object.__setattr__(self, "_ambc", AMBCParams(model=model, K=np.zeros(theta.shape[0]),
                                                     kp=self.kp, kd=self.kd))

    @classmethod
    def from_params(cls, params: UVParams, kp: float | np.ndarray = 300.0,
                    kd: float | np.ndarray = 100.0) -> MBCParams:
        return cls(theta=params.theta, kp=kp, kd=kd)


@dataclass(frozen=True, slots=True)
class MBCState:
    dpsi: np.ndarray = field(default_factory=lambda: np.zeros(6))
    dv: np.ndarray = field(default_factory=lambda: np.zeros(6))


def mbc_step(state: VehicleState, reference: Reference, params: MBCParams, ctrl: MBCState,
             dt: float) -> tuple[np.ndarray, MBCState]:
    """One MBC cycle, (5.11): u = −(k_p A⁻ᵀ(Δψ)Δψ + k_d Δv) + W_MBC θ_UV (5.12), with the
    feed-forward preview of :func:`ambc_step` when ``reference.preview`` is set."""
    code, P, n_out, f0 = params._ambc._hot  # K_θ = 0: no adaptation
    out = np.empty(n_out)
    ff, use_ff = _ff(code, params.theta, reference)
    _kernels.ambc_step_kernel(P, state.H, state.v, reference.H, reference.v, reference.vdot,
                        _mask(reference), ff, use_ff, params.theta, float(dt), 0.0, f0, -1.0,
                        out)
    return out[0:6], MBCState(dpsi=out[6:12], dv=out[12:18])


_ZERO6 = np.zeros(6)


# ---------------------------------------------------------------------------------------------
# Lyapunov functions (5.18), (5.32)
# ---------------------------------------------------------------------------------------------
def lyapunov_V1(dpsi: np.ndarray, dv: np.ndarray, M: np.ndarray, kp: float, eps: float) -> float:
    """V₁ = ½ xᵀ M_ε x (5.18) with M_ε = [[k_p I, εM], [εM, M]] (5.19), x = [Δψ; Δv] (5.5)."""
    return float(0.5 * kp * dpsi @ dpsi + eps * dpsi @ M @ dv + 0.5 * dv @ M @ dv)


def lyapunov_V2(dpsi: np.ndarray, dv: np.ndarray, M: np.ndarray, kp: float, eps: float,
                dtheta: np.ndarray, K: np.ndarray) -> float:
    """V₂ = V₁ + ½ Δθᵀ K_θ⁻¹ Δθ (5.32); K is the diagonal of K_θ, entries with K = 0 (fixed
    parameters, which must then be exact) are left out."""
    on = K > 0
    return lyapunov_V1(dpsi, dv, M, kp, eps) + float(0.5 * np.sum(dtheta[on] ** 2 / K[on]))


#: c of Appendix B.2 (B.11): ‖A⁻¹(ψ)x‖ < c‖x‖ for every ‖ψ‖ < π
C_APPENDIX_B2 = 6.0 + 5.0 * math.pi / 2.0 + math.pi ** 2 / 8.0


def epsilon_bound(M: np.ndarray, kp: float, kd: float, c: float = 1.0) -> float:
    """The bound of Theorems 5.2.1/5.2.2 on ε: min(4k_pk_d/(2λ₁k_pc + k_d²), √(k_pλ₆/λ₁²)),
    λ₁ ≥ … ≥ λ₆ the eigenvalues of M, c a bound of ‖A⁻¹(ψ)‖ on the region of interest
    (Appendix B.2; c → 1 as ‖Δψ‖ → 0). With the thesis's c (:data:`C_APPENDIX_B2`),
    k_p = 300, k_d = 100 and the jhu-rov M the bound is 0.0127; with c = 1, 0.162."""
    lam = np.linalg.eigvalsh(0.5 * (M + M.T))
    l1, l6 = lam[-1], lam[0]
    return float(min(4 * kp * kd / (2 * l1 * kp * c + kd * kd), np.sqrt(kp * l6 / l1 ** 2)))


def with_theta(ctrl: AMBCState, theta: np.ndarray) -> AMBCState:
    """A copy of ``ctrl`` with θ̂ replaced."""
    return replace(ctrl, theta=np.array(theta, dtype=float))


__all__ = [
    "AMBCParams", "AMBCState", "MBCParams", "MBCState", "RobustAdaptation",
    "ROBUST_DAEMON_DEFAULT", "adaptation_gains", "ambc_hold_dofs", "ambc_init", "ambc_params",
    "ambc_step", "ambc_with_allocation", "C_APPENDIX_B2", "epsilon_bound", "gravity_index",
    "hold_theta_dofs",
    "lyapunov_V1", "lyapunov_V2", "mass_index", "drag_index", "mbc_step", "params_of",
    "theta_of", "with_theta",
]


def m_hat_min_eig(theta: np.ndarray) -> float:
    """Smallest eigenvalue of M̂ of a decoupled (16: the six masses) or full (P_M of (2.46))
    parameter vector."""
    if theta.shape[0] == 16:
        return float(theta[:6].min())
    from uvd.model.params import SL_M, M_from_theta
    return float(np.linalg.eigvalsh(M_from_theta(theta[SL_M]))[0])


def ambc_diagnostics(ctrl: AMBCState) -> Diagnostics:
    """The diagnostics hook of AMBC's spec: θ̂ (a copy), M̂'s smallest eigenvalue, frozen."""
    theta = np.array(ctrl.theta, dtype=float)
    return Diagnostics(theta=theta, m_min_eig=m_hat_min_eig(theta), frozen=bool(ctrl.frozen))


def hold_theta_dofs(new: np.ndarray, old: np.ndarray, actuated: np.ndarray) -> np.ndarray:
    """θ̂ ``new`` with the parameters of the DOFs not ``actuated`` kept at ``old``.

    Decoupled (16: m₁…m₆, d₁…d₆, g, b): mᵢ and dᵢ of each such DOF i — they appear in the
    other DOFs' rows too (the Coriolis terms of (2.40): (m₅ − m₆) q r in roll), so masking the
    DOF's error in (5.28) alone does not stop them. g and b are kept as well when heave, roll
    or pitch is given up (the rows they enter). Full (241): every entry kept (M and the drags
    couple every DOF)."""
    keep = ~np.asarray(actuated, dtype=bool)
    if not keep.any():
        return new
    if new.shape[0] != 16:
        return old
    out = np.array(new, dtype=float)
    idx = np.concatenate([_DEC_M[keep], _DEC_D[keep]])
    if keep[2:5].any():
        idx = np.concatenate([idx, _DEC_GB])
    out[idx] = old[idx]
    return out


def ambc_hold_dofs(new: AMBCState, old: AMBCState, actuated: np.ndarray) -> AMBCState:
    """AMBC's ``hold_dofs`` hook (:class:`~uvd.control.types.ControllerSpec`)."""
    theta = hold_theta_dofs(new.theta, old.theta, actuated)
    return new if theta is new.theta else replace(new, theta=theta)


def ambc_with_allocation(params: AMBCParams, B_pinv: np.ndarray) -> AMBCParams:
    """AMBC's ``with_allocation`` hook (:class:`~uvd.control.types.ControllerSpec`): the robust
    freezes (saturation, thrust reversals) judged on the allocation ``B_pinv`` the core uses —
    with a thruster dead, its accommodated inverse — not the healthy B⁺. Params without an
    allocation (no robust freezes on thrust) are returned as they are."""
    if params.B_pinv.shape[0] == 0:
        return params
    return replace(params, B_pinv=np.array(B_pinv, dtype=float))


def ambc_spec(params: AMBCParams, theta0: np.ndarray, name: str = "ambc") -> ControllerSpec:
    """AMBC (Theorem 5.2.2) as the core runs it, starting from θ̂(t₀) = ``theta0``."""
    return ControllerSpec(name, ambc_step, params, ambc_init(params, theta0), ambc_diagnostics,
                          ambc_hold_dofs, ambc_with_allocation)
