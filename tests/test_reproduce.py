"""`make results-check` (uvd.experiments.reproduce): the comparison, and issue 32's two tables
re-run from their printed command, short, reproducing bit for bit in a second process."""

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


@pytest.mark.parametrize("name, hours", [("pdc-vs-ambc", 0.01)])
def test_short_run_reproduces_from_its_command_bit_for_bit(tmp_path, name, hours, capsys):
    """The printed command, twice, in two processes (a short duration: the full runs take
    hours and go to `make results-check`); every number equal to the bit."""
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        subprocess.run([sys.executable, "-m", "uvd", "experiment", name, "--hours", str(hours),
                        "--json", str(tmp_path / folder / f"{name}.json"), "--quiet"],
                       check=True, stdout=subprocess.DEVNULL, timeout=900)
    assert main([name, "--committed", str(tmp_path / "a"), "--against", str(tmp_path / "b"),
                 "--rel", "0"]) == 0
    assert f"{name}: reproduced" in capsys.readouterr().out
    # and the check can fail: one number of one run moved
    d = json.loads((tmp_path / "b" / f"{name}.json").read_text())
    key = "attempts" if name == "fig51-hunt" else "ambc_windows"
    first = d[key][0]
    field = "m4_min" if name == "fig51-hunt" else "position_mne"
    first[field] = first[field] * (1 + 1e-6)
    (tmp_path / "b" / f"{name}.json").write_text(json.dumps(d))
    assert main([name, "--committed", str(tmp_path / "a"), "--against",
                 str(tmp_path / "b")]) == 1


def test_fig51_hunt_run_in_parts_equals_the_command_bit_for_bit(tmp_path, capsys):
    """The attempts of fig51-hunt run in two parts apart (``python -m
    uvd.experiments.fig51_hunt part K 2``) and assembled give the command's JSON to the bit."""
    hours = "0.002"
    (tmp_path / "one").mkdir()
    subprocess.run([sys.executable, "-m", "uvd", "experiment", "fig51-hunt", "--hours", hours,
                    "--json", str(tmp_path / "one" / "fig51-hunt.json"), "--quiet"],
                   check=True, stdout=subprocess.DEVNULL, timeout=900)
    for k in ("0", "1"):
        subprocess.run([sys.executable, "-m", "uvd.experiments.fig51_hunt", "part", k, "2",
                        str(tmp_path / "parts"), "--hours", hours], check=True, timeout=900)
    (tmp_path / "two").mkdir()
    subprocess.run([sys.executable, "-m", "uvd.experiments.fig51_hunt", "assemble",
                    str(tmp_path / "parts"), "--json", str(tmp_path / "two" / "fig51-hunt.json"),
                    "--hours", hours], check=True, stdout=subprocess.DEVNULL, timeout=900)
    assert main(["fig51-hunt", "--committed", str(tmp_path / "one"), "--against",
                 str(tmp_path / "two"), "--rel", "0"]) == 0
    assert "fig51-hunt: reproduced" in capsys.readouterr().out
