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


def _command(name: str, hours: str, out) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "uvd", "experiment", name, "--hours", hours,
                    "--json", str(out), "--quiet"], check=True, stdout=subprocess.DEVNULL,
                   timeout=900)


def test_pdc_vs_ambc_rows_run_apart_equal_the_command_bit_for_bit(tmp_path, capsys):
    """pdc-vs-ambc's printed command, short, against its rows run in processes apart and
    assembled (``python -m uvd.experiments.control pdc-vs-ambc-row``): every number equal to
    the bit; then one number moved makes the check fail."""
    from uvd.experiments.control import PDC_VS_AMBC_ROWS
    hours = "0.01"
    _command("pdc-vs-ambc", hours, tmp_path / "one" / "pdc-vs-ambc.json")
    for spec in PDC_VS_AMBC_ROWS:
        subprocess.run([sys.executable, "-m", "uvd.experiments.control", "pdc-vs-ambc-row",
                        spec["name"], str(tmp_path / "rows" / f"{spec['name']}.json"),
                        "--hours", hours], check=True, stderr=subprocess.DEVNULL, timeout=900)
    (tmp_path / "two").mkdir()
    subprocess.run([sys.executable, "-m", "uvd.experiments.control", "pdc-vs-ambc-assemble",
                    str(tmp_path / "rows"), "--json", str(tmp_path / "two" / "pdc-vs-ambc.json"),
                    "--hours", hours], check=True, stdout=subprocess.DEVNULL, timeout=900)
    assert main(["pdc-vs-ambc", "--committed", str(tmp_path / "one"), "--against",
                 str(tmp_path / "two"), "--rel", "0"]) == 0
    assert "pdc-vs-ambc: reproduced" in capsys.readouterr().out
    d = json.loads((tmp_path / "two" / "pdc-vs-ambc.json").read_text())
    d["ambc_windows"][0]["position_mne"] *= 1 + 1e-6
    (tmp_path / "two" / "pdc-vs-ambc.json").write_text(json.dumps(d))
    assert main(["pdc-vs-ambc", "--committed", str(tmp_path / "one"), "--against",
                 str(tmp_path / "two")]) == 1
    assert "NOT reproduced" in capsys.readouterr().out


def test_fig51_hunt_run_in_parts_equals_the_command_bit_for_bit(tmp_path, capsys):
    """The attempts of fig51-hunt run in two parts apart (``python -m
    uvd.experiments.fig51_hunt part K 2``) and assembled give the command's JSON to the bit."""
    hours = "0.002"
    _command("fig51-hunt", hours, tmp_path / "one" / "fig51-hunt.json")
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
