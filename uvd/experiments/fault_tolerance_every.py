"""``uvd experiment fault-tolerance-every``: every thruster dead in turn, on both simulated
vehicles (issue 33's acceptance, across thrusters).

:mod:`uvd.experiments.fault_tolerance` runs three chosen cases with every arm; this one runs,
for the JHU ROV (``config/sim.toml``, six thrusters) and the BlueROV2-heavy
(``config/sim-bluerov2.toml``, eight), the fault-free run and then each thruster ``k`` dead
(η 0) from ``T`` with the ``told`` arm (the schedule's source: ``SetThrusterEta(k, 0)`` at
the first cycle at or after the fault, allocation with η, the DOFs it can no longer reach
given up by ``[control] dof_priority``), each by :func:`~uvd.experiments.fault_tolerance.run_arm`.

Per thruster: each DOF's position MAE from ``T + settle`` to the end over the fault-free run's
over the same span, the DOFs given up, the cycles not ``ok`` (these runs are unsupervised —
no failsafe acts, so this count is what a supervised daemon would have seen as its triggers'
material: 0 means no failsafe could have cascaded), each thruster's share of cycles at its
limit after the fault, and whether the issue's bound holds: the JHU ROV's depth and attitude
(z, roll, pitch, heading) within 2×, the BlueROV2-heavy's position and attitude (all six)
within 1.5×.
"""

from __future__ import annotations

from typing import Any

from uvd.experiments import Experiment, ExperimentOptions
from uvd.experiments.fault_tolerance import DOFS, DURATION_S, SETTLE_S, T_FAULT_S, _fmt, run_arm

#: (label, configuration file, thrusters, the DOFs the bound applies to, the bound)
CASES = (("jhu-rov", "sim.toml", 6, ("z", "roll", "pitch", "heading"), 2.0),
         ("bluerov2-heavy", "sim-bluerov2.toml", 8, DOFS, 1.5))


def _run(opts: ExperimentOptions) -> dict[str, Any]:
    duration = DURATION_S if opts.hours is None else opts.hours * 3600.0
    out: dict[str, Any] = {}
    lines = [f"fault-tolerance-every: each thruster dead (η 0, told) from t = {T_FAULT_S:g} s, "
             f"RefTraj1, lockstep, {duration:g} s; MAE after (from T + {SETTLE_S:g} s) / "
             "fault-free's over the same span"]
    for label, config_name, n, keep, bound in CASES:
        opts.progress(f"{label}: fault-free")
        free = run_arm(config_name, 1, 1.0, "fault-free", duration_s=duration, seed=opts.seed)
        rows = {}
        lines.append("")
        lines.append(f"{label} (bound: {', '.join(keep)} within {bound:g}x); fault-free MAE "
                     "after T  " + "  ".join(f"{d} {_fmt(d, free['after'][d])}" for d in DOFS))
        lines.append("   k  " + "  ".join(f"{d:>7s}" for d in DOFS)
                     + "  bound  given up         not ok  worst saturation")
        for k in range(1, n + 1):
            opts.progress(f"{label}: thruster {k} dead")
            r = run_arm(config_name, k, 0.0, "told", duration_s=duration, seed=opts.seed)
            ratio = {d: r["after"][d] / free["after"][d] for d in DOFS}
            worst = max(keep, key=lambda d: ratio[d])
            sat = r["saturated_fraction_after"]
            j = max(range(n), key=lambda i: sat[i])
            rows[str(k)] = {"ratio_after": ratio, "after": r["after"],
                            "given_up": r["given_up"], "cycles_not_ok": r["cycles_not_ok"],
                            "saturated_fraction_after": sat,
                            "max_abs_error_after": r["max_abs_error_after"],
                            "worst_kept": worst, "meets_bound": ratio[worst] <= bound}
            lines.append(f"  {k:2d}  " + "  ".join(f"{ratio[d]:6.2f}x" for d in DOFS)
                         + f"  {'yes' if ratio[worst] <= bound else 'NO ':5s}"
                         + f"  {', '.join(r['given_up']) or 'none':15s}"
                         + f"  {r['cycles_not_ok']:6d}  thruster {j + 1} {sat[j]:.0%}")
        out[label] = {"thrusters": n, "bound": bound, "bound_dofs": list(keep),
                      "fault-free": free, "dead": rows}
    return {"vehicles": out, "t_fault_s": T_FAULT_S, "duration_s": duration,
            "settle_s": SETTLE_S, "summary": "\n".join(lines),
            "thesis_reference": THESIS_REFERENCE}


THESIS_REFERENCE = (
    "beyond the thesis (issue 33's acceptance across thrusters): every thruster of the JHU ROV "
    "(six, `config/sim.toml`) and of the BlueROV2-heavy (eight, `config/sim-bluerov2.toml`) "
    "dead in turn from 60 s of RefTraj1 in lockstep, η 0 told at the fault "
    "(`SetThrusterEta(k, 0)`, the schedule's source); each DOF's position MAE from 70 s to the "
    "end over the fault-free run's. Bounds: JHU ROV depth and attitude within 2×, BlueROV2 "
    "position and attitude within 1.5×.")


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
                f"{max(v['dead'][k]['saturated_fraction_after']):.0%})" for k in miss)
        if lost:
            text += (f". Thrusters {', '.join(lost)}: the remaining ones no longer reach a DOF "
                     "the bound covers (it is given up by [control] dof_priority), so no "
                     "allocation can meet it — under-actuation, not the priorities")
        if coupled:
            text += (f". Thrusters {', '.join(coupled)}: every DOF of the bound is still "
                     "allocated, the DOF given up lies outside it, and the misses come with "
                     "the remaining thrusters at their limit in the share of cycles shown")
        parts.append(text)
    return "**Reading.** " + ". ".join(parts) + "."


EXPERIMENTS = [Experiment(
    "fault-tolerance-every",
    "every thruster dead in turn (η 0 told) on the JHU ROV and the BlueROV2-heavy: per-DOF "
    "MAE against fault-free, the DOF given up, cycles not ok, whether issue 33's bound holds",
    _run)]
