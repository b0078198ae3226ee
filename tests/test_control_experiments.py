"""Smoke tests of the Chapter 5 experiments and of ``uvd bench control``: each runs shortened
(``--hours 0.02``, ~70 simulated seconds) and must produce its documented JSON keys and a
summary. The figures themselves come from the full-length runs (docs/RESULTS.md)."""

import argparse
import json
import math

import pytest

from uvd import experiments
from uvd.cli import main as uvd_main

SHORT = 0.02

KEYS = {
    "ambc-6dof-unstable": ["parameters", "true", "initial", "final", "series",
                           "min_mass_eigenvalue", "m4_m5", "final_relative_error"],
    "pitch-reversal": ["cases"],
    "two-step": ["final", "true", "step1", "windows", "masses_drags_within_10pct",
                 "g_b_within_5pct", "theta_after_s"],
    "two-step-no-lag": ["final", "true", "step1", "windows", "thruster_effects"],
    "pdc-vs-ambc": ["pdc", "ambc", "position_ratio", "velocity_ratio", "headline", "idealised",
                    "heading_account"],
    "fig51-hunt": ["attempts", "causes", "selective_drift_reproduced", "thesis_like_rate",
                   "epsilon_bound"],
    "xval-two-step": ["models", "states", "adaptation_times_s"],
    "ambc-robust": ["min_mass_eigenvalue", "final", "masses_drags_within_25pct"],
    "ambc-full": ["pdc", "ambc", "position_ratio", "velocity_ratio",
                  "relative_parameter_error", "min_mass_eigenvalue"],
}


@pytest.mark.parametrize("name", sorted(KEYS))
def test_experiment_runs_shortened(name):
    exp = experiments.get(name)
    msgs = []
    res = exp.run(experiments.ExperimentOptions(seed=0, hours=SHORT, progress=msgs.append))
    for key in KEYS[name]:
        assert key in res, f"{name}: missing {key}"
    assert isinstance(res["summary"], str) and res["summary"]
    assert msgs  # progress is reported
    json.dumps(res)  # JSON-serialisable as is
    if name in ("pdc-vs-ambc", "ambc-full"):
        for k in ("position_mne", "velocity_mne"):
            assert math.isfinite(res["pdc"][k]) and res["pdc"][k] > 0
            assert math.isfinite(res["ambc"][k]) and res["ambc"][k] > 0
        assert res["position_ratio"] == pytest.approx(res["ambc"]["position_mne"]
                                                      / res["pdc"]["position_mne"])
    if name == "pitch-reversal":
        rev, none = res["cases"]["reversals"], res["cases"]["no_reversals"]
        # about 0° the pitch thrusters reverse; about 5° ± 3° they do not
        assert rev["reversals"] > 0
        assert none["reversals"] < rev["reversals"]
    if name == "xval-two-step":
        assert set(res["models"]) == {"250s", "1000s", "5000s", "true"}
    if name == "pdc-vs-ambc":
        assert res["vehicle"] == "jhu-rov-coupled"  # the headline: the coupled plant
        assert res["rows"][res["idealised"]]["vehicle"] == "jhu-rov"
    if name == "fig51-hunt":  # every cause alone, from the plant's and Table 5.2's values
        from uvd.experiments.fig51_hunt import CAUSES
        for cause, _, _ in CAUSES:
            inits = {a["init"] for a in res["attempts"] if a["cause"] == cause}
            assert inits == {"plant", "table-5.2"}, cause


def test_experiment_command_writes_json(tmp_path, capsys):
    out = tmp_path / "r.json"
    rc = uvd_main(["experiment", "ambc-robust", "--hours", "0.005", "--json", str(out)])
    assert rc == 0
    data = json.loads(out.read_text())
    assert data["experiment"] == "ambc-robust" and data["seed"] == 0
    assert "ambc-robust" in capsys.readouterr().out


def test_bench_control_reports_median_and_p99():
    from uvd.bench.control import BENCH

    figs = BENCH.run(argparse.Namespace(cycles=300, lockstep_seconds=20.0))
    for key in ("pdc", "ambc_full_241", "ambc_full_241_robust", "ambc_decoupled_16"):
        assert figs[key]["p50"] > 0 and figs[key]["p99"] >= figs[key]["p50"]
    assert figs["lockstep_two_step"]["extrapolated_wall_s_for_6_h"] > 0


def test_results_page_puts_each_summary_next_to_its_thesis_figure(tmp_path):
    from uvd.experiments import results

    reg = experiments.registry()
    page = results.render({"two-step": {"summary": "TABLE", "wall_seconds": 3.0},
                           "pdc-vs-ambc": {"error": "RuntimeError('x')"}}, reg)
    assert "## two-step" in page and "Table 5.5" in page and "TABLE" in page
    assert "uvd experiment two-step --json docs/results/two-step.json" in page
    assert "**Failed:**" in page
    # --reuse renders from JSON files without running anything
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "two-step.json").write_text(json.dumps({"summary": "REUSED"}))
    assert results.main(["--reuse", "--out", str(tmp_path), "--only", "two-step"]) == 0
    assert "REUSED" in (tmp_path / "RESULTS.md").read_text()
    # --only: the experiments not run keep their section, in the page's order
    (tmp_path / "results" / "pitch-reversal.json").write_text(json.dumps({"summary": "KEPT"}))
    assert results.main(["--reuse", "--out", str(tmp_path), "--only", "two-step"]) == 0
    page = (tmp_path / "RESULTS.md").read_text()
    assert "KEPT" in page and page.index("## pitch-reversal") < page.index("## two-step")
    # --only with no name is refused (it used to mean every experiment and every campaign)
    with pytest.raises(SystemExit) as refused:
        results.main(["--reuse", "--out", str(tmp_path), "--only"])
    assert refused.value.code == 2
