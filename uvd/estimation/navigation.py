"""Navigation state: pose H ∈ SE(3) and body velocity v = [ν; ω] from INS, DVL and depth.

Pure (numpy, plus the pure frame functions of :mod:`drivers.frames`; no I/O, no clock, no
logging) and cheap enough to run every control cycle.
One call of :func:`nav_step` per cycle takes the samples that arrived since the previous call
(``None`` where none did) and returns a :class:`NavState` and the next :class:`NavMemory`.

How the state is assembled (thesis App. A.1, Table A.1):

* **Attitude R and ω** from the latest INS sample (PHINS III, 10 Hz): R = Rz(ψ)Ry(θ)Rx(φ)
  (App. A), ω in the body frame. When the INS delivers no rates (``rates_valid=False``, e.g.
  PHINS standard ASCII, which carries none) and its ``omega_body`` is not finite, ω is derived
  here from successive attitudes, ω ≈ vee(log(R_prevᵀ R)) / Δt, and ``rates_degraded`` is set;
  when the driver already derived them (finite ``omega_body``), they are used and flagged
  degraded too.
* **ν** from the latest DVL sample with bottom lock (6 Hz): ν = R_mount v_dvl − ω × r with the
  configured mounting rotation and lever arm (:func:`drivers.frames.dvl_mount_to_body`; the
  defaults make it the identity, which is what the lockstep instrument models deliver).
* **x, y (north, east)** by dead reckoning, as the thesis's DVLNAV did: each locked DVL sample's
  velocity is rotated into the world frame once, with the attitude at the sample's time (the
  INS attitude propagated by its body rate across the gap between the two stamps), and that
  world velocity is held until the next sample (the interval is split exactly at the sample's
  time). Rotating the *held body* velocity by the *current* attitude instead would turn the
  correlation of yaw rate and sway (RefTraj1 drives both at 0.21 rad/s) into a steady drift —
  R(ω × ν)·age has a non-zero mean — where the world-frame hold only delays the position.
* **z (depth)** from the latest valid depth sample (Digiquartz, 7 Hz).
* **Carried to the cycle's time** (``propagate_ins``): the INS is not synchronised with the
  control loop, so its latest sample is 0–100 ms old at a 10 Hz cycle, and that delay sits
  inside the heading loop. With measured rates, R and ω are reported at the cycle's time t:
  ω(t) = ω_k + ω̇ a and R(t) = R_k e^{J((ω_k + ω̇ a/2) a)}, a = t − t_k the sample's age and
  ω̇ = (ω_k − ω_{k−1})/(t_k − t_{k−1}) from the last two samples (a first-order hold of the
  rate, whose integral is the rotation). Only while the sample is valid, and never with rates
  derived from attitude (differencing noisy attitudes twice would amplify the noise). An age
  of 0 — the lockstep instruments, sampled on the tick — leaves the sample unchanged.

Validity and ages: a source is valid when its latest usable sample is at most its timeout old
(``NavConfig.*_timeout_s``); ages are seconds since the sample's ``t_ns`` (``inf`` before the
first one). ``valid`` is the conjunction of INS, DVL and depth validity — what control needs.

**Lost bottom lock.** A DVL sample without bottom lock (or with fewer good beams than
``min_good_beams``) does not change ν; ``bottom_lock`` turns False at once. The last locked
velocity is then *held* (zero-order hold) and dead reckoning continues with it for at most
``dvl_timeout_s`` after the last locked sample — the DVL's normal dropout gap. After that the
DVL is invalid: ``dvl_valid`` and ``valid`` become False, dead reckoning stops (north/east are
frozen at their last value, not extrapolated), and ν keeps its last finite value only so
nothing non-finite leaves this module; the consumer must act on ``valid``. Dead reckoning
resumes with the next locked sample (the position is not corrected: a DVLNAV-style solution
drifts, <0.5 % of distance travelled in Table A.1; use :func:`nav_set_position` to reset it
from an external fix).

Time going backwards or samples stamped after ``t_ns`` are treated as age 0 / no integration;
nothing here raises on bad input — non-finite samples are ignored.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, NamedTuple

import numba
import numpy as np

from drivers.frames import dvl_mount_to_body
from uvd.model.lie import _exp_so3, euler_R

if TYPE_CHECKING:  # the sample types are plain dataclasses; only their attributes are read
    from drivers.samples import DepthSample, DvlSample, InsSample

__all__ = ["NavConfig", "NavState", "NavMemory", "nav_init", "nav_step", "nav_set_position"]

_I3 = np.eye(3)


def _eye3() -> np.ndarray:
    return np.eye(3)


def _zeros3() -> np.ndarray:
    return np.zeros(3)


@dataclass(frozen=True)
class NavConfig:
    """Constant configuration of :func:`nav_step`.

    Attributes
    ----------
    ins_timeout_s, dvl_timeout_s, depth_timeout_s : float
        Largest age (s) of a source's latest usable sample for it to count as valid. The DVL
        one is also the longest time a lost bottom lock is bridged by holding the velocity.
    dvl_mount_R : (3, 3) ndarray
        Rotation DVL frame → body frame (identity: DVL axes along the body axes).
    dvl_lever_arm_m : (3,) ndarray
        Position of the DVL in the body frame, metres from the vehicle origin.
    min_good_beams : int
        Fewest good beams for a DVL sample to count as bottom lock (RDI 3-beam solution).
    derive_rates_min_dt_s : float
        Shortest attitude interval used to derive rates (shorter ones keep the previous ω).
    propagate_ins : bool
        Carry the INS attitude and rate to the cycle's time (module docstring). Off, the
        latest sample is reported as it is, however old.
    """

    ins_timeout_s: float = 0.1
    dvl_timeout_s: float = 1.0
    depth_timeout_s: float = 0.5
    dvl_mount_R: np.ndarray = field(default_factory=_eye3)
    dvl_lever_arm_m: np.ndarray = field(default_factory=_zeros3)
    min_good_beams: int = 3
    derive_rates_min_dt_s: float = 1e-3
    propagate_ins: bool = True

    def __post_init__(self):
        R = np.asarray(self.dvl_mount_R, dtype=float)
        r = np.asarray(self.dvl_lever_arm_m, dtype=float)
        if R.shape != (3, 3) or not np.allclose(R.T @ R, _I3, atol=1e-6) \
                or np.linalg.det(R) < 0.0:
            raise ValueError(f"NavConfig.dvl_mount_R must be a rotation matrix (3x3), got {R!r}")
        if r.shape != (3,) or not np.all(np.isfinite(r)):
            raise ValueError(f"NavConfig.dvl_lever_arm_m must be 3 finite numbers, got {r!r}")
        for name in ("ins_timeout_s", "dvl_timeout_s", "depth_timeout_s"):
            val = getattr(self, name)
            if not (val > 0.0 and math.isfinite(val)):
                raise ValueError(f"NavConfig.{name} must be a positive number, got {val!r}")
        object.__setattr__(self, "dvl_mount_R", R)
        object.__setattr__(self, "dvl_lever_arm_m", r)
        # derived constants (not fields), computed once
        has_arm = bool(np.any(r != 0.0))
        object.__setattr__(self, "_has_lever_arm", has_arm)
        object.__setattr__(self, "_mount_is_identity", bool(np.array_equal(R, _I3)) and not has_arm)
        # the constants of the compiled step in one array (_C_* of _step)
        object.__setattr__(self, "_kernel_cfg", np.array(
            [self.ins_timeout_s, self.dvl_timeout_s, self.depth_timeout_s,
             self.derive_rates_min_dt_s, *R.reshape(-1), *r, float(self._mount_is_identity),
             float(has_arm), float(bool(self.propagate_ins))], dtype=np.float64))

    @property
    def has_lever_arm(self) -> bool:
        """True when the DVL is not at the origin (ν then depends on ω)."""
        return self._has_lever_arm

    @property
    def mount_is_identity(self) -> bool:
        """True when the DVL frame is the body frame at the origin (ν = v_dvl)."""
        return self._mount_is_identity


class NavState(NamedTuple):
    """Navigation output of one cycle. Immutable (a named tuple: built every cycle, it costs a
    fraction of a frozen dataclass).

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

    __slots__ = ("f", "i")

    def __init__(self, f: np.ndarray, i: np.ndarray) -> None:
        # stored as the compiled step reads and writes it: ``f`` (float64, the numbers in the
        # order of _F_*) and ``i`` (int64, the stamps and flags of _I_*); the attributes above
        # are read from them
        self.f = f
        self.i = i

    def _stamp(self, k: int) -> int | None:
        return int(self.i[k]) if self.i[k + _I_HAS] else None

    def _vec(self, k: int, flag: int | None = None) -> np.ndarray | None:
        if flag is not None and not self.i[flag]:
            return None
        return self.f[k:k + 3].copy()

    t_ns = property(lambda self: self._stamp(_I_T))
    ins_t_ns = property(lambda self: self._stamp(_I_INS_T))
    dvl_t_ns = property(lambda self: self._stamp(_I_DVL_T))
    depth_t_ns = property(lambda self: self._stamp(_I_DEPTH_T))
    att_prev_t_ns = property(lambda self: self._stamp(_I_ATT_T))
    north_m = property(lambda self: float(self.f[_F_NORTH]))
    east_m = property(lambda self: float(self.f[_F_EAST]))
    depth_m = property(lambda self: float(self.f[_F_DEPTH]))
    R = property(lambda self: self.f[_F_R:_F_R + 9].reshape(3, 3).copy())
    omega = property(lambda self: self._vec(_F_OMEGA))
    nu = property(lambda self: self._vec(_F_NU))
    v_world_prev = property(lambda self: self._vec(_F_VW, _I_HAS_VW))
    att_prev_R = property(lambda self: None if not self.i[_I_HAS_ATT_R]
                          else self.f[_F_ATT_R:_F_ATT_R + 9].reshape(3, 3).copy())
    dvl_raw = property(lambda self: self._vec(_F_DVL_RAW, _I_HAS_DVL_RAW))
    omega_dot = property(lambda self: self._vec(_F_OMEGA_DOT))
    rates_degraded = property(lambda self: bool(self.i[_I_DEGRADED]))
    bottom_lock = property(lambda self: bool(self.i[_I_LOCK]))


# the layout of NavMemory's arrays: f (floats) and i (stamps, then whether each is set, flags)
_F_NORTH, _F_EAST, _F_DEPTH, _F_R, _F_OMEGA, _F_NU, _F_VW, _F_ATT_R, _F_DVL_RAW, _F_OMEGA_DOT = (
    0, 1, 2, 3, 12, 15, 18, 21, 30, 33)
_NF = 36
_I_T, _I_INS_T, _I_DVL_T, _I_DEPTH_T, _I_ATT_T = 0, 1, 2, 3, 4
_I_HAS = 5  # i[k + _I_HAS]: stamp k is set (not None)
_I_HAS_VW, _I_HAS_ATT_R, _I_HAS_DVL_RAW, _I_DEGRADED, _I_LOCK = 10, 11, 12, 13, 14
_NI = 15


def nav_init(cfg: NavConfig, north_m: float = 0.0, east_m: float = 0.0) -> NavMemory:
    """Initial memory: position (north_m, east_m), no sample seen, every source invalid."""
    f = np.zeros(_NF)
    f[_F_NORTH], f[_F_EAST] = float(north_m), float(east_m)
    f[_F_R:_F_R + 9] = _I3.reshape(-1)
    return NavMemory(f, np.zeros(_NI, dtype=np.int64))


def nav_set_position(mem: NavMemory, north_m: float, east_m: float) -> NavMemory:
    """Memory with the dead-reckoned position replaced by an external fix (north, east, m)."""
    f = mem.f.copy()
    f[_F_NORTH], f[_F_EAST] = float(north_m), float(east_m)
    return NavMemory(f, mem.i.copy())


# ------------------------------------------------------------------ the compiled step
# nav_step is one compiled call (_step) behind thin Python that reads the samples' fields;
# its helpers are the formulas of the module docstring (Euler → R is uvd.model.lie.euler_R,
# the DVL mounting drivers.frames.dvl_mount_to_body, compiled as they are).

_mount_to_body = numba.njit(cache=True)(dvl_mount_to_body)


@numba.njit(cache=True)
def _rotate(R, x):
    """R x for a 3×3 R."""
    y = np.empty(3)
    for i in range(3):
        y[i] = R[i, 0] * x[0] + R[i, 1] * x[1] + R[i, 2] * x[2]
    return y


@numba.njit(cache=True)
def _carry(R, omega, omega_dot, age):
    """(R(t), ω(t)) carried ``age`` seconds past the sample (R, ω) with ω(t) = ω + ω̇ t:
    R e^{J(φ)} with φ = ∫ω = (ω + ω̇ age/2) age (module docstring)."""
    phi = np.empty(3)
    w = np.empty(3)
    for i in range(3):
        phi[i] = (omega[i] + 0.5 * omega_dot[i] * age) * age
        w[i] = omega[i] + omega_dot[i] * age
    return R @ _exp_so3(phi), w


@numba.njit(cache=True)
def _log_so3_vee(R):
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


@numba.njit(cache=True)
def _finite3(a):
    return np.isfinite(a[0]) and np.isfinite(a[1]) and np.isfinite(a[2])


@numba.njit(cache=True)
def _age_s(t_ns, stamp, has):
    if not has:
        return np.inf
    d = t_ns - stamp
    return d * 1e-9 if d > 0 else 0.0


# _step is long (~150 lines) on purpose: its sources' rules share a dozen intermediate values;
# split into helpers they would be passed around for no gain in clarity (each rule is its own
# commented block, in the order of the module docstring).
@numba.njit(cache=True)
def _step(t_ns, mf, mi, f, i, H, v, ins_ok, roll, pitch, heading, w_ins, rates_valid, ins_tns,
          dvl_seen, dvl_lock, vb, dvl_tns, depth_ok, depth_val, depth_tns, cf):
    """One navigation cycle (:func:`nav_step`): reads the memory ``mf``, ``mi`` and writes the
    next into ``f``, ``i`` (NavMemory's arrays), the pose into ``H`` and ``v``; returns the
    ages, validities and flags of the NavState. ``cf``: :class:`NavConfig` as numbers (the
    timeouts, the shortest attitude interval, the DVL's mounting R and lever arm, whether
    the mounting is the identity, whether there is a lever arm, ``propagate_ins``)."""
    ins_timeout, dvl_timeout, depth_timeout, min_dt = cf[0], cf[1], cf[2], cf[3]
    mount_R = cf[4:13].reshape(3, 3)
    lever = cf[13:16]
    mount_identity, has_lever_arm, propagate = cf[16] != 0.0, cf[17] != 0.0, cf[18] != 0.0
    f[:] = mf
    i[:] = mi
    R = mf[_F_R:_F_R + 9].reshape(3, 3).copy()
    omega = mf[_F_OMEGA:_F_OMEGA + 3].copy()
    rates_degraded = mi[_I_DEGRADED] != 0
    omega_changed = False
    has_ins_t = mi[_I_HAS + _I_INS_T] != 0
    ins_t = mi[_I_INS_T]

    # --- INS: attitude and rates ------------------------------------------------------------
    if ins_ok and np.isfinite(roll) and np.isfinite(pitch) and np.isfinite(heading):
        R_new = euler_R(roll, pitch, heading)
        if _finite3(w_ins):
            # the rate's slope from the previous measured rate, for carrying it forward
            gap_s = (ins_tns - ins_t) * 1e-9 if has_ins_t else 0.0
            if not rates_degraded and rates_valid and min_dt <= gap_s <= ins_timeout:
                for k in range(3):
                    f[_F_OMEGA_DOT + k] = (w_ins[k] - omega[k]) / gap_s
            else:
                f[_F_OMEGA_DOT:_F_OMEGA_DOT + 3] = 0.0
            for k in range(3):
                omega[k] = w_ins[k]
            omega_changed = True
            rates_degraded = not rates_valid
        else:
            rates_degraded = True
            f[_F_OMEGA_DOT:_F_OMEGA_DOT + 3] = 0.0
            if mi[_I_HAS_ATT_R] != 0 and mi[_I_HAS + _I_ATT_T] != 0:
                dt = (ins_tns - mi[_I_ATT_T]) * 1e-9
                if dt >= min_dt:
                    att_prev_R = mf[_F_ATT_R:_F_ATT_R + 9].reshape(3, 3).copy()
                    omega = _log_so3_vee(att_prev_R.T @ R_new) / dt
                    omega_changed = True
        R = R_new
        f[_F_ATT_R:_F_ATT_R + 9] = R_new.reshape(9)
        i[_I_HAS_ATT_R] = 1
        i[_I_ATT_T], i[_I_HAS + _I_ATT_T] = ins_tns, 1
        ins_t, has_ins_t = ins_tns, True
        i[_I_INS_T], i[_I_HAS + _I_INS_T] = ins_tns, 1
    f[_F_R:_F_R + 9] = R.reshape(9)
    f[_F_OMEGA:_F_OMEGA + 3] = omega

    # --- DVL: body velocity of the origin ---------------------------------------------------
    new_dvl = False
    bottom_lock = mi[_I_LOCK] != 0
    if dvl_seen:
        locked = dvl_lock and _finite3(vb)
        bottom_lock = locked
        if locked:
            f[_F_DVL_RAW:_F_DVL_RAW + 3] = vb[:3]
            i[_I_HAS_DVL_RAW] = 1
            i[_I_DVL_T], i[_I_HAS + _I_DVL_T] = dvl_tns, 1
            new_dvl = True
    if i[_I_HAS_DVL_RAW] != 0 and (new_dvl or (omega_changed and has_lever_arm)):
        # re-applied when ω changes so the lever-arm term uses the latest rate
        if mount_identity:
            f[_F_NU:_F_NU + 3] = f[_F_DVL_RAW:_F_DVL_RAW + 3]
        else:
            f[_F_NU:_F_NU + 3] = _mount_to_body(mount_R, lever,
                                                f[_F_DVL_RAW:_F_DVL_RAW + 3], omega)
    nu = f[_F_NU:_F_NU + 3]

    # --- depth --------------------------------------------------------------------------------
    if depth_ok and np.isfinite(depth_val):
        f[_F_DEPTH] = depth_val
        i[_I_DEPTH_T], i[_I_HAS + _I_DEPTH_T] = depth_tns, 1

    # --- ages and validity -----------------------------------------------------------------
    dvl_t = i[_I_DVL_T]
    ins_age = _age_s(t_ns, ins_t, has_ins_t)
    dvl_age = _age_s(t_ns, dvl_t, i[_I_HAS + _I_DVL_T] != 0)
    depth_age = _age_s(t_ns, i[_I_DEPTH_T], i[_I_HAS + _I_DEPTH_T] != 0)
    ins_valid = ins_age <= ins_timeout
    dvl_valid = dvl_age <= dvl_timeout
    depth_valid = depth_age <= depth_timeout

    # --- dead reckoning (DVLNAV): each DVL sample's world velocity, held until the next ------
    north, east = mf[_F_NORTH], mf[_F_EAST]
    hold = dvl_valid and mi[_I_HAS_VW] != 0
    has_t_prev = mi[_I_HAS + _I_T] != 0
    t_prev = mi[_I_T]
    if new_dvl and dvl_valid:
        # rotated once, with the attitude at the sample's own time: the INS attitude propagated
        # by its body rate over the (< one INS period) gap, R(t_dvl) ≈ R(t_ins) e^{J(ω)Δt}
        R_dvl = R
        if has_ins_t and dvl_t != ins_t and _finite3(omega):
            gap_s = (dvl_t - ins_t) * 1e-9
            if abs(gap_s) <= ins_timeout:
                phi = np.empty(3)
                for k in range(3):
                    phi[k] = omega[k] * gap_s
                R_dvl = R @ _exp_so3(phi)
        v_new = _rotate(R_dvl, nu)
        if has_t_prev and t_ns > t_prev:
            t_split = min(max(dvl_t, t_prev), t_ns)  # the old velocity holds until the sample
            if hold:
                north += mf[_F_VW] * (t_split - t_prev) * 1e-9
                east += mf[_F_VW + 1] * (t_split - t_prev) * 1e-9
            north += v_new[0] * (t_ns - t_split) * 1e-9
            east += v_new[1] * (t_ns - t_split) * 1e-9
        f[_F_VW:_F_VW + 3] = v_new
        hold = True
    elif hold and has_t_prev and t_ns > t_prev:
        north += mf[_F_VW] * (t_ns - t_prev) * 1e-9
        east += mf[_F_VW + 1] * (t_ns - t_prev) * 1e-9
    i[_I_HAS_VW] = 1 if hold else 0
    f[_F_NORTH], f[_F_EAST] = north, east

    if propagate and ins_valid and ins_age > 0.0 and not rates_degraded:
        R_now, omega_now = _carry(R, omega, f[_F_OMEGA_DOT:_F_OMEGA_DOT + 3], ins_age)
    else:
        R_now, omega_now = R, omega
    # H = [[R, p], [0, 1]] with p = (north, east, depth), and v = [ν; ω]
    for r in range(3):
        for c in range(3):
            H[r, c] = R_now[r, c]
        H[3, r] = 0.0
        v[r] = nu[r]
        v[3 + r] = omega_now[r]
    H[0, 3], H[1, 3], H[2, 3], H[3, 3] = north, east, f[_F_DEPTH], 1.0

    i[_I_T], i[_I_HAS + _I_T] = t_ns, 1
    i[_I_DEGRADED] = 1 if rates_degraded else 0
    i[_I_LOCK] = 1 if bottom_lock else 0
    return (ins_age, dvl_age, depth_age, ins_valid, dvl_valid, depth_valid, rates_degraded,
            bottom_lock)


_F64 = np.dtype(np.float64)
_NAN3 = np.full(3, np.nan)


def _vec3(w) -> np.ndarray:
    """``w`` as a writable contiguous float64 array of at least three entries (the first three
    are read): the one array type the compiled step is specialised for."""
    if type(w) is np.ndarray and w.dtype == _F64 and w.ndim == 1 and w.shape[0] >= 3 \
            and w.flags.c_contiguous and w.flags.writeable:
        return w
    return np.array([float(w[0]), float(w[1]), float(w[2])])


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
    t_ns = int(t_ns)
    if ins is not None and ins.valid:
        ins_args = (True, float(ins.roll), float(ins.pitch), float(ins.heading),
                    _vec3(ins.omega_body), bool(ins.rates_valid), int(ins.t_ns))
    else:
        ins_args = (False, 0.0, 0.0, 0.0, _NAN3, False, 0)
    if dvl is not None:
        lock = bool(dvl.bottom_lock) and dvl.good_beams >= cfg.min_good_beams
        dvl_args = (True, lock, _vec3(dvl.velocity_body) if lock else _NAN3, int(dvl.t_ns))
    else:
        dvl_args = (False, False, _NAN3, 0)
    if depth is not None and depth.valid:
        depth_args = (True, float(depth.depth_m), int(depth.t_ns))
    else:
        depth_args = (False, 0.0, 0)
    f, i = np.empty(_NF), np.empty(_NI, dtype=np.int64)
    H, v = np.empty((4, 4)), np.empty(6)
    ins_age, dvl_age, depth_age, ins_valid, dvl_valid, depth_valid, degraded, lock = _step(
        t_ns, mem.f, mem.i, f, i, H, v, *ins_args, *dvl_args, *depth_args, cfg._kernel_cfg)
    state = NavState(t_ns, H, v, ins_valid and dvl_valid and depth_valid, ins_valid, dvl_valid,
                     depth_valid, ins_age, dvl_age, depth_age, degraded, lock)
    return state, NavMemory(f, i)
