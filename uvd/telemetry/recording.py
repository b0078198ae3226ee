"""The black box's file contract: its MCAP channels, their JSON Schemas, and reading a recording.

Every channel and its schema are listed in docs/recording.md; the schemas are the files of
``uvd/telemetry/schemas/`` (:func:`schema`). The writer is the black-box recorder
(:class:`uvd.links.mcap.McapRecorder`); replay, ``uvd report`` and the tests read what it
wrote through :func:`read_messages`.
"""

from __future__ import annotations

import io
import json
import mmap
import re
import struct
from collections.abc import Iterator, Mapping, Sequence
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Header, Message, Schema
from mcap.stream_reader import breakup_chunk

__all__ = ["CHANNELS", "schema", "read_messages", "RecordingError", "part_number", "run_files",
           "start_of", "drawn_files", "read_run", "load_run", "foreign_note"]

#: topic → (schema name, record type on the hub; None for the taps and the derived pose)
CHANNELS: dict[str, tuple[str, str | None]] = {
    "/uvd/start": ("uvd.start.v1", "start"),
    "/uvd/cycle": ("uvd.cycle.v1", "cycle"),
    "/uvd/pose": ("foxglove.PoseInFrame", None),
    "/uvd/estimate": ("uvd.estimate.v1", "estimate"),
    "/uvd/failsafe": ("uvd.failsafe.v1", "failsafe"),
    "/uvd/lifecycle": ("uvd.lifecycle.v1", "lifecycle"),
    "/uvd/command": ("uvd.command.v1", "command"),
    "/uvd/reload": ("uvd.reload.v1", "reload"),
    "/uvd/sink": ("uvd.sink.v1", "sink"),
    "/uvd/raw/serial": ("uvd.raw_serial.v1", None),
    "/uvd/raw/can": ("uvd.can_frame.v1", None),
}


class RecordingError(ValueError):
    """A recording that cannot be read as one (names the file and what is wrong)."""


@cache
def schema(name: str) -> dict[str, Any]:
    """The JSON Schema ``name`` (``uvd.cycle.v1`` …) shipped in uvd/telemetry/schemas."""
    text = resources.files("uvd.telemetry").joinpath("schemas", f"{name}.json").read_text(
        encoding="utf-8")
    return json.loads(text)


def read_messages(path: str | Path, topics: Sequence[str] | None = None, *,
                  unreadable: list[str] | None = None
                  ) -> Iterator[tuple[str, int, dict[str, Any]]]:
    """(topic, log time ns, decoded JSON) of every message of an MCAP file, in file order.

    Walks the data section record by record (:func:`_records`; MCAP's own record readers parse
    each one), so a file cut by a crash yields every message written before the cut (the cut
    itself ends the iteration quietly), and a damaged stretch in the middle — a record whose
    length, kind or content does not read, a message on a channel never declared — costs
    only itself: the walk goes on at the next record header that reads.

    ``unreadable``: where such a stretch and a message that is not JSON go instead of raising
    — one line naming the byte or the topic and time, the message skipped (``uvd report``
    counts them and draws the rest; replay covers the cycles before the first).

    Raises
    ------
    RecordingError
        Not an MCAP file, a channel of uvd's topics with another schema or encoding, or (unless
        ``unreadable`` takes it) a damaged record or a message that is not JSON (the message
        names the file and the problem). Channels of other topics are read as they are.
    """
    path = Path(path)
    want = None if topics is None else set(topics)
    channels: dict[int, str] = {}
    schemas: dict[int, str] = {}

    def damaged(what: str, exc: Exception | None = None) -> None:
        if unreadable is None:
            raise RecordingError(f"{path}: {what}") from exc
        unreadable.append(what)

    try:
        fh = path.open("rb")
    except IsADirectoryError as exc:  # a run's folder (uvd demo --record DIR)
        raise RecordingError(f"{path}: {_which_file(path)}") from exc
    except OSError as exc:
        raise RecordingError(f"{path}: cannot open: {exc}") from exc
    with fh:
        if fh.read(8) != MAGIC:
            raise RecordingError(f"{path}: not an MCAP file (no MCAP magic at its start)")
        with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            for at, rec in _records(mm, channels):
                if isinstance(rec, str):
                    damaged(rec)
                    continue
                inner = [rec]
                if isinstance(rec, Chunk):  # another writer's (uvd writes no chunks)
                    try:
                        inner = breakup_chunk(rec, validate_crc=True)
                    except Exception as exc:  # noqa: BLE001 - a damaged chunk, in any way
                        damaged(f"damaged MCAP chunk at byte {at}: {exc}", exc)
                        continue
                for r in inner:
                    if isinstance(r, Schema):
                        schemas[r.id] = r.name
                    elif isinstance(r, Channel):
                        want_schema = CHANNELS.get(r.topic, (None,))[0]
                        got = schemas.get(r.schema_id)
                        if want_schema is not None and (got not in (None, want_schema)
                                                        or r.message_encoding != "json"):
                            raise RecordingError(
                                f"{path}: channel {r.topic} has schema {got!r} and encoding "
                                f"{r.message_encoding!r}; uvd writes {want_schema!r} as json "
                                "(another program's file, or another version's)")
                        if want_schema is not None and got is None:  # its schema record lost
                            damaged(f"channel {r.topic} at byte {at} names schema id "
                                    f"{r.schema_id}, declared by no schema record read: its "
                                    f"messages are taken as uvd's {want_schema}")
                        channels[r.id] = r.topic
                    elif isinstance(r, Message):
                        topic = channels.get(r.channel_id)
                        if topic is None:
                            damaged(f"message on unknown channel {r.channel_id} at byte {at}")
                            continue
                        if want is not None and topic not in want:
                            continue
                        try:
                            msg = json.loads(r.data)
                        except ValueError as exc:
                            damaged(f"message on {topic} at {r.log_time} ns is not JSON: "
                                    f"{exc}", exc)
                            continue
                        yield topic, r.log_time, msg


#: the 8 bytes an MCAP file begins (and a complete one ends) with
MAGIC = b"\x89MCAP0\r\n"
_HEAD = struct.Struct("<BQ")  # a record's opcode and the length of its content
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
#: MCAP's opcodes, 0x01 (Header) to 0x0F (DataEnd)
_OPCODES = frozenset(range(0x01, 0x10))
#: a byte JSON text never holds (below 0x20 but tab, line feed and carriage return): what
#: uvd's messages are, and what every record header holds (its opcode, its length's zeros)
_NOT_JSON_TEXT = re.compile(rb"[\x00-\x08\x0b\x0c\x0e-\x1f]")
#: the records that end a data section (DataEnd, Footer) and their fixed lengths
_END_LENGTH = {Opcode.DATA_END: 4, Opcode.FOOTER: 20}
#: the records that belong to the summary section only, never to the data section
_SUMMARY_ONLY = frozenset({Opcode.CHUNK_INDEX, Opcode.ATTACHMENT_INDEX, Opcode.STATISTICS,
                           Opcode.METADATA_INDEX, Opcode.SUMMARY_OFFSET})
#: MCAP's readers of the records uvd reads beside messages
_READERS = {Opcode.SCHEMA: Schema.read, Opcode.CHANNEL: Channel.read,
            Opcode.HEADER: Header.read, Opcode.CHUNK: Chunk.read}
#: where a record uvd can resynchronise on may begin: a schema, a channel or a message
_SYNC = re.compile(rb"[\x03\x04\x05]")


def _records(mm: mmap.mmap, channels: dict[int, str]) -> Iterator[tuple[int, object]]:
    """(byte offset, record) of each record of an MCAP file's data section, in file order, up
    to its DataEnd (or Footer) or the end of the file.

    A record that does not read — its length runs past the end, an opcode MCAP does not have,
    content its own reader (MCAP's) fails on — is (offset, text naming it and the bytes
    skipped), and the walk goes on at the next offset where a record header reads and the
    record after it does too (:func:`_resync`). Where none does, the file ends inside that
    record — a file cut by a crash — and the walk ends quietly: everything before was read.
    """
    size, pos, after = len(mm), len(MAGIC), 0
    while pos < size:
        rec, end, why = _record_at(mm, pos, after)
        if why is not None:
            nxt = _resync(mm, pos + 1, channels)
            if nxt is None:
                return  # the file ends inside this record: cut by a crash
            yield pos, (f"damaged MCAP record at byte {pos} ({why}): {nxt - pos} bytes "
                        "skipped to the next record")
            pos, after = nxt, Opcode.MESSAGE
            continue
        if end is None:  # DataEnd or Footer: the data section is over
            return
        if rec is not None:
            yield pos, rec
        pos, after = end, mm[pos]


def _record_at(mm: mmap.mmap, pos: int, after: int = 0
               ) -> tuple[object | None, int | None, str | None]:
    """(record or None for a kind uvd does not read, offset of the next record or None at the
    data section's end, None) of the record at ``pos``, ``after`` a record of that opcode (0:
    the first); (None, None, why) if it does not read. Besides its own reader's (MCAP's)
    checks: a kind in its place in a data section (a header first, a message index after a
    chunk, no summary record), the end records of their fixed lengths, and the byte after the
    record an opcode (or the end of the file, or a cut in the next header): a length that
    runs into the middle of another record is found there, not taken for a long message."""
    size = len(mm)
    if pos + _HEAD.size > size:
        return None, None, "the file ends inside its header"
    op, length = _HEAD.unpack_from(mm, pos)
    end = pos + _HEAD.size + length
    if op not in _OPCODES:
        return None, None, f"no MCAP record has opcode 0x{op:02x}"
    name = Opcode(op).name.lower()
    if end > size:
        return None, None, f"its length, {length} B, runs past the end of the file"
    if op in _SUMMARY_ONLY or (op == Opcode.HEADER) != (after == 0) or \
            (op == Opcode.MESSAGE_INDEX and after not in (Opcode.CHUNK, Opcode.MESSAGE_INDEX)):
        return None, None, f"a {name} record cannot stand there"
    if op in _END_LENGTH:
        if length != _END_LENGTH[op]:
            return None, None, f"a {name} record of {length} B, not {_END_LENGTH[op]} B"
        return None, None, None
    if not _record_begins(mm, end):
        return None, None, (f"its length, {length} B, ends at byte {end}, where no record "
                            f"begins (0x{mm[end]:02x})")
    if op == Opcode.MESSAGE:  # the bulk of a recording: its fixed fields read here
        if length < _MESSAGE_HEAD.size:
            return None, None, f"a message of {length} B, shorter than a message's header"
        channel_id, sequence, log_time, publish_time = _MESSAGE_HEAD.unpack_from(
            mm, pos + _HEAD.size)
        data = mm[pos + _HEAD.size + _MESSAGE_HEAD.size:end]
        if (bad := _NOT_JSON_TEXT.search(data)) is not None:  # a length that runs into the
            # next record's binary header, or a byte of the text damaged into a control byte
            return None, None, (f"its content holds byte 0x{bad[0][0]:02x} at offset "
                                f"{bad.start()}, which no JSON text has")
        return Message(channel_id=channel_id, sequence=sequence, log_time=log_time,
                       publish_time=publish_time,
                       data=data), end, None
    reader = _READERS.get(op)
    if reader is None:
        return None, end, None  # a message index, an attachment, metadata: not uvd's
    try:
        rec = reader(ReadDataStream(io.BytesIO(mm[pos + _HEAD.size:end])))
    except (McapError, ValueError, struct.error, UnicodeDecodeError) as exc:
        return None, None, f"its {name} record does not read: {type(exc).__name__}: {exc}"
    return rec, end, None


def _record_begins(mm: mmap.mmap, at: int, damaged_opcode: bool = True) -> bool:
    """Whether a record may begin at ``at``: the file ends there or inside the header there
    (a cut), an opcode stands there, or — ``damaged_opcode`` — another byte stands there whose
    length ends where an opcode stands: then the record before ``at`` is whole and the damage
    is this one's, named when the walk reaches it. (A message's length too long is found by
    its content instead, which then holds the next header's bytes: no JSON text has them.)"""
    size = len(mm)
    if at + _HEAD.size > size or mm[at] in _OPCODES:
        return True
    nxt = at + _HEAD.size + _HEAD.unpack_from(mm, at)[1]
    return damaged_opcode and nxt <= size and _record_begins(mm, nxt, damaged_opcode=False)


def _resync(mm: mmap.mmap, start: int, channels: dict[int, str]) -> int | None:
    """The first offset from ``start`` where a record reads (:func:`_record_at`, which also
    checks that a record begins right after it) — a message on a channel declared so far, or
    a schema or channel; None if there is none. JSON text, what messages hold, has no byte
    below 0x20, so only the binary headers of records are ever tried."""
    for m in _SYNC.finditer(mm, start):
        q = m.start()
        rec, _, why = _record_at(mm, q, after=Opcode.MESSAGE)
        if why is None and rec is not None and (
                not isinstance(rec, Message) or rec.channel_id in channels):
            return q
    return None


#: the recorder's file names (uvd.links.mcap.McapRecorder): its wall clock at the file's start
#: and the file's number in the run, 000 for the first
_PART = re.compile(r"uvd-\d{8}T\d{6}-(\d{3,})\.mcap")


def part_number(path: str | Path) -> int | None:
    """The number the recorder gave this file in its run (0: the first), None for a file
    not named by it."""
    m = _PART.fullmatch(Path(path).name)
    return int(m[1]) if m else None


def _which_file(folder: Path) -> str:
    """What to say of a folder given where a recording is wanted: which of its files to give
    (a run's first files, as the recorder names them)."""
    firsts = sorted(str(f) for f in folder.glob("*.mcap") if part_number(f) == 0)
    return ("a folder, not a recording: give a run's first file in it, "
            + (", ".join(firsts[:3]) if firsts else "uvd-<time>-000.mcap (it holds none)"))


def foreign_note(path: str | Path) -> str:
    """``"; …"`` saying that ``path`` is another system's MCAP (its summary lists channels,
    none of them uvd's), with two of its topics and what reads such a file; ``""`` for
    anything else (uvd's own, a file without a summary: cut by a crash, or not MCAP)."""
    from mcap.reader import make_reader
    try:
        with Path(path).open("rb") as fh:
            summary = make_reader(fh).get_summary()
    except Exception:  # noqa: BLE001 - not MCAP, cut, damaged: nothing to say of it
        return ""
    topics = sorted({c.topic for c in summary.channels.values()}) if summary else []
    if not topics or set(topics) & set(CHANNELS):
        return ""
    return (f"; its topics are another system's ({', '.join(topics[:2])}"
            f"{', …' if len(topics) > 2 else ''}): uvd identify --profile reads such a "
            "recording (docs/real-vehicles.md)")


def start_of(path: str | Path) -> Mapping[str, Any] | None:
    """A file's start record (the first message the recorder writes in each of a run's
    files), None if it has none that reads (or is not MCAP at all)."""
    try:
        for _topic, _t, msg in read_messages(path, ("/uvd/start",), unreadable=[]):
            return msg
    except (RecordingError, OSError):
        return None
    return None


def run_files(path: str | Path) -> tuple[list[Path], str | None]:
    """The files of the run ``path`` is the first file of, in order, and what ended the list
    early (None: nothing). Past ``rotate_mb`` / ``rotate_s`` the recorder starts a new file in
    the same folder, numbered on, with the run's start record repeated at its top: the run
    is the first file and those that follow it with the same start record. A file not named
    by the recorder is a run of its own.

    Raises
    ------
    RecordingError
        ``path`` is a later file of its run (a replay starts from the run's first file: the
        cycle's state before it is not recorded); the message names the first when it is in
        the folder.
    """
    path = Path(path)
    n = part_number(path)
    if n is None:
        return [path], None
    start = start_of(path)
    same = {}
    for p in path.parent.glob("uvd-*.mcap"):
        k = part_number(p)
        if k is not None and p != path and start is not None and start_of(p) == start:
            same.setdefault(k, p)
    if n > 0:
        first = same.get(0)
        raise RecordingError(f"{path} is file {n:03d} of its run: a replay starts from the "
                             f"run's first file (the cycle's state before this one is not "
                             f"recorded), "
                             + (f"{first}" if first else f"numbered 000, not in {path.parent}"))
    files, k = [path], 1
    while k in same:
        files.append(same[k])
        k += 1
    later = sorted(x for x in same if x > k)
    gap = (f"file {k:03d} of the run is not in {path.parent}: the run is read up to it "
           f"({len(later)} later file(s) not read)") if later else None
    return files, gap


def drawn_files(path: str | Path) -> tuple[list[Path], str | None]:
    """What ``uvd report``, ``uvd identify`` and ``uvd xval`` read of a recording: the run
    whole from its first file (:func:`run_files`), a later file alone (its data need no
    state recorded before it); and the missing file that ended the run early, or None."""
    return run_files(path) if not part_number(path) else ([Path(path)], None)


def read_run(files: Sequence[Path], topics: Sequence[str], *,
             unreadable: list[str] | None = None) -> Iterator[tuple[str, int, dict[str, Any]]]:
    """:func:`read_messages` of ``files`` one after another, the start record repeated atop
    each later file of a run left out."""
    for k, part in enumerate(files):
        for topic, t_ns, msg in read_messages(part, topics, unreadable=unreadable):
            if not (k and topic == "/uvd/start"):
                yield topic, t_ns, msg


def load_run(path: str | Path):
    """A :class:`uvd.io.runlog.RunLog` of a run in any form uvd leaves: a black-box recording
    (an ``.mcap`` holding a start record — its ``/uvd/cycle`` records of :func:`drawn_files`)
    or what :func:`uvd.io.runlog.load_runlog` reads (``.npz``, the telemetry's JSON lines).
    Before session 33 ``uvd identify`` and ``uvd xval`` refused the daemon's own recording as
    "another system's" and asked for a log profile. A folder of runs is told which file to
    give (a ROS 2 bag's folder goes on to ``load_runlog``, which names its profile)."""
    from uvd.errors import ConfigError
    from uvd.io.runlog import load_runlog, runlog_from_records
    path = Path(path)
    if path.is_dir() and any(part_number(f) == 0 for f in path.glob("*.mcap")):
        raise ConfigError(f"{path}: {_which_file(path)}")  # not a ROS 2 bag's folder
    if path.suffix != ".mcap" or not path.is_file() or start_of(path) is None:
        return load_runlog(path)
    files, gap = drawn_files(path)
    cycles = (msg for _topic, _t, msg in read_run(files, ("/uvd/cycle",), unreadable=[]))
    where = f"{path} ({len(files)} files of the run)" if len(files) > 1 else path
    run = runlog_from_records(cycles, name=path.stem, source=f"recording {where}",
                              where=where)
    if gap is not None:
        run.extra["missing_file"] = gap
    return run
