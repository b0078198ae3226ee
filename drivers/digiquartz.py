"""Paroscientific Digiquartz depth sensor (8CDP010-1 on the JHU ROV, App. A.1): codec and depth.

Serial protocol (Paroscientific "Digiquartz Programming and Operation Manual"): ASCII lines
``*ddss<payload>\\r\\n`` with ``dd`` the destination and ``ss`` the source address. The host is
``00``, the sensor ``01`` by default, so

* a command is ``*0100P3`` (one pressure sample), ``*0100P4`` (continuous pressure samples,
  "P4 mode"), ``*0100UN`` (query the unit), ``*0100EW*0100UN=2`` (enable write, set the unit);
* a reply is ``*0001<value>`` — a pressure in the configured unit (``*000114.69812``) — or
  ``*0001<CMD>=<value>`` for a parameter (``*0001UN=1``).

There is no checksum; a line is accepted only if it matches the format exactly.

Pressure unit (``UN``): 1 psi, 2 hPa (mbar), 3 bar, 4 kPa, 5 MPa, 6 inHg, 7 mmHg, 8 mH₂O.
:class:`DepthConverter` turns absolute pressure into depth below the surface with an
atmospheric tare: in fresh water (the JHU tank) by d = (p − p_atm)/(ρ g); in sea water with
TEOS-10 (``gsw.z_from_p``) at the configured latitude.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from drivers.samples import DepthSample
from uvd.errors import FrameError

SYNC = b"*"

#: Pascal per unit, by the ``UN`` code.
UNIT_PA = {1: 6894.757293168361, 2: 100.0, 3: 1.0e5, 4: 1.0e3, 5: 1.0e6,
           6: 3386.388640341, 7: 133.322387415, 8: 9806.65}
UNIT_NAMES = {1: "psi", 2: "hPa", 3: "bar", 4: "kPa", 5: "MPa", 6: "inHg", 7: "mmHg",
              8: "mH2O"}

_LINE = re.compile(rb"\*(\d{2})(\d{2})(.*)")
_NUMBER = re.compile(r"[-+]?(\d+(\.\d*)?|\.\d+)([eE][-+]?\d+)?")
_PARAM = re.compile(r"([A-Z]{2})=(.{1,32})")
_COMMAND = re.compile(r"[A-Z][A-Z0-9][A-Z0-9=.*]{0,40}")


@dataclass(frozen=True, slots=True)
class DigiquartzLine:
    """One line of the protocol.

    Attributes
    ----------
    dest, src : int
        Destination and source addresses (00 host, 01 first sensor).
    kind : str
        ``"pressure"`` (``value`` in the sensor's unit), ``"param"`` (``name`` = ``text``
        after ``=``) or ``"command"`` (a host command, ``text``).
    text : str
        The payload as on the wire (encoded back verbatim).
    value : float or None
        The pressure (kind pressure) or a numeric parameter value; None otherwise.
    name : str
        Parameter or command name (``"UN"``, ``"P4"``…), empty for a pressure.
    """

    dest: int
    src: int
    kind: str
    text: str
    value: float | None = None
    name: str = ""


class DigiquartzCodec:
    """Line framing for :class:`drivers.framing.StreamDecoder`."""

    name = "digiquartz"
    sync = SYNC

    def __init__(self, max_frame: int = 64):
        self.max_frame = int(max_frame)

    def frame_length(self, buf: bytearray, start: int) -> int | None:
        end = buf.find(b"\n", start + 1, start + self.max_frame)
        limit = end if end >= 0 else min(len(buf), start + self.max_frame)
        star = buf.find(b"*", start + 1, limit)
        # a second '*' means the line was cut — except in the "EW*ddssCMD" write command
        if star >= 0 and buf[star - 2:star] != b"EW":
            raise FrameError(f"digiquartz: line cut by a new '*' after {star - start} bytes")
        if end < 0:
            if len(buf) - start >= self.max_frame:
                raise FrameError(f"digiquartz: no end of line within {self.max_frame} bytes")
            return None
        return end + 1 - start

    def decode(self, frame: bytes) -> DigiquartzLine:
        return decode_line(frame)

    def encode(self, line: DigiquartzLine) -> bytes:
        return encode_line(line)


def decode_line(frame: bytes) -> DigiquartzLine:
    """Decode ``*ddss<payload>[\\r]\\n``; raises FrameError for anything else."""
    s = frame.rstrip(b"\r\n")
    m = _LINE.fullmatch(s)
    if not m:
        raise FrameError(f"digiquartz: not a '*ddss…' line: {s[:40]!r}")
    dest, src = int(m.group(1)), int(m.group(2))
    try:
        text = m.group(3).decode("ascii")
    except UnicodeDecodeError as exc:
        raise FrameError(f"digiquartz: non-ASCII payload {s[:40]!r}") from exc
    if not text or not text.isprintable():
        raise FrameError(f"digiquartz: empty or unprintable payload {s[:40]!r}")
    payload = text.strip()
    if _NUMBER.fullmatch(payload):
        v = float(payload)
        if not math.isfinite(v):
            raise FrameError(f"digiquartz: pressure {payload!r} is not finite")
        return DigiquartzLine(dest, src, "pressure", text, v)
    pm = _PARAM.fullmatch(payload)
    if pm and dest == 0:
        val = pm.group(2).strip()
        num = float(val) if _NUMBER.fullmatch(val) else None
        return DigiquartzLine(dest, src, "param", text, num, pm.group(1))
    if _COMMAND.fullmatch(payload) and src == 0:
        return DigiquartzLine(dest, src, "command", text, None, payload[:2])
    raise FrameError(f"digiquartz: unrecognised payload {payload[:30]!r}")


def encode_line(line: DigiquartzLine) -> bytes:
    """``*ddss<text>\\r\\n``."""
    if not (0 <= line.dest <= 99 and 0 <= line.src <= 99):
        raise ValueError("digiquartz addresses are two decimal digits")
    return b"*%02d%02d" % (line.dest, line.src) + line.text.encode("ascii") + b"\r\n"


def pressure_line(value: float, src: int = 1, digits: int = 5) -> DigiquartzLine:
    """A sensor reply carrying a pressure in the sensor's unit (as the emulator sends)."""
    return decode_line(encode_line(DigiquartzLine(0, src, "pressure", f"{value:.{digits}f}")))


def command(cmd: str, dest: int = 1) -> bytes:
    """Bytes of a host command, e.g. ``command("P4")`` → ``b"*0100P4\\r\\n"``."""
    if not _COMMAND.fullmatch(cmd):
        raise ValueError(f"not a Digiquartz command: {cmd!r}")
    return b"*%02d00" % dest + cmd.encode("ascii") + b"\r\n"


def raw_fields(line: DigiquartzLine) -> dict:
    """Instrument-unit fields for display (``uvd decode``)."""
    out = {"dest": line.dest, "src": line.src, "kind": line.kind, "text": line.text}
    if line.kind == "pressure":
        out["pressure"] = line.value
    elif line.name:
        out["name"] = line.name
    return out


# ---------------------------------------------------------------------------------------------
# depth from pressure
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DepthConverter:
    """Absolute pressure → depth of the sensor below the surface (m, positive down).

    Parameters
    ----------
    unit : int
        The sensor's ``UN`` setting (1 psi … 8 mH₂O).
    water : {"fresh", "sea"}
        Fresh: d = (p − p_atm)/(ρ g) (the JHU tank, App. A.1). Sea: TEOS-10 via
        ``gsw.z_from_p`` at ``latitude_deg`` (sea pressure in dbar).
    atmosphere_pa : float
        Atmospheric tare (absolute pressure at the surface), Pa; see :meth:`tared`.
    rho_kg_m3, g_m_s2 : float
        Fresh-water density and gravity.
    latitude_deg : float
        Latitude for the sea-water conversion.
    offset_m : float
        Added to the depth (sensor below the vehicle origin: positive).
    """

    unit: int = 1
    water: str = "fresh"
    atmosphere_pa: float = 101325.0
    rho_kg_m3: float = 998.2
    g_m_s2: float = 9.80665
    latitude_deg: float = 39.33
    offset_m: float = 0.0

    def __post_init__(self):
        if self.unit not in UNIT_PA:
            raise ValueError(f"DepthConverter.unit must be one of {sorted(UNIT_PA)} "
                             f"(1 psi … 8 mH2O), got {self.unit!r}")
        if self.water not in ("fresh", "sea"):
            raise ValueError(f"DepthConverter.water must be 'fresh' or 'sea', got "
                             f"{self.water!r}")
        for name, what in (("rho_kg_m3", "density (kg/m³)"), ("g_m_s2", "gravity (m/s²)")):
            x = getattr(self, name)
            if not (math.isfinite(x) and x > 0):
                raise ValueError(f"DepthConverter.{name} must be a finite {what} > 0, got {x!r}")
        if not -90 <= self.latitude_deg <= 90:  # NaN too
            raise ValueError(f"DepthConverter.latitude_deg must be within ±90°, got "
                             f"{self.latitude_deg!r}")
        if not (math.isfinite(self.atmosphere_pa) and self.atmosphere_pa >= 0.0):
            raise ValueError("DepthConverter.atmosphere_pa must be a finite pressure >= 0 Pa "
                             f"(0 for a gauge sensor), got {self.atmosphere_pa!r}")
        if not math.isfinite(self.offset_m):
            raise ValueError(f"DepthConverter.offset_m must be finite, got {self.offset_m!r}")

    def pressure_pa(self, value: float) -> float:
        """A reading in the sensor's unit → Pa."""
        return value * UNIT_PA[self.unit]

    def depth_m(self, pressure_pa: float) -> float:
        """Depth (m, positive down) at absolute pressure ``pressure_pa``."""
        gauge = pressure_pa - self.atmosphere_pa
        if self.water == "fresh":
            return gauge / (self.rho_kg_m3 * self.g_m_s2) + self.offset_m
        import gsw  # TEOS-10; imported lazily (only sea-water users pay for it)

        return float(-gsw.z_from_p(gauge * 1e-4, self.latitude_deg)) + self.offset_m

    def pressure_from_depth_pa(self, depth_m: float) -> float:
        """Inverse of :meth:`depth_m` (used by the emulator)."""
        d = depth_m - self.offset_m
        if self.water == "fresh":
            return self.atmosphere_pa + d * self.rho_kg_m3 * self.g_m_s2
        import gsw

        return self.atmosphere_pa + float(gsw.p_from_z(-d, self.latitude_deg)) * 1e4

    def tared(self, surface_readings) -> DepthConverter:
        """A converter whose atmospheric tare is the mean of readings taken at the surface."""
        vals = [float(v) for v in surface_readings]
        if not vals or not all(math.isfinite(v) for v in vals):
            raise ValueError("tare needs at least one finite surface reading")
        from dataclasses import replace

        return replace(self, atmosphere_pa=self.pressure_pa(sum(vals) / len(vals)))

    def to_sample(self, line: DigiquartzLine, t_ns: int) -> DepthSample | None:
        """A :class:`DepthSample` from a pressure line (None for other lines)."""
        if line.kind != "pressure":
            return None
        p = self.pressure_pa(line.value)
        d = self.depth_m(p)
        return DepthSample(t_ns=int(t_ns), depth_m=d, pressure_pa=p,
                           valid=math.isfinite(d), source="digiquartz")
