"""Resynchronising stream decoder shared by every codec (bytes in, decoded frames out).

A serial line or a file is a byte stream with frames somewhere in it, garbage between them and
sometimes damage inside them. :class:`StreamDecoder` turns such a stream into frames:

1. search the codec's sync word (``b"\\x7f\\x7f"`` PD0, ``b"IX"`` STDBIN, ``b"$"`` NMEA,
   ``b"*"`` Digiquartz); bytes before it are dropped and counted;
2. ask the codec for the frame length from its header (``None``: wait for more bytes; a
   :class:`~uvd.errors.FrameError` means the header is impossible);
3. when the whole frame is buffered, decode it (the codec verifies the checksum);
4. on any error, drop **one** byte and search again — a valid frame may start inside the
   rejected one, so nothing that could still be good is thrown away.

The buffer is capped (``max_buffer``) so a stream of garbage cannot grow memory; partial frames
stay buffered across :meth:`StreamDecoder.feed` calls. Every rejection is counted in
:class:`~drivers.counters.Counters` and the latest few are kept in ``errors`` with their stream
offset and reason, so a user can be told what was dropped and where. Nothing here raises on bad
input; only a codec bug could.

A codec is any object with the attributes of :class:`FrameCodec`.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any, Protocol

from drivers.counters import Counters
from uvd.errors import ChecksumError, FrameError


class FrameCodec(Protocol):
    """What :class:`StreamDecoder` needs from a codec.

    Attributes
    ----------
    name : str
        Short name (``"pd0"``, ``"phins-stdbin"``, …) used in messages.
    sync : bytes
        The bytes every frame starts with.
    max_frame : int
        Largest frame the codec accepts; longer declared lengths are header errors.
    """

    name: str
    sync: bytes
    max_frame: int

    def frame_length(self, buf: bytearray, start: int) -> int | None:
        """Length of the frame starting at ``buf[start]`` (which holds ``sync``).

        Returns ``None`` when more bytes are needed to tell; raises
        :class:`~uvd.errors.FrameError` when the header cannot be a frame.
        """

    def decode(self, frame: bytes) -> Any:
        """Decode one complete frame; raises ChecksumError / FrameError."""


@dataclass(frozen=True, slots=True)
class DecodeErrorRecord:
    """One rejected frame or dropped run: where in the stream, what kind and why."""

    offset: int
    kind: str  # "checksum", "frame", "garbage", "overflow", "truncated"
    message: str
    n_bytes: int


@dataclass(frozen=True, slots=True)
class Stamped:
    """A decoded frame with its monotonic receive time (ns) and the raw bytes."""

    t_ns: int
    frame: Any
    raw: bytes = b""


class StreamDecoder:
    """Incremental, resynchronising decoder of one byte stream.

    Parameters
    ----------
    codec : FrameCodec
    max_buffer : int, optional
        Cap of the internal buffer in bytes (default: 4 × ``codec.max_frame``, at least 4096).
    counters : Counters, optional
        Counters to update (a new one by default); shared with the transport.
    keep_errors : int
        How many of the latest :class:`DecodeErrorRecord` to keep in ``errors``.
    keep_raw : bool
        Return ``(frame, raw_bytes)`` pairs from :meth:`feed` instead of frames.
    keep_offset : bool
        With ``keep_raw``: return ``(frame, raw_bytes, stream_offset)`` triples.
    """

    def __init__(self, codec: FrameCodec, max_buffer: int | None = None,
                 counters: Counters | None = None, keep_errors: int = 100,
                 keep_raw: bool = False, keep_offset: bool = False):
        self.codec = codec
        self.max_buffer = int(max_buffer or max(4096, 4 * codec.max_frame))
        if self.max_buffer < codec.max_frame:
            raise ValueError(f"max_buffer {self.max_buffer} is smaller than the largest "
                             f"{codec.name} frame ({codec.max_frame})")
        self.counters = counters if counters is not None else Counters()
        self.errors: deque[DecodeErrorRecord] = deque(maxlen=keep_errors)
        self.keep_raw = keep_raw
        self.keep_offset = keep_offset
        self._buf = bytearray()
        self._base = 0  # stream offset of _buf[0]
        self._in_sync = True  # False while dropping bytes (one resync per lost-sync episode)

    @property
    def buffered(self) -> int:
        """Bytes waiting in the buffer (a partial frame or not-yet-searched input)."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget buffered bytes (after a reconnect: a partial frame cannot continue)."""
        if self._buf:
            self._drop_count(len(self._buf), "truncated", "partial frame discarded on reset",
                             self._base)
        self._base += len(self._buf)
        self._buf.clear()

    def _drop_count(self, n: int, kind: str, message: str, offset: int) -> None:
        c = self.counters
        c.bytes_dropped += n
        if self._in_sync:
            c.resyncs += 1
            self._in_sync = False
        self.errors.append(DecodeErrorRecord(offset, kind, message, n))

    def feed(self, data: bytes | bytearray | memoryview) -> list:
        """Add bytes; return the frames completed by them (possibly none)."""
        c = self.counters
        c.bytes_in += len(data)
        buf = self._buf
        buf += data
        out: list = []
        codec = self.codec
        sync = codec.sync
        nsync = len(sync)
        pos = 0
        n_buf = len(buf)
        try:
            while True:
                i = buf.find(sync, pos)
                if i < 0:
                    # keep a tail that could be the start of a sync word
                    keep = 0
                    for k in range(min(nsync - 1, n_buf - pos), 0, -1):
                        if buf[n_buf - k:] == sync[:k]:
                            keep = k
                            break
                    n_drop = n_buf - keep - pos
                    if n_drop > 0:
                        self._drop_count(n_drop, "garbage", f"no {codec.name} sync word",
                                         self._base + pos)
                        pos += n_drop
                    break
                if i > pos:
                    self._drop_count(i - pos, "garbage",
                                     f"{i - pos} bytes before the {codec.name} sync word",
                                     self._base + pos)
                    pos = i
                try:
                    n = codec.frame_length(buf, pos)
                except FrameError as exc:
                    c.bad_frames += 1
                    self._drop_count(1, "frame", str(exc), self._base + pos)
                    pos += 1
                    continue
                if n is None or n_buf - pos < n:
                    break
                frame = bytes(buf[pos:pos + n])
                try:
                    msg = codec.decode(frame)
                except ChecksumError as exc:
                    c.bad_checksums += 1
                    self._drop_count(1, "checksum", str(exc), self._base + pos)
                    pos += 1
                    continue
                except FrameError as exc:
                    c.bad_frames += 1
                    self._drop_count(1, "frame", str(exc), self._base + pos)
                    pos += 1
                    continue
                c.frames += 1
                self._in_sync = True
                if not self.keep_raw:
                    out.append(msg)
                elif self.keep_offset:
                    out.append((msg, frame, self._base + pos))
                else:
                    out.append((msg, frame))
                pos += n
        finally:
            if pos:
                del buf[:pos]
                self._base += pos
            excess = len(buf) - self.max_buffer
            if excess > 0:
                c.overflows += 1
                self._drop_count(excess, "overflow", f"buffer cap {self.max_buffer} B exceeded",
                                 self._base)
                del buf[:excess]
                self._base += excess
        return out

    def finish(self) -> list:
        """End of stream: try every remaining sync position, then count the rest as dropped.

        A header that promised more bytes than the stream delivered would otherwise hide any
        valid frame after it; at the end we know no more bytes come, so it is dropped.
        """
        out: list = []
        guard = len(self._buf) + 1
        while self._buf and guard > 0:
            guard -= 1
            start = self._buf.find(self.codec.sync)
            if start < 0:
                break
            # drop up to and including the first sync byte, then re-run the scanner
            cut = start + 1
            at, n_errors = self._base, len(self.errors)
            self._drop_count(cut, "truncated", f"incomplete {self.codec.name} frame at end",
                             self._base)
            del self._buf[:cut]
            self._base += cut
            rest = bytes(self._buf)
            self._buf.clear()
            self.counters.bytes_in -= len(rest)  # feed() counts them again
            found = self.feed(rest)
            out.extend(found)
            if not found and len(self.errors) > n_errors:
                # no frame behind it: what the scanner dropped after that byte is the cut
                # frame too (one record, not 1 B "truncated" and the rest "garbage")
                dropped = [self.errors.pop() for _ in range(len(self.errors) - n_errors)]
                self.errors.append(DecodeErrorRecord(
                    at, "truncated", f"incomplete {self.codec.name} frame at end",
                    sum(r.n_bytes for r in dropped)))
        if self._buf:
            self._drop_count(len(self._buf), "truncated", "bytes left at end of stream",
                             self._base)
            self._base += len(self._buf)
            self._buf.clear()
        return out


def decode_bytes(codec: FrameCodec, data: bytes, counters: Counters | None = None,
                 keep_raw: bool = False, keep_offset: bool = False
                 ) -> tuple[list, StreamDecoder]:
    """Decode a whole byte string (e.g. a recorded file); returns (frames, decoder)."""
    dec = StreamDecoder(codec, counters=counters, keep_raw=keep_raw or keep_offset,
                        keep_offset=keep_offset,
                        max_buffer=max(len(data) + 1, 4 * codec.max_frame))
    frames = dec.feed(data)
    frames.extend(dec.finish())
    return frames, dec
