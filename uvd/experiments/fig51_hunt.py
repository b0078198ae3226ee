"""``uvd experiment fig51-hunt``: a search for the mechanism of Fig. 5.1 (issue 32).

§5.3.2: single-step decoupled AMBC on RefTraj1 from the identified values (k_p = 300,
k_d = 100, γ_m = 1000, γ_d = 5000, γ_g = γ_b1 = γ_b2 = 0.5, γ_b3 = 10), 2 h; on the real
vehicle m₄ and m₅ fell to −1.35 and 42.5 and m₆ to 41 (Tables 5.2/5.3), the others stayed
near their values. ``ambc-6dof-unstable`` does not reproduce that on our plant. Here every
candidate cause of :mod:`sim_bridge.tank` (each a named option) is switched on alone, from the
plant's own values and from Table 5.2/5.3's initial values, then all together; and the
coupled plant (``jhu-rov-coupled``) with Table 5.2's values at several ε. Every attempt is the
same 2 h run as ``ambc-6dof-unstable``'s first block (plant lag, stiction 5 N, saturation,
Table A.1 noise and rates: INS 10 Hz, DVL 6 Hz, depth 7 Hz; no lag compensation, no preview),
changed only by its option. Each attempt's minimum of m₄, m₅, m₆ (the 10 s samples of θ̂) and
its final m₆ go into the table; an attempt reproduces the *selective* drift when m₄ or m₅
goes below zero while every other mass and drag stays within 0.5–2× its initial value.
When one does, robust single-step AMBC and two-step AMBC run on that plant.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from sim_bridge.instruments.models import InstrumentConfig
from sim_bridge.tank import TankEffects
from uvd import core
from uvd.control.allocation import Allocator
from uvd.control.ambc import (
    C_APPENDIX_B2,
    ROBUST_DAEMON_DEFAULT,
    ambc_init,
    ambc_params,
    ambc_step,
    epsilon_bound,
    theta_of,
)
from uvd.control.trajectory import reftraj1
from uvd.experiments import Experiment, ExperimentOptions
from uvd.experiments._control_runner import run_control, series_summary
from uvd.experiments.control import (
    DEC_NAMES,
    EPS,
    KD,
    KP,
    THESIS_TABLE_5_2_5_3,
)
from uvd.io.vehicle import load_vehicle

HOURS = 2.0  # §5.3.2's "two-hour duration experiment" (Fig. 5.1's time axis runs to ~8000 s)
_DEG = math.pi / 180.0

#: the causes of issue 32, each a named option (sim_bridge.tank) with the value tried and why
CAUSES: tuple[tuple[str, str, dict], ...] = (
    ("none", "ambc-6dof-unstable's plant, nothing added", {}),
    ("mounting-bias+", "INS mounted +1° in roll and pitch",
     {"tank": TankEffects(mounting_bias_rad=(_DEG, _DEG, 0.0))}),
    ("mounting-bias-", "INS mounted -1° in roll and pitch (issue 32's hypothesis: the sign of a "
                       "bias decides the sign of the unexcited direction's drift)",
     {"tank": TankEffects(mounting_bias_rad=(-_DEG, -_DEG, 0.0))}),
    ("latency", "INS, DVL and depth frames 1 sample late (100, 167, 143 ms)",
     {"tank": TankEffects(latency_samples=(1, 1, 1))}),
    ("dvl-depth-10hz", "DVL and depth at 10 Hz: every other run has them at 6 and 7 Hz as on "
                       "the vehicle (Table A.1), so this row is the contrast",
     {"instruments": InstrumentConfig(dvl_rate_hz=10.0, depth_rate_hz=10.0)}),
    ("tether", "10 N tether from 3 m aft, 2 m above the start, on a point 0.5 m aft, 0.3 m up",
     {"tank": TankEffects(tether_n=10.0)}),
    ("buoyancy-depth", "20 N of buoyancy lost per m of depth, centre of buoyancy 0.1 m up",
     {"tank": TankEffects(buoyancy_n_per_m=20.0)}),
    ("advance-loss", "thrust loss k_a |ω| u_a, k_a 0.5 N s/m (~17 % at 0.1 m/s, 60 rad/s)",
     {"tank": TankEffects(advance_loss=0.5)}),
    ("reversal-band-x3", "reversal dead band (stiction) 15 N instead of 5 N",
     {"tank": TankEffects(reversal_band_scale=3.0)}),
    ("reversal-hold", "a longer reversal dead band in time: no command for 0.3 s after a "
                      "thruster's command changes sign (the propeller stops and restarts)",
     {"tank": TankEffects(reversal_hold_s=0.3)}),
    ("hysteretic-band", "dead band about zero, on at 10 N, off below 2 N",
     {"tank": TankEffects(hysteresis_n=(10.0, 2.0))}),
    ("all", "every option above at once (DVL 6 Hz, depth 7 Hz)",
     {"tank": TankEffects(mounting_bias_rad=(_DEG, _DEG, 0.0), latency_samples=(1, 1, 1),
                          tether_n=10.0, buoyancy_n_per_m=20.0, advance_loss=0.5,
                          reversal_band_scale=3.0, reversal_hold_s=0.3,
                          hysteresis_n=(10.0, 2.0))}),
    ("coupled-plant", "the coupled plant jhu-rov-coupled (Tables 4.8/4.9), eps 0.1",
     {"vehicle": "jhu-rov-coupled"}),
)
#: ε from Table 5.2's values besides EPS: Theorem 5.2.2's bound with App. B.2's c for the
#: plant's M (None here, computed), and on the coupled plant the 1 an independent run tried on
#: the decoupled one
COUPLED_EPS = (None, 1.0)


def eps_bound(vehicle: str) -> float:
    """Theorem 5.2.2's bound on ε (5.21, 5.25) for the plant's M, k_p, k_d and App. B.2's c."""
    return epsilon_bound(load_vehicle(vehicle).params.M, KP, KD, C_APPENDIX_B2)
INITS = ("plant", "table-5.2")


def selective(th: np.ndarray) -> bool:
    """m₄ or m₅ below zero while every other mass and drag stays within 0.5–2× its initial."""
    if min(th[:, 3].min(), th[:, 4].min()) >= 0.0:
        return False
    others = [0, 1, 2, 5] + list(range(6, 12))
    r = th[:, others] / th[0, others]
    return bool(r.min() >= 0.5 and r.max() <= 2.0)


def attempt(name: str, init: str, *, seconds: float, seed: int, eps: float = EPS,
            vehicle: str = "jhu-rov", tank: TankEffects | None = None,
            instruments: InstrumentConfig | None = None, robust: bool = False,
            progress=None, advance=None) -> dict:
    """One 2 h run of §5.3.2's single-step AMBC with a cause on; its row of the table."""
    veh = load_vehicle(vehicle)
    truth = theta_of(veh.params, "decoupled")
    theta0 = truth if init == "plant" else np.array(THESIS_TABLE_5_2_5_3["initial"], float)
    p = ambc_params("decoupled", kp=KP, kd=KD, eps=eps, allocator=Allocator.from_vehicle(veh),
                    robust=ROBUST_DAEMON_DEFAULT if robust else None)
    spec = core.ControllerSpec("ambc", ambc_step, p, ambc_init(p, theta0))
    label = f"fig51-hunt {name} from {init}: "
    run = run_control(veh, spec, reftraj1(), seconds, seed=seed, theta_every_s=10.0,
                      progress=progress, advance=advance, label=label, tank=tank,
                      instruments=instruments)
    th = run.theta
    i = {n: DEC_NAMES.index(n) for n in ("m4", "m5", "m6", "g", "b3")}
    return {
        "cause": name, "init": init, "vehicle": veh.name, "eps": eps, "robust": robust,
        "tank_options": [] if tank is None else tank.on(),
        "m4_min": float(th[:, i["m4"]].min()), "m5_min": float(th[:, i["m5"]].min()),
        "m6_min": float(th[:, i["m6"]].min()), "m6_final": float(th[-1, i["m6"]]),
        "m4_final": float(th[-1, i["m4"]]), "m5_final": float(th[-1, i["m5"]]),
        "g_final": float(th[-1, i["g"]]), "b3_final": float(th[-1, i["b3"]]),
        "initial": th[0].tolist(), "final": th[-1].tolist(),
        "max_abs_change_other": float(np.max(np.abs(np.delete(th[-1] - th[0], [3, 4]))
                                             / np.maximum(np.abs(np.delete(th[0], [3, 4])),
                                                          1e-9))),
        "selective_drift": selective(th),
        "min_mass_eigenvalue": float(th[:, :6].min()),
        "series": series_summary(run.theta_t, th[:, [3, 4, 5]], ["m4", "m5", "m6"], 60.0),
        "sim_wall_s": run.wall_s,
    }


#: the thesis's drift per hour over §5.3.2's 2 h (Tables 5.2/5.3): m4, m5, m6
THESIS_RATE_PER_H = tuple((THESIS_TABLE_5_2_5_3["final"][i] - THESIS_TABLE_5_2_5_3["initial"][i])
                          / 2.0 for i in (3, 4, 5))
_OTHERS = [0, 1, 2, 5] + list(range(6, 12))


def rate_per_h(r: dict, i: int, seconds: float) -> float:
    """(final − initial) of parameter ``i`` per simulated hour."""
    return (r["final"][i] - r["initial"][i]) / (seconds / 3600.0)


def thesis_like(r: dict, seconds: float) -> bool:
    """m₄ or m₅ falls at least half as fast as in the thesis while every other mass and drag
    ends within 0.5–2× its initial value (the run-length-free form of the selective drift)."""
    falls = (rate_per_h(r, 3, seconds) <= 0.5 * THESIS_RATE_PER_H[0]
             or rate_per_h(r, 4, seconds) <= 0.5 * THESIS_RATE_PER_H[1])
    ratio = np.array(r["final"])[_OTHERS] / np.array(r["initial"])[_OTHERS]
    return bool(falls and ratio.min() >= 0.5 and ratio.max() <= 2.0)


def _row(r: dict, seconds: float) -> str:
    return (f"{r['cause']:>17} {r['init']:>9} {r['eps']:>6.4g} {r['m4_min']:>7.1f} "
            f"{r['m5_min']:>7.1f} {r['m6_min']:>7.1f} {r['m6_final']:>7.1f} "
            + " ".join(f"{rate_per_h(r, i, seconds):>6.1f}" for i in (3, 4, 5))
            + f" {r['g_final']:>6.2f} {r['b3_final']:>5.0f} "
            f"{'YES' if r['selective_drift'] else 'no':>4} "
            f"{'YES' if thesis_like(r, seconds) else 'no':>4}")


def plan() -> list[tuple[str, str, dict]]:
    """Every attempt of the hunt: (cause, initial values, keyword arguments of attempt)."""
    out = [(name, init, kw) for name, _, kw in CAUSES for init in INITS]
    out += [("coupled-plant", "table-5.2",
             {"vehicle": "jhu-rov-coupled",
              "eps": eps_bound("jhu-rov-coupled") if e is None else e}) for e in COUPLED_EPS]
    out += [("none", "table-5.2", {"eps": eps_bound("jhu-rov")})]
    return out


def run_plan(items, seconds: float, opts: ExperimentOptions) -> list[dict]:
    """The attempts of ``items`` (a part of :func:`plan`), in order."""
    rows = []
    for k, (name, init, kw) in enumerate(items, 1):
        opts.progress(f"[fig51-hunt] ({k}/{len(items)}) {name} from {init}, "
                      f"eps {kw.get('eps', EPS):g}, {seconds / 3600:.2f} h")
        rows.append(attempt(name, init, seconds=seconds, seed=opts.seed,
                            progress=opts.progress, advance=opts.advance, **kw))
    return rows


def priority() -> list[int]:
    """The plan's indices in the order the parts run them: Table 5.2's initial values first
    (the thesis's start), then the plant's."""
    items = plan()
    return ([i for i, it in enumerate(items) if it[1] == "table-5.2"]
            + [i for i, it in enumerate(items) if it[1] != "table-5.2"])


def run_attempts(indices, seconds: float, out: Path, opts: ExperimentOptions) -> None:
    """The plan's attempts ``indices`` (each exactly as :func:`run_plan` runs it), one JSON per
    attempt in ``out`` (``NN.json``, NN the plan index, with its CPU seconds); an attempt whose
    file exists is skipped, so a stopped part resumes."""
    import json
    import time
    items = plan()
    out.mkdir(parents=True, exist_ok=True)
    for i in indices:
        f = out / f"{i:02d}.json"
        if f.exists():
            continue
        t0 = time.process_time()
        row = run_plan([items[i]], seconds, opts)[0]
        row["cpu_s"] = time.process_time() - t0
        f.write_text(json.dumps(row))


def load_attempts(out: Path) -> dict[int, dict]:
    """The attempts :func:`run_attempts` wrote into ``out``, by plan index."""
    import json
    return {int(f.stem): json.loads(f.read_text()) for f in sorted(out.glob("[0-9][0-9].json"))}


def _not_run(attempts: dict[int, dict], items: list, seconds: float) -> list[str]:
    """The plan's attempts missing from ``attempts``; an attempt not the plan's, or of another
    duration, is an error."""
    for i, a in attempts.items():
        if not 0 <= i < len(items) or (a["cause"], a["init"]) != items[i][:2]:
            raise ValueError(f"fig51-hunt: attempt {i} ({a['cause']} from {a['init']}) is not "
                             "the plan's")
        if a["series"]["t"] and abs(a["series"]["t"][-1] - seconds) > 60.0:
            raise ValueError(f"fig51-hunt: attempt {i} ran {a['series']['t'][-1]:.0f} s, not "
                             f"{seconds:.0f} s")
    return [f"{items[i][0]} from {items[i][1]}"
            + (f" (eps {items[i][2]['eps']:.3g})" if "eps" in items[i][2] else "")
            for i in range(len(items)) if i not in attempts]


def run_fig51_hunt(opts: ExperimentOptions, attempts: dict[int, dict] | None = None) -> dict:
    """The hunt; ``attempts`` given (by plan index, :func:`load_attempts` of parts run apart)
    are taken instead of running them — the plan's others are listed as not run."""
    seconds = (HOURS if opts.hours is None else float(opts.hours)) * 3600.0
    items = plan()
    if attempts is None:
        attempts = dict(enumerate(run_plan(items, seconds, opts)))
    not_run = _not_run(attempts, items, seconds)
    attempts = [attempts[i] for i in sorted(attempts)]
    found = [a for a in attempts if a["selective_drift"]]
    on_plant: dict = {}
    if found:
        a = found[0]
        kw = next(k for n, i, k in items if n == a["cause"] and i == a["init"])
        opts.progress(f"[fig51-hunt] {a['cause']} reproduces the selective drift: robust "
                      "single-step AMBC on that plant")
        on_plant["robust"] = attempt(a["cause"], a["init"], seconds=seconds, seed=opts.seed,
                                     robust=True, progress=opts.progress, **kw)
        on_plant["two_step"] = _two_step_on(a["cause"], kw, opts)
    jhu = load_vehicle("jhu-rov").params.M
    cpl = load_vehicle("jhu-rov-coupled").params.M
    bound = {"c_appendix_b2": C_APPENDIX_B2,
             "jhu-rov": {"c1": epsilon_bound(jhu, KP, KD), "c_b2": epsilon_bound(jhu, KP, KD,
                                                                                 C_APPENDIX_B2)},
             "jhu-rov-coupled": {"c1": epsilon_bound(cpl, KP, KD),
                                 "c_b2": epsilon_bound(cpl, KP, KD, C_APPENDIX_B2)}}
    desc = {n: d for n, d, _ in CAUSES}
    lines = [
        f"fig51-hunt (§5.3.2, Fig. 5.1): single-step decoupled AMBC on RefTraj1, "
        f"{seconds / 3600:.2f} h per attempt, k_p={KP:g}, k_d={KD:g}, thesis gammas; each "
        "cause alone from the plant's values and from Table 5.2/5.3's initial values",
        "thesis (Tables 5.2/5.3, Fig. 5.1): m4 103.5 -> -1.35, m5 137.1 -> 42.5, m6 106.4 -> "
        "41, g 3.63 -> -5.71, b3 300 -> 261; the other masses and drags stay near their values",
        f"{'':>17} {'':>9} {'':>6} {'':>7} {'':>7} {'':>7} {'':>7} {'change per hour':>20} "
        f"{'':>6} {'':>5} {'sel.':>4} {'rate':>4}",
        f"{'cause':>17} {'from':>9} {'eps':>6} {'m4 min':>7} {'m5 min':>7} {'m6 min':>7} "
        f"{'m6 end':>7} {'m4':>6} {'m5':>6} {'m6':>6} {'g end':>6} {'b3':>5} {'<0':>4} "
        f"{'1/2':>4}",
        f"{'thesis':>17} {'table-5.2':>9} {'':>6} {'':>7} {'':>7} {'':>7} "
        f"{THESIS_TABLE_5_2_5_3['final'][5]:>7.1f} "
        + " ".join(f"{v:>6.1f}" for v in THESIS_RATE_PER_H)
        + f" {THESIS_TABLE_5_2_5_3['final'][12]:>6.2f} {THESIS_TABLE_5_2_5_3['final'][15]:>5.0f}"
          f" {'YES':>4} {'YES':>4}",
    ]
    lines += [_row(a, seconds) for a in attempts]
    if not_run:
        lines.append(f"NOT RUN at {seconds / 3600:.2f} h ({len(not_run)} of {len(items)} "
                     "attempts of the plan): " + "; ".join(not_run))
    m6 = [a["m6_final"] - a["initial"][5] for a in attempts]
    lines.append(f"m6 (thesis 106.4 -> 41, {THESIS_RATE_PER_H[2]:.1f} per hour): ends above its "
                 f"start in {sum(d > 0 for d in m6)} of {len(attempts)} attempts; change over "
                 f"the run {min(m6):+.1f} to {max(m6):+.1f}")
    like = [a for a in attempts if thesis_like(a, seconds)]
    lines.append("<0: selective drift (m4 or m5 below zero, every other mass and drag within "
                 "0.5-2x its initial value throughout): "
                 + (", ".join(f"{a['cause']} from {a['init']}" for a in found) or "none"))
    lines.append("1/2: m4 or m5 falling at least half as fast as the thesis's (per hour), the "
                 "other masses and drags ending within 0.5-2x: "
                 + (", ".join(f"{a['cause']} from {a['init']} (eps {a['eps']:.3g})"
                              for a in like) or "none"))
    for a in attempts:
        a["rate_per_h"] = {n: rate_per_h(a, i, seconds) for n, i in (("m4", 3), ("m5", 4),
                                                                    ("m6", 5))}
        a["thesis_like_rate"] = thesis_like(a, seconds)
    lines.append("causes: " + "; ".join(f"{n}: {d}" for n, d in desc.items()))
    lines.append(
        f"eps: Theorem 5.2.2's bound min(4 k_p k_d / (2 lambda_1 k_p c + k_d^2), "
        f"sqrt(k_p lambda_6) / lambda_1) with App. B.2's c = 6 + 5pi/2 + pi^2/8 = "
        f"{C_APPENDIX_B2:.3f}: {bound['jhu-rov']['c_b2']:.4f} (jhu-rov M), "
        f"{bound['jhu-rov-coupled']['c_b2']:.4f} (jhu-rov-coupled M); with c = 1: "
        f"{bound['jhu-rov']['c1']:.3f}, {bound['jhu-rov-coupled']['c1']:.3f}. The attempts "
        f"use eps {EPS:g} (ambc-6dof-unstable's) unless the eps column says otherwise")
    if on_plant:
        r, t = on_plant["robust"], on_plant["two_step"]
        lines.append(f"on the plant of {found[0]['cause']}: robust single-step AMBC min "
                     f"eigenvalue of M-hat {r['min_mass_eigenvalue']:.1f}; two-step AMBC "
                     f"(second half of step 2) {t['min_mass_eigenvalue']:.1f}")
    out = {"duration_s": seconds, "gains": {"kp": KP, "kd": KD, "eps": EPS},
           "thesis": {**THESIS_TABLE_5_2_5_3,
                      "fig_5_1": "m4 and m5 adapt to physically unrealistic negative values "
                                 "and show no signs of asymptotic behavior (§5.3.2)"},
           "causes": {n: d for n, d in desc.items()}, "attempts": attempts,
           "selective_drift_reproduced": bool(found),
           "thesis_rate_per_h": dict(zip(("m4", "m5", "m6"), THESIS_RATE_PER_H, strict=True)),
           "thesis_like_rate": [f"{a['cause']} from {a['init']}" for a in like],
           "reproduced_by": [f"{a['cause']} from {a['init']}" for a in found],
           "on_reproducing_plant": on_plant, "epsilon_bound": bound,
           "plan_size": len(items), "not_run": not_run,
           "summary": "\n".join(lines)}
    if opts.plots is not None:
        write_m4_m5_figure(out, Path(opts.plots) / "fig51-hunt-m4-m5.png")
    return out


def _two_step_on(cause: str, kw: dict, opts: ExperimentOptions) -> dict:
    """Two-step AMBC (§5.3.5 gains, from zero) on the plant of ``cause``; M̂'s smallest
    eigenvalue over the second half of step 2."""
    from uvd.control.twostep import STEP1_DURATION_S, STEP2_DURATION_S
    from uvd.experiments.control import _pd_summary, _two_step_run
    run, _ = _two_step_run(opts, STEP1_DURATION_S, STEP2_DURATION_S,
                           f"fig51-hunt two-step on {cause}", lag_compensation=False,
                           ff_preview=False, vehicle=kw.get("vehicle", "jhu-rov"),
                           tank=kw.get("tank"), instruments=kw.get("instruments"))
    sel = run.theta_t >= STEP1_DURATION_S + 0.5 * STEP2_DURATION_S
    return _pd_summary(run.theta[sel], run.theta_t[sel])


def write_m4_m5_figure(result: dict, path: Path) -> Path | None:
    """m₄(t), m₅(t) of every attempt from Table 5.2's values (and the plant's), beside the
    thesis's Fig. 5.1 as Tables 5.2/5.3 give its ends (a PNG; None without matplotlib)."""
    from uvd.io.figures import _pyplot
    plt = _pyplot()
    if plt is None:
        return None
    th = result["thesis"]
    fig, axes = plt.subplots(2, 2, figsize=(12, 7), sharex=True, sharey="row")
    for col, init in enumerate(INITS):
        for row, (nm, k) in enumerate((("m4", 3), ("m5", 4))):
            ax = axes[row, col]
            mine = [a for a in result["attempts"] if a["init"] == init]
            colours = plt.get_cmap("tab20")(np.linspace(0.0, 1.0, max(len(mine), 2)))
            for a, colour in zip(mine, colours, strict=False):
                s = a["series"]
                lbl = a["cause"] + (f" eps {a['eps']:.3g}" if a["eps"] != EPS else "")
                ax.plot(s["t"], s[nm], lw=1.0, label=lbl, color=colour)
            if init == "table-5.2":
                ax.plot([0, 7200], [th["initial"][k], th["final"][k]], "k--", lw=2,
                        label="thesis: ends of Tables 5.2/5.3")
            ax.axhline(0.0, color="grey", lw=0.5)
            ax.set_title(f"{nm}(t), from {'the plant' if init == 'plant' else 'Table 5.2'}"
                         "'s values")
            ax.set_ylabel(f"{nm} (kg m²)")
    for ax in axes[1]:
        ax.set_xlabel("time (s)")
    axes[0, 1].legend(fontsize="x-small", ncol=2)
    fig.suptitle("fig51-hunt: m4, m5 of single-step AMBC, RefTraj1 (thesis Fig. 5.1: both fall "
                 "to 'physically unrealistic negative values', no asymptote)", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    """``python -m uvd.experiments.fig51_hunt part K N DIR [--hours H]``: part K of N of the
    plan (every N-th attempt in :func:`priority` order), one JSON per attempt in DIR, resumable;
    ``… assemble DIR --json OUT [--plots D] [--hours H]``: the result from the attempts in DIR
    (those not run are listed). ``uvd experiment fig51-hunt`` runs the same attempts in one
    process, and an attempt's row is the same either way (tests/test_reproduce.py)."""
    import argparse

    from uvd.jsonio import write_json
    ap = argparse.ArgumentParser(prog="python -m uvd.experiments.fig51_hunt")
    sub = ap.add_subparsers(dest="cmd", required=True)
    pp = sub.add_parser("part")
    pp.add_argument("k", type=int)
    pp.add_argument("n", type=int)
    pp.add_argument("dir", type=Path)
    pa = sub.add_parser("assemble")
    pa.add_argument("dir", type=Path)
    pa.add_argument("--json", type=Path, required=True)
    pa.add_argument("--plots", type=Path)
    for q in (pp, pa):
        q.add_argument("--hours", type=float, default=HOURS)
    args = ap.parse_args(argv)
    if args.cmd == "part":
        if not 0 <= args.k < args.n:
            ap.error(f"part {args.k} of {args.n}: K must be in 0..N-1")
        opts = ExperimentOptions(seed=0)
        run_attempts(priority()[args.k::args.n], args.hours * 3600.0, args.dir, opts)
        return 0
    opts = ExperimentOptions(seed=0, hours=args.hours, plots=args.plots)
    result = run_fig51_hunt(opts, load_attempts(args.dir))
    result.update(experiment="fig51-hunt", seed=0)
    write_json(args.json, result)
    print(result["summary"])
    return 0


EXPERIMENTS = [
    Experiment("fig51-hunt", "§5.3.2, Fig. 5.1: single-step AMBC with each candidate cause of "
               "the m4/m5 drift on (sim_bridge.tank), from the plant's and Table 5.2's values, "
               "2 h each", run_fig51_hunt),
]


if __name__ == "__main__":
    raise SystemExit(main())
