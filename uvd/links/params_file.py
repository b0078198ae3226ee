"""A telemetry sink keeping the latest online estimate θ̂ in a ``[parameters]`` TOML file.

It takes the loop's ``"estimate"`` records (:meth:`uvd.runtime.daemon.Daemon.estimate_records`)
and rewrites ``path`` with the newest θ̂ at most every ``every_s`` seconds and once more when
closed, so a run that identified the vehicle for an hour leaves its result behind — also
after a crash, up to ``every_s`` old. Each write is atomic
(:func:`uvd.io.params.save_params`); the file loads wherever parameters are taken
(``[estimation] initial_params``, ``uvd xval --params``, ``uvd identify --init``).

The encoding and the disk write run in the sink's own daemon thread: never in the loop.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from uvd.telemetry._worker import DaemonWorker

__all__ = ["ParamsFileSink", "RECORD_TYPE"]

#: The record type this sink takes (others are ignored).
RECORD_TYPE = "estimate"


def _title(rec: Mapping[str, Any]) -> str:
    parts = [f"{rec.get('estimator', 'estimator')}: online estimate θ̂ of uvd run",
             f"{rec.get('steps', '?')} adaptation steps in this run",
             f"M̂ eigenvalues {rec.get('m_min_eig', float('nan')):.6g}"
             f"..{rec.get('m_max_eig', float('nan')):.6g}"]
    if rec.get("frozen"):
        parts.append(f"FROZEN ({rec.get('freeze_reason', '')}): the last positive-definite "
                     "estimate")
    if rec.get("wall_time"):
        parts.append(f"written {rec['wall_time']}")
    return "; ".join(parts)


class ParamsFileSink:
    """Keep the newest ``"estimate"`` record's θ̂ in ``path`` (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The TOML file; its folder is created.
    every_s : float
        Shortest interval between two writes while running (monotonic clock).
    name : str
        Sink name in statistics.
    clock : callable
        Monotonic seconds (tests inject one).
    """

    def __init__(self, path: str | Path, *, every_s: float = 60.0, name: str = "params-file",
                 clock=time.monotonic) -> None:
        self.path = Path(path)
        self.every_s = float(every_s)
        self.name = name
        self.writes = 0
        self._clock = clock
        self._latest: Mapping[str, Any] | None = None
        self._written: Mapping[str, Any] | None = None
        self._last_write = -float("inf")
        self._worker = DaemonWorker(f"uvd-sink-{name}")

    def _mkdir(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)

    def _save(self, rec: Mapping[str, Any]) -> None:
        from uvd.io.params import save_params
        from uvd.model.params import params_from_theta
        rec = {**rec, "wall_time": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        save_params(params_from_theta(np.asarray(rec["theta"], dtype=float)), self.path,
                    title=_title(rec))

    async def _write_latest(self) -> None:
        rec = self._latest
        if rec is None or rec is self._written:
            return
        await self._worker.submit(self._save, rec)
        self._written = rec
        self._last_write = self._clock()
        self.writes += 1

    async def open(self) -> None:
        await self._worker.submit(self._mkdir)

    async def write(self, records: Sequence[Mapping[str, Any]]) -> None:
        for r in records:
            if r.get("type") == RECORD_TYPE and r.get("theta") is not None \
                    and r.get("source", "estimator") == "estimator":
                self._latest = r
        if self._clock() - self._last_write >= self.every_s:
            await self._write_latest()

    async def flush(self) -> None:
        """Nothing buffered beyond the newest estimate; that is written at close."""

    async def aclose(self) -> None:
        try:
            await self._write_latest()
        finally:
            self._worker.close()
