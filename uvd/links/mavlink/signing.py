"""MAVLink 2 message signing, checked in the order that keeps a forger out.

A signed MAVLink 2 packet ends with a 13-byte block: link id (1 byte), timestamp (6 bytes,
10 µs units since 2015-01-01 00:00 UTC) and the first 6 bytes of SHA-256(key ‖ packet without
those 6 bytes). Each stream (link id, system id, component id) must carry increasing
timestamps (replay protection; MAVLink's signing specification).

pymavlink's ``MAVLink.check_signature`` stores a new stream's timestamp *before* it compares
the signature: one forged packet with a far-future timestamp and a wrong signature then makes
every later packet of the real station "old" — a lock-out. :meth:`SigningState.verify` checks
the signature first and lets only a correctly signed packet advance any timestamp.

The key comes from a file that only its owner may read (:func:`load_key`); the timestamp the
link signs with persists across restarts (:func:`load_timestamp` / :func:`save_timestamp`), so
a restarted vehicle never signs with a timestamp a station has already seen.
"""

from __future__ import annotations

import hashlib
import hmac
import stat
import time
from pathlib import Path

from uvd.errors import UvdError
from uvd.jsonio import write_whole

__all__ = ["SigningError", "SigningState", "load_key", "load_timestamp", "save_timestamp",
           "now_timestamp", "sign_block_parts"]

_EPOCH_2015 = 1420070400
#: a new stream may start at most one minute behind our timestamp (10 µs units)
NEW_STREAM_WINDOW = 6_000_000
_SIG_LEN = 13


class SigningError(UvdError, ValueError):
    """The signing key file is missing, malformed or readable by others."""


def now_timestamp() -> int:
    """The current time as a signing timestamp (10 µs units since 2015-01-01 UTC)."""
    return int((time.time() - _EPOCH_2015) * 100_000)


def load_key(path: str | Path) -> bytes:
    """The 32-byte secret key of ``path``: raw bytes or 64 hexadecimal digits.

    Raises
    ------
    SigningError
        Missing or unreadable, readable or writable by group or others, or not 32 bytes.
    """
    p = Path(path)
    try:
        st = p.stat()
        data = p.read_bytes()
    except OSError as exc:
        raise SigningError(f"[mavlink] signing_key_file {p}: {exc.strerror or exc}") from exc
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise SigningError(f"[mavlink] signing_key_file {p}: mode "
                           f"{stat.S_IMODE(st.st_mode):04o} lets others read it (chmod 600)")
    if len(data) == 32:
        return data
    text = data.strip()
    try:
        key = bytes.fromhex(text.decode("ascii"))
    except (UnicodeDecodeError, ValueError):
        key = b""
    if len(key) != 32:
        raise SigningError(f"[mavlink] signing_key_file {p}: not a 32-byte key (32 raw bytes "
                           f"or 64 hex digits; {len(data)} bytes read)")
    return key


def load_timestamp(path: str | Path | None) -> int:
    """The timestamp kept in ``path`` (0 when there is none or it cannot be read)."""
    if not path:
        return 0
    try:
        return max(0, int(Path(path).read_text(encoding="ascii").strip()))
    except (OSError, ValueError):
        return 0


def save_timestamp(path: str | Path, ts: int) -> None:
    """Keep ``ts`` in ``path``, whole, through a power cut too (:func:`uvd.jsonio.write_whole`:
    a file lost reads 0, and a vehicle whose clock starts behind would sign again with
    timestamps its stations have seen)."""
    p = Path(path)
    write_whole(p, lambda tmp: tmp.write_text(f"{int(ts)}\n", encoding="ascii"),
                p.with_name(p.name + ".tmp"), "the signing timestamp file " + str(p))


def sign_block_parts(packet: bytes) -> tuple[int, int, int, int] | None:
    """``(link_id, timestamp, system id, component id)`` of a signed MAVLink 2 packet, None
    when the packet carries no signature."""
    if len(packet) < 12 + _SIG_LEN or packet[0] != 0xFD or not packet[2] & 0x01:
        return None
    ts = int.from_bytes(packet[-12:-6], "little")
    return packet[-13], ts, packet[5], packet[6]


class SigningState:
    """The receive side of signing: the key, the newest timestamp, one per stream.

    Parameters
    ----------
    key : bytes
        32-byte secret key.
    timestamp : int
        Start value of the link's timestamp (the persisted one, or now).
    """

    def __init__(self, key: bytes, timestamp: int = 0) -> None:
        if len(key) != 32:
            raise SigningError("a MAVLink signing key has 32 bytes")
        self.key = bytes(key)
        self.timestamp = max(int(timestamp), now_timestamp())
        self.streams: dict[tuple[int, int, int], int] = {}
        self.counts = {"ok": 0, "unsigned": 0, "bad_signature": 0, "old_timestamp": 0}

    def verify(self, packet: bytes) -> str | None:
        """Check one packet; None when it is correctly signed and new, else the reason.

        The signature is checked first; only then may its timestamp update the stream (and
        the link's own timestamp).
        """
        parts = sign_block_parts(packet)
        if parts is None:
            self.counts["unsigned"] += 1
            return "unsigned"
        digest = hashlib.sha256(self.key + bytes(packet[:-6])).digest()[:6]
        if not hmac.compare_digest(digest, bytes(packet[-6:])):
            self.counts["bad_signature"] += 1
            return "wrong signature"
        link_id, ts, sysid, compid = parts
        stream = (link_id, sysid, compid)
        last = self.streams.get(stream)
        if (last is not None and ts <= last) or (
                last is None and ts + NEW_STREAM_WINDOW < self.timestamp):
            self.counts["old_timestamp"] += 1
            return "old timestamp (replayed?)"
        self.streams[stream] = ts
        self.timestamp = max(self.timestamp, ts)
        self.counts["ok"] += 1
        return None
