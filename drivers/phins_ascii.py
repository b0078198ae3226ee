"""iXblue PHINS "standard" ASCII output (NMEA-style lines): decode and encode.

A line is ``$<id>,<field>,…*<hh>\\r\\n`` with ``hh`` the hexadecimal XOR of the characters
between ``$`` and ``*`` (NMEA 0183). The sentences of the PHINS standard protocol parsed into
typed values (instrument units, names carry them):

===============  ==========================================================================
``$HEHDT``       true heading (deg)
``$HETHS``       true heading (deg) and mode indicator (A autonomous, E estimated, M manual,
                 S simulator, V not valid)
``ATITUD``       roll (deg, + port up), pitch (deg, **+ bow down**)
``POSITI``       latitude (deg), longitude (deg, 0–360), altitude (m)
``SPEED_``       east, north, up speed (m/s) — ENU order
``HEAVE_``       surge, sway, heave (m)
``STDHRP``       heading, roll, pitch standard deviation (deg)
``STDPOS``       latitude, longitude standard deviation (m), altitude standard deviation (m)
``STDSPD``       north, east, vertical speed standard deviation (m/s)
``ALGSTS``       INS algorithm status, two 32-bit hex words (LSB, MSB)
``STATUS``       INS system status, two 32-bit hex words (LSB, MSB)
``HT_STS``       high-level status, one 32-bit hex word
``TIME__``       UTC time hhmmss.ssssss
===============  ==========================================================================

(``ATITUD`` … ``TIME__`` are ``$PIXSE,<id>,…``.) Any other sentence with a valid checksum is
returned with its raw fields (``values`` empty), so nothing valid is lost.

This protocol carries no angular rates: :class:`AsciiInsAssembler` combines heading and
attitude into :class:`~drivers.samples.InsSample` and derives ω from successive attitudes,
flagging the rates degraded (``rates_valid=False``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from drivers import frames
from drivers.samples import InsSample
from uvd.errors import ChecksumError, FrameError

SYNC = b"$"

# sentence id → (value names, converter per field)
_F = float


def _hex(s: str) -> int:
    if not re.fullmatch(r"[0-9A-Fa-f]{1,8}", s):
        raise ValueError(f"not a 32-bit hex word: {s!r}")
    return int(s, 16)


def _hms(s: str) -> float:
    m = re.fullmatch(r"(\d{2})(\d{2})(\d{2}(?:\.\d*)?)", s)
    if not m:
        raise ValueError(f"not hhmmss.ssss: {s!r}")
    h, mi, sec = int(m.group(1)), int(m.group(2)), float(m.group(3))
    if h > 23 or mi > 59 or sec >= 61.0:
        raise ValueError(f"time out of range: {s!r}")
    return h * 3600.0 + mi * 60.0 + sec


def _mode(s: str) -> str:
    if s not in ("A", "E", "M", "S", "V"):
        raise ValueError(f"unknown mode indicator {s!r}")
    return s


def _true(s: str) -> str:
    if s != "T":
        raise ValueError(f"expected 'T', got {s!r}")
    return s


SENTENCES: dict[str, tuple[tuple[str, ...], tuple]] = {
    "HEHDT": (("heading_deg", "true"), (_F, _true)),
    "HETHS": (("heading_deg", "mode"), (_F, _mode)),
    "ATITUD": (("roll_deg", "pitch_deg"), (_F, _F)),
    "POSITI": (("latitude_deg", "longitude_deg", "altitude_m"), (_F, _F, _F)),
    "SPEED_": (("east_m_s", "north_m_s", "up_m_s"), (_F, _F, _F)),
    "HEAVE_": (("surge_m", "sway_m", "heave_m"), (_F, _F, _F)),
    "STDHRP": (("heading_std_deg", "roll_std_deg", "pitch_std_deg"), (_F, _F, _F)),
    "STDPOS": (("latitude_std_m", "longitude_std_m", "altitude_std_m"), (_F, _F, _F)),
    "STDSPD": (("north_std_m_s", "east_std_m_s", "vertical_std_m_s"), (_F, _F, _F)),
    "ALGSTS": (("status_lsb", "status_msb"), (_hex, _hex)),
    "STATUS": (("status_lsb", "status_msb"), (_hex, _hex)),
    "HT_STS": (("status",), (_hex,)),
    "TIME__": (("utc_s_of_day",), (_hms,)),
}

# ALGSTS LSB (same layout as the STDBIN INS algorithm status word 1)
ALGO_ALIGNMENT = 1 << 1


@dataclass(frozen=True, slots=True)
class PhinsSentence:
    """One checked line.

    Attributes
    ----------
    kind : str
        ``"HEHDT"``, ``"HETHS"`` or the ``$PIXSE`` id (``"ATITUD"``, …); for other talkers the
        whole address field (``"GPGGA"``).
    fields : tuple of str
        The raw fields after the id (what is encoded back).
    values : dict
        Typed values for the sentences of :data:`SENTENCES` (instrument units), else empty.
    pixse : bool
        True for a ``$PIXSE,<kind>,…`` line.
    """

    kind: str
    fields: tuple[str, ...]
    values: dict = field(default_factory=dict)
    pixse: bool = False


def nmea_checksum(body: bytes) -> int:
    """XOR of the bytes between ``$`` and ``*``."""
    c = 0
    for b in body:
        c ^= b
    return c


class PhinsAsciiCodec:
    """Line framing for :class:`drivers.framing.StreamDecoder`.

    A line runs from ``$`` to ``\\n``; a second ``$`` before the newline means the first line
    was cut (dropped as a frame error at once, without waiting).
    """

    name = "phins-ascii"
    sync = SYNC

    def __init__(self, max_frame: int = 256):
        self.max_frame = int(max_frame)

    def frame_length(self, buf: bytearray, start: int) -> int | None:
        end = buf.find(b"\n", start + 1, start + self.max_frame)
        nxt = buf.find(b"$", start + 1, end if end >= 0 else start + self.max_frame)
        if nxt >= 0:
            raise FrameError(f"phins-ascii: line cut by a new '$' after {nxt - start} bytes")
        if end < 0:
            if len(buf) - start >= self.max_frame:
                raise FrameError(f"phins-ascii: no end of line within {self.max_frame} bytes")
            return None
        return end + 1 - start

    def decode(self, frame: bytes) -> PhinsSentence:
        return decode_line(frame)

    def encode(self, s: PhinsSentence) -> bytes:
        return encode_sentence(s)


def decode_line(line: bytes) -> PhinsSentence:
    """Decode one line (with or without the trailing CR/LF).

    Raises
    ------
    ChecksumError
        The ``*hh`` checksum does not match.
    FrameError
        No ``$``/``*hh``, non-ASCII bytes, or a typed field that does not parse.
    """
    s = line.rstrip(b"\r\n")
    if not s.startswith(b"$"):
        raise FrameError("phins-ascii: line does not start with '$'")
    star = s.rfind(b"*")
    if star < 0 or len(s) - star != 3:
        raise FrameError(f"phins-ascii: no '*hh' checksum at the end of {s[:40]!r}")
    body = s[1:star]
    try:
        want = int(s[star + 1:], 16)
        text = body.decode("ascii")
    except (ValueError, UnicodeDecodeError) as exc:
        raise FrameError(f"phins-ascii: unreadable line {s[:40]!r}: {exc}") from exc
    got = nmea_checksum(body)
    if got != want:
        raise ChecksumError(f"phins-ascii: checksum {want:02X} != computed {got:02X} in "
                            f"{text[:40]!r}")
    if not text.isprintable():
        raise FrameError(f"phins-ascii: control characters in {text[:40]!r}")
    parts = text.split(",")
    pixse = parts[0] == "PIXSE"
    if pixse:
        if len(parts) < 2 or not parts[1]:
            raise FrameError("phins-ascii: $PIXSE without a sentence id")
        kind, flds = parts[1], tuple(parts[2:])
    else:
        kind, flds = parts[0], tuple(parts[1:])
    if not kind or not all(c.isalnum() or c == "_" for c in kind):
        raise FrameError(f"phins-ascii: bad sentence id {kind!r}")
    values: dict = {}
    spec = SENTENCES.get(kind)
    if spec is not None and (pixse == (kind not in ("HEHDT", "HETHS"))):
        names, convs = spec
        if len(flds) != len(names):
            raise FrameError(f"phins-ascii: {kind} has {len(flds)} fields, expected "
                             f"{len(names)}: {text[:60]!r}")
        try:
            for n, conv, f in zip(names, convs, flds, strict=True):
                values[n] = conv(f)
        except ValueError as exc:
            raise FrameError(f"phins-ascii: {kind}: {exc}") from exc
        for n, v in values.items():
            if isinstance(v, float) and not math.isfinite(v):
                raise FrameError(f"phins-ascii: {kind}.{n} is not finite")
    return PhinsSentence(kind, flds, values, pixse)


def encode_sentence(s: PhinsSentence) -> bytes:
    """``$…*hh\\r\\n`` bytes of a sentence from its raw fields."""
    head = ["PIXSE", s.kind] if s.pixse else [s.kind]
    body = ",".join(head + list(s.fields)).encode("ascii")
    return b"$" + body + b"*%02X\r\n" % nmea_checksum(body)


def make(kind: str, *values) -> PhinsSentence:
    """A sentence of :data:`SENTENCES` from typed values (formatted as PHINS does)."""
    names, _ = SENTENCES[kind]
    n_values = 1 if kind == "HEHDT" else len(names)  # HEHDT's second field is always "T"
    if len(values) != n_values:
        raise ValueError(f"{kind} takes {n_values} value(s)")
    if kind in ("ALGSTS", "STATUS", "HT_STS"):
        flds = tuple(f"{int(v) & 0xFFFFFFFF:08X}" for v in values)
    elif kind == "TIME__":
        t = float(values[0]) % 86400.0
        h, rem = divmod(t, 3600.0)
        m, sec = divmod(rem, 60.0)
        flds = (f"{int(h):02d}{int(m):02d}{sec:09.6f}",)
    elif kind == "HEHDT":
        flds = (f"{values[0]:.3f}", "T")
    elif kind == "HETHS":
        flds = (f"{values[0]:.3f}", str(values[1]))
    elif kind == "POSITI":
        flds = (f"{values[0]:.8f}", f"{values[1]:.8f}", f"{values[2]:.3f}")
    else:
        flds = tuple(f"{float(v):.3f}" for v in values)
    return decode_line(encode_sentence(PhinsSentence(kind, flds, {}, kind not in
                                                     ("HEHDT", "HETHS"))))


def raw_fields(s: PhinsSentence) -> dict:
    """Instrument-unit fields for display (``uvd decode``)."""
    return {"sentence": ("PIXSE," if s.pixse else "") + s.kind, "fields": list(s.fields),
            **s.values}


# ---------------------------------------------------------------------------------------------
# assembling INS samples from an ASCII stream (no rates in this protocol)
# ---------------------------------------------------------------------------------------------
class AsciiInsAssembler:
    """Build :class:`InsSample` from PHINS standard ASCII lines; derive rates from attitude.

    Feed every decoded sentence with its receive time; an ``ATITUD`` line produces a sample,
    using the latest heading (``HEHDT``/``HETHS``) if it is at most ``max_heading_age_s`` old.
    ω is vee(log(R_prevᵀ R))/Δt between successive samples (App. A Euler sequence), marked
    ``rates_valid=False``; the first sample has NaN rates. ``ALGSTS`` with the alignment bit,
    or ``HETHS`` mode V, marks samples invalid.

    Parameters
    ----------
    max_heading_age_s : float
        Oldest heading combined with an attitude line.
    min_rate_dt_s : float
        Shortest interval used to derive rates (shorter keeps the previous ω).
    """

    def __init__(self, max_heading_age_s: float = 0.2, min_rate_dt_s: float = 1e-3):
        self.max_heading_age_s = max_heading_age_s
        self.min_rate_dt_s = min_rate_dt_s
        self._heading: tuple[int, float, bool] | None = None
        self._prev: tuple[int, np.ndarray] | None = None
        self._omega = np.full(3, np.nan)
        self._aligned = True

    def push(self, t_ns: int, s: PhinsSentence) -> InsSample | None:
        """Take one sentence; return an InsSample when an attitude line completes one."""
        if s.kind in ("HEHDT", "HETHS") and s.values:
            ok = s.values.get("mode", "A") != "V"
            self._heading = (t_ns, frames.phins_heading_to_ours(s.values["heading_deg"]), ok)
            return None
        if s.kind == "ALGSTS" and s.values:
            self._aligned = not (s.values["status_lsb"] & ALGO_ALIGNMENT)
            return None
        if s.kind != "ATITUD" or not s.values or self._heading is None:
            return None
        th, heading, heading_ok = self._heading
        if (t_ns - th) * 1e-9 > self.max_heading_age_s:
            return None
        roll = frames.phins_roll_to_ours(s.values["roll_deg"])
        pitch = frames.phins_pitch_to_ours(s.values["pitch_deg"])
        R = frames.euler_to_R(roll, pitch, heading)
        if self._prev is not None:
            dt = (t_ns - self._prev[0]) * 1e-9
            if dt >= self.min_rate_dt_s:
                self._omega = _vee_log(self._prev[1].T @ R) / dt
        self._prev = (t_ns, R)
        return InsSample(t_ns=int(t_ns), roll=roll, pitch=pitch, heading=heading,
                         omega_body=self._omega.copy(), rates_valid=False,
                         valid=heading_ok and self._aligned, source="phins-ascii")


def _vee_log(R: np.ndarray) -> np.ndarray:
    c = min(1.0, max(-1.0, 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)))
    th = math.acos(c)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-6:
        return 0.5 * w
    s = math.sin(th)
    return (th / (2.0 * s)) * w if s > 1e-9 else np.zeros(3)


def from_state(roll: float, pitch: float, heading: float, t_utc_s: float | None = None,
               aligned: bool = True) -> list[PhinsSentence]:
    """The burst a PHINS sends per cycle (HEHDT, ATITUD, ALGSTS[, TIME__]) for our attitude."""
    out = [make("HEHDT", frames.ours_heading_to_phins(heading)),
           make("ATITUD", frames.ours_roll_to_phins(roll), frames.ours_pitch_to_phins(pitch)),
           make("ALGSTS", 0x1 if aligned else ALGO_ALIGNMENT, 0)]
    if t_utc_s is not None:
        out.append(make("TIME__", t_utc_s))
    return out
