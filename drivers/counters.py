"""Per-source counters of a framed reader: what arrived, what was bad, what was thrown away.

One :class:`Counters` belongs to one source (a port, a socket, a file). The stream decoder of
:mod:`drivers.framing` updates the frame/byte counts; a transport adds ``reconnects`` and
``overflows``. Counters only ever grow; :meth:`Counters.as_dict` is what ``uvd decode`` and the
telemetry print.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(slots=True)
class Counters:
    """Monotonic counters of one source.

    Attributes
    ----------
    frames : int
        Frames that decoded (checksum and fields valid).
    bad_checksums : int
        Complete frames whose checksum did not match.
    bad_frames : int
        Frames rejected for another reason (impossible header, length, field).
    resyncs : int
        Times the reader lost sync and had to search for the next sync word.
    bytes_in : int
        Bytes received.
    bytes_dropped : int
        Bytes discarded while searching for sync or inside rejected frames.
    overflows : int
        Times the buffer cap forced the oldest bytes out.
    reconnects : int
        Times the transport re-opened its port or socket after a failure.
    queue_drops : int
        Decoded frames dropped because the consumer did not take them (oldest first).
    """

    frames: int = 0
    bad_checksums: int = 0
    bad_frames: int = 0
    resyncs: int = 0
    bytes_in: int = 0
    bytes_dropped: int = 0
    overflows: int = 0
    reconnects: int = 0
    queue_drops: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict (for JSON)."""
        return asdict(self)
