"""A telemetry sink writing one JSON object per line (JSON Lines) to a file.

Records are encoded in the event loop in time-bounded slices (the sink yields every
``slice_s`` of encoding, so a large batch never holds the event loop for long) and written by
the sink's own daemon thread, so a slow disk never stalls the event loop, and a hung disk
cannot keep the daemon from exiting.
Numpy arrays become lists, NaN/inf become ``null`` (:func:`uvd.jsonio.to_jsonable`); anything
else JSON cannot represent is written as its ``str``. Each batch goes to the operating system
in one write; one that fails (a full disk) leaves the file at its last whole line and waits
for the disk, told in the log (:mod:`uvd.telemetry.appendfile`). On close the file is
``fsync``-ed, so a clean shutdown leaves only complete lines.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from uvd.jsonio import to_jsonable
from uvd.telemetry._worker import DaemonWorker
from uvd.telemetry.appendfile import AppendFile

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
    max_pending_mb : float
        Lines kept for a disk that fails writes; past that they are given up (counted).
    """

    def __init__(self, path: str | Path, *, name: str = "jsonl", truncate: bool = False,
                 slice_s: float = 2e-4, fsync_on_close: bool = True,
                 max_pending_mb: float = 16.0) -> None:
        self.path = Path(path)
        self.name = name
        self.truncate = truncate
        self.slice_s = float(slice_s)
        self.fsync_on_close = fsync_on_close
        self.lines = 0
        self._opened = False
        self._file = AppendFile(int(max_pending_mb * 1e6))
        self._worker = DaemonWorker(f"uvd-sink-{name}")

    def _open(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self.path.open("wb" if self.truncate else "ab"):
            pass  # a file that cannot be written is the open's error, named

    async def open(self) -> None:
        if not self._opened:
            await self._worker.submit(self._open)
            self._opened = True

    async def write(self, records: Sequence[Mapping[str, Any]]) -> None:
        if not self._opened:
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
            data = ("\n".join(parts) + "\n").encode("utf-8")
            await self._worker.submit(self._file.write, self.path, data)
            self.lines += len(parts)

    async def flush(self) -> None:
        return None  # every write reached the operating system (or waits in _file)

    def _close(self) -> None:
        self._file.write(self.path, b"", close=self.fsync_on_close)  # what waits: a last try
        self._file.close()

    async def aclose(self) -> None:
        if not self._opened:
            self._worker.close()
            return
        try:
            await self._worker.submit(self._close)
        finally:
            self._opened = False
            self._worker.close()

    def trouble(self) -> str | None:
        """The failure of the file's writes going on (the path and the error), None when the
        last write reached the file (the hub tells the operator of it)."""
        return self._file.failing

    def stats(self) -> dict[str, Any]:
        return {"lines": self.lines, **self._file.stats()}
