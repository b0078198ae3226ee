"""A telemetry sink writing one JSON object per line (JSON Lines) to a file.

Records are encoded in the event loop in time-bounded slices (the sink yields every
``slice_s`` of encoding, so a large batch never holds the event loop for long) and written by
the sink's own daemon thread, so a slow disk never stalls the event loop, and a hung disk
cannot keep the daemon from exiting.
Numpy arrays become lists, NaN/inf become ``null`` (:func:`uvd.jsonio.to_jsonable`); anything
else JSON cannot represent is written as its ``str``. On close the file is flushed and
``fsync``-ed, so a clean shutdown leaves only complete lines.
"""

from __future__ import annotations

import asyncio
import json
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from uvd.jsonio import to_jsonable
from uvd.telemetry._worker import DaemonWorker

__all__ = ["JsonLinesSink"]


class JsonLinesSink:
    """Append telemetry records to ``path`` as JSON lines.

    Parameters
    ----------
    path : str or Path
        Output file; its folder is created. Appended to if it exists (``truncate=False``).
    name : str
        Sink name in statistics.
    truncate : bool
        Start a fresh file instead of appending.
    slice_s : float
        Longest stretch of encoding before yielding to the event loop.
    fsync_on_close : bool
        ``os.fsync`` the file when closing.
    """

    def __init__(self, path: str | Path, *, name: str = "jsonl", truncate: bool = False,
                 slice_s: float = 2e-4, fsync_on_close: bool = True) -> None:
        self.path = Path(path)
        self.name = name
        self.truncate = truncate
        self.slice_s = float(slice_s)
        self.fsync_on_close = fsync_on_close
        self.lines = 0
        self._fh = None
        self._worker = DaemonWorker(f"uvd-sink-{name}")

    def _open(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        return self.path.open("w" if self.truncate else "a", encoding="utf-8",
                              buffering=1 << 16)

    async def open(self) -> None:
        if self._fh is None:
            self._fh = await self._worker.submit(self._open)

    async def write(self, records: Sequence[Mapping[str, Any]]) -> None:
        if self._fh is None:
            raise RuntimeError(f"sink {self.name} is not open")
        parts: list[str] = []
        t0 = time.perf_counter()
        for r in records:
            parts.append(json.dumps(to_jsonable(r), separators=(",", ":"), default=str,
                                    allow_nan=False))
            if time.perf_counter() - t0 > self.slice_s:
                await asyncio.sleep(0)
                t0 = time.perf_counter()
        if parts:
            await self._worker.submit(self._fh.write, "\n".join(parts) + "\n")
            self.lines += len(parts)

    async def flush(self) -> None:
        if self._fh is not None:
            await self._worker.submit(self._fh.flush)

    def _close(self) -> None:
        fh, self._fh = self._fh, None
        if fh is None:
            return
        try:
            fh.flush()
            if self.fsync_on_close:
                os.fsync(fh.fileno())
        finally:
            fh.close()

    async def aclose(self) -> None:
        try:
            await self._worker.submit(self._close)
        finally:
            self._worker.close()
