"""Another system's recording → :class:`~uvd.estimation.runlog.RunLog` (per uninterrupted
stretch), through a log profile (:mod:`uvd.io.logprofile`) and a vehicle file's thrusters.

Steps, each counted in :class:`LogReport`:

1. **Read** the profile's topics (:func:`uvd.io.logs.open_log`); a topic the profile names that
   has no message is a :class:`~uvd.errors.LogReadError` naming file, topic and signal.
2. **Clean** each signal on its own time stamps: samples whose stamp is not a time (not a
   finite number, or beyond 64-bit nanoseconds: a corrupted file's), samples with a non-finite
   component, repeated stamps (duplicates) and samples out of order (the fewest whose removal
   leaves the stamps increasing: one stamp corrupted far ahead costs that sample only) are
   dropped and counted; intervals longer than ``max_gap_s`` are counted as gaps.
3. **Units and frames** to ours (SI, body FRD, world NED), each flip in one named function
   (:func:`flu_to_frd`, :func:`enu_to_ned`, :func:`attitude_to_ned_frd`); values implausible for
   the stated unit are a :class:`~uvd.errors.LogReadError` ("wrong unit?").
4. **One clock**: a grid at ``rate_hz``; every signal brought onto it by the profile's rule —
   ``hold`` (the last sample at or before the grid time) or ``interpolate`` (linear between
   the samples either side; Euler angles unwrapped first). A grid time where a signal has no
   sample within ``max_gap_s`` (before it for hold, on both sides for interpolate) is not
   filled: the run is cut there, and stretches shorter than ``min_stretch_s`` are dropped and
   counted. Nothing is invented across a gap.
5. **Thrust**: commands → thrust through each thruster's curve (vehicle file) → body wrench
   u = B f.

The runs carry ν = 0 when the profile has no linear velocity: ``has_linear_velocity`` in
:class:`LogReport` says so, and identification refuses the translational DOFs.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from uvd.errors import LogReadError
from uvd.estimation.runlog import RunLog
from uvd.io.logprofile import LogProfile, SignalSpec
from uvd.io.logs import open_log

__all__ = ["LogReport", "SignalStats", "read_signals", "runs_from_log", "flu_to_frd",
           "enu_to_ned", "attitude_to_ned_frd", "clean_signal", "load_log_runs"]

_TIME_SCALE = {"s": 1e9, "ms": 1e6, "us": 1e3, "ns": 1.0}
# plausible magnitude of a value in each unit (a gyro's 2000 °/s range, angles, PWM 500–2500 µs)
_PLAUSIBLE = {"rad/s": 40.0, "deg/s": 2500.0, "rad": 2 * math.pi * 1.001, "deg": 360.5,
              "normalised": 1.5}


@dataclass
class SignalStats:
    """What happened to one signal of one file."""

    topic: str
    messages: int = 0
    bad_time: int = 0
    non_finite: int = 0
    out_of_order: int = 0
    duplicates: int = 0
    gaps: int = 0
    kept: int = 0
    rate_hz: float = 0.0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class LogReport:
    """Counts of one file's conversion (see the module docstring)."""

    path: str
    profile: str
    signals: dict = field(default_factory=dict)
    stretches: list = field(default_factory=list)
    dropped_stretches: int = 0
    grid_points: int = 0
    grid_points_cut: int = 0
    has_linear_velocity: bool = False
    rule: str = "hold"
    rate_hz: float = 0.0

    def as_dict(self) -> dict:
        d = dict(self.__dict__)
        d["signals"] = {k: v.as_dict() for k, v in self.signals.items()}
        return d

    def text(self) -> str:
        lines = [f"{self.path}: profile {self.profile}, {self.rule} onto {self.rate_hz:g} Hz"]
        for name, s in self.signals.items():
            lines.append(f"  {name:16s} {s.topic:32s} {s.messages:6d} msgs ~{s.rate_hz:6.1f} Hz;"
                         f" dropped: {s.bad_time} without a time, {s.non_finite} non-finite,"
                         f" {s.out_of_order} out of order,"
                         f" {s.duplicates} duplicates; {s.gaps} gaps > max_gap_s")
        kept = sum(n for _a, n in self.stretches)
        lines.append(f"  {len(self.stretches)} stretch(es), {kept} samples kept; "
                     f"{self.grid_points_cut} grid points cut (a signal older than max_gap_s), "
                     f"{self.dropped_stretches} short stretch(es) dropped")
        return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# frames (every sign flip between another system's convention and ours, named and tested)
# ---------------------------------------------------------------------------------------------
def flu_to_frd(x: np.ndarray) -> np.ndarray:
    """Body vectors from ROS's x-forward, y-left, z-up (REP 103) to x-forward, y-starboard,
    z-down (ours, ArduPilot's): (x, −y, −z). Shape (..., 3)."""
    x = np.asarray(x, dtype=float)
    return x * np.array([1.0, -1.0, -1.0])


def enu_to_ned(x: np.ndarray) -> np.ndarray:
    """World vectors from east-north-up (ROS) to north-east-down (ours): (y, x, −z)."""
    x = np.asarray(x, dtype=float)
    return np.stack([x[..., 1], x[..., 0], -x[..., 2]], axis=-1)


def _euler_R(roll, pitch, yaw) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll), vectorised over samples: (n, 3, 3)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    ch, sh = np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([ch * cp, ch * sp * sr - sh * cr, ch * sp * cr + sh * sr], -1),
                     np.stack([sh * cp, sh * sp * sr + ch * cr, sh * sp * cr - ch * sr], -1),
                     np.stack([-sp, cp * sr, cp * cr], -1)], axis=-2)


_T_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_F_FLU_FRD = np.diag([1.0, -1.0, -1.0])


def attitude_to_ned_frd(euler: np.ndarray, frame: str) -> np.ndarray:
    """Body → world rotations (n, 3, 3), world NED and body FRD, from ZYX Euler angles (rad).

    ``frame`` "ned": the angles are of an FRD body in NED (ArduPilot, the 2016 BlueROV's EKF).
    "enu": of an FLU body in ENU (ROS REP 103): R_ned_frd = T R_enu_flu F with T the ENU→NED
    swap and F = diag(1, −1, −1) (FRD → FLU).
    """
    e = np.asarray(euler, dtype=float)
    R = _euler_R(e[:, 0], e[:, 1], e[:, 2])
    if frame == "ned":
        return R
    if frame == "enu":
        return _T_ENU_NED @ R @ _F_FLU_FRD
    raise ValueError(f"attitude frame must be 'ned' or 'enu', got {frame!r}")


# ---------------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------------
def _value(msg, spec: SignalSpec, path: Path) -> np.ndarray:
    def attr(obj, name):
        for part in name.split("."):
            if not hasattr(obj, part):
                raise LogReadError(f"{path}: topic {spec.topic}: no field {name!r} (signal "
                                   f"{spec.name})")
            obj = getattr(obj, part)
        return obj

    if spec.fields is not None:
        return np.array([float(attr(msg, f)) for f in spec.fields])
    v = attr(msg, spec.field)
    if spec.index is None:
        return np.atleast_1d(np.asarray(v, dtype=float)).reshape(-1)[:1]
    arr = np.asarray(v, dtype=float).reshape(-1)
    if max(spec.index) >= arr.size:
        raise LogReadError(f"{path}: topic {spec.topic}: field {spec.field!r} has {arr.size} "
                           f"element(s), the profile's signal {spec.name} reads index "
                           f"{max(spec.index)}")
    return arr[list(spec.index)]


#: the time stamps uvd can hold: int64 nanoseconds
_T_MIN, _T_MAX = -(2 ** 63), 2 ** 63 - 1


def read_signals(path: str | Path, profile: LogProfile,
                 stats: dict[str, SignalStats] | None = None
                 ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every profile signal of one file as (t_ns (n,), raw values (n, k)) in file order,
    before any cleaning but for the samples whose stamp is not a time (none, not finite, or
    beyond int64 nanoseconds: a corrupted file's), which are left out and counted in
    ``stats[name].bad_time`` when ``stats`` is given; raises :class:`LogReadError` for a
    missing topic or field."""
    path = Path(path)
    by_topic: dict[str, list[SignalSpec]] = {}
    for s in profile.signals.values():
        by_topic.setdefault(s.topic, []).append(s)
    ts: dict[str, list] = {k: [] for k in profile.signals}
    xs: dict[str, list] = {k: [] for k in profile.signals}
    field_time = profile.time[6:] if profile.time.startswith("field:") else None
    tscale = _TIME_SCALE[profile.time_unit]
    bad_time = dict.fromkeys(profile.signals, 0)
    for topic, t_ns, msg in open_log(path, profile.format, topics=by_topic):
        if field_time is not None:
            if not hasattr(msg, field_time):
                raise LogReadError(f"{path}: topic {topic}: no time field {field_time!r}")
            t = float(getattr(msg, field_time)) * tscale
            t_ns = int(round(t)) if math.isfinite(t) else None
        timed = t_ns is not None and _T_MIN <= t_ns <= _T_MAX
        for s in by_topic.get(topic, ()):
            if s.match and any(getattr(msg, k, None) != v for k, v in s.match):
                continue
            if not timed:
                bad_time[s.name] += 1
                continue
            ts[s.name].append(t_ns)
            xs[s.name].append(_value(msg, s, path))
    if stats is not None:
        for name, n in bad_time.items():
            stats[name].bad_time = n
    for name, s in profile.signals.items():
        if not ts[name]:
            why = (f"{bad_time[name]} message(s), none with a time stamp" if bad_time[name]
                   else "no messages")
            raise LogReadError(f"{path}: topic {s.topic}: {why} (the profile's signal "
                               f"{name}); check the profile {profile.name!r} against the "
                               f"file's topics")
    return {k: (np.asarray(ts[k], dtype=np.int64), np.vstack(xs[k])) for k in ts}


def _in_time_order(t_ns: np.ndarray) -> np.ndarray:
    """The samples to keep so that the stamps strictly increase, dropping as few as possible:
    a longest strictly increasing subsequence, of all those the one of the earliest samples
    (so the earliest of equal stamps). Where the stamps never go back this keeps the first
    sample of each stamp; where one stamp jumps far ahead (a corrupted time field) it drops
    that one sample, not every sample after it (as "older than the newest seen" would).
    O(n log n): the longest run starting at each sample, then the earliest samples greedily."""
    t = t_ns.tolist()
    n = len(t)
    longest = [0] * n              # longest[i]: the longest increasing run starting at sample i
    tails: list[int] = []          # over the samples after i: -(the largest first stamp) of
    for i in range(n - 1, -1, -1):  # a run of each length
        k = bisect.bisect_left(tails, -t[i])
        longest[i] = k + 1
        if k == len(tails):
            tails.append(-t[i])
        else:
            tails[k] = -t[i]
    keep = np.zeros(n, dtype=bool)
    need, last = len(tails), None
    for i in range(n):
        if need and longest[i] == need and (last is None or t[i] > last):
            keep[i], need, last = True, need - 1, t[i]
    return keep


def clean_signal(t_ns: np.ndarray, x: np.ndarray, stats: SignalStats, max_gap_s: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Drop (and count in ``stats``) non-finite samples, duplicates (a stamp kept already)
    and samples out of order: the fewest whose removal leaves the stamps increasing
    (:func:`_in_time_order`); count gaps > ``max_gap_s``. ``stats.messages`` counts as well
    the samples :func:`read_signals` left out for their stamp (``stats.bad_time``)."""
    stats.messages = int(t_ns.size) + stats.bad_time
    finite = np.all(np.isfinite(x), axis=1)
    stats.non_finite = int(np.count_nonzero(~finite))
    t_ns, x = t_ns[finite], x[finite]
    keep = np.ones(t_ns.size, dtype=bool)
    if t_ns.size:
        prev_max = np.maximum.accumulate(t_ns)
        older = np.zeros(t_ns.size, dtype=bool)
        older[1:] = t_ns[1:] < prev_max[:-1]
        if older.any():            # the stamps go back somewhere: the longest run in order
            keep = _in_time_order(t_ns)
        else:                      # never back (every real recording here): first of each
            keep[1:] = t_ns[1:] != prev_max[:-1]
        dup = ~keep & np.isin(t_ns, t_ns[keep])
        stats.duplicates = int(np.count_nonzero(dup))
        stats.out_of_order = int(np.count_nonzero(~keep & ~dup))
    t_ns, x = t_ns[keep], x[keep]
    stats.kept = int(t_ns.size)
    if t_ns.size > 1:
        d = np.diff(t_ns) * 1e-9
        stats.gaps = int(np.count_nonzero(d > max_gap_s))
        stats.rate_hz = float((t_ns.size - 1) / ((t_ns[-1] - t_ns[0]) * 1e-9))
    return t_ns, x


def _check_unit(spec: SignalSpec, x: np.ndarray, path: Path) -> None:
    if x.size == 0:
        return
    ax = np.abs(x)
    if spec.unit == "pwm_us":
        med = float(np.median(ax))
        if med < 100.0:
            raise LogReadError(f"{path}: topic {spec.topic}: signal {spec.name} says unit "
                               f"pwm_us but its median magnitude is {med:.3g} (wrong unit? "
                               "normalised commands are unit 'normalised')")
        return
    lim = _PLAUSIBLE.get(spec.unit)
    if lim is not None:
        frac = float(np.mean(ax > lim))
        if frac > 0.01:
            raise LogReadError(f"{path}: topic {spec.topic}: signal {spec.name} says unit "
                               f"{spec.unit} but {100 * frac:.1f} % of its values exceed "
                               f"{lim:.4g} (max {float(ax.max()):.4g}): wrong unit?")


def _to_si(spec: SignalSpec, x: np.ndarray) -> np.ndarray:
    """Unit, scale/offset and frame of one signal → SI, body FRD / world NED."""
    x = x * spec.scale + spec.offset
    if spec.unit in ("deg/s", "deg"):
        x = np.deg2rad(x)
    elif spec.unit in ("hPa", "mbar"):
        x = x * 100.0
    elif spec.unit == "mm/s":
        x = x * 1e-3
    elif spec.unit == "cm/s":
        x = x * 1e-2
    if spec.name == "depth":
        if spec.unit != "m":
            x = (x - spec.reference_pa) / (spec.density_kg_m3 * spec.gravity_m_s2)
        if spec.frame == "up":
            x = -x
    elif spec.name in ("angular_rate", "linear_velocity"):
        if spec.frame == "flu":
            x = flu_to_frd(x)
        elif spec.frame == "enu":
            x = enu_to_ned(x)
    return x


# ---------------------------------------------------------------------------------------------
# one clock
# ---------------------------------------------------------------------------------------------
def _onto_grid(t: np.ndarray, x: np.ndarray, grid: np.ndarray, rule: str, max_gap_ns: float,
               angles: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Values at ``grid`` (ns) by ``rule`` and a mask of the grid points it could fill."""
    i = np.searchsorted(t, grid, side="right") - 1  # last sample at or before
    ok = i >= 0
    ic = np.clip(i, 0, t.size - 1)
    if rule == "hold":
        ok &= (grid - t[ic]) <= max_gap_ns
        return x[ic], ok
    j = np.clip(ic + 1, 0, t.size - 1)
    exact = t[ic] == grid
    ok &= exact | ((j > ic) & ((t[j] - t[ic]) <= max_gap_ns))
    xx = np.unwrap(x, axis=0) if angles else x
    span = np.where(j > ic, (t[j] - t[ic]).astype(float), 1.0)
    w = np.clip((grid - t[ic]) / span, 0.0, 1.0)[:, None]
    out = xx[ic] * (1 - w) + xx[j] * w
    return out, ok


def _stretches(ok: np.ndarray) -> list[tuple[int, int]]:
    """(start, length) of the runs of True in ``ok``."""
    d = np.diff(np.concatenate(([0], ok.astype(np.int8), [0])))
    starts = np.flatnonzero(d == 1)
    stops = np.flatnonzero(d == -1)
    return [(int(a), int(b - a)) for a, b in zip(starts, stops, strict=True)]


def runs_from_log(path: str | Path, profile: LogProfile, vehicle, *,
                  min_stretch_s: float = 2.0) -> tuple[list[RunLog], LogReport]:
    """The uninterrupted stretches of one recording as runs, and the report of what was
    dropped (module docstring). ``vehicle`` supplies the thrust curves and B."""
    path = Path(path)
    stats = {name: SignalStats(topic=spec.topic) for name, spec in profile.signals.items()}
    raw = read_signals(path, profile, stats)
    rep = LogReport(path=str(path), profile=profile.name, rule=profile.resample,
                    rate_hz=profile.rate_hz,
                    has_linear_velocity="linear_velocity" in profile.signals)
    sig = {}
    for name, (t, x) in raw.items():
        spec = profile.signals[name]
        st = stats[name]
        t, x = clean_signal(t, x, st, profile.max_gap_s)
        rep.signals[name] = st
        if t.size == 0:
            raise LogReadError(f"{path}: topic {spec.topic}: no usable sample of signal {name} "
                               f"({st.non_finite} non-finite)")
        _check_unit(spec, x, path)
        sig[name] = (t, _to_si(spec, x))
    cmd_spec = profile.signals["thrusters"]
    if cmd_spec.width != vehicle.n_thrusters:
        raise LogReadError(f"{path}: topic {cmd_spec.topic}: the profile reads "
                           f"{cmd_spec.width} thruster commands, vehicle {vehicle.name!r} has "
                           f"{vehicle.n_thrusters} thrusters")
    for s in vehicle.thrusters:
        if s.curve is None:
            raise LogReadError(f"vehicle {vehicle.name!r}: thruster {s.name!r} has no thrust "
                               "curve; the vehicle file must give one (curve = ...)")
        if s.curve.unit != cmd_spec.unit:
            raise LogReadError(f"{path}: topic {cmd_spec.topic}: commands in {cmd_spec.unit}, "
                               f"thruster {s.name!r}'s curve takes {s.curve.unit}")
    t0 = max(t[0] for t, _x in sig.values())
    t1 = min(t[-1] for t, _x in sig.values())
    if profile.span == "thrusters":
        tc = sig["thrusters"][0]
        t0, t1 = max(t0, tc[0]), min(t1, tc[-1])
    period = int(round(1e9 / profile.rate_hz))
    if t1 - t0 < period:
        raise LogReadError(f"{path}: the signals overlap for {max(0, t1 - t0) * 1e-9:.3g} s only")
    grid = np.arange(t0, t1 + 1, period, dtype=np.int64)
    gap = profile.max_gap_s * 1e9
    on = {}
    ok = np.ones(grid.size, dtype=bool)
    for name, (t, x) in sig.items():
        rule = "hold" if name == "thrusters" else profile.resample  # commands are held
        v, m = _onto_grid(t, x, grid, rule, gap, angles=name == "attitude")
        on[name] = v
        ok &= m
    rep.grid_points = int(grid.size)
    rep.grid_points_cut = int(np.count_nonzero(~ok))
    R_all = attitude_to_ned_frd(on["attitude"], profile.signals["attitude"].frame)
    from uvd.model.thrusters import thrust_from_commands
    u_all = thrust_from_commands(vehicle.thrusters, on["thrusters"]) @ vehicle.B.T
    nu_all = np.zeros((grid.size, 3))
    if "linear_velocity" in on:
        lv = on["linear_velocity"]
        if profile.signals["linear_velocity"].frame in ("ned", "enu"):  # world → body
            lv = np.einsum("nji,nj->ni", R_all, lv)
        nu_all = lv
    depth = on["depth"][:, 0] if "depth" in on else np.zeros(grid.size)
    runs = []
    min_n = max(2, int(round(min_stretch_s * profile.rate_hz)))
    for a, n in _stretches(ok):
        if n < min_n:
            rep.dropped_stretches += 1
            continue
        sl = slice(a, a + n)
        p = np.zeros((n, 3))
        p[:, 2] = depth[sl]
        v = np.hstack([nu_all[sl], on["angular_rate"][sl]])
        runs.append(RunLog(t=np.arange(n) / profile.rate_hz, R=R_all[sl], p=p, v=v,
                           u=u_all[sl], name=f"{path.stem}" + (f"#{len(runs)}" if runs else ""),
                           input_interp="linear",
                           source=f"{profile.format or 'log'} {path} (profile {profile.name})",
                           extra={"t0_ns": int(grid[a]), "has_linear_velocity":
                                  rep.has_linear_velocity}))
        rep.stretches.append((a, n))
    if not runs:
        raise LogReadError(f"{path}: no stretch of at least {min_stretch_s:g} s where every "
                           f"signal has a sample within max_gap_s = {profile.max_gap_s:g} s")
    return runs, rep

def load_log_runs(paths, profile, vehicle, *, quiet: bool = False):
    """(runs, reports) of every file; progress per file on long inputs."""
    from uvd.progress import Progress

    runs, reports = [], []
    with Progress("reading logs", unit="files", quiet=quiet) as pr:
        for i, path in enumerate(paths):
            r, rep = runs_from_log(path, profile, vehicle)
            runs.extend(r)
            reports.append(rep)
            pr.update(i + 1, len(paths))
    return runs, reports

