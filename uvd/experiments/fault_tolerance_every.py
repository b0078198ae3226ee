"""``uvd experiment fault-tolerance-every``: every thruster dead in turn, on both simulated
vehicles (issue 33's acceptance, across thrusters).

:mod:`uvd.experiments.fault_tolerance` runs three chosen cases with every arm; this one runs,
for the JHU ROV (``config/sim.toml``, six thrusters) and the BlueROV2-heavy
(``config/sim-bluerov2.toml``, eight), the fault-free run and then each thruster ``k`` dead
(η 0) from ``T`` with the ``told`` arm (the schedule's source: ``SetThrusterEta(k, 0)`` at
the first cycle at or after the fault, allocation with η, the DOFs it can no longer reach
given up by ``[control] dof_priority``), each by :func:`~uvd.experiments.fault_tolerance.run_arm`
through the daemon's supervised cycle (``supervised=True``: its failsafes and lifecycle, armed
from the start, as ``uvd demo``'s lockstep run).

Per thruster: each DOF's position MAE from ``T + settle`` to the end over the fault-free run's
over the same span, the DOFs given up as the operator is told them (the ``SetThrusterEta``
command event's text, "thruster 1 eta 0 (schedule); given up: surge"), the failsafe events and
lifecycle transitions the supervised cycle had (count and kinds; a cascade would show here),
the cycles not ``ok``, whether the adaptive controller's θ̂ rows of the DOFs given up stayed
where they were at the fault (m, d of each such DOF, and g, b when heave, roll or pitch is
given up, :func:`uvd.control.ambc.hold_theta_dofs`; the largest change of those rows and of the
others from the fault to the end), each thruster's share of cycles at its limit after the
fault, and whether the issue's bound holds: the JHU ROV's depth and attitude (z, roll, pitch,
heading) within 2×, the BlueROV2-heavy's position and attitude (all six) within 1.5×.

Then each thruster's drive faults at ``T`` instead (the ``amplifier`` arm: the cycle's own
amplifier source under ``[failsafe] amplifier_fault = "reallocate"``), supervised too: the
``accommodated`` event it tells ("thruster 1 eta 0 (amplifier); given up: surge"), or — where
depth and attitude would not stay actuated — the failsafe that disarms instead, with every
event and transition counted.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from uvd.experiments import Experiment, ExperimentOptions
from uvd.experiments.fault_tolerance import (
    DOFS,
    DURATION_S,
    SETTLE_S,
    T_FAULT_S,
    _fmt,
    run_arm,
    run_duration,
)

#: (label, configuration file, thrusters, the DOFs the bound applies to, the bound)
CASES = (("jhu-rov", "sim.toml", 6, ("z", "roll", "pitch", "heading"), 2.0),
         ("bluerov2-heavy", "sim-bluerov2.toml", 8, DOFS, 1.5))


def theta_rows(n_theta: int, given_up) -> list[int]:
    """The θ̂ entries of the DOFs ``given_up`` (allocation names): decoupled (16) mᵢ and dᵢ of
    each, and g, b when heave, roll or pitch is among them; full (241) every entry (M and the
    drags couple every DOF) — what :func:`uvd.control.ambc.hold_theta_dofs` must hold."""
    from uvd.control.allocation import DOF_NAMES
    from uvd.control.ambc import drag_index, gravity_index, mass_index
    if not given_up:
        return []
    if n_theta != 16:
        return list(range(n_theta))
    idx = [int(mass_index("decoupled")[DOF_NAMES.index(d)]) for d in given_up]
    idx += [int(drag_index("decoupled")[DOF_NAMES.index(d)]) for d in given_up]
    if {"heave", "roll", "pitch"} & set(given_up):
        idx += [int(i) for i in gravity_index("decoupled")]
    return sorted(idx)


def adaptation_held(r: dict) -> dict[str, Any] | None:
    """From a supervised run: the largest |Δθ̂| from the fault to the end over the given-up
    DOFs' rows and over the others (None: the controller does not adapt)."""
    a, b = r.get("theta_at_fault"), r.get("theta_end")
    if a is None or b is None:
        return None
    d = np.abs(np.asarray(b) - np.asarray(a))
    rows = theta_rows(d.size, r["given_up"])
    rest = np.setdiff1d(np.arange(d.size), rows)
    return {"rows": rows, "max_change_given_up": float(d[rows].max()) if rows else None,
            "max_change_others": float(d[rest].max()) if rest.size else None,
            "held": bool(rows) and float(d[rows].max()) == 0.0}


def _events(r: dict) -> dict[str, Any]:
    """The supervised cycle's failsafe events and lifecycle transitions, counted by kind."""
    ev = r.get("failsafe_events") or []
    kinds = Counter(f"{e.get('kind')} {e.get('trigger')}" if e.get("type") == "failsafe"
                    else f"{e.get('from')}->{e.get('to')}" for e in ev)
    return {"count": len(ev), "kinds": dict(kinds)}


def _share(x: float) -> str:
    return f"{x:.0%}" if x > 0 else "none"


def _told_given_up(text: str | None) -> str:
    """The DOFs given up as the command event names them ("…; given up: surge")."""
    return "-" if not text or "given up: " not in text else text.split("given up: ", 1)[1]


def _run(opts: ExperimentOptions) -> dict[str, Any]:
    duration = run_duration("fault-tolerance-every", opts, DURATION_S, T_FAULT_S)
    out: dict[str, Any] = {}
    lines = [f"fault-tolerance-every: each thruster dead (η 0, told) from t = {T_FAULT_S:g} s, "
             f"RefTraj1, lockstep through the supervised cycle, {duration:g} s; MAE after (from "
             f"T + {SETTLE_S:g} s) / fault-free's over the same span"]
    for label, config_name, n, keep, bound in CASES:
        opts.progress(f"{label}: fault-free")
        free = run_arm(config_name, 1, 1.0, "fault-free", duration_s=duration, seed=opts.seed,
                       supervised=True)
        free["failsafes"] = _events(free)
        rows = {}
        lines.append("")
        lines.append(f"{label} (bound: {', '.join(keep)} within {bound:g}x); fault-free MAE "
                     "after T  " + "  ".join(f"{d} {_fmt(d, free['after'][d])}" for d in DOFS)
                     + f"; failsafe events {free['failsafes']['count']}")
        lines.append("   k  " + "  ".join(f"{d:>7s}" for d in DOFS)
                     + "  bound  given up (event)  failsafes  not ok  θ̂ given up   "
                       "worst saturation")
        for k in range(1, n + 1):
            opts.progress(f"{label}: thruster {k} dead")
            r, ratio, worst = _dead(config_name, k, "told", duration, opts.seed, free, keep)
            sat = r["saturated_fraction_after"]
            j = max(range(n), key=lambda i: sat[i])
            held, fs = adaptation_held(r), _events(r)
            told = _told_given_up(r["told"])
            rows[str(k)] = {"ratio_after": ratio, "after": r["after"],
                            "given_up": r["given_up"], "told": r["told"],
                            "failsafes": fs, "failsafe_events": r["failsafe_events"],
                            "adaptation": held, "theta_at_fault": r["theta_at_fault"],
                            "theta_end": r["theta_end"], "cycles_not_ok": r["cycles_not_ok"],
                            "saturated_fraction_after": sat,
                            "max_abs_error_after": r["max_abs_error_after"],
                            "worst_kept": worst, "meets_bound": ratio[worst] <= bound}
            if held is None:
                th = "no adaptation"
            elif not held["rows"]:
                th = "none given up"
            else:
                th = "held" if held["held"] else f"moved {held['max_change_given_up']:.3g}"
            fs_text = "none" if not fs["count"] else ", ".join(
                f"{c} {kd}" for kd, c in sorted(fs["kinds"].items()))
            lines.append(f"  {k:2d}  " + "  ".join(f"{ratio[d]:6.2f}x" for d in DOFS)
                         + f"  {'yes' if ratio[worst] <= bound else 'NO ':5s}"
                         + f"  {told:17s}  {fs_text:9s}  {r['cycles_not_ok']:6d}  {th:12s}"
                         + "  " + (f"thruster {j + 1} {sat[j]:.0%}" if sat[j] > 0 else "none"))
        lines += _amplifier_arm(config_name, n, keep, bound, free, rows, duration, opts)
        out[label] = {"thrusters": n, "bound": bound, "bound_dofs": list(keep),
                      "fault-free": free, "dead": rows}
    return {"vehicles": out, "t_fault_s": T_FAULT_S, "duration_s": duration,
            "settle_s": SETTLE_S, "supervised": True, "summary": "\n".join(lines),
            "thesis_reference": THESIS_REFERENCE}


def _dead(config_name: str, k: int, source: str, duration: float, seed: int, free: dict,
          keep) -> tuple[dict, dict, str]:
    """Thruster ``k`` dead from ``T`` (η 0 from ``source``), supervised: the run, each DOF's
    MAE ratio to the fault-free run after ``T`` and the worst DOF of the bound ``keep``."""
    r = run_arm(config_name, k, 0.0, source, duration_s=duration, seed=seed, supervised=True)
    ratio = {d: r["after"][d] / free["after"][d] for d in DOFS}
    return r, ratio, max(keep, key=lambda d: ratio[d])


def _amplifier_arm(config_name: str, n: int, keep, bound: float, free: dict, rows: dict,
                   duration: float, opts: ExperimentOptions) -> list[str]:
    """Each thruster's drive faulting at ``T`` instead (the cycle's amplifier source under
    ``[failsafe] amplifier_fault = "reallocate"``): the ``accommodated`` event it tells, or,
    where depth and attitude would not stay actuated, the failsafe that acts instead. Adds
    ``rows[k]["amplifier"]``; returns the table's lines."""
    lines = ["  amplifier source (thruster k's drive faults at T, [failsafe] amplifier_fault = "
             "\"reallocate\"): the event, the failsafes"]
    for k in range(1, n + 1):
        opts.progress(f"thruster {k}: its amplifier faults")
        r, ratio, worst = _dead(config_name, k, "amplifier", duration, opts.seed, free, keep)
        fs = _events(r)
        disarmed = any(e.get("type") == "lifecycle" and e.get("to") == "STANDBY"
                       for e in r["failsafe_events"])
        rows[str(k)]["amplifier"] = {
            "accommodated": r["events"], "given_up": r["given_up"], "failsafes": fs,
            "failsafe_events": r["failsafe_events"], "disarmed": disarmed,
            "ratio_after": ratio, "worst_kept": worst, "meets_bound": ratio[worst] <= bound,
            "cycles_not_ok": r["cycles_not_ok"]}
        what = "; ".join(f"accommodated: {t}" for t in r["events"]) or "not accommodated"
        kinds = ", ".join(f"{c} {kd}" for kd, c in sorted(fs["kinds"].items()))
        lines.append(f"  {k:2d}  " + ("disarmed" if disarmed else
                                       f"{worst} {ratio[worst]:.2f}x") + f"  {what}  "
                     f"[{fs['count']} event{'' if fs['count'] == 1 else 's'}: {kinds}]")
    return lines


THESIS_REFERENCE = (
    "beyond the thesis (issue 33's acceptance across thrusters): every thruster of the JHU ROV "
    "(six, `config/sim.toml`) and of the BlueROV2-heavy (eight, `config/sim-bluerov2.toml`) "
    "dead in turn from 60 s of RefTraj1 in lockstep through the daemon's supervised cycle "
    "(failsafes and lifecycle on), η 0 told at the fault (`SetThrusterEta(k, 0)`, the "
    "schedule's source; its command event names the DOFs given up); each DOF's position MAE "
    "from 70 s to the end over the fault-free run's; the failsafe events of each run; whether "
    "the adaptive controller's θ̂ rows of the given-up DOFs stayed at their value at the fault. "
    "Bounds: JHU ROV depth and attitude within 2×, BlueROV2 position and attitude within 1.5×.")


def note(result: dict) -> str | None:
    """The page's reading (docs/RESULTS.md), from the JSON only."""
    try:
        veh = result["vehicles"]
    except (KeyError, TypeError):
        return None
    # the allocation's DOF names against the bound's tracked ones
    tracked = {"surge": "x", "sway": "y", "heave": "z", "roll": "roll", "pitch": "pitch",
               "yaw": "heading"}
    parts = []
    for label, v in veh.items():
        lost = sorted({k for k, r in v["dead"].items() if not r["meets_bound"]
                       and any(tracked.get(g) in v["bound_dofs"] for g in r["given_up"])})
        coupled = sorted({k for k, r in v["dead"].items() if not r["meets_bound"]} - set(lost))
        ok = [k for k, r in v["dead"].items() if r["meets_bound"]]
        miss = [k for k, r in v["dead"].items() if not r["meets_bound"]]
        text = (f"{label}: {len(ok)} of {v['thrusters']} thrusters meet the bound "
                f"({', '.join(v['bound_dofs'])} within {v['bound']:g}×)")
        if miss:
            text += "; missed by " + "; ".join(
                f"thruster {k} ({v['dead'][k]['worst_kept']} "
                f"{v['dead'][k]['ratio_after'][v['dead'][k]['worst_kept']]:.2f}×, given up: "
                f"{', '.join(v['dead'][k]['given_up']) or 'none'}, worst saturation "
                f"{_share(max(v['dead'][k]['saturated_fraction_after']))})" for k in miss)
        if lost:
            text += (f". Thrusters {', '.join(lost)}: the remaining ones no longer reach a DOF "
                     "the bound covers (it is given up by [control] dof_priority), so no "
                     "allocation can meet it — under-actuation, not the priorities")
        if coupled:
            xy = [v["dead"][k]["ratio_after"][d] for k in coupled for d in ("x", "y")
                  if d in v["dead"][k]["ratio_after"]]
            sat = max(max(v["dead"][k]["saturated_fraction_after"]) for k in coupled)
            text += (f". Thrusters {', '.join(coupled)}: every DOF of the bound is still "
                     "allocated, the DOF given up lies outside it, and the misses come with "
                     + ("the remaining thrusters at their limit in the share of cycles shown"
                        if sat >= 0.1 else "the remaining thrusters at their limit in at most "
                        f"{sat:.0%} of the cycles (docs/experiments.md, \"fault-tolerance\", "
                        "has what the depth miss comes from)"))
            if xy:
                text += (f" and the horizontal position {min(xy):.1f}–{max(xy):.1f}× its "
                         "fault-free error")
        amp = {k: r["amplifier"] for k, r in v["dead"].items() if "amplifier" in r}
        if amp:
            acc = [k for k, a in amp.items() if a["accommodated"]]
            off = [k for k, a in amp.items() if a["disarmed"]]
            text += (". The drive's own fault instead (the amplifier source): accommodated "
                     f"for thrusters {', '.join(acc) or 'none'}")
            if acc:
                extra = sum(amp[k]["failsafes"]["count"] - len(amp[k]["accommodated"])
                            for k in acc)
                text += (", each told by an `accommodated` event naming what was given up "
                         f"({amp[acc[0]]['accommodated'][0]}), {extra} other events")
            if off:
                kinds = amp[off[0]]["failsafes"]["kinds"]
                text += (f"; for thrusters {', '.join(off)} not (depth and attitude would not "
                         "stay actuated): the daemon disarms — "
                         + ", ".join(f"{c} {kd}" for kd, c in sorted(kinds.items())))
        if result.get("supervised"):
            fired = sum(r["failsafes"]["count"] for r in v["dead"].values())
            text += (f". Supervised cycle, η told: {fired} failsafe events or lifecycle "
                     f"transitions over the {v['thrusters']} runs")
            held = [r["adaptation"] for r in v["dead"].values()
                    if r["adaptation"] is not None and r["adaptation"]["rows"]]
            if held:
                n_held = sum(h["held"] for h in held)
                text += (f"; the adaptive controller's θ̂ rows of the DOF given up unchanged "
                         f"from the fault to the end in {n_held} of {len(held)} runs")
        parts.append(text)
    return "**Reading.** " + ". ".join(parts) + "."


EXPERIMENTS = [Experiment(
    "fault-tolerance-every",
    "every thruster dead in turn (η 0 told) on the JHU ROV and the BlueROV2-heavy: per-DOF "
    "MAE against fault-free, the DOF given up, cycles not ok, whether issue 33's bound holds",
    _run)]
