"""The benchmark history (docs/bench/history.jsonl) and the page generated from it."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from uvd.bench import all as bench_all
from uvd.bench.page import (
    HISTORY,
    PAGE,
    append_history,
    flatten,
    load_history,
    main,
    new_record,
    render,
)
from uvd.cli import main as uvd_main
from uvd.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
MACHINE = {"python": "3.11.7", "processor": "x86_64", "cpus": 2}


def _rec(bench, date, figures, commit="abc1234", machine=MACHINE):
    return {"bench": bench, "date": date, "commit": commit, "machine": machine,
            "summary": f"{bench} summary", "figures": figures}


def test_the_repository_page_is_rendered_from_its_history():
    """docs/BENCHMARKS.md is exactly what `python -m uvd.bench.page` makes of the history."""
    records = load_history(ROOT / HISTORY)
    assert len(records) >= 25  # the 25 dumps of the old append-only page, converted
    assert {r["bench"] for r in records} >= {"can", "control", "drivers", "estimation",
                                             "latency", "loop", "plant"}
    assert (ROOT / PAGE).read_text(encoding="utf-8") == render(records)


def test_latest_beside_previous_one_table_per_benchmark():
    pct = {"n": 10, "p50": 1.5, "p90": 2.0, "p99": 3.25, "p999": 4.0, "max": 5.0}
    records = [
        _rec("b", "2026-01-01 00:00 UTC", {"rtf": 100.0, "step_us": pct, "old": 1}),
        _rec("a", "2026-01-01 00:00 UTC", {"x": 1}),
        _rec("b", "2026-01-02 00:00 UTC", {"rtf": 250.0, "step_us": pct,
                                          "nested": {"ok": True, "none": None}},
             commit="def5678-dirty", machine={**MACHINE, "cpus": 8, "blas": "SkylakeX"}),
    ]
    page = render(records)
    assert page.index("## `uvd bench a`") < page.index("## `uvd bench b`")
    assert page.count("## `uvd bench") == 2
    b = page[page.index("## `uvd bench b`"):]
    assert "Latest run: 2026-01-02 00:00 UTC · commit `def5678-dirty` · x86_64, 8 CPUs, " \
           "BLAS SkylakeX, Python 3.11.7 · 2 run(s) in the history." in b
    assert "| `rtf` | 250 | 100 |" in b
    assert "| `step_us` | p50 1.5 · p90 2 · p99 3.25 · p99.9 4 · max 5 (n 10) | " in b
    assert "| `nested.ok` | true | not measured |" in b
    assert "| `nested.none` | — | not measured |" in b
    assert "`old`" not in b  # figures of the latest run only
    assert "| *machine* | x86_64, 8 CPUs, BLAS SkylakeX, Python 3.11.7 | x86_64, 2 CPUs, " \
           "Python 3.11.7 |" in b   # (the BLAS kernels recorded since session 20)
    a = page[page.index("## `uvd bench a`"):page.index("## `uvd bench b`")]
    assert "| figure | latest |\n| --- | --- |\n| `x` | 1 |" in a


def test_flatten_keeps_percentiles_and_lists_whole():
    figs = {"a": {"b": {"c": 1}, "p": {"p50": 1.0, "p99": 2.0}}, "l": [1, 2]}
    assert flatten(figs) == {"a.b.c": 1, "a.p": {"p50": 1.0, "p99": 2.0}, "l": [1, 2]}


def test_history_round_trip_and_bad_lines(tmp_path):
    h = tmp_path / "h" / "history.jsonl"
    rec = new_record("x", "sum", {"v": math.inf, "bench": "x", "machine": MACHINE},
                     commit=None, date="2026-01-01 00:00 UTC")
    append_history(h, rec)
    append_history(h, rec)
    got = load_history(h)
    assert len(got) == 2 and got[0]["figures"] == {"v": None}  # non-finite: null, as --json
    assert got[0]["machine"] == MACHINE and got[0]["commit"] is None
    h.write_text(h.read_text() + '{"bench": "x"}\n')
    with pytest.raises(ConfigError, match=r"history.jsonl:3: a history record needs date"):
        load_history(h)
    h.write_text('{"bench": \n')
    with pytest.raises(ConfigError, match=r"history.jsonl:1: not JSON"):
        load_history(h)
    with pytest.raises(ConfigError, match="cannot read the benchmark history"):
        load_history(tmp_path / "none.jsonl")


def test_page_command_only_renders(tmp_path, capsys):
    h = tmp_path / "history.jsonl"
    append_history(h, _rec("p", "2026-01-01 00:00 UTC", {"rtf": 3.0}))
    out = tmp_path / "B.md"
    assert main(["--history", str(h), "--out", str(out)]) == 0
    assert "| `rtf` | 3 |" in out.read_text()
    assert "rendered from 1 record(s)" in capsys.readouterr().out
    assert main(["--history", str(tmp_path / "none"), "--out", str(out)]) == 2


def test_uvd_bench_appends_to_the_history(tmp_path, capsys):
    h = tmp_path / "history.jsonl"
    assert uvd_main(["bench", "plant", "--seconds", "5", "--history", str(h)]) == 0
    printed = json.loads(capsys.readouterr().out)
    (rec,) = load_history(h)
    assert rec["bench"] == "plant" and rec["figures"]["steps"] == 500 == printed["steps"]
    assert rec["figures"]["real_time_factor"] == printed["real_time_factor"] > 0
    assert rec["machine"] == printed["machine"] and "bench" not in rec["figures"]


def test_make_bench_records_and_renders(tmp_path, monkeypatch, capsys):
    """`make bench` (uvd.bench.all) on one benchmark, in a scratch folder: out/bench/NAME.json,
    one history record, the page re-rendered from the history."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "docs" / "bench").mkdir(parents=True)
    append_history(tmp_path / HISTORY, _rec("plant", "2026-01-01 00:00 UTC",
                                            {"real_time_factor": 1.0}))
    assert bench_all.main(["plant"]) == 0
    records = load_history(tmp_path / HISTORY)
    assert [r["bench"] for r in records] == ["plant", "plant"]
    out = json.loads((tmp_path / "out" / "bench" / "plant.json").read_text())
    assert out["real_time_factor"] == records[-1]["figures"]["real_time_factor"]
    assert records[-1]["commit"] is None  # not a git checkout
    page = (tmp_path / PAGE).read_text()
    assert page == render(records) and "2 run(s) in the history" in page
    assert "| `real_time_factor` | " in page and " | 1 |" in page
    assert bench_all.main(["no-such-bench"]) == 1
    assert "benchmarks that failed: no-such-bench" in capsys.readouterr().err
