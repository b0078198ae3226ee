"""Recording every CAN frame uvd sends and receives, with python-can's own writers.

The format follows the file suffix — ``.log`` (candump, readable by ``can.LogReader``,
``python -m can.player`` and the Linux ``canplayer``), ``.asc`` (Vector ASCII) or ``.blf``
(Vector binary) — and the file rotates by size (``can.SizedRotatingLogger``) when
``max_bytes`` > 0: the full file is renamed ``<stem>_<date>_#NNN<suffix>`` and a new one is
started under the configured name.

Recording is off the control cycle's critical path: :meth:`CanRecorder.record` only puts the
frame on a bounded queue; a writer thread does the file I/O. If the disk cannot keep up and
the queue fills, frames are dropped from the *log* (counted in ``dropped``), never delayed on
the bus. A write that fails (a full disk) loses its frame from the log (counted in
``write_errors``); failures are told in spells, as the daemon's record files tell theirs
(:class:`uvd.spells.FailureSpells`): a spell's first failure and its end (the
first ten spells), and every :data:`LOG_EVERY` th failure throughout; :meth:`CanRecorder.trouble`
says why while writes fail (the daemon tells the operator).
"""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
from pathlib import Path

import can

from drivers.can.config import LOG_SUFFIXES, CanLogConfig
from uvd.errors import ConfigError, TransportError
from uvd.spells import FailureSpells

log = logging.getLogger(__name__)

#: after a spell's first failed write, one in this many is logged (a full disk fails them all)
LOG_EVERY = 100
#: the file is flushed and forced to the disk at most this often while frames come (s), as the
#: black box is (``[recording] sync_interval_s``): a power cut then loses at most about this
#: much of a candump or ASC log (of a BLF log also the container python-can still compresses)
SYNC_EVERY_S = 1.0


class CanRecorder:
    """Writes frames to a candump/ASC/BLF file from a background thread.

    Parameters
    ----------
    path : str or Path
        Log file; the suffix chooses the format.
    max_bytes : int
        Rotate when the file reaches this size; 0 never rotates.
    queue_size : int
        Frames that may wait for the writer thread.

    Raises
    ------
    ConfigError
        Unsupported suffix.
    TransportError
        The file cannot be created.
    """

    def __init__(self, path: str | Path, max_bytes: int = 0, queue_size: int = 100_000) -> None:
        self.path = Path(path)
        if self.path.suffix.lower() not in LOG_SUFFIXES:
            raise ConfigError(f"[can.log] path: {str(self.path)!r} must end in one of "
                              f"{', '.join(LOG_SUFFIXES)}")
        self.max_bytes = int(max_bytes)
        self.written = 0
        self.dropped = 0
        self.syncs = 0
        self.sync_errors = 0
        self._sync_trouble: str | None = None
        self._spells = FailureSpells(LOG_EVERY)
        self._failing_since = 0.0
        self._last_error = ""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if self.max_bytes > 0:
                self._writer = can.SizedRotatingLogger(str(self.path), max_bytes=self.max_bytes)
            else:
                self._writer = can.Logger(str(self.path))
        except (OSError, ValueError) as exc:
            raise TransportError(f"cannot open CAN log {str(self.path)!r}: {exc}") from exc
        self._queue: queue.Queue[can.Message | None] = queue.Queue(maxsize=queue_size)
        self._thread = threading.Thread(target=self._run, name="uvd-can-log", daemon=True)
        self._stopped = False
        self._thread.start()

    @classmethod
    def from_config(cls, cfg: CanLogConfig) -> CanRecorder | None:
        """A recorder for ``[can.log]``, or ``None`` when no path is configured."""
        if cfg.path is None:
            return None
        return cls(cfg.path, cfg.max_bytes)

    def record(self, msg: can.Message, *, is_rx: bool) -> None:
        """Queue one frame for the log (never blocks, never raises)."""
        if self._stopped:
            return
        msg.is_rx = is_rx
        try:
            self._queue.put_nowait(msg)
        except queue.Full:
            self.dropped += 1

    def __call__(self, msg: can.Message) -> None:
        self.record(msg, is_rx=True)

    @property
    def write_errors(self) -> int:
        """Frames whose write to the file failed (lost from the log)."""
        return self._spells.total

    def trouble(self) -> str | None:
        """Why the last write failed while writes fail, else why the last sync failed while
        syncs fail — a buffered writer's frames meet a full disk only when flushed (None: the
        last of each worked; the daemon tells the operator,
        :meth:`uvd.telemetry.sink.TelemetryHub.watch`)."""
        return self._last_error if self._spells.in_a_row else self._sync_trouble

    @property
    def rollovers(self) -> int:
        """How many times the file was rotated."""
        return int(getattr(self._writer, "rollover_count", 0))

    def _run(self) -> None:
        synced_at, dirty = time.monotonic(), False
        while True:
            if dirty and time.monotonic() - synced_at >= SYNC_EVERY_S:
                self._sync()
                synced_at, dirty = time.monotonic(), False
            try:
                msg = self._queue.get(timeout=SYNC_EVERY_S if dirty else None)
            except queue.Empty:
                continue
            if msg is None:
                return
            dirty = True
            try:
                self._writer.on_message_received(msg)
            except Exception as exc:  # noqa: BLE001 - a log problem must not stop the bus
                self._last_error = f"{self.path}: {type(exc).__name__}: {exc}"
                if not self._failing_since:
                    self._failing_since = time.monotonic()
                if self._spells.failed():
                    log.warning("CAN log: cannot write %s (%d failed writes): %s; those frames "
                                "are not in the log", self.path, self.write_errors, exc)
                continue
            self.written += 1
            if self._spells.recovered():
                log.warning("CAN log: %s written again after %.1f s of failed writes "
                            "(%d so far)", self.path, time.monotonic() - self._failing_since,
                            self.write_errors)
            self._failing_since = 0.0

    def _sync(self) -> None:
        """What the writer wrote, flushed and forced to the disk (the writer thread's)."""
        try:
            f = getattr(self._writer, "writer", self._writer).file  # a rotating one's current
            f.flush()
            os.fsync(f.fileno())
            self.syncs += 1
            self._sync_trouble = None
        except (OSError, ValueError, AttributeError) as exc:
            self.sync_errors += 1
            self._sync_trouble = f"{self.path}: {type(exc).__name__}: {exc}"
            if self.sync_errors == 1 or self.sync_errors % LOG_EVERY == 0:
                log.warning("CAN log: cannot force %s to the disk (%d times): %s", self.path,
                            self.sync_errors, exc)

    def stop(self, timeout: float = 5.0) -> None:
        """Write what is queued, close the file (idempotent)."""
        if self._stopped:
            return
        self._stopped = True
        try:
            self._queue.put(None, timeout=timeout)
        except queue.Full:
            pass
        self._thread.join(timeout)
        try:
            self._writer.stop()
        except Exception as exc:  # noqa: BLE001
            log.warning("closing CAN log %s: %s", self.path, exc)

    def __enter__(self) -> CanRecorder:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
