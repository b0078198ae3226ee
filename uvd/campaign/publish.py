"""The built-in campaigns in ``make results``: run (or resume) each in ``campaigns/<name>/``,
then publish its table, summary and figures under ``docs/results/`` and its section of
docs/RESULTS.md."""

from __future__ import annotations

import json
import os
import shutil
import statistics
import time
from collections.abc import Callable
from pathlib import Path

from uvd.progress import Pace

#: the campaigns of docs/RESULTS.md, in page order
PUBLISHED = ("fdc-false-alarms", "fdc-detection", "control-model-error")


def publish(name: str, work: Path, results_dir: Path, *, workers: int | None = None,
            limit: int | None = None, progress: Callable[[str], None] = print) -> dict:
    """Run what is missing of campaign ``name`` — a built-in one, or a campaign file, whose
    ``[campaign] name`` then names what is written — at most ``limit`` runs now, in ``work``;
    then write ``results_dir/campaign-<name>.parquet`` (the rows so far, in run order), ``.json``
    (the summary, the counts, wall time and the machine's load) and the figures in
    ``results_dir/campaign-<name>/``. Returns the JSON's content."""
    from uvd.campaign import builtin
    from uvd.campaign.execute import run_campaign
    from uvd.campaign.report import write_figures
    from uvd.campaign.store import RowStore, code_version, run_key
    from uvd.campaign.summary import format_summary, summarize

    spec = builtin.resolve(name)
    source, name = name, spec.name
    load0 = os.getloadavg()
    progress(f"[results] uvd campaign {source} --out {work}"
             + (f" --limit {limit}" if limit else ""))

    t0 = time.perf_counter()
    pace = Pace(t0)

    def on_row(row: dict, done: int, todo: int) -> None:
        now = time.perf_counter()
        left = pace.mark(done, todo, now)
        if done % 10 == 0 or done == todo:
            progress(f"  {name}: {done} / {todo} runs"
                     + _pace(now - t0, left if done < todo else None))

    res = run_campaign(spec, work, workers=workers, on_row=on_row, limit=limit)
    keys = [run_key(spec.kind, i, code_version()) for i in spec.runs]
    rows = RowStore(work).rows([k for k in keys if (Path(work) / "rows" / f"{k}.parquet")
                                .exists()])
    summary = summarize(spec.kind, rows)
    results_dir.mkdir(parents=True, exist_ok=True)
    if res.table is not None:
        shutil.copyfile(res.table, results_dir / f"campaign-{name}.parquet")
    figs = write_figures(spec.kind, summary, rows, results_dir / f"campaign-{name}")
    out = {"campaign": name, "kind": spec.kind, "description": spec.description,
           "runs_in_campaign": len(spec.runs), "runs_summarised": len(rows),
           "ran_now": res.ran, "workers": res.workers, "wall_seconds": round(res.wall_s, 1),
           "wall_per_run_s": [r["wall_s"] for r in rows],
           "load_average_before": list(load0), "load_average_after": list(os.getloadavg()),
           "code_version": code_version(), "summary": summary,
           "summary_text": format_summary(spec.kind, summary),
           "figures": [f.name for f in figs]}
    path = results_dir / f"campaign-{name}.json"
    out.update(_instalment_kept(path, out))
    path.write_text(json.dumps(out, indent=1, default=float) + "\n")
    return out


def _pace(elapsed_s: float, left_s: float | None) -> str:
    """``", 12 min, ~1 h 50 min left"``: the time so far and what is left at the recent pace
    (:class:`uvd.progress.Pace`; runs differ in length, so an estimate; nothing left to say
    when ``left_s`` is None)."""
    def hm(s: float) -> str:
        m = round(s / 60.0)
        return f"{m // 60} h {m % 60} min" if m >= 60 else f"{m} min"
    return f", {hm(elapsed_s)}" + ("" if left_s is None else f", ~{hm(left_s)} left")


#: the figures of the instalment that ran a campaign's runs (what docs/RESULTS.md quotes)
_INSTALMENT = ("ran_now", "workers", "wall_seconds", "load_average_before", "load_average_after")


def _instalment_kept(path: Path, out: dict) -> dict:
    """Published again with nothing run now (a new summary or figures of the same rows): the
    instalment figures of the JSON already there, when it summarised the very same rows (the
    code version, the count and every run's own wall time alike) — so a re-summary keeps how
    long the rows took instead of recording its own second. Else nothing."""
    if out["ran_now"] or not path.exists():
        return {}
    try:
        old = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    same = all(old.get(k) == out[k] for k in ("code_version", "runs_summarised",
                                                 "wall_per_run_s"))
    if not same or not old.get("ran_now") or any(k not in old for k in _INSTALMENT):
        return {}
    return {k: old[k] for k in _INSTALMENT}


def run_published(results_dir: Path, work_root: Path = Path("campaigns"), *,
                  workers: int | None = None, limit: int | None = None,
                  names: tuple[str, ...] = PUBLISHED,
                  progress: Callable[[str], None] = print) -> dict[str, dict]:
    out = {}
    for name in names:
        t0 = time.perf_counter()
        out[name] = publish(name, work_root / name, results_dir, workers=workers, limit=limit,
                            progress=progress)
        progress(f"[results] campaign {name} done in {time.perf_counter() - t0:.0f} s")
    return out


def load_published(results_dir: Path) -> dict[str, dict]:
    """The published campaigns' JSON found in ``results_dir``, in page order."""
    out = {}
    for name in PUBLISHED:
        path = results_dir / f"campaign-{name}.json"
        if path.exists():
            out[name] = json.loads(path.read_text())
    return out


def _run_walls(r: dict) -> str:
    """The rows' own wall times (each run on its worker) and the code they ran on."""
    walls = [float(w) for w in r.get("wall_per_run_s") or ()]
    if not walls:
        return ""
    return (f"; every run's own wall time {sum(walls):.0f} s in all (median "
            f"{statistics.median(walls):.0f} s, longest {max(walls):.0f} s), on code version "
            f"`{r['code_version']}`")


def render(published: dict[str, dict]) -> list[str]:
    """The campaigns' part of docs/RESULTS.md."""
    if not published:
        return []
    lines = ["# Campaigns", "",
             "Monte-Carlo studies of many lockstep runs on Dask (`uvd campaign`, "
             "[campaigns.md](campaigns.md)). Each row of a campaign is one run "
             "(`docs/results/campaign-NAME.parquet`); intervals are 95 %: exact Poisson "
             "(Garwood) for false alarms per vehicle-hour, Clopper–Pearson for probabilities, "
             "percentile bootstrap for medians.", ""]
    for name, r in published.items():
        lines.append(f"## campaign {name}")
        lines.append("")
        lines.append(f"*Study:* {r['description']}.")
        lines.append("")
        partial = r["runs_summarised"] < r["runs_in_campaign"]
        lines.append(f"*Command:* `uvd campaign {name}` — {r['runs_summarised']} of "
                     f"{r['runs_in_campaign']} runs" + (" (**partial**: the rest of the "
                                                         "campaign was not run)" if partial
                                                         else "")
                     + (f"; this instalment {r['ran_now']} runs on {r['workers']} worker(s) "
                        f"in {r['wall_seconds']:.0f} s wall, load average "
                        f"{r['load_average_before'][0]:.1f} before and "
                        f"{r['load_average_after'][0]:.1f} after" if r["ran_now"] else
                        "; every run from earlier instalments") + _run_walls(r) + ".")
        lines.append("")
        lines.append("```")
        lines.append(r["summary_text"].rstrip())
        lines.append("```")
        for f in r.get("figures", []):
            lines.append("")
            lines.append(f"![{f}](results/campaign-{name}/{f})")
        lines.append("")
    return lines
