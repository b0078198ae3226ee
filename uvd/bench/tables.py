"""Measured tables of the docs, generated from data (``python -m uvd.bench.tables``).

The docs describe; the data records. A measured table lives as ``docs/results/tables/NAME.json``
and appears in a page between two markers::

    <!-- table: NAME -->
    | … the table, generated … |
    <!-- /table -->

``python -m uvd.bench.tables`` rewrites every such block of ``docs/*.md`` from its data;
``--check`` only reports the blocks that differ (exit 1), as the test suite does. A new
measurement goes into the JSON (a row, or a new file and a marker), never into the page.

A table file holds::

    {"columns": ["run", "p50", …],          # header cells
     "align": ["l", "r", …],                # optional: "l" (---) or "r" (---:) per column
     "rows": [["1 kHz", 0.7, …], …],       # one list per row: numbers stay numbers
     "about": "what was measured, how, on what machine, when",
     "source": ["docs/results/bench-….json", "uvd bench loop …"]}   # optional

Cells are numbers or text (text may carry the page's emphasis, ``**40.5**``); a number is
written as JSON gives it back (``0.7``, ``2085``).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path
from typing import Any

from uvd.errors import ConfigError

DOCS = Path("docs")
TABLES = Path("docs/results/tables")
_BLOCK = re.compile(r"(<!-- table: (?P<name>[\w.-]+) -->\n)(?P<body>.*?)(<!-- /table -->)",
                    re.S)


def _cell(value: Any) -> str:
    if isinstance(value, bool) or value is None:
        raise ConfigError(f"a table cell is a number or text, not {value!r}")
    if isinstance(value, int | float):
        return json.dumps(value)
    return str(value)


def load_table(name: str, tables: Path = TABLES) -> dict[str, Any]:
    """The table ``name`` (``tables/NAME.json``), checked: every row as wide as the header."""
    path = tables / f"{name}.json"
    try:
        t = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: {exc}") from exc
    cols = t.get("columns")
    if not isinstance(cols, list) or not cols:
        raise ConfigError(f"{path}: 'columns' must be a non-empty list")
    align = t.get("align", ["l"] * len(cols))
    if len(align) != len(cols) or set(align) - {"l", "r"}:
        raise ConfigError(f"{path}: 'align' must give 'l' or 'r' for each of {len(cols)} columns")
    for i, row in enumerate(t.get("rows", [])):
        if not isinstance(row, list) or len(row) != len(cols):
            raise ConfigError(f"{path}: row {i} has {len(row)} cells, not {len(cols)}")
    return t


def render_table(t: dict[str, Any]) -> str:
    """The markdown of a table (header, alignment row, rows; newline-terminated)."""
    cols = t["columns"]
    align = t.get("align", ["l"] * len(cols))
    lines = ["| " + " | ".join(cols) + " |",
             "| " + " | ".join("---:" if a == "r" else "---" for a in align) + " |"]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in t.get("rows", [])]
    return "\n".join(lines) + "\n"


def render_page(text: str, tables: Path = TABLES) -> str:
    """``text`` with every table block regenerated from its data."""
    def block(m: re.Match) -> str:
        return m.group(1) + render_table(load_table(m.group("name"), tables)) + m.group(4)
    return _BLOCK.sub(block, text)


def table_names(text: str) -> list[str]:
    """The tables a page shows, in order."""
    return [m.group("name") for m in _BLOCK.finditer(text)]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m uvd.bench.tables",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--docs", type=Path, default=DOCS, help="folder of the pages (docs)")
    p.add_argument("--tables", type=Path, default=TABLES,
                   help="folder of the table data (docs/results/tables)")
    p.add_argument("--check", action="store_true",
                   help="change nothing; exit 1 naming every page whose tables are stale")
    args = p.parse_args(argv)
    stale = []
    for page in sorted(args.docs.glob("*.md")):
        text = page.read_text(encoding="utf-8")
        try:
            new = render_page(text, args.tables)
        except ConfigError as exc:
            print(f"{page}: {exc}", file=sys.stderr)
            return 2
        if new != text:
            stale.append(page)
            if not args.check:
                page.write_text(new, encoding="utf-8")
    for page in stale:
        print(f"{page}: {'stale tables' if args.check else 'tables regenerated'}")
    return 1 if args.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
