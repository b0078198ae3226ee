"""A campaign's rows on disk (Parquet, pyarrow): one small file per finished run, written as it
completes (to a temporary name, then renamed: a crash never leaves half a row), named by the
run's key — the SHA-256 of its kind, inputs and the code version — so a restarted campaign
finds what is done and runs only the rest. :meth:`RowStore.table` gathers them into one table
in run order (``runs.parquet`` beside them once the campaign ends).

A row: ``key``, ``index`` (the run's place in the campaign), ``campaign``, ``kind``,
``code_version``, every input as ``in_<axis>``, every figure as ``out_<name>``, ``error``
(None, or the exception of a run that raised), ``wall_s`` and ``worker``.
"""

from __future__ import annotations

import hashlib
import json
import os
from functools import cache
from pathlib import Path

from uvd.campaign.spec import CampaignError
from uvd.jsonio import write_whole

#: columns that say how a run went on this machine, not what it computed: left out when rows
#: are compared across worker counts or orders
RUN_ENVIRONMENT = ("wall_s", "worker")
_PACKAGES = ("uvd", "sim_bridge", "drivers")


#: sources no run executes (the command line, benchmarks, the campaign's own bookkeeping,
#: summary and figures, the results page): editing them keeps the finished rows valid
_NOT_RUN = ("uvd/commands/", "uvd/bench/", "uvd/experiments/results.py", "uvd/campaign/builtin/",
            "uvd/campaign/execute.py", "uvd/campaign/store.py", "uvd/campaign/summary.py",
            "uvd/campaign/report.py", "uvd/campaign/publish.py", "uvd/cliargs.py")


@cache
def code_version() -> str:
    """SHA-256 (16 hex digits) of every Python source of uvd, sim_bridge and drivers that a
    run may execute, and the shipped vehicle and configuration files: a change to any of them
    is a new code version (its runs are new runs), whether or not the checkout is a git
    repository."""
    import uvd
    root = Path(uvd.__file__).resolve().parents[1]
    h = hashlib.sha256()
    for pkg in _PACKAGES:
        for f in sorted((root / pkg).rglob("*")):
            rel = f.relative_to(root).as_posix()
            if f.suffix in (".py", ".toml") and "__pycache__" not in f.parts \
                    and not rel.startswith(_NOT_RUN):
                h.update(rel.encode())
                h.update(f.read_bytes())
    for f in sorted((root / "config").glob("*.toml")):  # the demo configurations fdc runs take
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def run_key(kind: str, inputs: dict, version: str) -> str:
    """The key of one run: SHA-256 of its kind, inputs (canonical JSON) and code version."""
    text = json.dumps({"kind": kind, "inputs": inputs, "code": version}, sort_keys=True,
                      allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def make_row(campaign: str, kind: str, index: int, key: str, version: str, inputs: dict,
             result: dict) -> dict:
    """One row of the table from a run's inputs and :func:`uvd.campaign.runs.execute`'s
    result."""
    row = {"key": key, "index": index, "campaign": campaign, "kind": kind,
           "code_version": version}
    row.update({f"in_{k}": v for k, v in sorted(inputs.items())})
    row.update({f"out_{k}": v for k, v in sorted(result["figures"].items())})
    row["error"] = result["error"]
    row["wall_s"] = float(result["wall_s"])
    row["worker"] = result["worker"]
    return row


class RowStore:
    """The rows of one campaign in ``directory/rows/<key>.parquet``."""

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        self.rows_dir = self.directory / "rows"
        try:
            self.rows_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:  # a read-only or missing place: said by the command, no traceback
            raise CampaignError(f"{self.directory}: cannot hold the campaign's rows "
                                f"({exc.strerror or exc})") from exc
        self.stale_removed = self._remove_stale_tmp()

    def _remove_stale_tmp(self) -> int:
        """Remove the half-written rows (``<key>.tmp<pid>``) of a writer no longer alive — a
        campaign killed between writing a row and renaming it; that run is not done and runs
        again. A live writer's file is left alone. Returns how many were removed."""
        removed = 0
        for p in self.rows_dir.glob("*.tmp*"):
            pid = p.suffix[len(".tmp"):]
            if pid.isdigit() and _alive(int(pid)):
                continue
            p.unlink(missing_ok=True)
            removed += 1
        return removed

    def done(self) -> set[str]:
        """The keys of the runs already written."""
        return {p.stem for p in self.rows_dir.glob("*.parquet")}

    def write(self, row: dict) -> None:
        """Write one row (atomically: a temporary file, then a rename); a write that fails (a
        full disk) leaves no temporary file and names the row's path."""
        import pyarrow as pa
        import pyarrow.parquet as pq
        path = self.rows_dir / f"{row['key']}.parquet"
        table = pa.Table.from_pylist([row])
        write_whole(path, lambda tmp: pq.write_table(table, tmp),
                    path.with_suffix(f".tmp{os.getpid()}"), what=f"the row {path}")

    def rows(self, keys: list[str] | None = None) -> list[dict]:
        """The stored rows (of ``keys`` only, when given, in that order), else by index."""
        import pyarrow.parquet as pq
        files = ([self.rows_dir / f"{k}.parquet" for k in keys] if keys is not None
                 else sorted(self.rows_dir.glob("*.parquet")))
        rows = [pq.read_table(f).to_pylist()[0] for f in files if f.exists()]
        return rows if keys is not None else sorted(rows, key=lambda r: r["index"])

    def table(self, keys: list[str] | None = None):
        """The rows as one pyarrow table (columns the union of every row's)."""
        import pyarrow as pa
        rows = self.rows(keys)
        names: dict[str, None] = {}
        for r in rows:
            names.update(dict.fromkeys(r))
        return pa.Table.from_pylist([{n: r.get(n) for n in names} for r in rows])

    def write_table(self, keys: list[str], name: str = "runs.parquet") -> Path:
        """The campaign's rows (``keys``, in run order) as one Parquet file."""
        import pyarrow.parquet as pq
        path = self.directory / name
        pq.write_table(self.table(keys), path)
        return path


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists (signal 0 delivers nothing, only checks)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, another user's
        return True
    return True
