"""`make results-check` (uvd.experiments.reproduce): the comparison; and issue 32's two tables
(pdc-vs-ambc, fig51-hunt), short, from their printed command and from their parts run in
processes apart, equal bit for bit."""

from __future__ import annotations

import copy
import json
import subprocess
import sys

import pytest

from uvd.experiments.reproduce import compare, main, relative_difference, reproduced

RESULT = {"position_ratio": 0.754, "rows": {"a": {"theta": [1.0, -2.5, 0.0], "ok": True}},
          "summary": "ratio 0.754", "wall_seconds": 12.0, "attempts": [{"sim_wall_s": 3.0,
                                                                        "m4_min": 95.7}]}


def test_identical_results_reproduce():
    r = compare(RESULT, copy.deepcopy(RESULT))
    assert reproduced(r) and r["numbers"] == 5 and r["max_rel"] == 0.0


def test_a_number_off_by_more_than_the_tolerance_is_named():
    new = copy.deepcopy(RESULT)
    new["rows"]["a"]["theta"][1] = -2.5 * (1 + 1e-6)
    r = compare(RESULT, new)
    assert not reproduced(r)
    assert [p for p, *_ in r["over"]] == ["$.rows.a.theta[1]"]
    assert r["max_rel"] == pytest.approx(1e-6, rel=1e-3)


def test_last_bit_differences_are_within_the_tolerance_but_not_bit_for_bit():
    new = copy.deepcopy(RESULT)
    new["position_ratio"] = 0.754 * (1 + 1e-12)
    assert reproduced(compare(RESULT, new))
    assert not reproduced(compare(RESULT, new, rel=0.0))


def test_keys_lengths_strings_flags_must_be_equal_timings_are_not_compared():
    new = copy.deepcopy(RESULT)
    new["wall_seconds"], new["attempts"][0]["sim_wall_s"] = 99.0, 7.0
    assert reproduced(compare(RESULT, new))
    for change in (lambda d: d.pop("position_ratio"), lambda d: d["rows"]["a"]["theta"].pop(),
                   lambda d: d.update(summary="ratio 0.755"),
                   lambda d: d["rows"]["a"].update(ok=False),
                   lambda d: d["rows"]["a"].update(ok=1)):
        new = copy.deepcopy(RESULT)
        change(new)
        r = compare(RESULT, new)
        assert not reproduced(r) and r["unequal"], change


def test_relative_difference_edges():
    assert relative_difference(0.0, 0.0) == 0.0
    assert relative_difference(float("nan"), float("nan")) == 0.0
    assert relative_difference(float("inf"), 1e300) == float("inf")
    assert relative_difference(1.0, 2.0) == 0.5


def _json(x):
    return json.loads(json.dumps(x))


def test_a_pdc_vs_ambc_row_run_apart_equals_the_row_in_process_bit_for_bit(tmp_path, capsys):
    """A row of pdc-vs-ambc run in a process apart (``python -m uvd.experiments.control
    pdc-vs-ambc-row``, as the committed JSON's rows were) equals the same row computed here, by
    the function the command calls, to the bit (short: 0.001 h and the 60 s PDC)."""
    from uvd.experiments import ExperimentOptions
    from uvd.experiments.control import pdc_vs_ambc_row, run_pdc_vs_ambc
    hours = 0.001
    out = tmp_path / "rows" / "kd1000.json"
    subprocess.run([sys.executable, "-m", "uvd.experiments.control", "pdc-vs-ambc-row",
                    "kd1000", str(out), "--hours", str(hours)], check=True,
                   stderr=subprocess.DEVNULL, timeout=280)
    apart = json.loads(out.read_text())
    here = _json(pdc_vs_ambc_row("kd1000", ExperimentOptions(hours=hours,
                                                              progress=lambda m: None)))
    assert main(["pdc-vs-ambc", "--committed", str(_dump(tmp_path / "a", here)),
                 "--against", str(_dump(tmp_path / "b", apart["row"])), "--rel", "0"]) == 0
    assert "reproduced" in capsys.readouterr().out
    with pytest.raises(ValueError, match="every row"):  # a table is never built from some rows
        run_pdc_vs_ambc(ExperimentOptions(hours=hours), {"kd1000": apart["row"]})


def _dump(folder, result, name="pdc-vs-ambc"):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}.json").write_text(json.dumps(result))
    return folder


def test_fig51_hunt_attempt_run_in_a_part_equals_the_command_s_bit_for_bit(tmp_path, capsys):
    """An attempt of fig51-hunt run in a part apart (``python -m uvd.experiments.fig51_hunt
    part``) equals the same attempt as the command runs it (:func:`run_plan`), to the bit; the
    assembled result lists the plan's other attempts as not run."""
    from uvd.experiments import ExperimentOptions
    from uvd.experiments.fig51_hunt import (
        load_attempts,
        plan,
        priority,
        run_fig51_hunt,
        run_plan,
    )
    hours, n = 0.004, len(plan())
    subprocess.run([sys.executable, "-m", "uvd.experiments.fig51_hunt", "part", "0", str(n),
                    str(tmp_path / "parts"), "--hours", str(hours)], check=True, timeout=280)
    got = load_attempts(tmp_path / "parts")
    first = priority()[0]
    assert list(got) == [first]
    opts = ExperimentOptions(hours=hours, progress=lambda m: None)
    here = _json(run_plan([plan()[first]], hours * 3600.0, opts)[0])
    apart = {k: v for k, v in got[first].items() if k != "cpu_s"}
    assert main(["fig51-hunt", "--committed", str(_dump(tmp_path / "a", here, "fig51-hunt")),
                 "--against", str(_dump(tmp_path / "b", apart, "fig51-hunt")), "--rel",
                 "0"]) == 0
    assert "reproduced" in capsys.readouterr().out
    result = run_fig51_hunt(opts, got)
    assert len(result["attempts"]) == 1 and len(result["not_run"]) == n - 1
    assert f"NOT RUN at {hours:.2f} h ({n - 1} of {n}" in result["summary"]


def test_a_wall_time_quoted_in_a_summary_is_not_compared_its_figures_are():
    a = {"summary": "120 simulated min; lockstep 53.3 s wall\nwall: LS 0.5 s, xval 2.2 s\nerr 0.25"}
    later = {"summary": a["summary"].replace("53.3", "61.8").replace("0.5 s", "2.7 s")}
    assert reproduced(compare(a, later))
    moved = {"summary": a["summary"].replace("err 0.25", "err 0.26")}
    assert not reproduced(compare(a, moved))


def test_lines_printed_in_arrival_order_compare_as_a_multiset_latencies_not_at_all():
    """fdc-fleet: uvd-fdc's printed lines (its vehicles come "up" in the order their first
    samples arrive) and its wall-clock latency through Zenoh; a changed line still counts."""
    a = {"fdc_output": ["uvd-fdc: watching", "sim1: up", "sim0: up", "FAULT sim0: thruster"],
         "latency_ms": {"p50": 3.2}, "runs": {"sim0": {"latency_s": 60.0}}}
    b = copy.deepcopy(a)
    b["fdc_output"][:3] = ["sim0: up", "uvd-fdc: watching", "sim1: up"]
    b["latency_ms"]["p50"] = 6.8
    assert reproduced(compare(a, b))
    for change in (lambda d: d["fdc_output"].__setitem__(3, "FAULT sim0: buoyancy"),
                   lambda d: d["fdc_output"].pop(),
                   lambda d: d["runs"]["sim0"].update(latency_s=70.0)):
        c = copy.deepcopy(b)
        change(c)
        assert not reproduced(compare(a, c)), change


def test_a_real_time_run_is_judged_on_its_lockstep_part_and_its_texts_not_its_timing():
    """fault-tolerance-hil: its HIL figures move with the machine's timing; its lockstep
    reference, its texts (digits masked) and its keys must still reproduce."""
    from uvd.experiments.reproduce import compare_real_time, report_line
    strict = frozenset({"lockstep"})
    a = {"lockstep": {"x": 7.3}, "dead": {"x": 10.3, "accommodated": ["thruster 4 eta 0"],
                                          "given_up": "none"},
         "summary": "dead x 10.3 mm; largest: x"}
    b = copy.deepcopy(a)
    b["dead"]["x"], b["summary"] = 11.1, "dead x 11.1 mm; largest: y"
    r = compare_real_time(a, b, strict)
    assert reproduced(r) and r["real_time"]["max_rel"] > 0.07
    assert "not judged" in report_line("hil", r)
    for change in (lambda d: d["lockstep"].update(x=7.31),
                   lambda d: d["dead"].update(given_up="pitch"),
                   lambda d: d["dead"]["accommodated"].clear(),
                   lambda d: d["dead"].pop("x")):
        c = copy.deepcopy(b)
        change(c)
        assert not reproduced(compare_real_time(a, c, strict)), change


@pytest.mark.parametrize("core", [None, "Haswell", "Nehalem"])
def test_a_failed_check_names_the_blas_kernels_against_those_of_the_committed_files(core):
    """On an AVX-512 machine (OpenBLAS's SkylakeX kernels) aid-rot, aid-hover, fault-tolerance
    and fault-tolerance-every did not reproduce docs/results/ and did with
    OPENBLAS_CORETYPE=Haswell (0 to 3.8e-16 relative): the note a failed check prints names
    both and that command. Here in a fresh process with the kernels forced (x86_64 only)."""
    import os
    import platform
    from pathlib import Path
    if core is not None and (platform.machine() != "x86_64" or "avx2" not in
                             Path("/proc/cpuinfo").read_text(errors="replace")):
        pytest.skip("forcing x86_64 OpenBLAS kernels wants an x86_64 CPU with AVX2")
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    if core is not None:
        env["OPENBLAS_CORETYPE"] = core
    # the note and the kernels it names, both of the child: this process's kernels are what
    # its own environment chose (OPENBLAS_CORETYPE set where it runs, say), not the child's
    child = subprocess.run([sys.executable, "-c", "from uvd.experiments.reproduce import "
                            "_kernels_note; from uvd.blas import kernel_names; "
                            "print(kernel_names()); print(_kernels_note())"],
                           capture_output=True, text=True, env=env, timeout=120,
                           check=True).stdout
    named, note = child.split("\n", 1)  # named is "" where the kernels cannot be told
    note = note.strip()
    if core == "Haswell":
        assert note.startswith("the runs used the BLAS kernels docs/results/ was written with "
                               "(Haswell)")
    elif core == "Nehalem":
        assert note.startswith("the runs used the BLAS kernels Nehalem; docs/results/ was "
                               "written with Haswell's")
        assert note.endswith("OPENBLAS_CORETYPE=Haswell make results-check")
    else:
        assert (note.startswith("the runs used the BLAS kernels docs/results/ was written with")
                if named == "Haswell" else f"BLAS kernels {named or 'unknown'};" in note), note
