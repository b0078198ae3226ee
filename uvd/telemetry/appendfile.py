"""A file written only at its end, from one thread, whose failed writes never raise — what the
daemon's record files (the MCAP black box, the JSON lines) write through.

Every ``sync_interval_s`` the data is forced to the disk, so that a power cut of the machine
loses at most that much (the operating system's writeback would leave up to ~30 s in memory).
A full disk or an I/O error fails a write. The file is then cut back to its last whole write,
so that it stays readable to there (a reader never meets half a record in the middle), and the
bytes are kept and written first when the disk takes them again: the file goes on whole, with
nothing missing. Kept up to ``max_pending`` bytes; past that they are given up and counted.
Told in the log at a spell's first failure and when writing resumes (the first ten spells:
:class:`uvd.spells.FailureSpells`), every :data:`LOG_EVERY` th failure, and when bytes are given up;
counted in ``write_errors`` and ``lost_bytes``.

Before (session 25; on a full 1 MB tmpfs, and tests/test_recording.py): nothing was logged;
the black box's flush task ended at the first failed write, so nothing more reached the file
until the close, even after space came back, and the JSON lines waited in a 64 kB buffer — a
crash would have lost them.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from pathlib import Path

from uvd.jsonio import sync_to_disk
from uvd.spells import FailureSpells

__all__ = ["AppendFile", "LOG_EVERY"]

log = logging.getLogger("uvd.recording")

#: after a spell's first failed write, one in this many is logged (a full disk fails them all)
LOG_EVERY = 100


class AppendFile:
    """Append bytes to one file at a time (:meth:`write` to another path closes the first).

    Parameters
    ----------
    max_pending : int
        Bytes kept for the disk after failed writes; past that they are given up (counted).
    sync_interval_s : float
        After a write, the file's data is forced to the disk (``fdatasync``) when this long
        has passed since the last time (0: only at close, the operating system's writeback
        otherwise — on Linux up to ~30 s of data that a power cut of the machine loses); a new
        file's folder at its first sync, so that its name survives too. A failed sync is a
        failed write: the file is cut back and the bytes kept.
    """

    def __init__(self, max_pending: int, sync_interval_s: float = 0.0) -> None:
        self.max_pending = int(max_pending)
        self.sync_interval_s = float(sync_interval_s)
        self.syncs = 0  # forced to the disk, at an interval or at close
        self._synced_at = time.monotonic()
        self._entry_synced = True
        self.path: Path | None = None
        self.unwritten = b""  # what failed writes left, written first next time
        self.lost_bytes = 0
        self.last_write_error = ""
        self._fh = None
        self._spells = FailureSpells(LOG_EVERY)
        self._failing_since = 0.0

    @property
    def write_errors(self) -> int:
        return self._spells.total

    @property
    def failing(self) -> str | None:
        """The failure of the spell going on (the path and the error), None when the last
        write reached the file."""
        return self.last_write_error if self._spells.in_a_row else None

    def write(self, path: Path, data: bytes, close: bool = False) -> bool:
        """Append ``data`` (after any bytes kept from failed writes) to ``path``, creating its
        folder; ``close``: fsync and close it after. True when everything reached the file."""
        if self.path != path:
            self.close()
            self.path = path
        todo = self.unwritten + data if self.unwritten else data
        size = None
        try:
            if self._fh is None:
                path.parent.mkdir(parents=True, exist_ok=True)
                self._fh = open(path, "ab", buffering=0)  # noqa: SIM115 - kept open
                self._entry_synced = False
            size = os.fstat(self._fh.fileno()).st_size
            view = memoryview(todo)
            while view:
                view = view[self._fh.write(view):]
            if close or (self.sync_interval_s
                         and time.monotonic() - self._synced_at >= self.sync_interval_s):
                _datasync(self._fh.fileno())
                if not self._entry_synced:  # a new file: its name in the folder too
                    sync_to_disk(path.parent)
                    self._entry_synced = True
                self._synced_at = time.monotonic()
                self.syncs += 1
        except OSError as exc:
            if size is not None:  # cut back to the last whole write
                with contextlib.suppress(OSError):
                    os.ftruncate(self._fh.fileno(), size)
            self._failed(path, todo, exc)
            if close:
                self.close()
            return False
        if self._spells.recovered():
            log.warning("recording: %s written again after %.1f s of failed writes (%d so far)",
                        path, time.monotonic() - self._failing_since, self.write_errors)
        self.unwritten = b""
        self._failing_since = 0.0
        if close:
            self.close()
        return True

    def _failed(self, path: Path, todo: bytes, exc: OSError) -> None:
        tell = self._spells.failed()
        self.last_write_error = f"{path}: {exc}"
        if not self._failing_since:
            self._failing_since = time.monotonic()
        self.unwritten = todo
        if len(todo) > self.max_pending:
            self._give_up()
        if tell:
            log.warning("recording: cannot write %s (%d failed writes): %s; the file ends at its "
                        "last whole write, %d bytes wait for the disk", path, self.write_errors,
                        exc, len(self.unwritten))

    def _give_up(self) -> None:
        if self.unwritten:
            self.lost_bytes += len(self.unwritten)
            log.warning("recording: %d bytes never written to %s were given up",
                        len(self.unwritten), self.path)
            self.unwritten = b""

    def close(self) -> None:
        """Close the current file; bytes it could not take are given up (counted)."""
        self._give_up()
        if self._fh is not None:
            with contextlib.suppress(OSError):
                self._fh.close()
        self._fh = self.path = None

    def stats(self) -> dict[str, int | str]:
        return {"write_errors": self.write_errors, "lost_bytes": self.lost_bytes,
                "last_write_error": self.last_write_error, "syncs": self.syncs}


#: the file's data (and the size that finds it) to the disk, not its times: ``fdatasync`` where
#: the system has it
_datasync = getattr(os, "fdatasync", os.fsync)
