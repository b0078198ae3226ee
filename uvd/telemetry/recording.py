"""The black box's file contract: its MCAP channels, their JSON Schemas, and reading a recording.

Every channel and its schema are listed in docs/recording.md; the schemas are the files of
``uvd/telemetry/schemas/`` (:func:`schema`). The writer is the black-box recorder
(:class:`uvd.links.mcap.McapRecorder`); replay, ``uvd report`` and the tests read what it
wrote through :func:`read_messages`.
"""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Iterator, Sequence
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

__all__ = ["CHANNELS", "schema", "read_messages", "RecordingError"]

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

    Reads with MCAP's streaming reader, so a file cut by a crash yields every message written
    before the cut (the cut itself ends the iteration quietly).

    ``unreadable``: where a message that is not JSON goes instead of raising — one line naming
    its topic and time, the message skipped (``uvd report`` counts them and draws the rest).
    Replay leaves it None: it needs every input, and stops at the first.

    Raises
    ------
    RecordingError
        Not an MCAP file, a damaged record, a channel of uvd's topics with another schema or
        encoding, a message on a channel never declared, or a message that is not JSON
        unless ``unreadable`` takes it (the message names the file and the problem). Channels
        of other topics are read as they are.
    """
    from mcap.exceptions import EndOfFile, McapError
    from mcap.reader import StreamReader
    from mcap.records import Channel, Message, Schema

    path = Path(path)
    want = None if topics is None else set(topics)
    channels: dict[int, str] = {}
    schemas: dict[int, str] = {}
    try:
        fh = path.open("rb")
    except OSError as exc:
        raise RecordingError(f"{path}: cannot open: {exc}") from exc
    with fh:
        size = os.fstat(fh.fileno()).st_size
        if fh.read(8) != b"\x89MCAP0\r\n":
            raise RecordingError(f"{path}: not an MCAP file (no MCAP magic at its start)")
        fh.seek(0)
        it = StreamReader(fh, validate_crcs=False).records
        while True:
            try:
                rec = next(it)
            except StopIteration:
                return
            except (EndOfFile, McapError, ValueError, struct.error) as exc:
                if isinstance(exc, EndOfFile) or fh.tell() >= size:
                    return  # a file cut by a crash: everything before the cut was read
                raise RecordingError(f"{path}: damaged MCAP record: {exc}") from exc
            if isinstance(rec, Schema):
                schemas[rec.id] = rec.name
            elif isinstance(rec, Channel):
                want_schema = CHANNELS.get(rec.topic, (None,))[0]
                got = schemas.get(rec.schema_id)
                if want_schema is not None and (got != want_schema
                                                or rec.message_encoding != "json"):
                    raise RecordingError(
                        f"{path}: channel {rec.topic} has schema {got!r} and encoding "
                        f"{rec.message_encoding!r}; uvd writes {want_schema!r} as json "
                        "(another program's file, or another version's)")
                channels[rec.id] = rec.topic
            elif isinstance(rec, Message):
                topic = channels.get(rec.channel_id)
                if topic is None:
                    raise RecordingError(f"{path}: message on unknown channel {rec.channel_id}")
                if want is not None and topic not in want:
                    continue
                try:
                    msg = json.loads(rec.data)
                except ValueError as exc:
                    what = f"message on {topic} at {rec.log_time} ns is not JSON: {exc}"
                    if unreadable is None:
                        raise RecordingError(f"{path}: {what}") from exc
                    unreadable.append(what)
                    continue
                yield topic, rec.log_time, msg

