"""A report of a black-box recording: ``index.html`` and PNG figures (matplotlib, Agg backend).

Figures, each from the recording's own channels (docs/recording.md):

* ``tracking.png`` — per DOF, the navigation state against the reference, and the error;
* ``mne.png`` — position and velocity MNE (mean norm of Δψ and Δv, §5.3.1) in windows:
  15 minutes as Fig. 5.4 (shorter runs: a tenth of the run);
* ``thrust.png`` — per thruster, the commanded thrust and the thrust the propellers produced
  (f = k ω|ω| of the measured speed, App. A.1), as Fig. 5.2 shows them around reversals;
* ``estimates.png`` — the estimates over time (the six masses and drags, g, b): the online
  AID's θ̂ of a daemon run, or the adaptive controller's 16 decoupled parameters of a
  lockstep experiment (``uvd experiment … --record``); a run with both (AMBC and
  ``[estimation] aid``, as ``uvd demo --fault``) has one figure for each,
  ``estimates-<estimator>.png``;
* ``failsafe.png`` — the failsafe action over time with every trigger that fired;
* ``lateness.png`` — the distribution of the loop's measured period around its nominal one;
* ``xval-*.png`` — with a parameter set, its cross-validation on the run (Figs. 4.5–4.7).

The figures the experiments' ``--plots`` draw too come from :mod:`uvd.io.figures`.
"""

from __future__ import annotations

import collections
import html
import math
import re
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from uvd.geometry import wrap_angles
from uvd.io.figures import estimates_figure, mne_figure
from uvd.jsonio import is_int64
from uvd.telemetry.recording import RecordingError, drawn_files, foreign_note, read_run
from uvd.telemetry.records import (
    array_shape,
    cycle_record_problem,
    eta_of_record,
    tracking_error_norms,
)

__all__ = ["write_report"]

_DOF = ("north (m)", "east (m)", "down (m)", "roll (deg)", "pitch (deg)", "heading (deg)")
_ACTIONS = ("none", "warn", "fallback", "hold-depth", "zero-thrust", "disarm")


def _load(path: Path) -> dict[str, list]:
    """The report's channels of ``path`` — of the whole run when it is a run's first file
    (:func:`~uvd.telemetry.recording.drawn_files`: the files the recorder started after it;
    a later file is drawn alone). Skipped and counted, the rest of the run drawn:
    ``out["unreadable"]``, the messages that were not JSON (a damaged byte);
    ``out["malformed"]``, the records that are JSON but not what their schema promises in a
    field the report draws (:func:`_problem`); ``out["files"]``, the files read, and
    ``out["missing"]``, a file of the run not in the folder (what comes after it is not
    drawn)."""
    out: dict[str, list] = {"cycle": [], "estimate": [], "failsafe": [], "start": [],
                            "sink": []}
    topics = {f"/uvd/{k}": k for k in out}
    unreadable: list[str] = []
    malformed: list[str] = []
    files, gap = drawn_files(path)
    for topic, t_ns, msg in read_run(files, list(topics), unreadable=unreadable):
        why = _problem(topics[topic], msg)
        if why is None:
            out[topics[topic]].append(msg)
        else:
            malformed.append(f"{topic} record at {t_ns} ns: {why}")
    out["files"], out["missing"] = [str(f) for f in files], gap
    out["cycle"] = _one_thruster_count(out["cycle"], malformed)
    out["unreadable"], out["malformed"] = unreadable, malformed
    if not out["cycle"]:
        why = f" ({len(malformed)} malformed, first: {malformed[0]})" if malformed else ""
        raise RecordingError(f"{path}: no cycle records (/uvd/cycle){why}: nothing to "
                             f"report{foreign_note(path)}")
    return out


def _problem(kind: str, msg: Any) -> str | None:
    """What makes a record unfit for the report (None: nothing): a cycle record as
    :func:`~uvd.telemetry.records.cycle_record_problem` judges it, with its measured propeller
    speeds a row of numbers; an estimate's, a failsafe event's, a sink's (``sinks_told``: a
    recording or a link that failed, as the operator was told) or the start record's fields
    the report reads."""
    if kind == "cycle":
        why = cycle_record_problem(msg)
        if why is not None:
            return why
        act = (msg.get("inputs") or {}).get("actuators")
        if act is not None and not isinstance(act, Mapping):
            return "inputs.actuators is not an object"
        w = _speeds(msg)
        if w is not None and len(array_shape(w) or ()) != 1:
            return "inputs.actuators.omega_rad_s is not a row of numbers"
        return None
    if not isinstance(msg, Mapping):
        return f"a JSON {type(msg).__name__}, not an object"
    if kind in ("estimate", "failsafe") and not is_int64(msg.get("t_ns")):
        return f"t_ns {msg.get('t_ns')!r:.40} is not a 64-bit integer"
    if kind == "failsafe" and not all(isinstance(msg.get(k), str) for k in ("kind", "trigger")):
        return "kind or trigger is not a string"
    if kind == "sink" and not (isinstance(msg.get("text"), str)
                               and isinstance(msg.get("ok"), bool)):
        return "text or ok is not what uvd.sink.v1 holds"
    if kind == "estimate" and msg.get("theta") is not None \
            and len(array_shape(msg["theta"]) or ()) != 1:
        return "theta is not a row of numbers"  # of other lengths: not drawn, as before
    return None


def _one_thruster_count(cycles: list[dict], malformed: list[str]) -> list[dict]:
    """The cycles whose thrust (and measured propeller speeds) have the run's number of
    thrusters, the most common; the others join ``malformed``."""
    if not cycles:
        return cycles
    n = collections.Counter(len(r["thrust"]) for r in cycles).most_common(1)[0][0]
    keep = []
    for r in cycles:
        w = _speeds(r)
        m, w = len(r["thrust"]), None if w is None else len(w)
        if m == n and w in (None, n):
            keep.append(r)
        else:
            speeds = "" if w is None else f" and {w} propeller speeds"
            malformed.append(f"/uvd/cycle record at {r['t_ns']} ns: {m} thrusts{speeds} where "
                             f"the run's others have {n}")
    return keep


def _speeds(r: Mapping[str, Any]) -> Any:
    """The measured propeller speeds a cycle record holds (None: none), its inputs and their
    amplifier status objects (:func:`_problem` checks that they are)."""
    return ((r.get("inputs") or {}).get("actuators") or {}).get("omega_rad_s")


def _k_thrust(start: list[dict]) -> np.ndarray | None:
    """The thrusters' k of f = k ω|ω| from the recorded configuration's vehicle."""
    if not start or not start[0].get("config_toml"):
        return None
    import tomllib

    from uvd.io.vehicle import load_vehicle
    try:
        name = tomllib.loads(start[0]["config_toml"]).get("vehicle", {}).get("name", "jhu-rov")
        return np.asarray(load_vehicle(name).k_thrust, dtype=float)
    except Exception:  # noqa: BLE001 - a vehicle file we cannot find here: no realised thrust
        return None


def write_report(recording: str | Path, out_dir: str | Path, *,
                 params: str | Path | None = None,
                 progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Write ``out_dir/index.html`` and its PNG figures; returns what was written.

    With ``params`` (a parameters file) also the cross-validation of that set on the run:
    simulated open loop with the run's wrench from its first state (App. A.2), measured
    against simulated roll, pitch and body velocities, Figs. 4.5–4.7
    (:func:`uvd.io.figures.write_xval_figures`, the figures ``uvd xval --plots`` draws).

    Raises
    ------
    RecordingError
        The recording cannot be read or holds no cycles that can be drawn. A message that is
        not JSON, or a record that is not what its schema promises (valid JSON, but a field
        missing or of the wrong shape), is skipped and counted: the summary's
        ``unreadable_messages`` and ``malformed_records`` with the first of each.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from uvd.errors import UvdError

    path = Path(recording)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    say = progress or (lambda _msg: None)
    say(f"reading {path}")
    data = _load(path)
    try:
        return _draw(plt, path, out, data, params, say)
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
        if isinstance(exc, (RecordingError, UvdError)):  # the parameters' own errors
            raise
        plt.close("all")
        raise RecordingError(f"{path}: a record does not hold what its schema (uvd.cycle.v1, "
                             f"uvd.estimate.v1, …) promises: {type(exc).__name__}: "
                             f"{exc}") from exc


def _draw(plt, path: Path, out: Path, data: dict[str, list], params, say) -> dict[str, Any]:
    cyc = data["cycle"]
    t0 = int(cyc[0]["t_ns"])
    t = np.array([(int(r["t_ns"]) - t0) * 1e-9 for r in cyc])
    armed = np.array([r["state"] in ("ARMED", "FAILSAFE") and r.get("p_ref") is not None
                      for r in cyc])
    figures: list[tuple[str, str]] = []

    def save(fig, name: str, caption: str) -> None:
        fig.tight_layout()
        fig.savefig(out / name, dpi=100)
        plt.close(fig)
        figures.append((name, caption))
        say(f"wrote {name}")

    if armed.any():
        _tracking_figures(plt, save, cyc, t, armed)
    _thrust_figure(plt, save, cyc, t, data["start"])
    est = [e for e in data["estimate"] if e.get("theta") is not None
           and len(e["theta"]) in (16, 241)]
    _estimates_figures(plt, save, est, t0)
    _failsafe_figure(plt, save, cyc, t, t0, data["failsafe"])
    _period_figure(plt, save, cyc)

    xval = None
    if params is not None:
        xval = _xval(path, cyc, Path(params), out, figures, say)

    summary = {"recording": str(path), "cycles": len(cyc), "armed_cycles": int(armed.sum()),
               "duration_s": float(t[-1]) if len(t) else 0.0,
               "failsafe_fired": sum(1 for e in data["failsafe"] if e.get("kind") == "fired"),
               "estimates": len(est), "figures": [f for f, _ in figures],
               "files": data["files"]}
    if data["missing"]:
        summary["missing_file"] = data["missing"]
    if data["sink"]:  # a recording or a link that failed during the run, as the operator
        summary["sinks_told"] = [m["text"] for m in data["sink"]]  # was told of it
    if data["unreadable"]:  # uvd report says so on stderr, --quiet or not
        summary["unreadable_messages"] = len(data["unreadable"])
        summary["first_unreadable"] = data["unreadable"][0]
    if data["malformed"]:
        summary["malformed_records"] = len(data["malformed"])
        summary["first_malformed"] = data["malformed"][0]
    if xval is not None:
        summary["xval"] = xval
    _write_html(out / "index.html", summary, figures)
    return summary


def _tracking_figures(plt, save, cyc: list, t: np.ndarray, armed: np.ndarray) -> None:
    """Reference vs navigation per DOF with their difference, and the MNE windows (Fig. 5.4)."""
    ta = t[armed]
    eta = np.array([eta_of_record(r) for r, a in zip(cyc, armed, strict=True) if a])
    ref = np.array([eta_of_record(r, ref=True) for r, a in zip(cyc, armed, strict=True)
                    if a])
    err = eta - ref
    err[:, 3:] = wrap_angles(err[:, 3:])
    scale = np.array([1, 1, 1, 180 / math.pi, 180 / math.pi, 180 / math.pi])
    fig, axes = plt.subplots(6, 2, figsize=(12, 13), sharex=True)
    for i in range(6):
        a = np.unwrap(eta[:, i]) if i >= 3 else eta[:, i]
        b = np.unwrap(ref[:, i]) if i >= 3 else ref[:, i]
        axes[i, 0].plot(ta, b * scale[i], "k--", lw=1, label="reference")
        axes[i, 0].plot(ta, a * scale[i], lw=1, label="navigation")
        axes[i, 0].set_ylabel(_DOF[i])
        axes[i, 1].plot(ta, err[:, i] * scale[i], lw=1, color="C3")
        axes[i, 1].set_ylabel("error")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("time (s)")
    axes[-1, 1].set_xlabel("time (s)")
    save(fig, "tracking.png", "Reference and navigation state per DOF (armed cycles) and "
                              "their difference.")
    norms = np.array([tracking_error_norms(r) for r, a in zip(cyc, armed, strict=True) if a])
    dpsi, dv = norms[:, 0], norms[:, 1]
    span = ta[-1] - ta[0]
    win = 900.0 if span >= 1800.0 else max(span / 10.0, 1.0)
    edges = np.arange(ta[0], ta[-1] + 1e-9, win)
    idx = np.clip(np.searchsorted(edges, ta, side="right") - 1, 0, None)
    mp = [float(np.mean(np.asarray(dpsi)[idx == k])) for k in range(len(edges))
          if np.any(idx == k)]
    mv = [float(np.mean(np.asarray(dv)[idx == k])) for k in range(len(edges))
          if np.any(idx == k)]
    fig = mne_figure(plt, np.arange(len(mp)) * win / 60.0, win / 60.0, mp, mv)
    save(fig, "mne.png", f"Position and velocity MNE (§5.3.1) in {win / 60.0:.3g}-minute "
                         "windows, the layout of Fig. 5.4.")


def _estimates_figures(plt, save, est: list, t0: int) -> None:
    """The estimates over time, one figure an estimator (``estimates.png`` when there is one):
    AID's 241 parameters and an adaptive controller's 16 in one array ended the report in
    numpy's "inhomogeneous shape" ValueError (``uvd demo --fault``'s run, session 34)."""
    groups: dict[tuple[str, int], list] = {}
    for e in est:
        name = str(e.get("estimator") or e.get("source") or "estimate")
        groups.setdefault((name, len(e["theta"])), []).append(e)
    names = [name for name, _ in groups]
    for (name, n), group in groups.items():
        te = np.array([(int(e["t_ns"]) - t0) * 1e-9 for e in group])
        whose = ("the online AID's θ̂ (Theorem 4.3.1, cf. Figs. 4.x)"
                 if group[0].get("source") == "estimator" else
                 "the adaptive controller's θ̂ (the 16 decoupled parameters of §5.3.1, cf. "
                 "Fig. 5.1)" if n == 16 else "the adaptive controller's θ̂")
        label = name if names.count(name) == 1 else f"{name}-{n}"
        save(estimates_figure(plt, te, [e["theta"] for e in group]),
             "estimates.png" if len(groups) == 1
             else f"estimates-{re.sub(r'[^A-Za-z0-9_.-]', '_', label)}.png",
             f"Estimates over the run, {label}: {whose}.")


def _thrust_figure(plt, save, cyc: list, t: np.ndarray, start: Any) -> None:
    """Commanded vs realised thrust per thruster (Fig. 5.2's lag and reversals)."""
    thrust = np.array([r["thrust"] for r in cyc], dtype=float)
    k = _k_thrust(start)
    realised = None
    if k is not None:
        rows = []
        for r in cyc:
            w = _speeds(r)
            rows.append(np.full(thrust.shape[1], np.nan) if w is None
                        else k * np.asarray(w, float) * np.abs(np.asarray(w, float)))
        realised = np.array(rows)
    n = thrust.shape[1]
    fig, axes = plt.subplots(n, 1, figsize=(12, 1.8 * n + 1), sharex=True)
    for j, ax in enumerate(np.atleast_1d(axes)):
        ax.plot(t, thrust[:, j], lw=1, label="commanded")
        if realised is not None:
            ax.plot(t, realised[:, j], lw=1, label="realised (k ω|ω|)")
        ax.set_ylabel(f"thruster {j + 1} (N)")
    np.atleast_1d(axes)[0].legend(loc="upper right", fontsize=8)
    np.atleast_1d(axes)[-1].set_xlabel("time (s)")
    save(fig, "thrust.png", "Commanded and realised thrust per thruster (the realised from the "
                            "measured propeller speed, App. A.1): the lag and the reversals "
                            "of Fig. 5.2.")


def _failsafe_figure(plt, save, cyc: list, t: np.ndarray, t0: int, failsafe: list) -> None:
    """The failsafe action in force every cycle, each trigger marked when it fired."""
    level = np.array([_ACTIONS.index(r["action"]) if r["action"] in _ACTIONS else 0
                      for r in cyc])
    fig, ax = plt.subplots(figsize=(12, 3))
    ax.step(t, level, where="post")
    ax.set_yticks(range(len(_ACTIONS)), _ACTIONS)
    for ev in failsafe:
        if ev.get("kind") == "fired":
            te = (int(ev["t_ns"]) - t0) * 1e-9
            ax.axvline(te, color="C3", lw=0.8, ls=":")
            ax.text(te, len(_ACTIONS) - 0.8, ev["trigger"], rotation=90, fontsize=7,
                    va="top")
    ax.set_xlabel("time (s)")
    save(fig, "failsafe.png", "The failsafe action in force every cycle, with each trigger "
                              "when it fired.")


def _period_figure(plt, save, cyc: list) -> None:
    """Histogram of the loop's measured period around its median."""
    dt = np.array([r["dt"] for r in cyc[1:]], dtype=float)
    nominal = float(np.median(dt)) if dt.size else 0.0
    fig, ax = plt.subplots(figsize=(8, 4))
    if dt.size:
        ax.hist((dt - nominal) * 1e3, bins=50)
    ax.set_xlabel(f"measured period − median {nominal * 1e3:.3g} ms (ms)")
    ax.set_ylabel("cycles")
    ax.set_yscale("log")
    save(fig, "lateness.png", "Distribution of the loop's measured period around its median.")


def _xval(path: Path, cyc: list, params: Path, out: Path, figures: list,
          say: Callable[[str], None]) -> dict[str, Any]:
    """Cross-validate ``params`` on the recorded cycles; its figures join ``figures``."""
    from uvd.estimation.xval import STATES_6DOF, cross_validate
    from uvd.io.figures import write_xval_figures
    from uvd.io.params import params_from_toml
    from uvd.io.runlog import runlog_from_records

    prm = params_from_toml(params)
    run = runlog_from_records(cyc, name=path.stem, source=f"recording {path}", where=path)
    res = cross_validate(prm, run)
    for f in write_xval_figures(out, run, {params.stem: (res.R_sim, res.v_sim)}, STATES_6DOF,
                                prefix="xval-"):
        figures.append((f.name, f"Cross-validation of {params.name} on this run (App. A.2; "
                                "Figs. 4.5–4.7): measured against simulated open loop with "
                                "the recorded wrench, first 3 minutes."))
        say(f"wrote {f.name}")
    return {"params": str(params), "mae": res.mae, "diverged_at_s": res.diverged_at_s}


def _write_html(path: Path, summary: dict[str, Any], figures: list[tuple[str, str]]) -> None:
    rows = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(str(v))}</td></tr>"
                   for k, v in summary.items() if k != "figures")
    figs = "".join(f'<figure><img src="{html.escape(name)}" alt="{html.escape(name)}">'
                   f"<figcaption>{html.escape(cap)}</figcaption></figure>"
                   for name, cap in figures)
    path.write_text(f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>uvd report</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:auto}}img{{max-width:100%}}
th{{text-align:left;padding-right:1em}}figure{{margin:2em 0}}</style></head>
<body><h1>uvd report</h1><table>{rows}</table>{figs}</body></html>
""", encoding="utf-8")
