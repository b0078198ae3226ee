"""How both replays judge what they read from a recording: one reading, one judgement, one
wording for what ends it.

A replay plays a run up to its first damaged or malformed message, as it would up to a cut
(docs/recording.md): :func:`judged_messages` yields the messages before it and names it.
:func:`record_problem` judges the records (start, cycle, command, lifecycle, reload) in the
fields a replay reads; the raw channels are judged where they are decoded
(:func:`serial_entry`, :func:`malformed_message`), where a second decoding would cost a pass
over every byte.
"""

from __future__ import annotations

import base64
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from uvd.jsonio import is_int64
from uvd.runtime.commands import command_from_record
from uvd.telemetry.recording import RecordingError, read_messages, run_files
from uvd.telemetry.records import cycle_record_problem


def judged_messages(path: str | Path, topics: tuple[str, ...],
                    damage: list[str]) -> Iterator[tuple[str, int, Mapping[str, Any]]]:
    """(topic, log time ns, message) of ``topics`` in file order, each message a JSON object;
    the records among them fit for a replay (:func:`record_problem`). At a damaged message
    or the first malformed record the iteration ends and ``damage`` names it — by its log
    time, which the recorder sets to the record's own ``t_ns`` (a malformed record's may be
    anything)."""
    for topic, t_ns, msg in read_messages(path, topics, unreadable=damage):
        if damage:  # this message comes after the damage: what is read ends before it
            return
        why = record_problem(topic, msg)
        if why is not None:  # valid JSON, not what its schema promises: damage as well
            damage.append(f"a {topic} record at {t_ns} ns is malformed ({why})")
            return
        yield topic, t_ns, msg


def record_problem(topic: str, msg: Any) -> str | None:
    """What makes a message unfit for a replay, in the fields the replay reads (None:
    nothing): any message that is not a JSON object, and the records' fields."""
    if topic == "/uvd/cycle":
        return cycle_record_problem(msg)
    if not isinstance(msg, Mapping):
        return f"a JSON {type(msg).__name__}, not an object"
    if topic == "/uvd/start":
        for k, types in (("config_toml", str), ("config_path", (str, type(None))),
                         ("params_kept", (Mapping, type(None))),
                         ("estimators", (Mapping, type(None)))):
            if not isinstance(msg.get(k), types):
                return f"{k} {msg.get(k)!r:.40} is not what uvd.start.v1 holds"
        return None
    if topic in ("/uvd/command", "/uvd/lifecycle", "/uvd/reload") \
            and not is_int64(msg.get("t_ns")):
        return f"t_ns {msg.get('t_ns')!r:.40} is not a 64-bit integer"
    if topic == "/uvd/command":
        try:
            command_from_record(msg)
        except ValueError as exc:
            return str(exc)
    if topic == "/uvd/reload" and not (msg.get("applied") is None or (
            isinstance(msg["applied"], list) and all(isinstance(k, str)
                                                     for k in msg["applied"]))):
        return f"applied {msg['applied']!r:.40} is not a list of keys"
    return None


def serial_entry(msg: Mapping[str, Any]) -> tuple[int, str, bytes]:
    """A ``/uvd/raw/serial`` message's (receive t_ns, source, bytes).

    Raises
    ------
    KeyError, ValueError, TypeError
        A field missing or not what uvd.raw.serial.v1 holds (:func:`malformed_message`).
    """
    return (int(msg["t_ns"]), str(msg["source"]),
            base64.b64decode(msg["data"], validate=True))


def malformed_message(topic: str, t_ns: int, exc: Exception) -> str:
    """The damage line of a raw message (log time ``t_ns``) that did not decode."""
    return f"a {topic} message at {t_ns} ns is malformed ({type(exc).__name__}: {exc})"


def require_start(path: str | Path, start: Mapping[str, Any] | None, before: str) -> None:
    """Refuse a recording without a start record holding the configuration (``before``: the
    damage that ended the reading, or empty)."""
    if start is None or not start.get("config_toml"):
        raise RecordingError(f"{path}: no start record with the configuration (/uvd/start)"
                             f"{before} — not a uvd recording, or not the first file of a run")


def run_messages(path: str | Path, topics: tuple[str, ...], damage: list[str],
                 read: list[Path]) -> Iterator[tuple[str, int, Mapping[str, Any]]]:
    """:func:`judged_messages` over the run ``path`` begins
    (:func:`~uvd.telemetry.recording.run_files`), file after file, its start record once (the
    first file's); ``read`` gets each file as it is opened.
    Damage in a file ends the run there; a file of the run missing from the folder is told
    in ``damage`` as what ends it."""
    files, gap = run_files(path)
    for i, part in enumerate(files):
        read.append(Path(part))
        for topic, t_ns, msg in judged_messages(part, topics, damage):
            if i and topic == "/uvd/start":
                continue
            yield topic, t_ns, msg
        if damage:
            return
    if gap is not None:
        damage.append(gap)
