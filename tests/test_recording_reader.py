"""The black box's reader (uvd.telemetry.recording.read_messages) on files written here by
MCAP's own writer: a bit flipped anywhere in a message record costs at most that message, and
never silently; another writer's chunks are read too. (The HIL recording's damage cases are in
tests/test_recording.py.)"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uvd.telemetry.recording import CHANNELS, RecordingError, read_messages, schema

N = 40  # messages in the file


def _write(path: Path, *, chunked: bool = False, finish: bool = True) -> list[tuple]:
    """A small uvd-like recording: N messages alternating /uvd/cycle and /uvd/raw/serial, of
    varied lengths; returns what read_messages must yield."""
    from mcap.writer import CompressionType, Writer
    out = []
    with path.open("wb") as fh:
        w = Writer(fh, use_chunking=chunked, compression=CompressionType.NONE,
                   chunk_size=600)
        w.start()
        ids = {}
        for topic in ("/uvd/cycle", "/uvd/raw/serial"):
            name = CHANNELS[topic][0]
            sid = w.register_schema(name, "jsonschema", json.dumps(schema(name)).encode())
            ids[topic] = w.register_channel(topic, "json", sid)
        for k in range(N):
            topic = ("/uvd/cycle", "/uvd/raw/serial")[k % 2]
            msg = {"t_ns": 1_000_000 * k, "x": "y" * (k * 7 % 50)}
            w.add_message(ids[topic], msg["t_ns"], json.dumps(msg).encode(), msg["t_ns"], k)
            out.append((topic, msg["t_ns"], msg))
        if finish:
            w.finish()
    return out


def _message_records(data: bytes) -> list[tuple[int, int]]:
    """(offset, length) of each message record, walked by MCAP's framing."""
    out, pos = [], 8
    while pos < len(data):
        op, length = struct.unpack_from("<BQ", data, pos)
        if op == 0x0F:
            break
        if op == 0x05:
            out.append((pos, length))
        pos += 9 + length
    return out


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "clean.mcap"
    return path, _write(path)


@settings(max_examples=500, deadline=None)
@given(which=st.integers(1, N - 2), where=st.floats(0, 1, exclude_max=True),
       bit=st.integers(0, 7), header=st.booleans())
def test_a_flipped_bit_costs_at_most_its_message_and_is_named(clean, tmp_path_factory, which,
                                                             where, bit, header):
    """Any one bit of a message record but the first's and last's (``header``: within its 31
    bytes of opcode, length, channel, sequence and times, where the framing is): read_messages
    never raises with ``unreadable`` given, yields every other message, and every message it
    does not yield is named there."""
    path, every = clean
    data = bytearray(path.read_bytes())
    at, length = _message_records(bytes(data))[which]
    k = at + int(where * (31 if header else 9 + length))
    data[k] ^= 1 << bit
    bad = tmp_path_factory.mktemp("flip") / "flipped.mcap"
    bad.write_bytes(bytes(data))
    notes: list[str] = []
    got = list(read_messages(bad, unreadable=notes))
    others = every[:which] + every[which + 1:]
    kept = [m for m in got if m in others]
    assert kept == others, (k, bit, notes)  # every other message, in order
    assert len(got) in (N - 1, N) and len(notes) <= 2, (k, bit, got, notes)
    if len(got) == N - 1:  # that message lost: named (a changed one cannot be told: MCAP
        assert notes, (k, bit)  # keeps no checksum of an unchunked message)


def test_a_length_past_the_end_in_the_middle_is_damage_not_a_cut(clean, tmp_path):
    """It was read as a file cut by a crash: the rest of the file was lost, silently."""
    path, every = clean
    data = bytearray(path.read_bytes())
    at, _ = _message_records(bytes(data))[5]
    data[at + 1:at + 9] = (2**40).to_bytes(8, "little")
    bad = tmp_path / "long.mcap"
    bad.write_bytes(bytes(data))
    notes: list[str] = []
    assert list(read_messages(bad, unreadable=notes)) == every[:5] + every[6:]
    assert notes == [f"damaged MCAP record at byte {at} (its length, 1099511627776 B, runs "
                     f"past the end of the file): {_message_records(path.read_bytes())[6][0] - at}"
                     " bytes skipped to the next record"]
    with pytest.raises(RecordingError, match=f"long.mcap: damaged MCAP record at byte {at}"):
        list(read_messages(bad))


@pytest.mark.parametrize("cut", [0.3, 0.55, 0.9])
def test_a_cut_file_yields_every_message_before_the_cut_quietly(tmp_path, cut):
    path = tmp_path / "run.mcap"
    every = _write(path, finish=False)
    data = path.read_bytes()
    short = tmp_path / "cut.mcap"
    short.write_bytes(data[:int(len(data) * cut)])
    whole = [at + 9 + n <= len(data) * cut for at, n in _message_records(data)]
    notes: list[str] = []
    assert list(read_messages(short, unreadable=notes)) == every[:sum(whole)] and notes == []


def test_another_writers_chunks_are_read_and_a_damaged_chunk_is_named(tmp_path):
    path = tmp_path / "chunked.mcap"
    every = _write(path, chunked=True)
    assert list(read_messages(path)) == every
    data = bytearray(path.read_bytes())
    data[data.index(b'{"t_ns": 20000000')] ^= 0x01  # message 20's chunk: its CRC fails
    bad = tmp_path / "bad-chunk.mcap"
    bad.write_bytes(bytes(data))
    notes: list[str] = []
    got = list(read_messages(bad, unreadable=notes))
    lost = [m for m in every if m not in got]  # that chunk's messages, and only those
    assert every[20] in lost and 1 < len(lost) < 10
    assert got == [m for m in every if m not in lost]
    assert len(notes) == 1 and notes[0].startswith("damaged MCAP chunk at byte ") and \
        "crc" in notes[0].lower(), notes
