"""The benchmark history (``docs/bench/history.jsonl``) and the page generated from it
(``docs/BENCHMARKS.md``).

The history is data: one JSON object per line, one line per run of one benchmark, appended by
``make bench`` (:mod:`uvd.bench.all`) and ``uvd bench NAME --history FILE``; never edited by
hand. Each record holds ``bench``, ``date`` ("YYYY-MM-DD HH:MM UTC"), ``commit`` (the code
measured; "-dirty" when it had uncommitted changes; None when unknown), ``machine``,
``summary`` (the benchmark's one-line description) and ``figures`` (what the benchmark
printed, as it printed it).

The page shows, per benchmark, the latest run as one table (with its date, machine and
commit) beside the run before it. ``python -m uvd.bench.page`` re-renders it from the
history without running anything.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from uvd.bench import machine
from uvd.errors import ConfigError
from uvd.jsonio import to_jsonable

HISTORY = Path("docs/bench/history.jsonl")
PAGE = Path("docs/BENCHMARKS.md")
_KEYS = ("bench", "date", "commit", "machine", "summary", "figures")
#: keys of a percentile summary (uvd.bench.percentiles), shown on one line in this order
_PCT = ("p50", "p90", "p99", "p999", "max", "mean")

INTRO = """\
# Benchmarks

Generated from the history `docs/bench/history.jsonl` (one JSON object per run of one
benchmark) by `make bench`, which runs every `uvd bench NAME` and appends its figures, or by
`python -m uvd.bench.page`, which only re-renders; do not edit by hand. Each table shows the
latest run of a benchmark beside the run before it. Medians and percentiles, never means
alone (percentile rows: p50 · p90 · p99 · p99.9 · max, n = samples). Timing figures depend on
the machine and its load: read them with the date, machine and commit above each table. The
long real-time benchmarks (`can` 60 s at 100 Hz, `loop` at 1 kHz / 100 Hz with the HIL demo
running, `latency`) were measured with their set-up in `docs/results/bench-*.json`,
`docs/can.md` and `docs/runtime-measured.md`.
"""


# ------------------------------------------------------------------------------ history
def current_commit(repo: Path | None = None) -> str | None:
    """The short hash of HEAD, with "-dirty" when code (anything outside docs/) has
    uncommitted changes; None outside a git checkout."""
    cwd = repo or Path.cwd()
    try:
        head = subprocess.run(["git", "rev-parse", "--short=7", "HEAD"], cwd=cwd, text=True,
                              capture_output=True, check=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", ".", ":(exclude)docs"],
                               cwd=cwd, text=True, capture_output=True, check=True,
                               timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head + ("-dirty" if dirty else "")


def new_record(bench: str, summary: str, figures: dict[str, Any], *,
               commit: str | None = None, date: str | None = None) -> dict[str, Any]:
    """A history record of one run (``figures`` without the ``bench``/``machine`` keys)."""
    figures = dict(figures)
    figures.pop("bench", None)
    mach = figures.pop("machine", None) or machine()
    date = date or _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return {"bench": bench, "date": date, "commit": commit, "machine": mach,
            "summary": summary, "figures": figures}


def append_history(path: Path, record: dict[str, Any]) -> None:
    """Append one record (one line) to the history file (folders made)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    line = json.dumps(to_jsonable(record), ensure_ascii=False)
    with path.open("a", encoding="utf-8") as fh:
        fh.write(line + "\n")


def load_history(path: Path) -> list[dict[str, Any]]:
    """Every record of the history file, in file order; a bad line is a
    :class:`~uvd.errors.ConfigError` naming the file and line."""
    path = Path(path)
    out = []
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the benchmark history: {exc}") from exc
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{path}:{n}: not JSON: {exc}") from exc
        missing = [k for k in _KEYS if not isinstance(rec, dict) or k not in rec]
        if missing:
            raise ConfigError(f"{path}:{n}: a history record needs {', '.join(missing)}")
        if not isinstance(rec["figures"], dict):
            raise ConfigError(f"{path}:{n}: 'figures' must be an object")
        out.append(rec)
    return out


# ------------------------------------------------------------------------------- render
def _num(x: float | int) -> str:
    if isinstance(x, bool):
        return str(x).lower()
    if isinstance(x, int):
        return str(x)
    if not math.isfinite(x):
        return str(x)
    if x != 0 and (abs(x) >= 1e6 or abs(x) < 1e-3):
        return f"{x:.3e}"
    return f"{x:.4g}"


def _is_percentiles(d: dict) -> bool:
    return "p50" in d and all(k in _PCT or k == "n" for k in d) \
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in d.values())


def _cell(value: Any) -> str:
    """One value as Markdown table text."""
    if value is None:
        return "—"
    if isinstance(value, bool | int | float):
        return _num(value)
    if isinstance(value, str):
        return value.replace("|", "\\|") or '""'
    if isinstance(value, dict) and _is_percentiles(value):
        parts = [f"{k.replace('p999', 'p99.9')} {_num(value[k])}" for k in _PCT if k in value]
        n = f" (n {value['n']})" if "n" in value else ""
        return " · ".join(parts) + n
    if isinstance(value, list):
        if not value:
            return "[]"
        return "[" + ", ".join(_cell(v) for v in value) + "]"
    return json.dumps(value, default=float).replace("|", "\\|")


def flatten(figures: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """{dotted key: value}; percentile summaries and lists stay whole (one row each)."""
    out: dict[str, Any] = {}
    for k, v in figures.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and v and not _is_percentiles(v):
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


def _run_label(rec: dict[str, Any]) -> str:
    return f"{rec['date']}, commit {rec['commit'] or 'unknown'}"


def _machine_label(m: dict[str, Any]) -> str:
    blas = f", BLAS {m['blas']}" if m.get("blas") else ""
    return (f"{m.get('processor', '?')}, {m.get('cpus', '?')} CPUs{blas}, "
            f"Python {m.get('python', '?')}")


def render(records: Iterable[dict[str, Any]]) -> str:
    """The Markdown page: per benchmark (alphabetical), its latest run as a table beside the
    previous one."""
    runs: dict[str, list[dict[str, Any]]] = {}
    for rec in records:
        runs.setdefault(rec["bench"], []).append(rec)
    parts = [INTRO]
    for name in sorted(runs):
        latest = runs[name][-1]
        prev = runs[name][-2] if len(runs[name]) > 1 else None
        parts.append(f"\n## `uvd bench {name}`\n\n{latest['summary']}\n\n"
                     f"Latest run: {latest['date']} · commit `{latest['commit'] or 'unknown'}` "
                     f"· {_machine_label(latest['machine'])} · {len(runs[name])} run(s) in "
                     f"the history.\n")
        now = flatten(latest["figures"])
        before = flatten(prev["figures"]) if prev else {}
        if prev:
            rows = ["| figure | latest | previous run |", "| --- | --- | --- |"]
            if prev["machine"] != latest["machine"]:
                rows.append(f"| *machine* | {_machine_label(latest['machine'])} | "
                            f"{_machine_label(prev['machine'])} |")
            rows.append(f"| *run* | {_run_label(latest)} | {_run_label(prev)} |")
            for k, v in now.items():
                rows.append(f"| `{k}` | {_cell(v)} | "
                            f"{_cell(before[k]) if k in before else 'not measured'} |")
        else:
            rows = ["| figure | latest |", "| --- | --- |"]
            rows += [f"| `{k}` | {_cell(v)} |" for k, v in now.items()]
        parts.append("\n" + "\n".join(rows) + "\n")
    return "".join(parts)


def write_page(history: Path = HISTORY, page: Path = PAGE) -> int:
    """Render ``page`` from ``history``; returns the number of records."""
    records = load_history(history)
    Path(page).write_text(render(records), encoding="utf-8")
    return len(records)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m uvd.bench.page",
                                description="re-render docs/BENCHMARKS.md from the history")
    p.add_argument("--history", type=Path, default=HISTORY, help=f"default {HISTORY}")
    p.add_argument("--out", type=Path, default=PAGE, help=f"default {PAGE}")
    args = p.parse_args(argv)
    try:
        n = write_page(args.history, args.out)
    except ConfigError as exc:
        print(f"uvd.bench.page: {exc}", file=sys.stderr)
        return 2
    print(f"{args.out}: rendered from {n} record(s) of {args.history}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
