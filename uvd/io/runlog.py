"""Run-log files: :class:`uvd.estimation.runlog.RunLog` as ``.npz`` and from ``uvd run``'s
JSON-lines telemetry or any cycle records (a black-box recording's, :func:`runlog_from_records`).

The ``.npz`` layout is in :mod:`uvd.estimation.runlog`'s docstring and
``docs/experiments-identification.md``. Every reader raises :class:`~uvd.errors.ConfigError`
naming the file and what is wrong with it.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from uvd.errors import ConfigError
from uvd.estimation.runlog import RunLog
from uvd.jsonio import is_int64

_META_KEYS = ("name", "input_interp", "source", "format")


def save_runlog(run: RunLog, path: str | Path) -> None:
    """Write ``run`` as the ``.npz`` file of :mod:`uvd.estimation.runlog` (folders made)."""
    meta = {"name": run.name, "input_interp": run.input_interp, "source": run.source,
            "format": "uvd-runlog-1", **run.extra}
    arrays = {"t": run.t, "R": run.R, "p": run.p, "v": run.v, "u": run.u,
              "meta": np.array(json.dumps(meta))}
    if run.R_true is not None:
        arrays["R_true"] = run.R_true
    if run.v_true is not None:
        arrays["v_true"] = run.v_true
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as fh:
        np.savez_compressed(fh, **arrays)


def _profile_hint(path: Path) -> str:
    """What to do with an existing file or folder named as another system's recording (a ROS
    bag, MCAP, .tlog, .BIN): read it through a log profile; "" for anything else."""
    from uvd.errors import LogReadError
    from uvd.io.logprofile import builtin_profiles
    from uvd.io.logs import FORMATS, detect_format

    try:
        if not path.exists():
            return ""
        fmt = detect_format(path)
    except (LogReadError, OSError):  # a format uvd does not know by name; a name too long
        return ""
    if fmt == "uvd-telemetry":
        return ""
    return (f"; by its name another system's recording ({FORMATS[fmt].description}), read "
            f"through a log profile: add --profile NAME (built-in: "
            f"{', '.join(builtin_profiles())}) or --profile FILE.toml (docs/real-vehicles.md)")


def load_runlog(path: str | Path) -> RunLog:
    """Read a run written by :func:`save_runlog`, or ``uvd run``'s JSON-lines telemetry
    (:func:`runlog_from_telemetry`); raises :class:`ConfigError` naming what is wrong."""
    path = Path(path)
    if path.is_file() and not zipfile.is_zipfile(path):
        with path.open("rb") as fh:
            head = fh.read(1)
        if head == b"{":
            return runlog_from_telemetry(path)
        raise ConfigError(f"{path}: not a readable run log: not a zip archive (.npz, "
                          "numpy's savez format) nor uvd run's JSON-lines telemetry"
                          f"{_profile_hint(path)}")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: not a readable run log (.npz): {exc}"
                          f"{_profile_hint(path)}") from exc
    missing = {"t", "R", "p", "v", "u"} - set(data)
    if missing:
        raise ConfigError(f"{path}: run log lacks array(s) {sorted(missing)}")
    meta = {}
    if "meta" in data:
        try:
            meta = json.loads(str(data["meta"]))
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{path}: meta is not JSON: {exc}") from exc
        if not isinstance(meta, dict):
            raise ConfigError(f"{path}: meta must be a JSON object, got {meta!r:.80}")
    extra = {k: v for k, v in meta.items() if k not in _META_KEYS}
    return RunLog(t=data["t"], R=data["R"], p=data["p"], v=data["v"], u=data["u"],
                  name=meta.get("name", path.stem),
                  input_interp=meta.get("input_interp", "linear"),
                  source=meta.get("source", str(path)), R_true=data.get("R_true"),
                  v_true=data.get("v_true"), extra=extra)


def _cycle_sample(rec) -> tuple | None:
    """(t_ns, p, R, v, u) of a usable cycle record (JSON form of
    uvd.telemetry.records.CycleRecord), None for a record to leave out without counting it,
    and raises ValueError for a malformed one."""
    if not isinstance(rec, dict) or rec.get("type") != "cycle" \
            or not rec.get("nav_valid") or rec.get("u") is None:
        return None
    try:
        arr = [np.asarray(rec[k], dtype=float) for k in ("p", "R", "v", "u")]
    except (KeyError, TypeError) as exc:
        raise ValueError(str(exc)) from exc
    t_ns = rec.get("t_ns")
    if [a.shape for a in arr] not in ([(3,), (9,), (6,), (6,)], [(3,), (3, 3), (6,), (6,)]) \
            or not all(np.all(np.isfinite(a)) for a in arr) \
            or not is_int64(t_ns):  # a time stamp as the daemon writes it
        raise ValueError("malformed cycle record")
    return rec["t_ns"], arr[0], arr[1].reshape(3, 3), arr[2], arr[3]


def runlog_from_telemetry(path: str | Path, *, name: str | None = None) -> RunLog:
    """A run from ``uvd run``'s JSON-lines telemetry (``[telemetry.jsonl]``): its cycle records.

    A cycle record holds the navigation pose (``p`` and row-major ``R``), the body velocity
    ``v``, ``nav_valid`` and ``u`` — the wrench the estimators saw at that cycle (measured
    propeller speeds, else the last command: ``input_interp`` "linear"). Cycles without valid
    navigation are left out; so is a line that is not JSON (a crash can cut the last one) or a
    malformed cycle record, counted in ``extra["bad_lines"]``.

    The loop wakes a few µs after its deadlines: the samples are put on the nominal grid
    t₀ + k·T (T the median spacing, the loop period times the sink's ``every_n_cycles``).
    Where the spacing is not one period (samples missing after an overrun or a navigation
    outage; a restart appending a new run) the run is cut; the longest uninterrupted
    stretch is returned and ``extra["segments"]`` lists every stretch as [first usable
    record, samples].
    """
    path = Path(path)

    def records():
        for line in fh:
            try:
                yield json.loads(line)
            except json.JSONDecodeError:
                yield None  # a line cut by a crash: counted

    try:
        with path.open("r", encoding="utf-8") as fh:
            return runlog_from_records(records(), name=name or path.stem,
                                       source=f"uvd run telemetry {path}", where=path)
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the telemetry: {exc}") from exc


def runlog_from_records(records, *, name: str, source: str, where: str | Path) -> RunLog:
    """A run from cycle records (dicts of :class:`uvd.telemetry.records.CycleRecord`'s JSON
    form: a telemetry file's lines, a black-box recording's ``/uvd/cycle`` messages) as
    :func:`runlog_from_telemetry` describes; ``None`` or a malformed record is counted in
    ``extra["bad_lines"]``. Errors name ``where``."""
    path = where
    t, p, R, v, u = [], [], [], [], []
    bad = 0
    for rec in records:
        try:
            if rec is None:
                raise ValueError("not a record")
            sample = _cycle_sample(rec)
        except ValueError:
            bad += 1
            continue
        if sample is None:
            continue
        for seq, x in zip((t, p, R, v, u), sample, strict=True):
            seq.append(x)
    if len(t) < 2:
        raise ConfigError(f"{path}: {len(t)} cycle record(s) with valid navigation and the "
                          "applied wrench 'u'; needs uvd run's telemetry ([telemetry.jsonl] "
                          "enabled) or recording over a stretch with valid navigation")
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
    sl = slice(a, a + n)
    return RunLog(t=np.arange(n) * (period_ns * 1e-9), R=np.asarray(R[sl]), p=np.asarray(p[sl]),
                  v=np.asarray(v[sl]), u=np.asarray(u[sl]), name=name,
                  input_interp="linear", source=source,
                  extra={"segments": segments, "kept_segment": [a, n], "bad_lines": bad,
                         "t0_ns": int(t_ns[a])})
