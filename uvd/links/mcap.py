"""The black-box recorder: every hub record and every raw input frame to MCAP, off the loop.

MCAP is the log format Foxglove and ROS 2 read; the ``mcap`` package writes it (the format's
own library: its records, indexes and summary are not ours to get wrong). Channels and their
JSON Schemas are listed in docs/recording.md and in :mod:`uvd.telemetry.recording` (the file
contract, and the reader of recordings).

Two ways in, neither of which waits:

* as a :class:`~uvd.telemetry.sink.TelemetrySink` of the hub — cycle records (also as a
  ``foxglove.PoseInFrame`` on ``/uvd/pose``), estimates, failsafe events, lifecycle
  transitions, commands, the start record, reloads;
* the raw-frame taps (:meth:`McapRecorder.tap_serial`, :meth:`McapRecorder.tap_can`), set on
  the drivers' ``tap`` attributes: every chunk of bytes a serial reader received and every CAN
  frame, stamped on the monotonic clock. They only append to a bounded deque (when full the
  oldest frame is dropped and counted).

The pump (the hub's, in the event loop) serialises messages in slices of at most
``slice_s`` into an in-memory buffer; a worker thread hands the bytes to the operating system
every ``flush_interval_s``. Messages are written as plain records (no chunks), so a file cut
by SIGKILL or a crash is readable by a streaming reader
(:func:`~uvd.telemetry.recording.read_messages`) up to the last flush — at most
``flush_interval_s`` (0.25 s by default) before the kill; a clean stop writes MCAP's summary
section too. A new file is started past ``rotate_mb`` or ``rotate_s``; the
start record is repeated at the top of each. A stalled disk bounds the bytes waiting for it
(``max_pending_mb``): past that, records are dropped and counted, never queued without end.
The disk's free room is measured as the files are written (:meth:`McapRecorder.low_space`:
below ``min_free_mb`` the operator is told ahead of a full disk).

A lockstep experiment, which has no event loop, writes the same files from its own thread
(:meth:`McapRecorder.open_now`, :meth:`~McapRecorder.write_now`,
:meth:`~McapRecorder.close_now`).
"""

from __future__ import annotations

import asyncio
import base64
import collections
import json
import math
import shutil
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from uvd.jsonio import to_jsonable
from uvd.telemetry._worker import DaemonWorker
from uvd.telemetry.appendfile import AppendFile
from uvd.telemetry.recording import CHANNELS, schema

__all__ = ["McapRecorder"]

_TOPIC_OF_TYPE = {t: topic for topic, (_, t) in CHANNELS.items() if t is not None}

#: the recording's free disk space is measured at most this often (s), by the worker thread
FREE_EVERY_S = 5.0


def _quaternion(R) -> dict[str, float]:
    """Unit quaternion (x, y, z, w) of a rotation matrix (Shepperd's method)."""
    r = [[float(R[i][j]) for j in range(3)] for i in range(3)]
    tr = r[0][0] + r[1][1] + r[2][2]
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        w, x = 0.25 * s, (r[2][1] - r[1][2]) / s
        y, z = (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s
    elif r[0][0] > r[1][1] and r[0][0] > r[2][2]:
        s = math.sqrt(1.0 + r[0][0] - r[1][1] - r[2][2]) * 2.0
        w, x = (r[2][1] - r[1][2]) / s, 0.25 * s
        y, z = (r[0][1] + r[1][0]) / s, (r[0][2] + r[2][0]) / s
    elif r[1][1] > r[2][2]:
        s = math.sqrt(1.0 + r[1][1] - r[0][0] - r[2][2]) * 2.0
        w, x = (r[0][2] - r[2][0]) / s, (r[0][1] + r[1][0]) / s
        y, z = 0.25 * s, (r[1][2] + r[2][1]) / s
    else:
        s = math.sqrt(1.0 + r[2][2] - r[0][0] - r[1][1]) * 2.0
        w, x = (r[1][0] - r[0][1]) / s, (r[0][2] + r[2][0]) / s
        y, z = (r[1][2] + r[2][1]) / s, 0.25 * s
    return {"x": x, "y": y, "z": z, "w": w}


def _pose(rec: Mapping[str, Any]) -> dict[str, Any]:
    t = int(rec["t_ns"])
    p = [float(x) for x in rec["p"]]
    return {"timestamp": {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000},
            "frame_id": "ned", "pose": {"position": {"x": p[0], "y": p[1], "z": p[2]},
                                        "orientation": _quaternion(rec["R"])}}


class _Buffer:
    """The writer's output: bytes collected in the event loop, taken by the worker thread."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.size = 0  # bytes written since the file began: its position (MCAP's summary
        self.lock = threading.Lock()  # offsets ask for it)
        self.pending = 0  # bytes not yet taken by the worker

    def write(self, b) -> int:
        b = bytes(b)
        with self.lock:
            self.parts.append(b)
            self.size += len(b)
            self.pending += len(b)
        return len(b)

    def tell(self) -> int:
        return self.size

    def take(self) -> bytes:
        with self.lock:
            out, self.parts, self.pending = b"".join(self.parts), [], 0
        return out

    def flush(self) -> None:
        return None


class McapRecorder:
    """Record the hub's records and the raw input frames to ``directory/uvd-<time>.mcap``.

    Parameters
    ----------
    directory : path
        Folder of the files (created).
    flush_interval_s : float
        Most data lost by a crash or SIGKILL (seconds before it).
    rotate_mb, rotate_s : float
        Start a new file past this size / age (0: never).
    raw_queue_size : int
        Raw frames that may wait; when full the oldest is dropped and counted.
    slice_s : float
        Longest stretch of serialising before the pump yields to the event loop.
    max_pending_mb : float
        Serialised bytes that may wait for a stalled disk; past that, records are dropped and
        counted (``stalled_dropped``) and raw frames pile up in their bounded queue (dropped
        oldest first, ``raw_dropped``): memory stays bounded, the loop never waits.
    clock_wall : callable
        Wall clock for the file names only.
    min_free_mb : float
        :meth:`low_space` names the disk when it has less free than this (0: never); the
        worker thread measures it every :data:`FREE_EVERY_S` after a write.
    sync_interval_s : float
        The worker forces the file's data to the disk at most this long apart (0: only at a
        file's end): what a power cut of the machine may lose
        (:class:`~uvd.telemetry.appendfile.AppendFile`).
    """

    name = "mcap"

    def __init__(self, directory: str | Path, *, flush_interval_s: float = 0.25,
                 rotate_mb: float = 512.0, rotate_s: float = 0.0, raw_queue_size: int = 65536,
                 slice_s: float = 2e-4, max_pending_mb: float = 64.0,
                 clock_wall=time.time, min_free_mb: float = 0.0,
                 sync_interval_s: float = 0.0) -> None:
        self.directory = Path(directory)
        self.flush_interval_s = float(flush_interval_s)
        self.rotate_bytes = int(rotate_mb * 1e6)
        self.rotate_ns = int(rotate_s * 1e9)
        self.slice_s = float(slice_s)
        self.max_pending = int(max_pending_mb * 1e6)
        self.stalled_dropped = 0
        self.clock_wall = clock_wall
        self._raw: collections.deque = collections.deque(maxlen=int(raw_queue_size))
        self.raw_taken = 0
        self.raw_dropped = 0
        self.messages = 0
        self.files: list[Path] = []
        self._writer = None
        self._buf: _Buffer | None = None
        # the worker's file; what waits in it after failed writes counts against the bound
        # twice over, so that write() drops records before whole bytes are given up
        self._file = AppendFile(2 * self.max_pending, sync_interval_s)
        self._channels: dict[str, int] = {}
        self._seq: dict[int, int] = {}
        self._start_rec: Mapping[str, Any] | None = None
        self._file_bytes = 0
        self._file_t0_ns = 0
        self._worker = DaemonWorker("uvd-sink-mcap")
        self._sync = False  # open_now: the caller's thread writes (lockstep experiments)
        self._flusher: asyncio.Task | None = None
        self.min_free = int(min_free_mb * 1e6)
        #: the disk's free bytes when the worker last measured them (None: not yet, or the
        #: measure failed), and the bytes written and the monotonic time since the first
        self.free_bytes: int | None = None
        self._free_at = -math.inf
        self._bytes_out = 0
        self._t_first = 0.0

    # -- taps (any thread; cheap; never raise) --

    def tap_serial(self, source: str, t_ns: int, data: bytes) -> None:
        """``FrameReader.tap``: one chunk of bytes of ``source`` as it arrived."""
        q = self._raw
        if len(q) == q.maxlen:
            self.raw_dropped += 1
        q.append(("/uvd/raw/serial", t_ns, (source, bytes(data))))

    def tap_can(self, msg, t_ns: int, is_rx: bool) -> None:
        """``CanBus.tap``: one CAN frame sent or received."""
        q = self._raw
        if len(q) == q.maxlen:
            self.raw_dropped += 1
        q.append(("/uvd/raw/can", t_ns, (bool(is_rx), int(msg.arbitration_id),
                                        bool(msg.is_extended_id), bool(msg.is_remote_frame),
                                        bool(msg.is_error_frame), bytes(msg.data))))

    # -- files --

    def _new_file(self, t_ns: int) -> None:
        from mcap.writer import CompressionType, Writer
        if self._writer is not None:
            self._finish_file()
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime(self.clock_wall()))
        path = self.directory / f"uvd-{stamp}-{len(self.files):03d}.mcap"
        self._buf = _Buffer()
        self._writer = Writer(self._buf, use_chunking=False, compression=CompressionType.NONE)
        self._writer.start(profile="", library="uvd")
        self._channels = {}
        for topic, (schema_name, _) in CHANNELS.items():
            sid = self._writer.register_schema(
                schema_name, "jsonschema", json.dumps(schema(schema_name)).encode())
            self._channels[topic] = self._writer.register_channel(topic, "json", sid)
        self._seq = dict.fromkeys(self._channels.values(), 0)
        self._file_bytes = 0
        self._file_t0_ns = t_ns
        self.files.append(path)
        if self._start_rec is not None:
            self._add("/uvd/start", t_ns, self._start_rec)

    def _finish_file(self) -> None:
        self._writer.finish()
        data = self._buf.take()
        if self._sync:
            self._write_bytes(self.files[-1], data, True)
        else:  # queued behind the earlier writes of that file (one worker thread, in order)
            self._worker.submit(self._write_bytes, self.files[-1], data, True)
        self._writer = None

    def _write_bytes(self, path: Path, data: bytes, close: bool) -> None:
        """Worker thread: append ``data`` to ``path`` (the file open while it is current). A
        failed write never raises: :class:`~uvd.telemetry.appendfile.AppendFile` keeps the
        file whole to its last write and the bytes for the disk; past ``max_pending_mb``
        waiting, :meth:`write` drops records (``stalled_dropped``)."""
        self._file.write(path, data, close)
        now = time.monotonic()
        if not self._t_first:
            self._t_first = now
        self._bytes_out += len(data)
        if self.min_free and now - self._free_at >= FREE_EVERY_S:
            self._free_at = now
            try:
                self.free_bytes = shutil.disk_usage(path.parent).free
            except OSError:
                self.free_bytes = None  # not known: nothing told of it

    def low_space(self) -> str | None:
        """The recording's disk, when it has less free than ``min_free_mb`` (None: more, or
        not measured): its free megabytes and, at the rate written so far, the hours of
        recording left (the hub tells the operator: ``TelemetryHub.watch``)."""
        free = self.free_bytes
        if not self.min_free or free is None or free >= self.min_free:
            return None
        text = (f"{free / 1e6:.0f} MB free on {self.directory} (below [recording] min_free_mb "
                f"{self.min_free / 1e6:g})")
        span = time.monotonic() - self._t_first if self._t_first else 0.0
        if span >= 10.0 and self._bytes_out:
            rate = self._bytes_out / span  # bytes a second
            text += (f"; about {free / rate / 3600:.1f} h of recording left at "
                     f"{rate * 3600 / 1e6:.0f} MB/h")
        return text

    def _add(self, topic: str, t_ns: int, obj: Any) -> None:
        data = json.dumps(obj, separators=(",", ":"), default=str, allow_nan=False).encode()
        cid = self._channels[topic]
        seq = self._seq[cid]
        self._seq[cid] = seq + 1
        self._writer.add_message(cid, t_ns, data, t_ns, seq)
        self._file_bytes += len(data)
        self.messages += 1

    def _rotate_due(self, t_ns: int) -> bool:
        return (self.rotate_bytes and self._file_bytes >= self.rotate_bytes) or \
            (self.rotate_ns and t_ns - self._file_t0_ns >= self.rotate_ns)

    # -- the sink --

    async def open(self) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        self._new_file(time.monotonic_ns())
        self._flusher = asyncio.get_running_loop().create_task(self._flush_loop(),
                                                               name="mcap-flush")

    async def _flush_loop(self) -> None:
        while True:
            await asyncio.sleep(self.flush_interval_s)
            await self.flush()

    async def write(self, records: Sequence[Mapping[str, Any]]) -> None:
        if self._writer is None:
            raise RuntimeError(f"sink {self.name} is not open")
        if self._stalled():
            self.stalled_dropped += len(records)
            return
        # the raw bytes first: a cycle's record follows the bytes its samples came from in
        # the file, so a file cut anywhere (a crash) holds every sample its cycles name
        self._drain_raw()
        t0 = time.perf_counter()
        for r in records:
            self._take(r)
            if time.perf_counter() - t0 > self.slice_s:
                await asyncio.sleep(0)
                t0 = time.perf_counter()
        self._drain_raw()

    def trouble(self) -> str | None:
        """What keeps records from the file now — a failing disk (the path and the error) or
        a hung one — None when nothing does (the hub tells the operator of it)."""
        if self._file.failing:
            return self._file.failing
        if self._buf is not None and self._stalled():
            return (f"{self._file.path or self.directory}: the disk takes nothing "
                    f"({self.max_pending / 1e6:g} MB wait); records are dropped")
        return None

    def _stalled(self) -> bool:
        """The disk takes nothing (hung, or failing): more than ``max_pending_mb`` wait."""
        return self._buf.pending + len(self._file.unwritten) > self.max_pending

    def _take(self, r: Mapping[str, Any]) -> None:
        """Serialise one hub record onto its channel (a cycle record onto the pose too)."""
        kind = r.get("type")
        t_ns = int(r.get("t_ns") or time.monotonic_ns())
        if self._rotate_due(t_ns):
            self._new_file(t_ns)
        obj = to_jsonable(r)
        if kind == "start":
            self._start_rec = obj
        topic = _TOPIC_OF_TYPE.get(kind)
        if topic is not None:
            self._add(topic, t_ns, obj)
            if kind == "cycle":
                self._add("/uvd/pose", t_ns, _pose(obj))

    # -- without an event loop: a lockstep experiment's thread writes the same files --

    def open_now(self, t_ns: int = 0) -> None:
        """Start writing from the calling thread (no event loop, no worker: lockstep runs)."""
        self._sync = True
        self.directory.mkdir(parents=True, exist_ok=True)
        self._new_file(t_ns)

    def write_now(self, records: Sequence[Mapping[str, Any]]) -> None:
        """Serialise ``records``; every few MB go to the file from the calling thread."""
        for r in records:
            self._take(r)
        if self._buf.pending > 4_000_000:
            self._write_bytes(self.files[-1], self._buf.take(), False)

    def close_now(self) -> None:
        """Finish the file (MCAP's summary included) from the calling thread."""
        if self._writer is not None:
            self._finish_file()

    def _drain_raw(self) -> None:
        q = self._raw
        while q:
            topic, t_ns, payload = q.popleft()
            self.raw_taken += 1
            if topic == "/uvd/raw/serial":
                obj = {"source": payload[0], "t_ns": t_ns,
                       "data": base64.b64encode(payload[1]).decode("ascii")}
            else:
                rx, cid, ext, rtr, err, data = payload
                obj = {"t_ns": t_ns, "rx": rx, "id": cid, "extended": ext, "remote": rtr,
                       "error": err, "data": base64.b64encode(data).decode("ascii")}
            self._add(topic, t_ns, obj)

    async def flush(self) -> None:
        """Hand what is serialised to the operating system (a worker thread writes it)."""
        if self._writer is None:
            return
        if not self._stalled():  # else the raw frames wait in their bounded queue
            self._drain_raw()
        data = self._buf.take()
        if data or self._file.unwritten:
            await self._worker.submit(self._write_bytes, self.files[-1], data, False)

    async def aclose(self) -> None:
        if self._flusher is not None:
            self._flusher.cancel()
        try:
            if self._writer is not None:
                self._drain_raw()
                self._writer.finish()
                await self._worker.submit(self._write_bytes, self.files[-1], self._buf.take(),
                                          True)
                self._writer = None
        finally:
            self._worker.close()

    def stats(self) -> dict[str, Any]:
        return {"files": [str(p) for p in self.files], "messages": self.messages,
                "raw_taken": self.raw_taken, "raw_dropped": self.raw_dropped,
                "stalled_dropped": self.stalled_dropped, **self._file.stats()}
