"""A recorded run as the identification tools read it: (t, R, p, v, u) per control cycle.

This is the interface between recordings and :mod:`uvd.estimation.ls` /
:mod:`uvd.estimation.xval` / ``uvd identify`` / ``uvd xval``. Until the black-box recorder
exists, runs come from the lockstep experiments (``uvd experiment aid-6dof --plots DIR`` writes
``DIR/<dataset>-run.npz``), from :meth:`RunLog.from_lockstep` on a
:class:`uvd.lockstep.LockstepLog`, or from the JSON-lines telemetry of ``uvd run``
on a vehicle or ``sim-bridge``. The files are read and written by :mod:`uvd.io.runlog`
(:func:`~uvd.io.runlog.save_runlog`, :func:`~uvd.io.runlog.load_runlog`, which tells the two
file kinds apart, :func:`~uvd.io.runlog.runlog_from_telemetry`); this module does no I/O.

File format (``.npz``, numpy's zip of arrays; see ``docs/experiments-identification.md``):

==============  ===========  =====================================================================
key             shape        meaning
==============  ===========  =====================================================================
``t``           (n,)         sample times (s), uniformly spaced (the control period)
``R``           (n, 3, 3)    measured attitude, body → world (NED)
``p``           (n, 3)       measured position, world (m)
``v``           (n, 6)       measured body velocity [ν; ω] (m/s, rad/s)
``u``           (n, 6)       applied body wrench [f; τ] (N, N m), see ``input_interp``
``meta``        ()           JSON text: ``name``, ``input_interp``, free-form ``source``
``R_true`` …    optional     ``R_true``, ``v_true``: the plant's true state (simulation only)
==============  ===========  =====================================================================

``input_interp`` says how u relates to the intervals: ``"linear"`` — u[k] is the instantaneous
wrench at t[k] (from measured propeller speeds, App. A.1; the core's ``u_applied``);
``"hold"`` — u[k] was held over [t[k−1], t[k]] (ideal actuators driven by the previous command).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from uvd.errors import ConfigError

_INTERP = ("linear", "hold")


@dataclass(frozen=True)
class RunLog:
    """One recorded run; arrays are per control cycle (see the module docstring)."""

    t: np.ndarray
    R: np.ndarray
    p: np.ndarray
    v: np.ndarray
    u: np.ndarray
    name: str = "run"
    input_interp: str = "linear"
    source: str = ""
    R_true: np.ndarray | None = None
    v_true: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for key in ("name", "source"):
            if not isinstance(getattr(self, key), str):
                raise ConfigError(f"run {self.name!r}: {key} must be a string, got "
                                  f"{getattr(self, key)!r}")
        t = self._numbers("t", self.t)
        if t.ndim != 1:
            raise ConfigError(f"run {self.name!r}: t must hold one time stamp a sample (1-D), "
                              f"got shape {t.shape}")
        if not np.all(np.isfinite(t)):
            raise ConfigError(f"run {self.name!r}: t has non-finite entries")
        n = t.shape[0]
        shapes = {"R": (n, 3, 3), "p": (n, 3), "v": (n, 6), "u": (n, 6),
                  "R_true": (n, 3, 3), "v_true": (n, 6)}
        for key, shape in shapes.items():
            if getattr(self, key) is None:  # R_true, v_true: only a simulated run has them
                continue
            arr = self._numbers(key, getattr(self, key))
            if arr.shape != shape:
                raise ConfigError(f"run {self.name!r}: {key} has shape {arr.shape}, "
                                  f"expected {shape}")
            if not np.all(np.isfinite(arr)):
                raise ConfigError(f"run {self.name!r}: {key} has non-finite entries")
            if key not in ("R_true", "v_true"):  # the truth is kept as given
                object.__setattr__(self, key, arr)
        object.__setattr__(self, "t", t)
        if n < 2:
            raise ConfigError(f"run {self.name!r}: needs at least 2 samples, got {n}")
        dts = np.diff(t)
        if not np.all(dts > 0):
            raise ConfigError(f"run {self.name!r}: time stamps must increase")
        if np.max(np.abs(dts - dts.mean())) > 1e-6 * max(1.0, dts.mean()) + 1e-9:
            raise ConfigError(f"run {self.name!r}: samples must be uniformly spaced "
                              f"(period {dts.min():.6g}…{dts.max():.6g} s)")
        if self.input_interp not in _INTERP:
            raise ConfigError(f"run {self.name!r}: input_interp must be one of {_INTERP}, "
                              f"got {self.input_interp!r}")

    def _numbers(self, key: str, value) -> np.ndarray:
        """``value`` as a float array; an array of booleans, texts or objects is refused."""
        arr = np.asarray(value)
        if arr.dtype.kind not in "iuf":
            raise ConfigError(f"run {self.name!r}: {key} must hold numbers, got an array of "
                              f"{arr.dtype}")
        return np.asarray(arr, dtype=float)

    @property
    def dt(self) -> float:
        return float((self.t[-1] - self.t[0]) / (len(self.t) - 1))

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def H(self) -> np.ndarray:
        """(n, 4, 4) measured poses."""
        n = len(self)
        H = np.zeros((n, 4, 4))
        H[:, :3, :3] = self.R
        H[:, :3, 3] = self.p
        H[:, 3, 3] = 1.0
        return H

    def slice(self, start: int, stop: int | None = None) -> RunLog:
        sl = slice(start, stop)
        return RunLog(t=self.t[sl], R=self.R[sl], p=self.p[sl], v=self.v[sl], u=self.u[sl],
                      name=self.name, input_interp=self.input_interp, source=self.source,
                      R_true=None if self.R_true is None else self.R_true[sl],
                      v_true=None if self.v_true is None else self.v_true[sl])

    def stretch_note(self) -> str:
        """What :func:`uvd.io.runlog.runlog_from_telemetry` kept, when it had to cut the run,
        and a recorded run's file missing from its folder ("" otherwise)."""
        segs = self.extra.get("segments") or []
        bad = self.extra.get("bad_lines", 0)
        parts = []
        if len(segs) > 1:
            parts.append(f"{len(segs)} uninterrupted stretches (cut where samples are "
                         f"missing or a run restarts); using the longest, {len(self)} of "
                         f"{sum(n for _, n in segs)} samples")
        if bad:
            parts.append(f"{bad} unreadable line(s) skipped")
        if self.extra.get("missing_file"):  # a black-box run's (uvd.telemetry.recording)
            parts.append(self.extra["missing_file"])
        return "; ".join(parts)

    @classmethod
    def from_lockstep(cls, log, name: str = "lockstep", input_interp: str = "linear") -> RunLog:
        """From the lockstep runner's own :class:`LockstepLog` (true state, ``u_applied``).

        The lockstep log records the plant's *true* pose and velocity, so the run is noise-free
        in its states; ``u_applied`` is the wrench the core's estimators saw.
        """
        from uvd.geometry import euler_to_R

        eta = np.asarray(log.eta, dtype=float)
        R = np.stack([euler_to_R(*e[3:]) for e in eta])
        return cls(t=log.t, R=R, p=eta[:, :3], v=log.v, u=log.u_applied, name=name,
                   input_interp=input_interp, source="LockstepLog (true states)")
