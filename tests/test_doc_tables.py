"""The measured tables of the docs are generated from docs/results/tables/*.json."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from uvd.bench.tables import load_table, main, render_page, render_table, table_names
from uvd.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def test_every_page_shows_its_tables_as_the_data_says():
    shown = []
    for page in sorted((ROOT / "docs").glob("*.md")):
        text = page.read_text(encoding="utf-8")
        shown += table_names(text)
        assert render_page(text, ROOT / "docs" / "results" / "tables") == text, \
            f"{page.name}: stale table (run python -m uvd.bench.tables)"
    data = sorted(p.stem for p in (ROOT / "docs" / "results" / "tables").glob("*.json"))
    assert sorted(shown) == data  # every table shown once, no data without a page
    assert len(data) >= 9


def test_a_table_renders_numbers_as_json_gives_them_and_aligns(tmp_path):
    t = {"columns": ["run", "p99"], "align": ["l", "r"], "rows": [["a", 0.7], ["b", "**2**"]]}
    assert render_table(t) == "| run | p99 |\n| --- | ---: |\n| a | 0.7 |\n| b | **2** |\n"
    (tmp_path / "t.json").write_text(json.dumps(t))
    page = tmp_path / "p.md"
    page.write_text("text\n<!-- table: t -->\nold\n<!-- /table -->\nmore\n")
    assert main(["--docs", str(tmp_path), "--tables", str(tmp_path), "--check"]) == 1
    assert main(["--docs", str(tmp_path), "--tables", str(tmp_path)]) == 0
    assert page.read_text() == ("text\n<!-- table: t -->\n| run | p99 |\n| --- | ---: |\n"
                                "| a | 0.7 |\n| b | **2** |\n<!-- /table -->\nmore\n")
    assert main(["--docs", str(tmp_path), "--tables", str(tmp_path), "--check"]) == 0


def test_a_ragged_table_is_refused_naming_the_file_and_row(tmp_path):
    (tmp_path / "bad.json").write_text(json.dumps({"columns": ["a", "b"], "rows": [[1]]}))
    with pytest.raises(ConfigError, match=r"bad.json: row 0 has 1 cells, not 2"):
        load_table("bad", tmp_path)
