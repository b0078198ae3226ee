"""Figure files: PNG through matplotlib when it is installed, else the plotted series as CSV.

matplotlib is optional (not a dependency): every writer here leaves at least a CSV that any
tool can draw. Each figure the experiments' ``--plots`` and ``uvd report`` share is drawn in
one place here: the estimates over time (:func:`estimates_figure`, Fig. 5.1), the MNE in
windows (:func:`mne_figure`, Fig. 5.4), the cross-validation (:func:`write_xval_figures`,
Figs. 4.3–4.7).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uvd.estimation.xval import STATE_LABELS, STATES_6DOF, mae, states_of


def _pyplot():
    """matplotlib.pyplot on the file-only Agg backend, or None when it is not installed."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    return plt


def mass_drag_gb(thetas) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masses, drags and (g, b) of θ_UV (241, eq. 2.48) or of the decoupled view (16, §5.3.1:
    m₁…m₆, d₁…d₆, g, b₁…b₃), one row per θ."""
    a = np.asarray(thetas, dtype=float)
    if a.shape[1] == 16:
        return a[:, :6], a[:, 6:12], a[:, 12:16]
    from uvd.model.params import UVParams
    ps = [UVParams.from_theta(t) for t in a]
    return (np.array([np.diag(p.M) for p in ps]),
            np.array([[p.D[i][i, i] for i in range(6)] for p in ps]),
            np.array([[p.g, *p.b] for p in ps]))


def estimates_figure(plt, t: np.ndarray, thetas):
    """The estimates over time (cf. Fig. 5.1): masses, drags and g, b in three panels."""
    masses, drags, gb = mass_drag_gb(thetas)
    fig, ax = plt.subplots(1, 3, figsize=(14, 4))
    for a, y, title, names in ((ax[0], masses, "masses M̂ᵢᵢ", "m"),
                               (ax[1], drags, "drags D̂ᵢ(i,i)", "d")):
        a.plot(t, y)
        a.set_title(title)
        a.legend([f"{names}{i + 1}" for i in range(6)], fontsize=7, ncol=2)
    ax[2].plot(t, gb)
    ax[2].set_title("g, b")
    ax[2].legend(["g", "b₁", "b₂", "b₃"], fontsize=7)
    for a in ax:
        a.set_xlabel("time (s)")
    fig.tight_layout()
    return fig


def mne_figure(plt, start_min, width_min: float, position, velocity,
               reference: tuple[float, float] | None = None, label: str = "run"):
    """Position and velocity MNE (mean ‖Δψ‖, ‖Δv‖, §5.3.1) per window as bars — Fig. 5.4's
    layout — with ``reference`` (e.g. PDC's MNE) as horizontal lines."""
    fig, ax = plt.subplots(1, 2, figsize=(12, 4))
    x = np.asarray(start_min, dtype=float)
    for a, y, name, color, k in ((ax[0], position, "position MNE (‖Δψ‖)", "C0", 0),
                                 (ax[1], velocity, "velocity MNE (‖Δv‖)", "C1", 1)):
        a.bar(x, y, width=width_min * 0.8, align="edge", color=color, label=label)
        if reference is not None:
            a.axhline(reference[k], color="k", ls="--", lw=1, label="PDC")
            a.legend(fontsize=8)
        a.set_ylabel(name)
        a.set_xlabel(f"window start (min), {width_min:.3g}-minute windows")
    fig.tight_layout()
    return fig


def _save(plt, fig, path: Path) -> Path:
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def write_estimates(directory: str | Path, name: str, t, thetas,
                    header: list[str]) -> list[Path]:
    """``name.csv`` (t and every parameter) and ``name.png`` (:func:`estimates_figure`)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    written = [d / f"{name}.csv"]
    np.savetxt(written[0], np.column_stack([t, thetas]), delimiter=",",
               header=",".join(header), comments="")
    plt = _pyplot()
    if plt is not None and len(t):
        written.append(_save(plt, estimates_figure(plt, t, thetas), d / f"{name}.png"))
    return written


def write_mne(directory: str | Path, name: str, start_min, width_min: float, position,
              velocity, reference: tuple[float, float] | None = None,
              label: str = "run") -> list[Path]:
    """``name.csv`` (window start, MNEs, the reference's) and ``name.png`` (:func:`mne_figure`)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    written = [d / f"{name}.csv"]
    ref = (np.nan, np.nan) if reference is None else reference
    np.savetxt(written[0], np.column_stack([start_min, position, velocity,
                                            np.full(len(start_min), ref[0]),
                                            np.full(len(start_min), ref[1])]),
               delimiter=",", comments="",
               header=f"window_start_min,{label}_position_mne,{label}_velocity_mne,"
                      "reference_position_mne,reference_velocity_mne")
    plt = _pyplot()
    if plt is not None:
        written.append(_save(plt, mne_figure(plt, start_min, width_min, position, velocity,
                                             reference, label), d / f"{name}.png"))
    return written


def write_series(directory: str | Path, name: str, header: list[str],
                 cols: np.ndarray) -> list[Path]:
    """``directory/name.csv`` with the columns ``cols`` (the first one the abscissa) and, when
    matplotlib is installed, ``directory/name.png`` plotting every other column against it.
    Returns the files written."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    written = [d / f"{name}.csv"]
    np.savetxt(written[0], cols, delimiter=",", header=",".join(header), comments="")
    plt = _pyplot()
    if plt is None:
        return written
    fig, ax = plt.subplots(figsize=(8, 4))
    for j, h in enumerate(header[1:], start=1):
        ax.plot(cols[:, 0], cols[:, j], label=h)
    ax.set_xlabel(header[0])
    ax.legend(fontsize="small")
    fig.tight_layout()
    written.append(d / f"{name}.png")
    fig.savefig(written[-1], dpi=120)
    plt.close(fig)
    return written


def write_xval_figures(directory: str | Path, run,
                       sims: dict[str, tuple[np.ndarray, np.ndarray]], states=STATES_6DOF, *,
                       window_s: tuple[float, float] = (0.0, 180.0),
                       prefix: str = "") -> list[Path]:
    """Cross-validation figures in the style of Figs. 4.3–4.7 (a 3-minute window): per state,
    measured vs each simulated model (top) and each model's error with its MAE (bottom).

    ``sims`` maps a model name to its simulated (R, v) (:func:`uvd.estimation.xval.
    cross_validate`). PNG with matplotlib; otherwise the plotted series as CSV. Returns the
    files written.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    t = run.t - run.t[0]
    sel = (t >= window_s[0]) & (t <= window_s[1])
    meas = states_of(run.R, run.v)
    simst = {name: states_of(R, v) for name, (R, v) in sims.items()}
    maes = {name: mae(meas, s, states) for name, s in simst.items()}
    written = []
    plt = _pyplot()
    for s in states:
        label, unit = STATE_LABELS[s]
        stem = f"{prefix}{s}"
        if plt is None:
            path = directory / f"{stem}.csv"
            cols = [t[sel], meas[s][sel]] + [simst[m][s][sel] for m in sims]
            header = "t_s,measured," + ",".join(sims)
            np.savetxt(path, np.column_stack(cols), delimiter=",", header=header, comments="")
            written.append(path)
            continue
        fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
        ax1.plot(t[sel] / 60, meas[s][sel], "k-", label="MEAS")
        for m in sims:
            ax1.plot(t[sel] / 60, simst[m][s][sel], label=m)
            ax2.plot(t[sel] / 60, simst[m][s][sel] - meas[s][sel], label=m)
        ax1.set_ylabel(f"{label} ({unit})")
        ax1.set_title(f"{run.name} - simulated vs measured {label}")
        ax1.legend(loc="upper right", fontsize=7)
        ax2.set_ylabel(f"{label} error ({unit})")
        ax2.set_xlabel("Time (min)")
        ax2.set_title("Mean Absolute Error: " + ", ".join(
            f"{m} {maes[m][s]:.3g}" for m in sims), fontsize=8)
        fig.tight_layout()
        path = directory / f"{stem}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        written.append(path)
    return written
