"""A ROS 1 bag read record by record, in file order, without its index: a bag cut short, or
the rest of a damaged one.

``rosbag record`` writes a bag's index at its end when it closes; a recording cut short (a
power cut on the vehicle, a crash: ``NAME.bag.active``) has none, and rosbags, which reads by
the index, refuses it ("Bag index looks damaged"). ROS 1's ``rosbag reindex`` mends such a
file, where ROS 1 is installed. This reads the records the bag does hold, as reindex does:
the format (ROS bag 2.0: http://wiki.ros.org/Bags/Format/2.0) is a magic line, then records
of a header (``name=value`` fields, ``op`` their kind) and data; connections (op 0x07) and
messages (op 0x02) lie in chunks (op 0x05), uncompressed, bz2 or lz4. The messages are
decoded by rosbags' type system from each connection's own message definition.

An uncompressed chunk is read up to the last whole record before the cut (its declared size
may be that of the whole chunk, or the placeholder of one never closed); a compressed chunk
cut short is skipped and said so (what it holds cannot be told from part of it). A record in
a chunk that does not read — a damaged header, a length that does not end where another
record begins — is skipped to the next offset where one does (``scan.skipped`` names it),
as rosbags, which stops at the first, cannot.
"""

from __future__ import annotations

import bz2
import mmap
import re
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

MAGIC = b"#ROSBAG V2.0\n"
_U32 = struct.Struct("<I")
#: the longest record header taken for one (a message's is 38 B, a chunk's about 40)
_HEADER_MAX = 4096
#: a record header's op field of a message or a connection: where resynchronising looks
_OP_FIELD = re.compile(rb"\x04\x00\x00\x00op=[\x02\x07]")
OP_MESSAGE, OP_CHUNK, OP_CONNECTION = 0x02, 0x05, 0x07


class BagRecordError(ValueError):
    """A record that does not read (the message names the byte)."""


@dataclass
class Connection:
    """A connection record: its topic and its message type and definition."""

    topic: str
    msgtype: str  # ROS 1 name, pkg/Type
    definition: str


@dataclass
class Scan:
    """What a record-by-record read found: connections by id, and where it ended."""

    connections: dict[int, Connection] = field(default_factory=dict)
    #: the end of the last whole record read: the file's size when every record was whole
    ended_at: int = 0
    size: int = 0
    #: what was skipped, one line each (a damaged stretch of a chunk, a compressed chunk cut
    #: short)
    skipped: list[str] = field(default_factory=list)


def _fields(header: bytes, where: int) -> dict[str, bytes]:
    """A record header's ``name=value`` fields."""
    out, pos = {}, 0
    while pos < len(header):
        if pos + 4 > len(header):
            raise BagRecordError(f"byte {where}: a header field's length is cut")
        (n,) = _U32.unpack_from(header, pos)
        text = header[pos + 4:pos + 4 + n]
        if len(text) != n or b"=" not in text:
            raise BagRecordError(f"byte {where}: a header field does not read")
        name, _, value = text.partition(b"=")
        out[name.decode("ascii", "replace")] = value
        pos += 4 + n
    return out


def _record(buf: bytes | memoryview, pos: int) -> tuple[dict[str, bytes], int, int, int] | None:
    """(header fields, data start, data length, next record's offset) of the record at
    ``pos``, or None if ``buf`` ends inside it."""
    if pos + 4 > len(buf):
        return None
    (hlen,) = _U32.unpack_from(buf, pos)
    if pos + 8 + hlen > len(buf):
        return None
    fields = _fields(bytes(buf[pos + 4:pos + 4 + hlen]), pos)
    (dlen,) = _U32.unpack_from(buf, pos + 4 + hlen)
    start = pos + 8 + hlen
    return fields, start, dlen, start + dlen


def _op(fields: dict[str, bytes], where: int) -> int:
    op = fields.get("op")
    if op is None or len(op) != 1:
        raise BagRecordError(f"byte {where}: a record without its op")
    return op[0]


def _connection(fields: dict[str, bytes], body: bytes | memoryview, where: int
                ) -> tuple[int, Connection]:
    info = _fields(bytes(body), where)  # a damaged byte in a text: replaced, not fatal (its
    # messages then may not decode, and are counted so by the reader)
    return _U32.unpack(fields["conn"])[0], Connection(
        fields["topic"].decode(errors="replace"), info["type"].decode(errors="replace"),
        info.get("message_definition", b"").decode(errors="replace"))


def _message(fields: dict[str, bytes], body: bytes | memoryview) -> tuple[int, int, bytes]:
    sec, nsec = struct.unpack("<II", fields["time"])
    return _U32.unpack(fields["conn"])[0], sec * 1_000_000_000 + nsec, bytes(body)


def _reads(data: bytes | memoryview, pos: int, scan: Scan, depth: int = 1
           ) -> tuple[int, dict[str, bytes], int, int] | None:
    """(op, header fields, data start, next offset) of the chunk record at ``pos`` if it reads
    whole — a connection, or a message with its fields on a connection declared so far — and
    (``depth``) where it ends, the data ends, or a record reads, or at least a record header
    stands (:func:`_frames`: a damaged record of its own, skipped when reached); None if
    not."""
    try:
        rec = _record(data, pos)
    except BagRecordError:
        return None
    if rec is None or rec[3] > len(data):
        return None
    fields, start, _, nxt = rec
    op = fields.get("op", b"")
    if len(op) != 1 or len(fields.get("conn", b"")) != 4:
        return None
    if op[0] == OP_MESSAGE:
        if len(fields.get("time", b"")) != 8 or (
                depth and _U32.unpack(fields["conn"])[0] not in scan.connections):
            return None  # (the record after a connection may be its first message)
    elif op[0] != OP_CONNECTION or "topic" not in fields:
        return None
    if depth and nxt < len(data) and _reads(data, nxt, scan, 0) is None \
            and not _frames(data, nxt):
        return None  # no record header where its length ends: its length is wrong
    return op[0], fields, start, nxt


def _frames(data: bytes | memoryview, at: int) -> bool:
    """Whether a record header stands at ``at`` (its content may be damaged, a record of its
    own to skip): a header length no longer than ``_HEADER_MAX`` whose fields read and hold
    an op, or that ``data`` ends inside (a cut)."""
    if at + 4 > len(data):
        return True
    (hlen,) = _U32.unpack_from(data, at)
    if hlen > _HEADER_MAX:
        return False
    if at + 4 + hlen > len(data):
        return True
    try:
        return "op" in _fields(bytes(data[at + 4:at + 4 + hlen]), at)
    except BagRecordError:
        return False


def _resync(data: bytes | memoryview, start: int, scan: Scan) -> int | None:
    """The first offset from ``start`` where a chunk record reads (:func:`_reads`): tried only
    where its header may begin, up to 255 bytes before an ``op`` field of a connection or a
    message; None if there is none."""
    raw = bytes(data)
    for m in _OP_FIELD.finditer(raw, start):
        for q in range(max(start, m.start() - 255), m.start() - 3):
            if _reads(data, q, scan) is not None:
                return q
    return None


def _inner(data: bytes | memoryview, scan: Scan, base: int
           ) -> Iterator[tuple[int, int, bytes]]:
    """(connection id, t_ns, raw) of the message records of one chunk's data, registering its
    connections. A record that does not read is skipped to the next one that does (named in
    ``scan.skipped``); where none does, the data ends inside it: the read stops quietly
    (``scan.ended_at`` tells where)."""
    pos = 0
    while pos < len(data):
        got = _reads(data, pos, scan)
        if got is None:
            nxt = _resync(data, pos + 1, scan)
            if nxt is None:
                return
            scan.skipped.append(f"{nxt - pos} damaged bytes at byte {base + pos}")
            pos = nxt
            continue
        op, fields, start, nxt = got
        if op == OP_CONNECTION:
            conn, c = _connection(fields, data[start:nxt], base + start)
            scan.connections[conn] = c
        else:
            yield _message(fields, data[start:nxt])
        pos = nxt
        scan.ended_at = base + pos


def read_records(path: str | Path, scan: Scan) -> Iterator[tuple[int, int, bytes]]:
    """(connection id, t_ns, raw ROS 1 message) of every message record of the bag ``path``,
    in file order, up to the end of what it holds; ``scan`` is filled as it goes
    (connections, where it ended, what was skipped).

    Raises
    ------
    BagRecordError
        Not a ROS 1 bag 2.0, or a record header that does not read (naming the byte).
    """
    with Path(path).open("rb") as fh:
        if fh.read(len(MAGIC)) != MAGIC:
            raise BagRecordError(f"{path}: not a ROS 1 bag (no '#ROSBAG V2.0' line at its "
                                 "start)")
        with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:  # a bag may be GBs
            yield from _top(mm, scan, path)


def _top(mm: mmap.mmap, scan: Scan, path) -> Iterator[tuple[int, int, bytes]]:
    """The file's own records (:func:`read_records`). Slices of an mmap are copies: it
    closes with nothing left pointing into it."""
    scan.size, scan.ended_at = len(mm), len(MAGIC)
    pos = len(MAGIC)
    try:
        while (rec := _record(mm, pos)) is not None:
            fields, start, _, nxt = rec
            op = _op(fields, pos)
            if op == OP_CHUNK:
                compression = fields.get("compression", b"none").decode()
                if compression == "none":  # read up to the last whole record
                    yield from _inner(mm[start:min(nxt, len(mm))], scan, start)
                elif nxt > len(mm):
                    scan.skipped.append(f"a {compression} chunk at byte {pos}, cut short")
                else:
                    yield from _inner(_decompress(compression, mm[start:nxt], pos), scan,
                                      start)
            elif nxt > len(mm):
                pass  # cut inside this record
            elif op == OP_MESSAGE:  # a chunk never closed declares no size (a placeholder
                # 0): its records follow its header as if they were the file's own
                yield _message(fields, mm[start:nxt])
            elif op == OP_CONNECTION:  # the index section's copy, or an unclosed chunk's
                conn, c = _connection(fields, mm[start:nxt], start)
                scan.connections.setdefault(conn, c)
            if nxt > len(mm):
                break  # cut inside this record: what it held whole was read
            pos = scan.ended_at = nxt
    except (KeyError, struct.error, UnicodeDecodeError) as exc:
        raise BagRecordError(f"{path}: a record near byte {pos} does not read: "
                             f"{type(exc).__name__}: {exc}") from exc


def _decompress(compression: str, data: bytes, where: int) -> bytes:
    if compression == "bz2":
        return bz2.decompress(data)
    if compression == "lz4":
        import lz4.frame
        return lz4.frame.decompress(data)
    raise BagRecordError(f"byte {where}: a chunk compressed as {compression!r} (none, bz2, lz4)")
