"""A recorded run as the identification tools read it: (t, R, p, v, u) per control cycle.

This is the interface between recordings and :mod:`uvd.estimation.ls` /
:mod:`uvd.estimation.xval` / ``uvd identify`` / ``uvd xval``. Until the black-box recorder
exists, runs come from the lockstep experiments (``uvd experiment aid-6dof --plots DIR`` writes
``DIR/<dataset>-run.npz``), from :meth:`RunLog.from_lockstep` on a
:class:`uvd.experiments.lockstep.LockstepLog`, or from the JSON-lines telemetry of ``uvd run``
on a vehicle or ``sim-bridge`` (:meth:`RunLog.from_telemetry`; :meth:`RunLog.load` tells the
two file kinds apart).

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

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from uvd.errors import ConfigError


def _eta_of(rec: dict) -> np.ndarray:
    """[north, east, down, roll, pitch, heading] of a cycle record (``p`` and row-major
    ``R``, uvd.telemetry.records.CycleRecord's JSON form)."""
    from drivers.samples import R_to_euler
    return np.array([*np.asarray(rec["p"], dtype=float),
                     *R_to_euler(np.asarray(rec["R"], dtype=float).reshape(3, 3))])

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
        t = np.asarray(self.t, dtype=float).reshape(-1)
        n = t.shape[0]
        shapes = {"R": (n, 3, 3), "p": (n, 3), "v": (n, 6), "u": (n, 6)}
        for key, shape in shapes.items():
            arr = np.asarray(getattr(self, key), dtype=float)
            if arr.shape != shape:
                raise ConfigError(f"run {self.name!r}: {key} has shape {arr.shape}, "
                                  f"expected {shape}")
            if not np.all(np.isfinite(arr)):
                raise ConfigError(f"run {self.name!r}: {key} has non-finite entries")
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

    # -- files ---------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the ``.npz`` file of the module docstring."""
        meta = {"name": self.name, "input_interp": self.input_interp, "source": self.source,
                "format": "uvd-runlog-1", **self.extra}
        arrays = {"t": self.t, "R": self.R, "p": self.p, "v": self.v, "u": self.u,
                  "meta": np.array(json.dumps(meta))}
        if self.R_true is not None:
            arrays["R_true"] = self.R_true
        if self.v_true is not None:
            arrays["v_true"] = self.v_true
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("wb") as fh:
            np.savez_compressed(fh, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> RunLog:
        """Read a run written by :meth:`save`, or ``uvd run``'s JSON-lines telemetry
        (:meth:`from_telemetry`); raises :class:`ConfigError` naming what is wrong."""
        path = Path(path)
        if path.is_file() and not zipfile.is_zipfile(path):
            with path.open("rb") as fh:
                head = fh.read(1)
            if head == b"{":
                return cls.from_telemetry(path)
            raise ConfigError(f"{path}: not a readable run log: not a zip archive (.npz, "
                              "numpy's savez format) nor uvd run's JSON-lines telemetry")
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{path}: not a readable run log (.npz): {exc}") from exc
        missing = {"t", "R", "p", "v", "u"} - set(data)
        if missing:
            raise ConfigError(f"{path}: run log lacks array(s) {sorted(missing)}")
        meta = {}
        if "meta" in data:
            try:
                meta = json.loads(str(data["meta"]))
            except json.JSONDecodeError as exc:
                raise ConfigError(f"{path}: meta is not JSON: {exc}") from exc
        extra = {k: v for k, v in meta.items()
                 if k not in ("name", "input_interp", "source", "format")}
        return cls(t=data["t"], R=data["R"], p=data["p"], v=data["v"], u=data["u"],
                   name=meta.get("name", path.stem), input_interp=meta.get("input_interp",
                                                                           "linear"),
                   source=meta.get("source", str(path)), R_true=data.get("R_true"),
                   v_true=data.get("v_true"), extra=extra)

    def stretch_note(self) -> str:
        """What :meth:`from_telemetry` kept, when it had to cut the run ("" otherwise)."""
        segs = self.extra.get("segments") or []
        bad = self.extra.get("bad_lines", 0)
        parts = []
        if len(segs) > 1:
            parts.append(f"{len(segs)} uninterrupted stretches (cut where samples are "
                         f"missing or a run restarts); using the longest, {len(self)} of "
                         f"{sum(n for _, n in segs)} samples")
        if bad:
            parts.append(f"{bad} unreadable line(s) skipped")
        return "; ".join(parts)

    @classmethod
    def from_telemetry(cls, path: str | Path, *, name: str | None = None) -> RunLog:
        """From ``uvd run``'s JSON-lines telemetry (``[telemetry.jsonl]``): its cycle records.

        A cycle record holds the navigation pose ``eta`` (north, east, down, roll, pitch,
        heading), the body velocity ``v``, ``nav_valid`` and ``u`` — the wrench the estimators
        saw at that cycle (measured propeller speeds, else the last command: ``input_interp``
        "linear"). Cycles without valid navigation are left out; so is a line that is not
        JSON (a crash can cut the last one), counted in ``extra["bad_lines"]``.

        The loop wakes a few µs after its deadlines: the samples are put on the nominal grid
        t₀ + k·T (T the median spacing, the loop period times the sink's ``every_n_cycles``).
        Where the spacing is not one period (samples missing after an overrun or a navigation
        outage; a restart appending a new run) the run is cut; the longest uninterrupted
        stretch is returned and ``extra["segments"]`` lists every stretch as [first usable
        record, samples].
        """
        from drivers.samples import euler_to_R

        path = Path(path)
        t, eta, v, u = [], [], [], []
        bad = 0
        try:
            with path.open("r", encoding="utf-8") as fh:
                for line in fh:
                    try:
                        rec = json.loads(line)
                    except json.JSONDecodeError:
                        bad += 1
                        continue
                    if not isinstance(rec, dict) or rec.get("type") != "cycle" \
                            or not rec.get("nav_valid") or rec.get("u") is None:
                        continue
                    try:
                        arr = [np.asarray(x, dtype=float) for x in
                               (_eta_of(rec), rec.get("v"), rec.get("u"))]
                    except (KeyError, TypeError, ValueError):
                        bad += 1
                        continue
                    if [a.shape for a in arr] != [(6,)] * 3 \
                            or not all(np.all(np.isfinite(a)) for a in arr) \
                            or not isinstance(rec.get("t_ns"), int):
                        bad += 1
                        continue
                    t.append(rec["t_ns"])
                    eta.append(arr[0])
                    v.append(arr[1])
                    u.append(arr[2])
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{path}: cannot read the telemetry: {exc}") from exc
        if len(t) < 2:
            raise ConfigError(f"{path}: {len(t)} cycle record(s) with valid navigation and the "
                              "applied wrench 'u'; needs uvd run's telemetry ([telemetry.jsonl] "
                              "enabled) over a stretch with valid navigation")
        # in file order (the sink writes in order; a restart appends a new run, whose clock
        # may even start lower after a reboot): a step of other than one period is a cut
        t_ns = np.asarray(t, dtype=np.int64)
        diffs = np.diff(t_ns)
        ahead = diffs[diffs > 0]
        if ahead.size == 0:
            raise ConfigError(f"{path}: cycle records do not advance in time")
        period_ns = float(np.median(ahead))
        cuts = np.flatnonzero(np.rint(diffs / period_ns) != 1) + 1
        starts = np.concatenate(([0], cuts))
        stops = np.concatenate((cuts, [len(t_ns)]))
        segments = [[int(a), int(b - a)] for a, b in zip(starts, stops, strict=True)]
        a, n = max(segments, key=lambda s: s[1])
        eta_a = np.asarray(eta[a:a + n])
        R = np.stack([euler_to_R(*e[3:]) for e in eta_a])
        return cls(t=np.arange(n) * (period_ns * 1e-9), R=R, p=eta_a[:, :3],
                   v=np.asarray(v[a:a + n]), u=np.asarray(u[a:a + n]), name=name or path.stem,
                   input_interp="linear", source=f"uvd run telemetry {path}",
                   extra={"segments": segments, "kept_segment": [a, n], "bad_lines": bad,
                          "t0_ns": int(t_ns[a])})

    @classmethod
    def from_lockstep(cls, log, name: str = "lockstep", input_interp: str = "linear") -> RunLog:
        """From the lockstep runner's own :class:`LockstepLog` (true state, ``u_applied``).

        The lockstep log records the plant's *true* pose and velocity, so the run is noise-free
        in its states; ``u_applied`` is the wrench the core's estimators saw.
        """
        from drivers.samples import euler_to_R

        eta = np.asarray(log.eta, dtype=float)
        R = np.stack([euler_to_R(*e[3:]) for e in eta])
        return cls(t=log.t, R=R, p=eta[:, :3], v=log.v, u=log.u_applied, name=name,
                   input_interp=input_interp, source="LockstepLog (true states)")
