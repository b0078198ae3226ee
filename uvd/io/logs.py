"""Other systems' recordings: a registry of log formats by name.

Each format reads one kind of file through that ecosystem's own library and yields the same
thing: ``(topic, t_ns, message)`` in file order, where ``message`` is the decoded message
(an object whose attributes are its fields) and ``t_ns`` the time stamp the file gives it
(a bag's receive time, a telemetry log's receive time, a dataflash log's ``TimeUS``), None
where that stamp is not a finite number (a corrupted file's).

=================  =====================================  ========================================
name               files                                  read by
=================  =====================================  ========================================
``ros1``           ROS 1 bag (``.bag``, ``.bag.active``)  rosbags (pure Python), ROS 1 Noetic types;
                                                          without an index (cut short), or the
                                                          rest after a damaged record: record by
                                                          record (:mod:`uvd.io.ros1_records`)
``ros2``           ROS 2 bag (folder, ``.db3``/``.mcap``) rosbags, ROS 2 Humble types
``mcap``           MCAP (``.mcap``) of ROS 2 (CDR), ROS 1  mcap's streaming reader; CDR/ROS 1
                   or JSON messages (uvd's black box)     by rosbags' type system, JSON by ``json``
``tlog``           MAVLink telemetry log (``.tlog``)      pymavlink (``mavutil.mavlink_connection``)
``dataflash``      ArduPilot dataflash log (``.BIN``)     pymavlink's DFReader (same entry point)
``uvd-telemetry``  ``uvd run``'s JSON lines (``.jsonl``)  ``json``; topic = the record's ``type``
=================  =====================================  ========================================

:func:`open_log` picks the format from the file (or by ``fmt=``); :func:`count_messages` counts
per topic. A file that is not readable as its format, truncated or corrupted raises
:class:`LogReadError` naming the file (and the topic where known); nothing blocks: every reader
works on the file, never on a stream that could wait.
"""

from __future__ import annotations

import json
import logging
import math
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

from uvd.errors import LogReadError

log = logging.getLogger(__name__)

__all__ = ["LogFormat", "FORMATS", "log_formats", "detect_format", "open_log",
           "count_messages", "LogReadError"]


@dataclass(frozen=True)
class LogFormat:
    """One log format: its name, what it reads and the reader."""

    name: str
    description: str
    suffixes: tuple[str, ...]
    read: Callable[[Path, frozenset[str] | None], Iterator[tuple[str, int, object]]]


# ---------------------------------------------------------------------------------------------
# ROS bags through rosbags
# ---------------------------------------------------------------------------------------------
def _read_rosbag(path: Path, topics: frozenset[str] | None, store: str
                 ) -> Iterator[tuple[str, int, object]]:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if store == "ROS1_NOETIC" and path.name.lower().endswith(".active"):
        yield from _read_ros1_by_record(path, topics, "a recording never closed (.active)")
        return
    topic = "?"
    try:
        reader = AnyReader([path], default_typestore=get_typestore(getattr(Stores, store)))
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags' errors, and its asserts on a bad index
        if store == "ROS1_NOETIC" and "index" in str(exc).lower() and path.is_file():
            yield from _read_ros1_by_record(path, topics, f"{type(exc).__name__}: {exc}")
            return
        raise LogReadError(f"{path}: not a readable ROS bag (truncated or corrupted?): "
                           f"{type(exc).__name__}: {exc}") from exc
    last_t, at_last, given = -1, set(), 0  # what was given (in rosbags' time order)
    why = None  # what stopped rosbags half way, in a ROS 1 bag
    try:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        for conn, t_ns, raw in reader.messages(connections=conns):
            topic = conn.topic
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:  # noqa: BLE001 - rosbags raises several kinds
                if store != "ROS1_NOETIC":
                    raise LogReadError(f"{path}: topic {topic}: message at t={t_ns} ns cannot "
                                       f"be decoded as {conn.msgtype}: {exc}") from exc
                why = f"a message on {topic} at t={t_ns} ns does not decode: {exc}"
                break
            if t_ns != last_t:
                last_t, at_last = t_ns, set()
            at_last.add(topic)
            given += 1
            yield topic, int(t_ns), msg
    except LogReadError:
        raise
    except Exception as exc:  # noqa: BLE001 - rosbags' errors, and its asserts on a bad index
        if store != "ROS1_NOETIC":
            raise LogReadError(f"{path}: not a readable ROS bag (truncated or corrupted?) "
                               f"near topic {topic}: {type(exc).__name__}: {exc}") from exc
        why = f"{type(exc).__name__}: {exc}"
    finally:
        reader.close()
    if why is None:
        return
    # a damaged record stopped rosbags half way: the rest, read record by record, which
    # skips a damaged record to the next one that reads (what rosbags gave is not given
    # again: every message before its last time stamp, and those at it)
    rest = _read_ros1_by_record(path, topics, f"rosbags stopped after {given} messages "
                                              f"({why}); the messages after them")
    for name, t_ns, msg in rest:
        if t_ns > last_t or (t_ns == last_t and name not in at_last):
            yield name, t_ns, msg


def _read_ros1_by_record(path: Path, topics: frozenset[str] | None, why: str
                         ) -> Iterator[tuple[str, int, object]]:
    """A ROS 1 bag without its index (a recording cut short), read record by record
    (:mod:`uvd.io.ros1_records`, as ROS 1's ``rosbag reindex`` would) and decoded by rosbags'
    type system from each connection's own definition; where it ended is logged."""
    from rosbags.typesys import Stores, get_typestore
    from rosbags.typesys.msg import get_types_from_msg, normalize_msgtype

    from uvd.io.ros1_records import BagRecordError, Scan, read_records

    log.warning("%s: %s — read record by record, as `rosbag reindex` would", path, why)
    scan, store, types, undecoded = Scan(), get_typestore(Stores.EMPTY), {}, []
    try:
        for conn, t_ns, raw in read_records(path, scan):
            c = scan.connections.get(conn)
            if c is None:
                raise LogReadError(f"{path}: a message at t={t_ns} ns on connection {conn}, "
                                   "which no connection record declares")
            if topics is not None and c.topic not in topics:
                continue
            msgtype = types.get(conn)
            if msgtype is None:
                msgtype = types[conn] = normalize_msgtype(c.msgtype)
                try:
                    store.register(get_types_from_msg(c.definition, msgtype))
                except Exception as exc:  # noqa: BLE001 - a damaged definition, any way
                    log.warning("%s: topic %s: its message definition does not read (%s)",
                                path, c.topic, exc)
            try:
                msg = store.deserialize_ros1(raw, msgtype)
            except Exception as exc:  # noqa: BLE001 - rosbags raises several kinds
                undecoded.append(f"{c.topic} at t={t_ns} ns ({type(exc).__name__}: {exc})")
                continue
            yield c.topic, t_ns, msg
    except BagRecordError as exc:
        raise LogReadError(f"{path}: not a readable ROS bag, without its index either: "
                           f"{exc}") from exc
    cut = "" if scan.ended_at == scan.size else \
        f"; the last {scan.size - scan.ended_at} B are a record cut short"
    skipped = "" if not scan.skipped else \
        f"; skipped {len(scan.skipped)} stretch(es) that do not read (first: {scan.skipped[0]})"
    log.warning("%s: read %d of %d B record by record%s%s%s", path, scan.ended_at, scan.size,
                cut, skipped,
                f"; {len(undecoded)} message(s) that do not decode skipped (first: "
                f"{undecoded[0]})" if undecoded else "")


def _read_ros1(path, topics):
    return _read_rosbag(path, topics, "ROS1_NOETIC")


def _read_ros2(path, topics):
    return _read_rosbag(path, topics, "ROS2_HUMBLE")


# ---------------------------------------------------------------------------------------------
# MCAP through mcap (+ rosbags' type system for CDR / ROS 1 messages)
# ---------------------------------------------------------------------------------------------
def _read_mcap(path: Path, topics: frozenset[str] | None) -> Iterator[tuple[str, int, object]]:
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    decoders: dict[int, Callable] = {}

    def decoder(schema, channel):
        enc = channel.message_encoding
        if enc == "json":
            return lambda data: json.loads(data, object_hook=lambda d: SimpleNamespace(**d))
        if enc in ("cdr", "ros1") and schema is not None:
            from rosbags.typesys import Stores, get_typestore
            from rosbags.typesys.msg import get_types_from_msg
            store = get_typestore(Stores.ROS2_HUMBLE if enc == "cdr" else Stores.ROS1_NOETIC)
            store.register(get_types_from_msg(schema.data.decode(), schema.name))
            if enc == "cdr":
                return lambda data: store.deserialize_cdr(data, schema.name)
            return lambda data: store.deserialize_ros1(data, schema.name)
        raise LogReadError(f"{path}: topic {channel.topic}: message encoding {enc!r} is not "
                           "readable (json, cdr, ros1)")

    topic = "?"
    try:
        with path.open("rb") as fh:
            reader = make_reader(fh)
            for schema, channel, message in reader.iter_messages(
                    topics=None if topics is None else sorted(topics), log_time_order=False):
                topic = channel.topic
                dec = decoders.get(channel.id)
                if dec is None:
                    dec = decoders[channel.id] = decoder(schema, channel)
                try:
                    msg = dec(message.data)
                except Exception as exc:  # noqa: BLE001 - a codec's own errors vary
                    raise LogReadError(f"{path}: topic {topic}: message at "
                                       f"t={message.log_time} ns cannot be decoded: "
                                       f"{exc}") from exc
                yield topic, int(message.log_time), msg
    except LogReadError:
        raise
    except (McapError, OSError, ValueError, KeyError, EOFError) as exc:
        raise LogReadError(f"{path}: not a readable MCAP file (truncated or corrupted?) near "
                           f"topic {topic}: {type(exc).__name__}: {exc}") from exc


# ---------------------------------------------------------------------------------------------
# MAVLink telemetry logs and ArduPilot dataflash logs through pymavlink
# ---------------------------------------------------------------------------------------------
def _read_mavlink(path: Path, topics: frozenset[str] | None, *, dataflash: bool
                  ) -> Iterator[tuple[str, int, object]]:
    from pymavlink import mavutil

    kind = "ArduPilot dataflash log" if dataflash else "MAVLink telemetry log"
    try:
        conn = mavutil.mavlink_connection(str(path), notimestamps=False,
                                          robust_parsing=True)
    except Exception as exc:  # noqa: BLE001 - pymavlink raises many kinds on a bad header
        raise LogReadError(f"{path}: not a readable {kind}: {type(exc).__name__}: "
                           f"{exc}") from exc
    # a dataflash log is read message by message, the wanted ones kept here: asked for by
    # type, pymavlink's dataflash reader goes by its index, which ends at the first message of
    # a type no FMT declares — one damaged type byte in the real small.BIN lost 673 of its 1542
    # ATT, IMU, BARO and RCOU messages, silently; read in turn, it skips the damaged bytes. A
    # telemetry log has no index: asked for by type, it reads in half the time
    want = None if topics is None or dataflash else sorted(topics)
    topic = "?"
    try:
        while True:
            try:
                msg = conn.recv_match(type=want, blocking=False)
            except Exception as exc:  # noqa: BLE001
                raise LogReadError(f"{path}: {kind} unreadable after topic {topic}: "
                                   f"{type(exc).__name__}: {exc}") from exc
            if msg is None:
                break
            topic = msg.get_type()
            if topics is not None and topic not in topics:
                continue
            t = float(getattr(msg, "_timestamp", 0.0)) * 1e9   # a corrupted stamp: not a time
            yield topic, int(round(t)) if math.isfinite(t) else None, msg
    finally:
        conn.close()


def _read_tlog(path, topics):
    return _read_mavlink(path, topics, dataflash=False)


def _read_dataflash(path, topics):
    return _read_mavlink(path, topics, dataflash=True)


# ---------------------------------------------------------------------------------------------
# uvd's own JSON-lines telemetry
# ---------------------------------------------------------------------------------------------
def _telemetry_stamp(t) -> int | None:
    """A record's ``t_ns`` as a time stamp, None where it is not one (a corrupted file's:
    text, null, a list, true, NaN or infinite)."""
    if isinstance(t, bool):
        return None
    try:
        return int(t)
    except (TypeError, ValueError, OverflowError):
        return None


def _read_uvd_telemetry(path: Path, topics: frozenset[str] | None
                        ) -> Iterator[tuple[str, int, object]]:
    try:
        with path.open("r", encoding="utf-8") as fh:
            for lineno, line in enumerate(fh, start=1):
                try:
                    rec = json.loads(line)
                except json.JSONDecodeError as exc:
                    raise LogReadError(f"{path}: line {lineno}: not JSON (truncated or "
                                       f"corrupted?): {exc}") from exc
                if not isinstance(rec, dict):
                    raise LogReadError(f"{path}: line {lineno}: not a JSON object")
                topic = str(rec.get("type", "?"))
                if topics is not None and topic not in topics:
                    continue
                yield topic, _telemetry_stamp(rec.get("t_ns", 0)), SimpleNamespace(**rec)
    except (OSError, UnicodeDecodeError) as exc:
        raise LogReadError(f"{path}: cannot read uvd telemetry: {exc}") from exc


FORMATS: dict[str, LogFormat] = {f.name: f for f in (
    LogFormat("ros1", "ROS 1 bag (rosbags, ROS 1 Noetic message types)", (".bag",), _read_ros1),
    LogFormat("ros2", "ROS 2 bag folder or .db3 (rosbags, ROS 2 Humble message types)",
              (".db3",), _read_ros2),
    LogFormat("mcap", "MCAP: ROS 2 (CDR), ROS 1 or JSON messages (mcap, rosbags)", (".mcap",),
              _read_mcap),
    LogFormat("tlog", "MAVLink telemetry log as a ground station records it (pymavlink)",
              (".tlog",), _read_tlog),
    LogFormat("dataflash", "ArduPilot dataflash log (pymavlink DFReader)", (".bin", ".log"),
              _read_dataflash),
    LogFormat("uvd-telemetry", "uvd run's JSON-lines telemetry", (".jsonl",),
              _read_uvd_telemetry),
)}


def log_formats() -> list[str]:
    """The registered format names."""
    return sorted(FORMATS)


def detect_format(path: str | Path) -> str:
    """The format of ``path`` from its name (a folder with ``metadata.yaml`` is a ROS 2 bag)."""
    path = Path(path)
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return "ros2"
        raise LogReadError(f"{path}: a folder but not a ROS 2 bag (no metadata.yaml)")
    suffix = path.suffix.lower()
    if path.name.lower().endswith(".bag.active"):  # rosbag record's file while it records
        return "ros1"
    for f in FORMATS.values():
        if suffix in f.suffixes:
            return f.name
    raise LogReadError(f"{path}: unknown log format (suffix {path.suffix!r}); give one of "
                       f"{log_formats()}")


def open_log(path: str | Path, fmt: str | None = None, topics=None
             ) -> Iterator[tuple[str, int, object]]:
    """``(topic, t_ns, message)`` of ``path`` in file order; only ``topics`` if given."""
    path = Path(path)
    if not path.exists():
        raise LogReadError(f"{path}: no such file")
    name = fmt or detect_format(path)
    if name not in FORMATS:
        raise LogReadError(f"{path}: unknown log format {name!r}; known: {log_formats()}")
    return FORMATS[name].read(path, None if topics is None else frozenset(topics))


def count_messages(path: str | Path, fmt: str | None = None) -> Counter:
    """Messages per topic of a whole file (reads and decodes every message)."""
    return Counter(topic for topic, _t, _m in open_log(path, fmt))
