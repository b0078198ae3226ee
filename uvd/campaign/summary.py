"""A campaign's figures from its rows, with confidence intervals (scipy.stats).

* a **rate of events per vehicle-hour** (false alarms): the exact Poisson interval of the count
  over the hours at risk (Garwood's, the Poisson form of Clopper–Pearson: χ² quantiles), and
  the one-sided 95 % upper bound;
* a **probability** (detection, the right kind, the right thruster; a run with a false
  alarm): Clopper–Pearson's exact binomial interval (``binomtest(...).proportion_ci``);
* a **median** (detection delay, tracking error): the percentile bootstrap
  (``scipy.stats.bootstrap``, seeded, so the summary is the same every time).

Every interval is two-sided 95 % unless said otherwise.
"""

from __future__ import annotations

import math

import numpy as np

CONFIDENCE = 0.95
BOOTSTRAP_RESAMPLES = 2000


def poisson_rate(count: int, exposure: float, confidence: float = CONFIDENCE) -> dict:
    """Events per unit of ``exposure``: the estimate, the exact two-sided interval and the
    one-sided upper bound at ``confidence`` (Garwood 1936)."""
    from scipy.stats import chi2
    a = 1.0 - confidence
    if exposure <= 0:
        return {"count": count, "exposure": exposure, "rate": None, "low": None,
                "high": None, "upper_one_sided": None}
    low = 0.0 if count == 0 else chi2.ppf(a / 2, 2 * count) / 2 / exposure
    high = chi2.ppf(1 - a / 2, 2 * count + 2) / 2 / exposure
    upper = chi2.ppf(confidence, 2 * count + 2) / 2 / exposure
    return {"count": int(count), "exposure": float(exposure), "rate": count / exposure,
            "low": float(low), "high": float(high), "upper_one_sided": float(upper)}


def proportion(k: int, n: int, confidence: float = CONFIDENCE) -> dict:
    """k successes of n: the estimate and Clopper–Pearson's exact interval."""
    from scipy.stats import binomtest
    if n == 0:
        return {"k": 0, "n": 0, "p": None, "low": None, "high": None}
    ci = binomtest(int(k), int(n)).proportion_ci(confidence, method="exact")
    return {"k": int(k), "n": int(n), "p": k / n, "low": float(ci.low), "high": float(ci.high)}


def median_ci(values, confidence: float = CONFIDENCE, seed: int = 0) -> dict:
    """The median of ``values`` and its percentile-bootstrap interval."""
    from scipy.stats import bootstrap
    x = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if x.size == 0:
        return {"n": 0, "median": None, "low": None, "high": None}
    if x.size == 1 or np.all(x == x[0]):
        m = float(np.median(x))
        return {"n": int(x.size), "median": m, "low": m, "high": m}
    res = bootstrap((x,), np.median, confidence_level=confidence, method="percentile",
                    n_resamples=BOOTSTRAP_RESAMPLES, rng=np.random.default_rng(seed))
    return {"n": int(x.size), "median": float(np.median(x)),
            "low": float(res.confidence_interval.low),
            "high": float(res.confidence_interval.high)}


def _ok(rows: list[dict]) -> list[dict]:
    return [r for r in rows if r.get("error") is None]


def size_bins(rows: list[dict], n_bins: int = 4) -> list[tuple[float, float, list[dict]]]:
    """Rows split into ``n_bins`` equal-width bins of ``in_fault_size`` (of one fault kind)."""
    sizes = np.array([r["in_fault_size"] for r in rows], dtype=float)
    if sizes.size == 0:
        return []
    lo, hi = float(sizes.min()), float(sizes.max())
    if hi == lo:
        return [(lo, hi, rows)]
    edges = np.linspace(lo, hi, n_bins + 1)
    out = []
    for j in range(n_bins):
        last = j == n_bins - 1
        sel = [r for r, s in zip(rows, sizes, strict=True)
               if edges[j] <= s and (s < edges[j + 1] or (last and s <= edges[j + 1]))]
        out.append((float(edges[j]), float(edges[j + 1]), sel))
    return out


def _size_key(kind: str, r: dict) -> float:
    return abs(r["in_fault_size"]) if kind == "buoyancy" else r["in_fault_size"]


def summarize_fdc(rows: list[dict]) -> dict:
    """False alarms per vehicle-hour (every run's hours at risk before any fault), and per fault
    kind and size: detection, right kind, right thruster, delay; per kind, what its detected
    faults were named as (:func:`named_as`)."""
    ok = _ok(rows)
    alarms = sum(int(r["out_false_alarms"]) for r in ok)
    hours = sum(float(r["out_monitored_h"]) for r in ok)
    by_vehicle = {}
    for veh in sorted({r["in_vehicle"] for r in ok}):
        sel = [r for r in ok if r["in_vehicle"] == veh]
        by_vehicle[veh] = poisson_rate(sum(int(r["out_false_alarms"]) for r in sel),
                                       sum(float(r["out_monitored_h"]) for r in sel))
    out: dict = {"runs": len(rows), "failed": len(rows) - len(ok),
                 "simulated_h": sum(float(r["out_simulated_h"]) for r in ok),
                 "false_alarms_per_vehicle_hour": poisson_rate(alarms, hours),
                 "false_alarms_by_vehicle": by_vehicle,
                 "runs_with_false_alarm": proportion(sum(1 for r in ok
                                                         if r["out_false_alarms"]), len(ok))}
    faults: dict = {}
    for kind in ("thruster", "drag", "mass", "buoyancy"):
        sel = [r for r in ok if r["in_fault"] == kind]
        if not sel:
            continue
        clean = [r for r in sel if not r["out_false_alarms"]]
        entry = _detection_block(kind, clean)
        entry["false_alarm_before_fault"] = len(sel) - len(clean)
        bins = []
        for lo, hi, rs in size_bins([{**r, "in_fault_size": _size_key(kind, r)}
                                     for r in clean]):
            bins.append({"size_low": lo, "size_high": hi, **_detection_block(kind, rs)})
        entry["by_size"] = bins
        faults[kind] = entry
    out["faults"] = faults
    allf = [r for r in ok if r["in_fault"] != "none" and not r["out_false_alarms"]]
    if allf:
        out["all_faults"] = _detection_block("all", allf)
    return out


def named_as(rows: list[dict]) -> dict[str, int]:
    """What the detected faults among ``rows`` were named as: the first alarm's kind, counted,
    most often first (ties by name) — a thruster fault named after another thruster counts as
    ``"thruster (another)"``. Where a kind is named wrongly, this says what it is taken for."""
    counts: dict[str, int] = {}
    for r in rows:
        if not r["out_detected"]:
            continue
        name = str(r.get("out_first_kind"))
        if name == "thruster" and r["in_fault"] == "thruster" and not r["out_right_thruster"]:
            name = "thruster (another)"
        counts[name] = counts.get(name, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def _detection_block(kind: str, rows: list[dict]) -> dict:
    det = [r for r in rows if r["out_detected"]]
    block = {"detected": proportion(len(det), len(rows)),
             "right_kind": proportion(sum(1 for r in rows if r["out_right_kind"]), len(rows)),
             "delay_s": median_ci([r["out_delay_s"] for r in det]),
             "named_as": named_as(rows)}
    if kind in ("thruster", "all"):
        thr = [r for r in rows if r["in_fault"] == "thruster"]
        block["right_thruster"] = proportion(sum(1 for r in thr if r["out_right_thruster"]),
                                             len(thr))
    return block


def summarize_control(rows: list[dict]) -> dict:
    """Per controller, and per controller and model-error sign: the median tracking MNE
    (measured and true) with bootstrap intervals, the share of runs that stayed finite."""
    ok = _ok(rows)
    out: dict = {"runs": len(rows), "failed": len(rows) - len(ok),
                 "simulated_h": sum(float(r["out_simulated_h"]) for r in ok)}
    ctrls = {}
    for c in sorted({r["in_controller"] for r in ok}):
        sel = [r for r in ok if r["in_controller"] == c]
        block = _control_block(sel)
        groups = {}
        for name, pred in (("model heavier/draggier (error > 0)",
                            lambda r: r["in_mass_error"] + r["in_drag_error"] > 0),
                           ("model lighter (error ≤ 0)",
                            lambda r: r["in_mass_error"] + r["in_drag_error"] <= 0)):
            g = [r for r in sel if pred(r)]
            if g:
                groups[name] = _control_block(g)
        block["by_model_error"] = groups
        ctrls[c] = block
    out["controllers"] = ctrls
    return out


def _control_block(rows: list[dict]) -> dict:
    fin = [r for r in rows if r["out_finite"]]
    return {"finite": proportion(len(fin), len(rows)),
            "position_mne": median_ci([r["out_position_mne"] for r in fin]),
            "velocity_mne": median_ci([r["out_velocity_mne"] for r in fin]),
            "true_position_mne": median_ci([r["out_true_position_mne"] for r in fin]),
            "saturated_fraction": median_ci([r["out_saturated_fraction"] for r in fin])}


SUMMARIES = {"fdc": summarize_fdc, "control": summarize_control}


def summarize(kind: str, rows: list[dict]) -> dict:
    return SUMMARIES[kind](rows)


def _ci(d: dict, fmt: str = "{:.3g}", scale: float = 1.0) -> str:
    if d.get("p", d.get("median", d.get("rate"))) is None:
        return "-"
    v = d.get("p", d.get("median", d.get("rate")))
    return (f"{fmt.format(v * scale)} [{fmt.format(d['low'] * scale)}, "
            f"{fmt.format(d['high'] * scale)}]")


def format_summary(kind: str, s: dict) -> str:
    """The summary as text (95 % intervals in brackets)."""
    lines = [f"{s['runs']} runs ({s['failed']} failed), {s['simulated_h']:.1f} simulated "
             "vehicle-hours"]
    if kind == "fdc":
        fa = s["false_alarms_per_vehicle_hour"]
        if fa["rate"] is not None:
            lines.append(f"false alarms: {fa['count']} in {fa['exposure']:.1f} vehicle-hours "
                         f"monitored: {fa['rate']:.4f} /h [{fa['low']:.4f}, {fa['high']:.4f}], "
                         f"95 % upper bound {fa['upper_one_sided']:.4f} /h")
        for veh, b in s["false_alarms_by_vehicle"].items():
            if b["rate"] is not None:
                lines.append(f"  {veh}: {b['count']} in {b['exposure']:.1f} h, upper bound "
                             f"{b['upper_one_sided']:.4f} /h")
        for kindf, e in s["faults"].items():
            lines.append(f"{kindf}: detected {_ci(e['detected'], '{:.0%}')} of "
                         f"{e['detected']['n']}, right kind {_ci(e['right_kind'], '{:.0%}')}"
                         + (f", right thruster {_ci(e['right_thruster'], '{:.0%}')}"
                            if "right_thruster" in e else "")
                         + f", median delay {_ci(e['delay_s'], '{:.0f}')} s")
            if e.get("named_as"):
                lines.append("    named as: " + ", ".join(f"{k} {n}"
                                                         for k, n in e["named_as"].items()))
            for b in e["by_size"]:
                lines.append(f"    size {b['size_low']:.3g}–{b['size_high']:.3g}: detected "
                             f"{_ci(b['detected'], '{:.0%}')} of {b['detected']['n']}, right "
                             f"kind {_ci(b['right_kind'], '{:.0%}')}, delay "
                             f"{_ci(b['delay_s'], '{:.0f}')} s")
    else:
        for c, b in s["controllers"].items():
            lines.append(f"{c}: finite {_ci(b['finite'], '{:.0%}')}, median MNE position "
                         f"{_ci(b['position_mne'], '{:.4f}')}, velocity "
                         f"{_ci(b['velocity_mne'], '{:.4f}')}")
            for g, gb in b["by_model_error"].items():
                lines.append(f"    {g}: position MNE {_ci(gb['position_mne'], '{:.4f}')} "
                             f"({gb['finite']['n']} runs)")
    return "\n".join(lines)
