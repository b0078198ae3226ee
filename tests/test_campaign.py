"""uvd campaign: the campaign file's checks, the draws, the intervals, and small campaigns of
real lockstep runs on real Dask clusters (a LocalCluster the test starts; 1 vs 2 workers; a
campaign killed mid-run and started again)."""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.procs import assert_gone, descendants
from uvd.campaign import builtin
from uvd.campaign.execute import run_campaign
from uvd.campaign.runs import kind_axes
from uvd.campaign.spec import CampaignError, parse
from uvd.campaign.store import RUN_ENVIRONMENT, RowStore
from uvd.campaign.summary import median_ci, poisson_rate, proportion

ROOT = Path(__file__).resolve().parents[1]
# a few simulated seconds of PDC: a run takes well under a second once the kernels are cached
TINY = {"controller": "pdc", "duration_h": 0.005, "window_min": 0.1}


def _spec(axes: dict, **head):
    return parse({"campaign": {"name": "t", "kind": "control", **head}, "axes": axes},
                 kind_axes(), source="t.toml")


# ------------------------------------------------------------------------------ the file
@pytest.mark.parametrize("data, words", [
    ({"campaign": {"name": "t", "kind": "nope"}}, ["campaign.kind", "'nope'", "fdc"]),
    ({"campaign": {"name": "t", "kind": "control"}, "axes": {"gain": [1.0]}},
     ["axes.gain", "unknown axis", "kp"]),
    ({"campaign": {"name": "t", "kind": "control"}, "axes": {"seed": {"integers": [0, 9]}}},
     ["axes.seed", "random"]),
    ({"campaign": {"name": "t", "kind": "control"}, "axes": {"controller": ["pid"]}},
     ["axes.controller[0]", "'pid'", "two-step"]),
    ({"campaign": {"name": "t", "kind": "control"}, "axes": {"kp": "high"}},
     ["axes.kp", "not a number"]),
    ({"campaign": {"name": "t", "kind": "control", "sampling": "random"}},
     ["campaign.runs", "positive"]),
    ({"campaign": {"name": "t", "kind": "control", "sampling": "random", "runs": 2},
      "axes": {"kp": {"uniform": [5.0, 1.0]}}}, ["axes.kp.uniform", "a < b"]),
    ({"campaign": {"name": "t", "kind": "control"}, "extra": {}}, ["extra", "unknown table"]),
    ({"campaign": {"name": "t", "kind": "fdc"}, "axes": {"fault_size": {"by": "fault"}}},
     ["axes.fault_size.by", "'fault'"]),
    # found by fuzzing the built-in campaigns: each raised a bare TypeError or ValueError, or
    # (runs) hung listing its runs
    ({"campaign": {"name": "t", "kind": ["control"]}}, ["campaign.kind", "['control']"]),
    ({"campaign": {"name": "t", "kind": "fdc"},
      "axes": {"fault": ["drag"], "fault_size": {"by": ["fault"]}}},
     ["axes.fault_size.by", "['fault']"]),
    ({"campaign": {"name": "t", "kind": "control", "sampling": "random", "runs": 10 ** 30}},
     ["campaign.runs", "at most 100000"]),
    ({"campaign": {"name": "t", "kind": "control"},
      "axes": {"kp": [float(k) for k in range(1, 401)],
               "kd": [float(k) for k in range(1, 401)]}}, ["[axes]", "160000 runs"]),
    ({"campaign": {"name": "t", "kind": "control", "sampling": "random", "runs": 2},
      "axes": {"seed": {"integers": [0, 10 ** 30]}}}, ["axes.seed.integers", "±2⁶³"]),
    ({"campaign": {"name": "t", "kind": "control", "sampling": "random", "runs": 2},
      "axes": {"kp": {"uniform": [-1e308, 1e308]}}}, ["axes.kp.uniform", "finite"]),
    ({"campaign": {"name": "t", "kind": "control", "description": 7}},
     ["campaign.description", "string"]),
    # found by probing (session 21): said "[campaign]: missing"
    ({"campaign": 5}, ["[campaign]: must be a table, got int 5"]),
    ({"campaign": [1]}, ["[campaign]: must be a table, got list [1]"]),
    # found by probing (session 24): each ran, as a row's error (a negative seed, onset before
    # the baseline, a plant of no mass), as figures of no meaning (negative gains, a run
    # shorter than 0, η above 1, a drag scale below 0, a misspelt case never used) or for
    # ever (1e30 simulated hours)
    ({"campaign": {"name": "t", "kind": "control"}, "axes": {"seed": [0, -1]}},
     ["axes.seed: -1 must be ≥ 0 (run 1)"]),
    ({"campaign": {"name": "t", "kind": "control"}, "axes": {"mass_error": -1.0}},
     ["axes.mass_error: -1.0 must be > -1 (run 0)"]),
    ({"campaign": {"name": "t", "kind": "control"}, "axes": {"kd": [100.0, -5.0]}},
     ["axes.kd: -5.0 must be ≥ 0 (run 1)"]),
    ({"campaign": {"name": "t", "kind": "control"}, "axes": {"duration_h": -0.5}},
     ["axes.duration_h: -0.5 must be in (0, 1000]"]),
    ({"campaign": {"name": "t", "kind": "fdc"}, "axes": {"onset_min": 10.0}},
     ["axes.onset_min: 10.0 must be ≥ 25: the detector learns its baseline until then"]),
    ({"campaign": {"name": "t", "kind": "fdc", "sampling": "random", "runs": 50, "seed": 1},
      "axes": {"fault": ["thruster", "drag"],
               "fault_size": {"by": "fault", "thruster": {"uniform": [0.5, 1.5]},
                              "drag": 1.5}}},
     ["axes.fault_size: 1.", "must be in [0, 1] for a thruster fault (run "]),
    ({"campaign": {"name": "t", "kind": "fdc"},
      "axes": {"fault": "drag", "fault_size": -0.5}},
     ["axes.fault_size: -0.5 must be > 0 for a drag fault (run 0)"]),
    ({"campaign": {"name": "t", "kind": "control"}, "axes": {"duration_h": 1e30}},
     ["axes.duration_h: 1e+30 must be in (0, 1000] (run 0)"]),
    ({"campaign": {"name": "t", "kind": "fdc"}, "axes": {"after_min": [30.0, 1e30]}},
     ["axes.after_min: 1e+30 must be in (0, 60000] (run 1)"]),
    ({"campaign": {"name": "t", "kind": "fdc"}, "axes": {"onset_min": 9e18}},
     ["axes.onset_min: 9e+18 must be ≤ 60000 (run 0)"]),
    ({"campaign": {"name": "t", "kind": "fdc"},
      "axes": {"fault": ["drag"], "fault_size": {"by": "fault", "drag": 1.5, "darg": 2.0}}},
     ["axes.fault_size.darg: fault never takes this value; it takes none, thruster"]),
])
def test_a_bad_campaign_file_is_refused_by_name(data, words):
    with pytest.raises(CampaignError) as err:
        parse(data, kind_axes(), source="bad.toml")
    assert str(err.value).startswith("bad.toml: ")
    for w in words:
        assert w in str(err.value)


def test_a_grid_is_the_product_of_its_lists_with_the_kinds_defaults():
    spec = _spec({"controller": ["pdc", "two-step"], "seed": [0, 1, 2], "kp": 200})
    assert len(spec.runs) == 6
    assert {(r["controller"], r["seed"]) for r in spec.runs} == {
        (c, s) for c in ("pdc", "two-step") for s in (0, 1, 2)}
    assert all(r["kp"] == 200.0 and r["kd"] == 100.0 and r["mass_error"] == 0.0
               for r in spec.runs)


def test_random_draws_are_seeded_per_run_and_conditional_axes_follow_their_axis():
    axes = {"fault": ["thruster", "drag"], "seed": {"integers": [0, 1000]},
            "fault_size": {"by": "fault", "thruster": {"uniform": [0.0, 0.8]},
                           "drag": {"uniform": [1.2, 2.0]}}}

    def spec(n, seed=3):
        return parse({"campaign": {"name": "r", "kind": "fdc", "sampling": "random",
                                   "runs": n, "seed": seed}, "axes": axes}, kind_axes())
    a, b = spec(20), spec(40)
    assert a.runs == b.runs[:20]  # more runs keep the first ones
    assert spec(20, seed=4).runs != a.runs
    for r in b.runs:
        lo, hi = (0.0, 0.8) if r["fault"] == "thruster" else (1.2, 2.0)
        assert lo <= r["fault_size"] < hi and 0 <= r["seed"] < 1000
    assert {r["fault"] for r in b.runs} == {"thruster", "drag"}


def test_every_builtin_campaign_is_valid():
    found = builtin.campaigns()
    assert {"fdc-false-alarms", "fdc-detection", "control-model-error"} <= set(found)
    fa = found["fdc-false-alarms"]
    assert all(r["fault"] == "none" for r in fa.runs)
    assert {r["vehicle"] for r in fa.runs} == {"jhu-rov", "bluerov2-heavy"}
    # the "varied trajectories": both of Table 5.1, on both vehicles
    assert {(r["vehicle"], r["reference"]) for r in fa.runs} == {
        (v, t) for v in ("jhu-rov", "bluerov2-heavy") for t in ("reftraj1", "reftraj2")}
    det = found["fdc-detection"]
    assert len(det.runs) >= 300
    assert {r["fault"] for r in det.runs} == {"thruster", "drag", "mass", "buoyancy"}


# ------------------------------------------------------------------------------ intervals
def test_intervals_match_their_closed_forms():
    # no event in T hours: the one-sided 95 % upper bound is −ln(0.05)/T (the "rule of three")
    r = poisson_rate(0, 500.0)
    assert r["rate"] == 0.0 and r["low"] == 0.0
    assert r["upper_one_sided"] == pytest.approx(-math.log(0.05) / 500.0, rel=1e-9)
    # 0 of n: Clopper–Pearson's upper limit is 1 − (α/2)^(1/n)
    p = proportion(0, 10)
    assert p["low"] == 0.0 and p["high"] == pytest.approx(1 - 0.025 ** 0.1, rel=1e-9)
    # n of n: the lower limit is (α/2)^(1/n)
    p = proportion(10, 10)
    assert p["low"] == pytest.approx(0.025 ** 0.1, rel=1e-9) and p["high"] == 1.0
    m = median_ci(list(range(1, 102)))
    assert m["median"] == 51.0 and m["low"] < 51.0 < m["high"]
    assert median_ci(list(range(1, 102))) == m  # seeded: the same every time


# ------------------------------------------------------------------------------ on Dask
# The first lockstep run after a change to a kernel's source compiles every numba kernel (the
# cache is keyed on the sources, uvd/_jitcache.py): ~30 s on a quiet machine, minutes on a
# loaded one. It is done once, here in the test process (the workers share the cache), and
# these tests get room for it beside the default 300 s.
@pytest.fixture(scope="module")
def kernels_compiled():
    from uvd.campaign.runs import execute
    r = execute("control", {**_spec(TINY).runs[0]})
    assert r["error"] is None


DASK = [pytest.mark.timeout(900), pytest.mark.usefixtures("kernels_compiled")]


def _comparable(rows):
    return {r["key"]: {k: v for k, v in r.items() if k not in RUN_ENVIRONMENT + ("index",)}
            for r in rows}


def test_a_scheduler_that_cannot_be_reached_or_has_no_worker_is_named(tmp_path):
    """``--scheduler`` not an address, or nothing listening: a named error before any run
    (was distributed's traceback after 30 s); a scheduler with no worker: a named error after
    the wait (was a campaign waiting for ever)."""
    from dask.distributed import LocalCluster

    spec = _spec(TINY)
    with pytest.raises(CampaignError, match=r"scheduler 'foo': cannot connect: .*port"):
        run_campaign(spec, tmp_path, scheduler="foo")
    with LocalCluster(n_workers=0, processes=True, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0") as cluster:
        with pytest.raises(CampaignError, match=r"no worker joined in 2 s; nothing was run"):
            run_campaign(spec, tmp_path, scheduler=cluster.scheduler_address, worker_wait_s=2)
    assert RowStore(tmp_path).rows() == []


@DASK[0]
@DASK[1]
def test_two_runs_on_a_local_cluster_the_test_starts_one_raising(tmp_path):
    from dask.distributed import LocalCluster

    # mass_error −1 makes the plant's mass 0: PlantFault refuses it, inside the run. A
    # campaign file may not hold it (axes.mass_error must be > -1), so the spec is built here
    # with that run as a Dask client's own code could submit it
    good_spec = _spec({**TINY, "mass_error": [0.0, 0.5]})
    spec = dataclasses.replace(good_spec, runs=(good_spec.runs[0],
                                                {**good_spec.runs[1], "mass_error": -1.0}))
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0") as cluster:
        out = run_campaign(spec, tmp_path, scheduler=cluster.scheduler_address)
    assert (out.total, out.ran, out.failed, out.skipped) == (2, 2, 1, 0)
    rows = RowStore(tmp_path).rows()
    assert [r["index"] for r in rows] == [0, 1]
    good, bad = rows
    assert good["error"] is None and math.isfinite(good["out_position_mne"])
    assert good["out_position_mne"] > 0 and good["in_mass_error"] == 0.0
    # where it ran: host, process and the BLAS kernels (rows are bit for bit on the same ones)
    from uvd.blas import kernels
    here = sorted(set(kernels().values()))
    assert good["worker"].endswith(f" blas {', '.join(here)}" if here else "")
    assert good["worker"].split(" ")[0].rsplit(":", 1)[1].isdigit()
    assert bad["error"].startswith("ValueError: PlantFault: scales must be finite and > 0")
    assert not any(k.startswith("out_") for k in bad)  # no figures, only its error
    import pyarrow.parquet as pq
    table = pq.read_table(out.table)
    assert table.num_rows == 2 and table.column("error").to_pylist()[0] is None
    assert table.column("out_position_mne").to_pylist() == [good["out_position_mne"], None]


@DASK[0]
@DASK[1]
def test_rows_are_bit_identical_whatever_the_worker_count_or_order(tmp_path):
    spec = _spec({**TINY, "seed": [0, 1, 2], "kp": [250.0, 300.0]})
    backwards = spec.__class__(**{**spec.__dict__, "runs": tuple(reversed(spec.runs))})
    one = run_campaign(spec, tmp_path / "one", workers=1)
    two = run_campaign(backwards, tmp_path / "two", workers=2)
    assert (one.workers, two.workers) == (1, 2) and one.failed == two.failed == 0
    a = _comparable(RowStore(tmp_path / "one").rows())
    b = _comparable(RowStore(tmp_path / "two").rows())
    assert len(a) == 6 and a == b  # == on floats: bit for bit
    assert len({r["out_position_mne"] for r in a.values()}) == 6


@DASK[0]
@DASK[1]
def test_uvd_bench_campaign_reports_throughput_per_worker_count_and_compares_the_rows():
    import argparse

    from uvd.bench import get, run

    b = get("campaign")
    parser = argparse.ArgumentParser()
    b.add_arguments(parser)
    fig = run(b, parser.parse_args(["--runs", "2", "--minutes", "0.3", "--workers", "2", "1"]))
    assert (fig["runs"], fig["simulated_minutes_per_run"]) == (2, 0.3)
    for n in ("1", "2"):
        w = fig["by_workers"][n]
        assert (w["workers"], w["failed"]) == (int(n), 0)
        assert w["runs_per_hour"] == 3600.0 * 2 / w["wall_s"]
        assert 0.0 < w["run_wall_s_median"] < w["wall_s"]
    # the fewest workers are the base, whichever ran first: 2 workers' throughput over 1's
    assert fig["throughput_2_over_1"] == \
        fig["by_workers"]["2"]["runs_per_hour"] / fig["by_workers"]["1"]["runs_per_hour"]
    assert not any(k.startswith("throughput_1_over") for k in fig)
    assert fig["rows_bit_identical"] is True


def _campaign_with_a_row(spec_file: Path, out: Path, workers: int) -> subprocess.Popen:
    """``uvd campaign SPEC --out OUT --workers N --quiet`` in a session of its own, once its
    first row is stored (its output piped); killed, with its cluster and workers, if that
    fails."""
    proc = subprocess.Popen([sys.executable, "-m", "uvd", "campaign", str(spec_file), "--out",
                             str(out), "--workers", str(workers), "--quiet"], cwd=ROOT,
                            start_new_session=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 240
        while not list((out / "rows").glob("*.parquet")):
            assert proc.poll() is None, "the campaign ended before its first row"
            assert time.monotonic() < deadline, "no row within 240 s"
            time.sleep(0.05)
    except BaseException:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        raise
    return proc


@DASK[0]
@DASK[1]
def test_a_campaign_killed_mid_run_resumes_without_redoing_a_finished_run(tmp_path):
    spec_file = tmp_path / "c.toml"
    spec_file.write_text('[campaign]\nname = "kill"\nkind = "control"\n[axes]\n'
                         'controller = "pdc"\nduration_h = 0.01\nwindow_min = 0.5\n'
                         'seed = [0, 1, 2, 3, 4, 5]\n')
    out = tmp_path / "out"
    rows_dir = out / "rows"
    proc = _campaign_with_a_row(spec_file, out, workers=1)
    os.killpg(proc.pid, signal.SIGKILL)  # the campaign, its cluster and its workers
    proc.communicate(timeout=30)
    before = {p.name: p.stat().st_mtime_ns for p in rows_dir.glob("*.parquet")}
    assert 1 <= len(before) < 6, f"the kill came too late to test anything: {len(before)} rows"
    spec = builtin.resolve(spec_file)
    res = run_campaign(spec, out, workers=1)
    assert res.skipped == len(before) and res.ran == 6 - len(before) and res.failed == 0
    after = {p.name: p.stat().st_mtime_ns for p in rows_dir.glob("*.parquet")}
    assert len(after) == 6 and all(after[n] == t for n, t in before.items())
    assert not list(rows_dir.glob("*.tmp*"))
    assert res.table is not None and res.table.exists()


@DASK[0]
@DASK[1]
@pytest.mark.parametrize("presses", [1, 2])
def test_ctrl_c_ends_a_campaign_with_one_line_its_rows_kept_and_no_worker_left(tmp_path,
                                                                              presses):
    """Ctrl-C in the terminal (SIGINT to the campaign's whole process group) while both
    workers compute: the campaign ends with 130 and says "interrupted" in one line, the rows
    it finished are kept, and no worker outlives it. Before (session 32) each worker died of
    the SIGINT itself with two tracebacks (CancelledError, KeyboardInterrupt); ignoring it,
    a worker closed mid-run sometimes logged a failed heartbeat with a third. Pressed twice,
    0.3 s apart, the second broke off the cluster's close and the campaign ended 10.5 s after
    the first instead of 1.9 s (session 34)."""
    spec_file = tmp_path / "c.toml"
    spec_file.write_text('[campaign]\nname = "ctrl-c"\nkind = "control"\n[axes]\n'
                         'controller = "pdc"\nduration_h = 0.05\nwindow_min = 0.5\n'
                         'seed = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]\n')
    out = tmp_path / "out"
    rows_dir = out / "rows"
    proc = _campaign_with_a_row(spec_file, out, workers=2)
    try:
        below = descendants(proc.pid)
        t0 = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)
        if presses == 2:
            time.sleep(0.3)
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        ended_s = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
    assert proc.returncode == 130, err[-3000:]
    assert ended_s < 8.0, f"ended {ended_s:.1f} s after the first Ctrl-C"
    assert err.strip().splitlines()[-1] == "uvd campaign: interrupted", err[-3000:]
    assert "Traceback" not in err and "ERROR" not in err, err[-3000:]
    assert len(below) >= 2, f"the campaign's worker processes: {below}"
    assert_gone(below)
    rows = list(rows_dir.glob("*.parquet"))
    assert 1 <= len(rows) < 12, f"the Ctrl-C came too late to test anything: {len(rows)} rows"
    assert len(RowStore(out).done()) == len(rows)


def test_fdc_summary_counts_hours_at_risk_and_keeps_false_alarms_apart():
    from uvd.campaign.publish import render
    from uvd.campaign.summary import format_summary, summarize_fdc

    def row(fault, **out):
        base = {"error": None, "in_vehicle": "jhu-rov", "in_fault": fault,
                "in_fault_size": out.pop("size", 0.0), "out_simulated_h": 1.0}
        return {**base, **{f"out_{k}": v for k, v in out.items()}}
    rows = [row("none", false_alarms=0, monitored_h=3.5),
            row("none", false_alarms=1, monitored_h=1.25),
            row("drag", size=1.5, false_alarms=0, monitored_h=0.5, detected=True,
                right_kind=True, delay_s=20.0),
            row("drag", size=1.9, false_alarms=0, monitored_h=0.5, detected=True,
                right_kind=False, delay_s=40.0),
            row("drag", size=1.2, false_alarms=1, monitored_h=0.2, detected=False,
                right_kind=False, delay_s=None),
            {"error": "ValueError: x", "in_vehicle": "jhu-rov", "in_fault": "none"}]
    s = summarize_fdc(rows)
    fa = s["false_alarms_per_vehicle_hour"]
    assert (fa["count"], fa["exposure"]) == (2, 3.5 + 1.25 + 0.5 + 0.5 + 0.2)
    assert s["failed"] == 1 and s["runs"] == 6
    drag = s["faults"]["drag"]
    assert drag["false_alarm_before_fault"] == 1
    assert drag["detected"]["k"] == 2 and drag["detected"]["n"] == 2
    assert drag["right_kind"]["k"] == 1 and drag["delay_s"]["median"] == 30.0
    text = format_summary("fdc", s)
    assert "false alarms: 2 in 6.0 vehicle-hours" in text and "drag: detected 100%" in text
    page = "\n".join(render({"fdc-x": {
        "description": "d", "runs_summarised": 6, "runs_in_campaign": 10, "ran_now": 6,
        "workers": 2, "wall_seconds": 1.0, "load_average_before": [1.0],
        "load_average_after": [2.0], "summary_text": text, "figures": ["a.png"]}}))
    assert "6 of 10 runs (**partial**" in page and "![a.png](results/campaign-fdc-x/a.png)" in page
    assert "own wall time" not in page  # a JSON of before the runs' walls were kept
    page = "\n".join(render({"fdc-x": {
        "description": "d", "runs_summarised": 3, "runs_in_campaign": 3, "ran_now": 3,
        "workers": 2, "wall_seconds": 1.0, "load_average_before": [1.0],
        "load_average_after": [2.0], "summary_text": text, "figures": [],
        "wall_per_run_s": [40.0, 10.0, 25.0], "code_version": "abc123"}}))
    assert "3 of 3 runs; this instalment 3 runs" in page and "**partial**" not in page
    assert "own wall time 75 s in all (median 25 s, longest 40 s), on code version `abc123`" \
        in page
    page = "\n".join(render({"fdc-x": {  # published again with nothing left to run
        "description": "d", "runs_summarised": 3, "runs_in_campaign": 3, "ran_now": 0,
        "workers": 0, "wall_seconds": 0.6, "load_average_before": [1.0],
        "load_average_after": [2.0], "summary_text": text, "figures": [],
        "wall_per_run_s": [40.0, 10.0, 25.0], "code_version": "abc123"}}))
    assert "3 of 3 runs; every run from earlier instalments; every run's own wall time 75 s" \
        in page and "this instalment" not in page



def test_the_summary_says_what_each_fault_kind_was_named_as():
    from uvd.campaign.summary import format_summary, named_as, summarize_fdc

    def row(fault, detected, kind=None, right_thruster=None):
        return {"error": None, "in_vehicle": "jhu-rov", "in_fault": fault, "in_fault_size": 0.5,
                "out_simulated_h": 1.0, "out_false_alarms": 0, "out_monitored_h": 0.5,
                "out_detected": detected, "out_right_kind": kind == {"mass": "flooding"}.get(
                    fault, fault), "out_delay_s": 30.0 if detected else None,
                "out_first_kind": kind, "out_right_thruster": right_thruster}
    rows = [row("mass", True, "flooding"), row("mass", True, "thruster"),
            row("mass", True, "flooding"), row("mass", True, "drag-decrease"),
            row("mass", False), row("thruster", True, "thruster", True),
            row("thruster", True, "thruster", False), row("thruster", True, "buoyancy", False)]
    assert named_as(rows[:5]) == {"flooding": 2, "drag-decrease": 1, "thruster": 1}
    assert list(named_as(rows[:5])) == ["flooding", "drag-decrease", "thruster"]
    assert named_as(rows[5:]) == {"buoyancy": 1, "thruster": 1, "thruster (another)": 1}
    s = summarize_fdc(rows)
    assert s["faults"]["mass"]["right_kind"]["k"] == 2
    assert s["faults"]["mass"]["named_as"] == {"flooding": 2, "drag-decrease": 1, "thruster": 1}
    text = format_summary("fdc", s)
    assert "    named as: flooding 2, drag-decrease 1, thruster 1" in text
    assert "    named as: buoyancy 1, thruster 1, thruster (another) 1" in text


def test_the_fdc_figures_include_what_each_fault_kind_was_named_as(tmp_path):
    from uvd.campaign.report import write_figures
    from uvd.campaign.summary import summarize_fdc

    def row(fault, kind, **more):
        return {"error": None, "in_vehicle": "jhu-rov", "in_fault": fault, "in_fault_size": 0.5,
                "out_simulated_h": 1.0, "out_false_alarms": 0, "out_monitored_h": 0.5,
                "out_detected": kind is not None, "out_right_kind": kind == "flooding",
                "out_delay_s": 30.0 if kind else None, "out_first_kind": kind, **more}
    faults = [row("mass", "flooding"), row("mass", "thruster"), row("mass", None)]
    s = summarize_fdc(faults)
    files = write_figures("fdc", s, faults, tmp_path / "with")
    assert [f.name for f in files] == ["detection-by-size.png", "detection-delay.png",
                                       "named-as.png", "false-alarms.png"]
    assert all(f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for f in files)
    free = [row("none", None), row("none", None)]  # a fault-free campaign: no faults to name
    files = write_figures("fdc", summarize_fdc(free), free, tmp_path / "free")
    assert [f.name for f in files] == ["false-alarms.png"]


@DASK[0]
@DASK[1]
def test_published_again_with_nothing_to_run_keeps_the_instalment_that_ran_the_rows(tmp_path):
    """A re-summary of finished rows (a new figure of the summary) keeps how long the rows took;
    a changed row set does not inherit it."""
    import json

    from uvd.campaign.publish import publish

    spec_file = tmp_path / "c.toml"
    spec_file.write_text('[campaign]\nname = "again"\nkind = "control"\n[axes]\n'
                         'controller = "pdc"\nduration_h = 0.005\nwindow_min = 0.1\n'
                         'seed = [0, 1]\n')
    work, res = tmp_path / "work", tmp_path / "results"
    first = publish(str(spec_file), work, res, workers=1, progress=lambda s: None)
    assert first["ran_now"] == 2 and first["wall_seconds"] > 0
    path = res / f"campaign-{first['campaign']}.json"
    again = publish(str(spec_file), work, res, workers=1, progress=lambda s: None)
    kept = json.loads(path.read_text())
    for k in ("ran_now", "workers", "wall_seconds", "load_average_before"):
        assert again[k] == kept[k] == first[k], k
    assert kept["summary"] == first["summary"]
    # the stored JSON summarised other rows (here: one run's wall time differs): not kept
    kept["wall_per_run_s"][0] += 1.0
    path.write_text(json.dumps(kept))
    third = publish(str(spec_file), work, res, workers=1, progress=lambda s: None)
    assert (third["ran_now"], third["workers"]) == (0, 0)  # its own: nothing ran


def test_make_results_campaign_progress_says_how_long_so_far_and_what_is_left():
    from uvd.campaign.publish import _pace
    assert _pace(660.0, 7920.0) == ", 11 min, ~2 h 12 min left"
    assert _pace(7400.0, None) == ", 2 h 3 min"  # done: nothing left to estimate
    assert _pace(90.0, 270.0) == ", 2 min, ~4 min left"


def test_a_row_half_written_by_a_dead_campaign_is_removed_and_a_live_writers_is_kept(tmp_path):
    rows = tmp_path / "rows"
    rows.mkdir()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait(timeout=30)  # its pid now names no process (reaped)
    stale = rows / f"abc.tmp{dead.pid}"
    live = rows / f"def.tmp{os.getpid()}"
    stale.write_bytes(b"half a row")
    live.write_bytes(b"being written")
    store = RowStore(tmp_path)
    assert store.stale_removed == 1 and not stale.exists() and live.exists()
    assert store.done() == set()  # neither counts as a finished run


@DASK[0]
def test_the_local_cluster_listens_on_loopback_only():
    """Scheduler, worker and dashboard on 127.0.0.1 (the dashboard on a free port: 8787 may be
    another cluster's)."""
    from uvd.campaign.execute import _client

    client, cluster = _client(1, None)
    try:
        client.wait_for_workers(1, timeout=60)
        workers = list(client.scheduler_info()["workers"])
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        assert workers and all(w.startswith("tcp://127.0.0.1:") for w in workers)
        assert client.dashboard_link.startswith("http://127.0.0.1:")
    finally:
        client.close()
        cluster.close()


def test_an_fdc_run_stops_at_its_first_alarm():
    """A campaign's fdc run ends with the estimates' batch that brought the first alarm (every
    figure is the first alarm's): a half-strength thruster 2 from minute 25.5 is named within
    the 4.5 minutes watched, and the run stops there, simulated hours and all."""
    from uvd.campaign.runs import execute
    from uvd.experiments.fdc import EVERY_S
    res = execute("fdc", {"vehicle": "jhu-rov", "seed": 3, "noise_scale": 1.0,
                          "fault": "thruster", "fault_size": 0.5, "fault_thruster": 1,
                          "onset_min": 25.5, "after_min": 4.5, "reference": "reftraj1"})
    assert res["error"] is None, res["error"]
    f = res["figures"]
    assert f["detected"] and f["false_alarms"] == 0 and f["first_channel"] == "thruster2", f
    simulated_s = f["simulated_h"] * 3600.0
    assert simulated_s < 30.0 * 60.0  # stopped before the planned end
    assert f["first_t_s"] - 1e-6 <= simulated_s <= f["first_t_s"] + EVERY_S + 1e-6, f
    assert f["alarms"] >= 1


def test_a_row_that_cannot_be_written_is_named_and_leaves_no_temporary_file(tmp_path):
    """A full disk (here RLIMIT_FSIZE of 1 byte: each write fails in the kernel) at a row: the
    error names the row's file and no ``.tmp`` is left (session 25, on a full tmpfs: pyarrow's
    message named no file; ``uvd campaign`` then ended in that line, and resumed without redoing
    a run once there was room)."""
    code = ("import resource, signal, sys\n"
            "from uvd.campaign.store import RowStore\n"
            "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
            "store = RowStore(sys.argv[1])\n"
            "hard = resource.getrlimit(resource.RLIMIT_FSIZE)[1]\n"
            "resource.setrlimit(resource.RLIMIT_FSIZE, (1, hard))\n"
            "try:\n    store.write({'key': 'k1', 'x': list(range(1000))})\n"
            "except OSError as exc:\n    print(exc)\n")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True,
                       text=True, timeout=120)
    row = tmp_path / "rows" / "k1.parquet"
    assert r.stdout.startswith(f"[Errno 27] cannot write the row {row}: "), r.stderr[-2000:]
    assert list((tmp_path / "rows").iterdir()) == []


def test_a_second_campaign_into_a_folder_being_filled_is_refused(tmp_path, capsys):
    """Two campaigns into one folder (a second terminal, a timer) each ran every run, beside
    the other on the same cores (60 and 58 of control-model-error's 60, session 34): the
    second now says who fills the folder and stops before it runs anything."""
    from uvd.claims import claim
    from uvd.cli import main
    out = tmp_path / "c"
    with claim("campaign", str(out.resolve())):  # as the first campaign holds it
        assert main(["campaign", "smoke", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"uvd campaign: {out} is being filled by another campaign (process {os.getpid()})" \
        in err, err
    assert not (out / "rows").exists() or not any((out / "rows").iterdir())
