"""``uvd campaign SPEC --report``: PNG figures of a campaign's summary (matplotlib, Agg) —
for fdc, the detection probability and right-kind probability per fault size with their
Clopper–Pearson intervals, the detection delays, what each fault kind was named as, the
false-alarm rate with its bounds; for control, the tracking MNE of each controller against the
model error."""

from __future__ import annotations

from pathlib import Path


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _err(block: dict, key: str = "p") -> tuple[float, float, float]:
    v = block[key]
    return v, v - block["low"], block["high"] - v


def fdc_figures(summary: dict, rows: list[dict], out: Path) -> list[Path]:
    plt = _plt()
    files = []
    kinds = list(summary["faults"])
    if kinds:
        fig, axes = plt.subplots(1, len(kinds), figsize=(4 * len(kinds), 3.4), squeeze=False)
        for ax, kind in zip(axes[0], kinds, strict=True):
            bins = [b for b in summary["faults"][kind]["by_size"] if b["detected"]["n"]]
            x = [(b["size_low"] + b["size_high"]) / 2 for b in bins]
            for key, label, dx in (("detected", "detected", 0.0),
                                   ("right_kind", "right kind", 0.01)):
                pts = [_err(b[key]) for b in bins]
                w = (bins[0]["size_high"] - bins[0]["size_low"]) if bins else 0
                ax.errorbar([xi + dx * w for xi in x], [p[0] for p in pts],
                            yerr=[[p[1] for p in pts], [p[2] for p in pts]], fmt="o-",
                            capsize=3, label=label)
            ax.set_title(kind)
            ax.set_xlabel({"thruster": "remaining effectiveness η", "drag": "drag scale",
                           "mass": "mass increase", "buoyancy": "|Δ buoyancy| (N)"}[kind])
            ax.set_ylim(-0.05, 1.05)
            ax.grid(alpha=0.3)
        axes[0][0].set_ylabel("probability (95 % Clopper–Pearson)")
        axes[0][0].legend(fontsize=8)
        fig.tight_layout()
        files.append(out / "detection-by-size.png")
        fig.savefig(files[-1], dpi=110)
        plt.close(fig)
        fig, ax = plt.subplots(figsize=(6, 3.4))
        data = [[r["out_delay_s"] for r in rows if r.get("error") is None
                 and r["in_fault"] == k and r.get("out_detected")] for k in kinds]
        ax.boxplot([d if d else [float("nan")] for d in data], tick_labels=kinds)
        ax.set_ylabel("detection delay (s)")
        ax.grid(alpha=0.3)
        fig.tight_layout()
        files.append(out / "detection-delay.png")
        fig.savefig(files[-1], dpi=110)
        plt.close(fig)
        named = {k: summary["faults"][k].get("named_as") or {} for k in kinds}
        if any(named.values()):
            files.append(_named_as_figure(plt, named, out / "named-as.png"))
    fa = summary["false_alarms_by_vehicle"]
    if fa:
        fig, ax = plt.subplots(figsize=(5, 3.2))
        names = [v for v in fa if fa[v]["rate"] is not None]
        ax.bar(names, [fa[v]["upper_one_sided"] for v in names], color="0.8",
               label="95 % upper bound")
        ax.plot(names, [fa[v]["rate"] for v in names], "ko", label="observed")
        for i, v in enumerate(names):
            ax.annotate(f"{fa[v]['count']} in {fa[v]['exposure']:.0f} h", (i, 0), ha="center",
                        va="bottom", fontsize=8)
        ax.set_ylabel("false alarms per vehicle-hour")
        ax.legend(fontsize=8)
        fig.tight_layout()
        files.append(out / "false-alarms.png")
        fig.savefig(files[-1], dpi=110)
        plt.close(fig)
    return files


def _named_as_figure(plt, named: dict[str, dict[str, int]], path: Path) -> Path:
    """The injected kinds (rows) against what their detections were named as (columns): the
    share of each row's detections, the count written in each cell."""
    import numpy as np
    cols: list[str] = []
    for counts in named.values():
        cols += [c for c in counts if c not in cols]
    kinds = list(named)
    share = np.zeros((len(kinds), len(cols)))
    for i, k in enumerate(kinds):
        total = sum(named[k].values())
        for j, c in enumerate(cols):
            share[i, j] = named[k].get(c, 0) / total if total else 0.0
    fig, ax = plt.subplots(figsize=(1.2 * len(cols) + 2.4, 0.6 * len(kinds) + 1.6))
    ax.imshow(share, cmap="Greys", vmin=0.0, vmax=1.0, aspect="auto")
    for i, k in enumerate(kinds):
        for j, c in enumerate(cols):
            n = named[k].get(c, 0)
            if n:
                ax.text(j, i, str(n), ha="center", va="center", fontsize=9,
                        color="white" if share[i, j] > 0.5 else "black")
    ax.set_xticks(range(len(cols)), cols, rotation=30, ha="right", fontsize=8)
    ax.set_yticks(range(len(kinds)), kinds, fontsize=8)
    ax.set_xlabel("named as (the first alarm's kind)")
    ax.set_ylabel("fault injected")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def control_figures(summary: dict, rows: list[dict], out: Path) -> list[Path]:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 3.6))
    for c in summary["controllers"]:
        sel = [r for r in rows if r.get("error") is None and r["in_controller"] == c
               and r["out_finite"]]
        err = [100 * (r["in_mass_error"] + r["in_drag_error"]) / 2 for r in sel]
        ax.plot(err, [r["out_position_mne"] for r in sel], "o", alpha=0.7, label=c)
    ax.set_xlabel("plant off the vehicle file: mean of mass and drag error (%)")
    ax.set_ylabel("position MNE, last window")
    ax.set_yscale("log")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = out / "control-mne.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]


def write_figures(kind: str, summary: dict, rows: list[dict], out: str | Path) -> list[Path]:
    """The campaign's figures into ``out``; returns their paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return (fdc_figures if kind == "fdc" else control_figures)(summary, rows, out)
