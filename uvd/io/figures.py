"""Figure files: PNG through matplotlib when it is installed, else the plotted series as CSV.

matplotlib is optional (not a dependency): every writer here leaves at least a CSV that any
tool can draw.
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
