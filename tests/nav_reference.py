# The Python nav_step of uvd/estimation/navigation.py as it was before the step became one
# compiled call (55a1ac8), kept unchanged as the reference tests/test_navigation_kernel.py
# holds the compiled step to, bit for bit. Not used by uvd.
"""The old Python navigation step (its rules: uvd/estimation/navigation.py's module docstring)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numba
import numpy as np

from drivers.frames import dvl_mount_to_body
from uvd.estimation.navigation import NavConfig, _carry, _eye3, _rotate, _zeros3
from uvd.model.lie import euler_R, exp_so3

if TYPE_CHECKING:  # the sample types are plain dataclasses; only their attributes are read
    from drivers.samples import DepthSample, DvlSample, InsSample

__all__ = ["NavConfig", "NavState", "NavMemory", "nav_init", "nav_step", "nav_set_position"]

_I3 = np.eye(3)
_Z3 = np.zeros(3)
_INF = float("inf")


@dataclass(frozen=True)
class NavState:
    """Navigation output of one cycle.

    Attributes
    ----------
    t_ns : int
        Time of the cycle (monotonic ns, the clock the samples are stamped with).
    H : (4, 4) ndarray
        Pose body → world, SE(3); p = [north, east, depth] in metres.
    v : (6,) ndarray
        Body velocity [ν; ω] (m/s, rad/s).
    valid : bool
        INS, DVL and depth all valid (what control needs).
    ins_valid, dvl_valid, depth_valid : bool
        Per-source validity (latest usable sample within its timeout).
    ins_age_s, dvl_age_s, depth_age_s : float
        Age of each source's latest usable sample (``inf`` before the first).
    rates_degraded : bool
        ω was derived from attitude, not measured.
    bottom_lock : bool
        The latest DVL sample had bottom lock.
    """

    t_ns: int
    H: np.ndarray
    v: np.ndarray
    valid: bool
    ins_valid: bool
    dvl_valid: bool
    depth_valid: bool
    ins_age_s: float
    dvl_age_s: float
    depth_age_s: float
    rates_degraded: bool
    bottom_lock: bool


@dataclass(slots=True)
class NavMemory:
    """Explicit memory of :func:`nav_step` (treat as opaque; a new one is returned each call).

    Attributes
    ----------
    t_ns : int or None
        Time of the previous call.
    north_m, east_m : float
        Dead-reckoned horizontal position.
    depth_m : float
        Latest valid depth (0 before the first).
    R : (3, 3) ndarray
        Latest attitude (identity before the first INS sample).
    omega : (3,) ndarray
        Latest body angular rate.
    nu : (3,) ndarray
        Latest (held) body translational velocity of the origin.
    v_world_prev : (3,) ndarray or None
        World velocity of the last locked DVL sample, held until the next one (None when the
        DVL is invalid).
    ins_t_ns, dvl_t_ns, depth_t_ns : int or None
        Stamp of each source's latest usable sample.
    rates_degraded, bottom_lock : bool
        Flags carried to the next cycle.
    att_prev_R, att_prev_t_ns :
        Previous INS attitude and its stamp, for rates derived from attitude.
    dvl_raw : (3,) ndarray or None
        Latest locked DVL velocity in the DVL frame (the lever arm is re-applied with each ω).
    omega_dot : (3,) ndarray
        Change of the measured rate between the last two INS samples, per second (zero
        until two samples with measured rates arrived within ``ins_timeout_s``).
    """

    t_ns: int | None = None
    north_m: float = 0.0
    east_m: float = 0.0
    depth_m: float = 0.0
    R: np.ndarray = field(default_factory=_eye3)
    omega: np.ndarray = field(default_factory=_zeros3)
    nu: np.ndarray = field(default_factory=_zeros3)
    v_world_prev: np.ndarray | None = None
    ins_t_ns: int | None = None
    dvl_t_ns: int | None = None
    depth_t_ns: int | None = None
    rates_degraded: bool = False
    bottom_lock: bool = False
    att_prev_R: np.ndarray | None = None
    att_prev_t_ns: int | None = None
    dvl_raw: np.ndarray | None = None
    omega_dot: np.ndarray = field(default_factory=_zeros3)


def nav_init(cfg: NavConfig, north_m: float = 0.0, east_m: float = 0.0) -> NavMemory:
    """Initial memory: position (north_m, east_m), no sample seen, every source invalid."""
    return NavMemory(north_m=float(north_m), east_m=float(east_m))


def nav_set_position(mem: NavMemory, north_m: float, east_m: float) -> NavMemory:
    """Memory with the dead-reckoned position replaced by an external fix (north, east, m)."""
    return replace(mem, north_m=float(north_m), east_m=float(east_m))


# ------------------------------------------------------------------ compiled small-matrix steps
# (the configuration, R x and the carried attitude are navigation's own: unchanged by the
# kernel; _assemble's formula follows)

@numba.njit(cache=True)
def _assemble(R, north, east, depth, nu, omega):
    """H = [[R, p], [0, 1]] with p = (north, east, depth), and v = [ν; ω]."""
    H = np.empty((4, 4))
    for i in range(3):
        for j in range(3):
            H[i, j] = R[i, j]
        H[3, i] = 0.0
    H[0, 3] = north
    H[1, 3] = east
    H[2, 3] = depth
    H[3, 3] = 1.0
    v = np.empty(6)
    for i in range(3):
        v[i] = nu[i]
        v[3 + i] = omega[i]
    return H, v


_F64 = np.dtype(np.float64)


def _vec3(w) -> np.ndarray:
    """The first three entries of ``w`` as a new float64 array (w checked finite)."""
    if type(w) is np.ndarray and w.ndim == 1 and w.dtype == _F64:
        return w[:3].copy()
    return np.array([float(w[0]), float(w[1]), float(w[2])])


def _log_so3_vee(R: np.ndarray) -> np.ndarray:
    """vee(log R) for a small rotation (rates derived from successive attitudes)."""
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    c = min(1.0, max(-1.0, c))
    th = math.acos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-6:
        return 0.5 * w
    s = math.sin(th)
    if s < 1e-9:  # θ ≈ π: not a rate step a 10 Hz INS can produce; give up on this one
        return np.zeros(3)
    return (th / (2.0 * s)) * w


def _finite3(a) -> bool:
    return math.isfinite(a[0]) and math.isfinite(a[1]) and math.isfinite(a[2])


def _age_s(t_ns: int, stamp: int | None) -> float:
    if stamp is None:
        return _INF
    d = t_ns - stamp
    return d * 1e-9 if d > 0 else 0.0


# nav_step is long (~135 lines) on purpose: it runs every cycle on the loop's path, and its
# sources' rules share a dozen intermediate values; split into helpers they would be passed
# around at ~0.1 µs a call for no gain in clarity (each rule is its own commented block).
def nav_step(cfg: NavConfig, mem: NavMemory, t_ns: int, ins: InsSample | None,
             dvl: DvlSample | None, depth: DepthSample | None) -> tuple[NavState, NavMemory]:
    """One navigation cycle at time ``t_ns`` (see the module docstring for the rules).

    Parameters
    ----------
    cfg : NavConfig
    mem : NavMemory
        Memory returned by the previous call (or :func:`nav_init`); not modified.
    t_ns : int
        Cycle time, monotonic ns on the clock the samples were stamped with.
    ins, dvl, depth : InsSample, DvlSample, DepthSample or None
        The newest sample of each source that arrived since the previous call.

    Returns
    -------
    (NavState, NavMemory)
    """
    R = mem.R
    omega = mem.omega
    nu = mem.nu
    ins_t = mem.ins_t_ns
    dvl_t = mem.dvl_t_ns
    depth_t = mem.depth_t_ns
    depth_m = mem.depth_m
    rates_degraded = mem.rates_degraded
    bottom_lock = mem.bottom_lock
    att_prev_R = mem.att_prev_R
    att_prev_t = mem.att_prev_t_ns
    dvl_raw = mem.dvl_raw
    omega_dot = mem.omega_dot
    omega_changed = False

    # --- INS: attitude and rates ------------------------------------------------------------
    if ins is not None and ins.valid and math.isfinite(ins.roll) and math.isfinite(ins.pitch) \
            and math.isfinite(ins.heading):
        R_new = euler_R(float(ins.roll), float(ins.pitch), float(ins.heading))
        w = ins.omega_body
        if _finite3(w):
            w = _vec3(w)
            # the rate's slope from the previous measured rate, for carrying it forward
            gap_s = (ins.t_ns - ins_t) * 1e-9 if ins_t is not None else 0.0
            if not rates_degraded and ins.rates_valid \
                    and cfg.derive_rates_min_dt_s <= gap_s <= cfg.ins_timeout_s:
                omega_dot = (w - omega) / gap_s
            else:
                omega_dot = _Z3
            omega = w
            omega_changed = True
            rates_degraded = not ins.rates_valid
        else:
            rates_degraded = True
            omega_dot = _Z3
            if att_prev_R is not None and att_prev_t is not None:
                dt = (ins.t_ns - att_prev_t) * 1e-9
                if dt >= cfg.derive_rates_min_dt_s:
                    omega = _log_so3_vee(att_prev_R.T @ R_new) / dt
                    omega_changed = True
        R = R_new
        att_prev_R = R_new
        att_prev_t = ins.t_ns
        ins_t = ins.t_ns

    # --- DVL: body velocity of the origin ---------------------------------------------------
    new_dvl = False
    if dvl is not None:
        vb = dvl.velocity_body
        locked = bool(dvl.bottom_lock) and dvl.good_beams >= cfg.min_good_beams \
            and _finite3(vb)
        bottom_lock = locked
        if locked:
            dvl_raw = _vec3(vb)
            dvl_t = dvl.t_ns
            new_dvl = True
    if dvl_raw is not None and (new_dvl or (omega_changed and cfg._has_lever_arm)):
        # re-applied when ω changes so the lever-arm term uses the latest rate
        if cfg._mount_is_identity:
            nu = dvl_raw
        else:
            nu = dvl_mount_to_body(cfg.dvl_mount_R, cfg.dvl_lever_arm_m, dvl_raw, omega)

    # --- depth --------------------------------------------------------------------------------
    if depth is not None and depth.valid and math.isfinite(depth.depth_m):
        depth_m = float(depth.depth_m)
        depth_t = depth.t_ns

    # --- ages and validity -----------------------------------------------------------------
    ins_age = _age_s(t_ns, ins_t)
    dvl_age = _age_s(t_ns, dvl_t)
    depth_age = _age_s(t_ns, depth_t)
    ins_valid = ins_age <= cfg.ins_timeout_s
    dvl_valid = dvl_age <= cfg.dvl_timeout_s
    depth_valid = depth_age <= cfg.depth_timeout_s

    # --- dead reckoning (DVLNAV): each DVL sample's world velocity, held until the next ------
    north, east = mem.north_m, mem.east_m
    v_hold = mem.v_world_prev if dvl_valid else None
    t_prev = mem.t_ns
    if new_dvl and dvl_valid:
        # rotated once, with the attitude at the sample's own time: the INS attitude propagated
        # by its body rate over the (< one INS period) gap, R(t_dvl) ≈ R(t_ins) e^{J(ω)Δt}
        R_dvl = R
        if ins_t is not None and dvl_t != ins_t and _finite3(omega):
            gap_s = (dvl_t - ins_t) * 1e-9
            if abs(gap_s) <= cfg.ins_timeout_s:
                R_dvl = R @ exp_so3(omega * gap_s)
        v_new = _rotate(R_dvl, nu)
        if t_prev is not None and t_ns > t_prev:
            t_split = min(max(dvl_t, t_prev), t_ns)  # the old velocity holds until the sample
            if v_hold is not None:
                north += float(v_hold[0]) * (t_split - t_prev) * 1e-9
                east += float(v_hold[1]) * (t_split - t_prev) * 1e-9
            north += float(v_new[0]) * (t_ns - t_split) * 1e-9
            east += float(v_new[1]) * (t_ns - t_split) * 1e-9
        v_hold = v_new
    elif v_hold is not None and t_prev is not None and t_ns > t_prev:
        north += float(v_hold[0]) * (t_ns - t_prev) * 1e-9
        east += float(v_hold[1]) * (t_ns - t_prev) * 1e-9
    v_world_prev = v_hold

    if cfg.propagate_ins and ins_valid and ins_age > 0.0 and not rates_degraded:
        R_now, omega_now = _carry(R, omega, omega_dot, ins_age)
    else:
        R_now, omega_now = R, omega
    H, v = _assemble(R_now, float(north), float(east), float(depth_m), nu, omega_now)

    state = NavState(
        int(t_ns), H, v, ins_valid and dvl_valid and depth_valid, ins_valid, dvl_valid,
        depth_valid, ins_age, dvl_age, depth_age, rates_degraded, bottom_lock,
    )
    new_mem = NavMemory(
        int(t_ns), north, east, depth_m, R, omega, nu, v_world_prev, ins_t, dvl_t, depth_t,
        rates_degraded, bottom_lock, att_prev_R, att_prev_t, dvl_raw, omega_dot,
    )
    return state, new_mem
