"""Teledyne RDI PD0 ensembles (Workhorse / Explorer DVL, thesis App. A.1): decode and encode.

Wire format (little-endian; RDI "WorkHorse Commands and Output Data Format", PD0 chapter):

* **Header** ``7F 7F``, ensemble length N (bytes, without the checksum), spare, number of data
  types n, then n uint16 offsets of the data types from the start of the ensemble.
* **Data types** by 16-bit ID: fixed leader ``0x0000`` (configuration: coordinate transform
  EX, beam angle, frequency, …), variable leader ``0x0080`` (ensemble number, RTC time,
  attitude, temperature, speed of sound), velocity ``0x0100`` (int16 mm/s, cells × beams,
  −32768 = bad), correlation ``0x0200``, echo intensity ``0x0300``, percent good ``0x0400``,
  status ``0x0500`` (uint8 cells × beams), bottom track ``0x0600`` (velocities, ranges,
  correlation, amplitude, percent good per beam). Any other ID is kept as raw bytes.
* **Checksum**: uint16 sum of the N bytes of the ensemble, after it.

Units at this edge carry their names (``heading_cdeg``, ``velocity_mm_s``, ``range_cm``); the
properties of :class:`Pd0Ensemble` give SI values, and :func:`to_dvl_sample` converts a
bottom-track solution into our body frame with the named functions of :mod:`drivers.frames`
(the bottom's motion is negated, RDI axes mapped, the mounting applied by navigation).

A bottom lock is valid when the three velocity components are present and at least
``min_good_beams`` (3) beams saw the bottom (RDI 3-beam solution).
"""

from __future__ import annotations

import calendar
import math
import struct
from dataclasses import dataclass, field

import numpy as np

from drivers import frames
from drivers._layout import Layout, byte_sum
from drivers.samples import DvlSample
from uvd.errors import ChecksumError, FrameError

SYNC = b"\x7f\x7f"
BAD_VELOCITY = -32768

ID_FIXED = 0x0000
ID_VARIABLE = 0x0080
ID_VELOCITY = 0x0100
ID_CORRELATION = 0x0200
ID_ECHO = 0x0300
ID_PERCENT_GOOD = 0x0400
ID_STATUS = 0x0500
ID_BOTTOM_TRACK = 0x0600

COORD_FRAMES = ("beam", "instrument", "ship", "earth")
FREQUENCIES_KHZ = (75, 150, 300, 600, 1200, 2400, 38, 0)
BEAM_ANGLES_DEG = (15.0, 20.0, 30.0, float("nan"))

FIXED_LEADER = Layout("fixed leader", (
    ("id", "H"), ("cpu_fw_ver", "B"), ("cpu_fw_rev", "B"), ("system_config", "H"),
    ("real_sim_flag", "B"), ("lag_length", "B"), ("num_beams", "B"), ("num_cells", "B"),
    ("pings_per_ensemble", "H"), ("cell_length_cm", "H"), ("blank_after_transmit_cm", "H"),
    ("profiling_mode", "B"), ("low_corr_threshold", "B"), ("num_code_reps", "B"),
    ("percent_good_min", "B"), ("error_velocity_max_mm_s", "H"), ("tpp_minutes", "B"),
    ("tpp_seconds", "B"), ("tpp_hundredths", "B"), ("coord_transform", "B"),
    ("heading_alignment_cdeg", "h"), ("heading_bias_cdeg", "h"), ("sensor_source", "B"),
    ("sensors_available", "B"), ("bin1_distance_cm", "H"), ("transmit_pulse_length_cm", "H"),
    ("ref_layer_start", "B"), ("ref_layer_end", "B"), ("false_target_threshold", "B"),
    ("spare", "B"), ("transmit_lag_distance_cm", "H"), ("cpu_board_serial", "8s"),
    ("system_bandwidth", "H"), ("system_power", "B"), ("spare2", "B"),
    ("serial_number", "I"), ("beam_angle_deg", "B"),
))

VARIABLE_LEADER = Layout("variable leader", (
    ("id", "H"), ("ensemble_number", "H"), ("rtc_year", "B"), ("rtc_month", "B"),
    ("rtc_day", "B"), ("rtc_hour", "B"), ("rtc_minute", "B"), ("rtc_second", "B"),
    ("rtc_hundredths", "B"), ("ensemble_msb", "B"), ("bit_result", "H"),
    ("speed_of_sound_m_s", "H"), ("transducer_depth_dm", "H"), ("heading_cdeg", "H"),
    ("pitch_cdeg", "h"), ("roll_cdeg", "h"), ("salinity_ppt", "H"),
    ("temperature_cdegc", "h"), ("mpt_minutes", "B"), ("mpt_seconds", "B"),
    ("mpt_hundredths", "B"), ("heading_std_deg", "B"), ("pitch_std_ddeg", "B"),
    ("roll_std_ddeg", "B"), ("adc", "8B"), ("error_status_word", "I"), ("reserved", "H"),
    ("pressure_dapa", "I"), ("pressure_variance_dapa", "I"), ("spare", "B"),
    ("y2k_rtc", "8B"),
))

BOTTOM_TRACK = Layout("bottom track", (
    ("id", "H"), ("pings_per_ensemble", "H"), ("delay_before_reacquire", "H"),
    ("corr_mag_min", "B"), ("eval_amp_min", "B"), ("percent_good_min", "B"), ("mode", "B"),
    ("error_velocity_max_mm_s", "H"), ("reserved", "I"), ("range_cm", "4H"),
    ("velocity_mm_s", "4h"), ("correlation", "4B"), ("eval_amp", "4B"),
    ("percent_good", "4B"), ("ref_layer_min_dm", "H"), ("ref_layer_near_dm", "H"),
    ("ref_layer_far_dm", "H"), ("ref_velocity_mm_s", "4h"), ("ref_correlation", "4B"),
    ("ref_intensity", "4B"), ("ref_percent_good", "4B"), ("max_depth_dm", "H"),
    ("rssi_amplitude", "4B"), ("gain", "B"), ("range_msb", "4B"),
))

_HDR = struct.Struct("<HHBB")
_U16 = struct.Struct("<H")
_PROFILE_IDS = {ID_VELOCITY: np.dtype("<i2"), ID_CORRELATION: np.dtype("u1"),
                ID_ECHO: np.dtype("u1"), ID_PERCENT_GOOD: np.dtype("u1"),
                ID_STATUS: np.dtype("u1")}


@dataclass(frozen=True, slots=True, eq=False)
class Pd0Ensemble:
    """One decoded PD0 ensemble, in instrument units (field names carry them).

    Attributes
    ----------
    fixed, variable, bottom_track : Mapping or None
        Fields of the fixed leader, variable leader and bottom-track data types (see the
        ``Layout`` tables above; a :class:`~drivers._layout.Record` when decoded, any mapping
        when built), ``_extra`` = any bytes past the known fields.
    profiles : dict
        ``{type id: ndarray (cells, beams)}`` for velocity (int16 mm/s), correlation, echo
        intensity, percent good and status (uint8).
    other : dict
        ``{type id: raw bytes}`` of data types this codec does not interpret.
    order : tuple of int
        Data-type IDs in wire order (so encoding reproduces the ensemble).
    spare : int
        The spare header byte.
    """

    fixed: dict | None
    variable: dict | None
    bottom_track: dict | None
    profiles: dict = field(default_factory=dict)
    other: dict = field(default_factory=dict)
    order: tuple = ()
    spare: int = 0

    def __eq__(self, other) -> bool:
        if not isinstance(other, Pd0Ensemble):
            return NotImplemented
        if (self.fixed, self.variable, self.bottom_track, self.other, self.order, self.spare) \
                != (other.fixed, other.variable, other.bottom_track, other.other, other.order,
                    other.spare):
            return False
        if self.profiles.keys() != other.profiles.keys():
            return False
        return all(np.array_equal(v, other.profiles[k]) for k, v in self.profiles.items())

    # ---- configuration -----------------------------------------------------------------
    @property
    def coord_frame(self) -> str:
        """``beam``, ``instrument``, ``ship`` or ``earth`` (EX command, bits 3–4)."""
        if not self.fixed or "coord_transform" not in self.fixed:
            return "beam"
        return COORD_FRAMES[(self.fixed["coord_transform"] >> 3) & 0b11]

    @property
    def beam_angle_deg(self) -> float:
        """Beam angle from the system configuration word (15/20/30°) or the explicit byte."""
        f = self.fixed or {}
        if "beam_angle_deg" in f and f["beam_angle_deg"]:
            return float(f["beam_angle_deg"])
        if "system_config" in f:
            return BEAM_ANGLES_DEG[(f["system_config"] >> 8) & 0b11]
        return float("nan")

    @property
    def frequency_khz(self) -> int:
        """System frequency (kHz) from the system configuration word (0 if unknown)."""
        f = self.fixed or {}
        return FREQUENCIES_KHZ[f["system_config"] & 0b111] if "system_config" in f else 0

    @property
    def convex(self) -> bool:
        """Transducer head convex (True, nearly all) or concave."""
        f = self.fixed or {}
        return bool(f.get("system_config", 0x08) & 0x08)

    @property
    def up_facing(self) -> bool:
        """Transducer facing up (system configuration bit 7)."""
        f = self.fixed or {}
        return bool(f.get("system_config", 0) & 0x80)

    # ---- variable leader in SI -------------------------------------------------------------
    @property
    def ensemble_number(self) -> int:
        v = self.variable or {}
        return int(v.get("ensemble_number", 0)) + (int(v.get("ensemble_msb", 0)) << 16)

    @property
    def time_unix_s(self) -> float:
        """RTC time as Unix seconds (UTC assumed; RDI years 00–99 → 2000–2099); NaN if bad."""
        v = self.variable or {}
        try:
            t = calendar.timegm((2000 + v["rtc_year"], v["rtc_month"], v["rtc_day"],
                                 v["rtc_hour"], v["rtc_minute"], v["rtc_second"], 0, 0, 0))
            if not (1 <= v["rtc_month"] <= 12 and 1 <= v["rtc_day"] <= 31):
                return float("nan")
            return t + v["rtc_hundredths"] / 100.0
        except (KeyError, ValueError, OverflowError):
            return float("nan")

    @property
    def heading_deg(self) -> float:
        return (self.variable or {}).get("heading_cdeg", float("nan")) / 100.0

    @property
    def pitch_deg(self) -> float:
        return (self.variable or {}).get("pitch_cdeg", float("nan")) / 100.0

    @property
    def roll_deg(self) -> float:
        return (self.variable or {}).get("roll_cdeg", float("nan")) / 100.0

    @property
    def temperature_degc(self) -> float:
        return (self.variable or {}).get("temperature_cdegc", float("nan")) / 100.0

    @property
    def speed_of_sound_m_s(self) -> float:
        return float((self.variable or {}).get("speed_of_sound_m_s", float("nan")))

    # ---- bottom track in SI ---------------------------------------------------------------
    @property
    def bt_velocity_m_s(self) -> np.ndarray:
        """Bottom-track velocities (4,), m/s, in the ensemble's coordinate frame; NaN = bad.

        These are the bottom's motion relative to the instrument (negate for the vehicle,
        :func:`drivers.frames.pd0_bottom_to_vehicle`).
        """
        bt = self.bottom_track
        if not bt or "velocity_mm_s" not in bt:
            return np.full(4, np.nan)
        return np.array([np.nan if v == BAD_VELOCITY else v * 1e-3 for v in bt["velocity_mm_s"]])

    @property
    def bt_range_m(self) -> np.ndarray:
        """Slant range to the bottom per beam (4,), metres; NaN where the beam saw no bottom."""
        bt = self.bottom_track
        if not bt or "range_cm" not in bt:
            return np.full(4, np.nan)
        msb = bt.get("range_msb", (0, 0, 0, 0))
        out = np.empty(4)
        for i in range(4):
            r = bt["range_cm"][i] + (msb[i] << 16)
            out[i] = r * 0.01 if r > 0 else np.nan
        return out

    @property
    def good_beams(self) -> int:
        """Beams that saw the bottom (range > 0; in beam coordinates also a valid velocity)."""
        bt = self.bottom_track
        if not bt or "range_cm" not in bt:
            return 0
        msb = bt.get("range_msb", (0, 0, 0, 0))
        beam = self.coord_frame == "beam"
        n = 0
        for i in range(4):
            if bt["range_cm"][i] + (msb[i] << 16) > 0 and (
                    not beam or bt.get("velocity_mm_s", (BAD_VELOCITY,) * 4)[i] != BAD_VELOCITY):
                n += 1
        return n

    @property
    def altitude_m(self) -> float:
        """Altitude above the bottom: mean slant range × cos(beam angle); NaN without lock."""
        r = self.bt_range_m
        good = r[np.isfinite(r)]
        ang = self.beam_angle_deg
        if good.size == 0 or not math.isfinite(ang):
            return float("nan")
        return float(good.mean() * math.cos(math.radians(ang)))


# ---------------------------------------------------------------------------------------------
# codec
# ---------------------------------------------------------------------------------------------
class Pd0Codec:
    """PD0 framing for :class:`drivers.framing.StreamDecoder` (and ``decode``/``encode``).

    Parameters
    ----------
    max_frame : int
        Largest ensemble accepted (bytes incl. checksum); larger declared lengths are treated
        as a false sync. 16 KiB covers 128 cells × 4 beams of every profile type.
    """

    name = "pd0"
    sync = SYNC

    def __init__(self, max_frame: int = 16384):
        self.max_frame = int(max_frame)

    def frame_length(self, buf: bytearray, start: int) -> int | None:
        """Ensemble length + 2 (checksum) from the header; sanity-checks the offsets."""
        avail = len(buf) - start
        if avail < 6:
            return None
        n_bytes, = _U16.unpack_from(buf, start + 2)
        n_types = buf[start + 5]
        if n_bytes + 2 > self.max_frame:
            raise FrameError(f"pd0: ensemble length {n_bytes} exceeds {self.max_frame} B")
        if n_types == 0 or n_types > 32:
            raise FrameError(f"pd0: implausible number of data types {n_types}")
        hdr_len = 6 + 2 * n_types
        if n_bytes < hdr_len:
            raise FrameError(f"pd0: ensemble length {n_bytes} shorter than its header")
        if avail >= hdr_len:
            first, = _U16.unpack_from(buf, start + 6)
            if first != hdr_len:
                raise FrameError(f"pd0: first data type at offset {first}, expected {hdr_len}")
        if avail >= hdr_len + 2 and _U16.unpack_from(buf, start + hdr_len)[0] != ID_FIXED:
            # a false sync is rejected now, not after waiting for its declared length
            raise FrameError("pd0: first data type is not the fixed leader")
        return n_bytes + 2

    def decode(self, frame: bytes) -> Pd0Ensemble:
        return decode_ensemble(frame)

    def encode(self, ens: Pd0Ensemble) -> bytes:
        return encode_ensemble(ens)


def checksum(data: bytes | memoryview) -> int:
    """PD0 checksum: 16-bit sum of the bytes."""
    return byte_sum(data) & 0xFFFF


def decode_ensemble(frame: bytes) -> Pd0Ensemble:
    """Decode one complete ensemble (header … checksum).

    Raises
    ------
    ChecksumError
        The 16-bit sum does not match.
    FrameError
        Bad sync, length, offsets, a data type that does not fit, or an ensemble that does
        not start with the fixed and variable leaders.
    """
    n = len(frame)
    if n < 8 or frame[0] != 0x7F or frame[1] != 0x7F:
        raise FrameError("pd0: ensemble does not start with 7F 7F")
    _, n_bytes, spare, n_types = _HDR.unpack_from(frame, 0)
    if n != n_bytes + 2:
        raise FrameError(f"pd0: frame is {n} B, header says {n_bytes} + 2")
    got, = _U16.unpack_from(frame, n_bytes)
    want = checksum(memoryview(frame)[:n_bytes])
    if got != want:
        raise ChecksumError(f"pd0: checksum 0x{got:04x} != computed 0x{want:04x} "
                            f"(ensemble of {n_bytes} B)")
    hdr_len = 6 + 2 * n_types
    if n_bytes < hdr_len:
        raise FrameError(f"pd0: {n_types} data types do not fit in {n_bytes} B")
    offsets = struct.unpack_from(f"<{n_types}H", frame, 6)
    bounds = list(offsets) + [n_bytes]
    fixed = variable = bt = None
    profiles: dict = {}
    other: dict = {}
    order = []
    n_cells = n_beams = 0
    prev = hdr_len
    for k in range(n_types):
        a, b = bounds[k], bounds[k + 1]
        if a < prev or b < a + 2 or b > n_bytes:
            raise FrameError(f"pd0: data type {k} at offset {a} out of order or out of bounds")
        prev = b
        tid, = _U16.unpack_from(frame, a)
        if tid in order:
            raise FrameError(f"pd0: data type 0x{tid:04x} appears twice")
        order.append(tid)
        length = b - a
        if tid == ID_FIXED:
            fixed = FIXED_LEADER.decode(frame, a, length)
            n_cells = fixed.get("num_cells", 0)
            n_beams = fixed.get("num_beams", 0)
        elif tid == ID_VARIABLE:
            variable = VARIABLE_LEADER.decode(frame, a, length)
        elif tid == ID_BOTTOM_TRACK:
            bt = BOTTOM_TRACK.decode(frame, a, length)
        elif tid in _PROFILE_IDS:
            dt = _PROFILE_IDS[tid]
            need = n_cells * n_beams * dt.itemsize
            if fixed is None or length - 2 < need:
                raise FrameError(f"pd0: profile 0x{tid:04x} of {length - 2} B, expected "
                                 f"{need} B for {n_cells} cells × {n_beams} beams")
            profiles[tid] = np.ndarray((n_cells, n_beams), dt, frame, a + 2)
            if length - 2 > need:
                other[(tid, "tail")] = frame[a + 2 + need:b]
        else:
            other[tid] = frame[a + 2:b]
    if order[:2] != [ID_FIXED, ID_VARIABLE]:
        # RDI: every ensemble starts with the fixed and the variable leader. Checked after the
        # 16-bit checksum, it makes a false sync that sums right by chance (1 in 65 536) a
        # frame error instead of a frame.
        raise FrameError("pd0: ensemble does not start with the fixed and variable leaders "
                         f"(data types {', '.join(f'0x{t:04x}' for t in order[:2])})")
    return Pd0Ensemble(fixed, variable, bt, profiles, other, tuple(order), spare)


def encode_ensemble(ens: Pd0Ensemble) -> bytes:
    """Bytes of an ensemble (header, data types in ``ens.order``, checksum).

    ``order`` defaults to fixed, variable, profiles, bottom track, others when empty.
    """
    order = list(ens.order)
    if not order:
        if ens.fixed is not None:
            order.append(ID_FIXED)
        if ens.variable is not None:
            order.append(ID_VARIABLE)
        order.extend(sorted(ens.profiles))
        if ens.bottom_track is not None:
            order.append(ID_BOTTOM_TRACK)
        order.extend(k for k in ens.other if not isinstance(k, tuple))
    blocks = []
    for tid in order:
        if tid == ID_FIXED:
            blk = FIXED_LEADER.encode({**ens.fixed, "id": ID_FIXED})
        elif tid == ID_VARIABLE:
            blk = VARIABLE_LEADER.encode({**ens.variable, "id": ID_VARIABLE})
        elif tid == ID_BOTTOM_TRACK:
            blk = BOTTOM_TRACK.encode({**ens.bottom_track, "id": ID_BOTTOM_TRACK})
        elif tid in ens.profiles:
            arr = np.ascontiguousarray(ens.profiles[tid], dtype=_PROFILE_IDS[tid])
            blk = _U16.pack(tid) + arr.tobytes() + ens.other.get((tid, "tail"), b"")
        else:
            blk = _U16.pack(tid) + bytes(ens.other[tid])
        blocks.append(blk)
    hdr_len = 6 + 2 * len(blocks)
    offsets = []
    off = hdr_len
    for blk in blocks:
        offsets.append(off)
        off += len(blk)
    n_bytes = off
    if n_bytes + 2 > 0xFFFF:
        raise ValueError(f"pd0: ensemble of {n_bytes} B does not fit a 16-bit length")
    body = b"".join([_HDR.pack(0x7F7F, n_bytes, ens.spare, len(blocks)),
                     struct.pack(f"<{len(blocks)}H", *offsets), *blocks])
    return body + _U16.pack(sum(body) & 0xFFFF)


# ---------------------------------------------------------------------------------------------
# conversion to the sample navigation uses
# ---------------------------------------------------------------------------------------------
def vehicle_velocity_dvl_frame(ens: Pd0Ensemble, R_body_to_world: np.ndarray | None = None
                               ) -> np.ndarray:
    """Velocity of the DVL over ground (3,), m/s, in the DVL's body-aligned frame.

    x forward (beam 3), y starboard, z down, for a down-looking DVL mounted as RDI's reference
    (any other mounting is ``NavConfig.dvl_mount_R``). NaN when there is no solution.

    Beam coordinates are transformed to instrument ones (4-beam, or 3-beam when one beam is
    bad); earth coordinates (ENU) are rotated into the body frame with ``R_body_to_world``
    (e.g. from the INS) — without it they cannot be, and NaN is returned.
    """
    v = ens.bt_velocity_m_s
    frame = ens.coord_frame
    if frame == "beam":
        n_bad = int(np.count_nonzero(~np.isfinite(v)))
        if n_bad == 0:
            x, y, z, _ = frames.beam_to_instrument(*v, ens.beam_angle_deg, ens.convex)
        elif n_bad == 1:
            x, y, z, _ = frames.three_beam_to_instrument(list(v), ens.beam_angle_deg,
                                                         ens.convex)
        else:
            return np.full(3, np.nan)
        bottom = frames.rdi_instrument_to_body(x, y, z)
    elif frame in ("instrument", "ship"):
        bottom = frames.rdi_ship_to_body(v[0], v[1], v[2])
    else:  # earth: east, north, up
        if R_body_to_world is None:
            return np.full(3, np.nan)
        bottom = np.asarray(R_body_to_world).T @ frames.enu_to_ned(v[0], v[1], v[2])
    return frames.pd0_bottom_to_vehicle(bottom)


def to_dvl_sample(ens: Pd0Ensemble, t_ns: int, min_good_beams: int = 3,
                  R_body_to_world: np.ndarray | None = None) -> DvlSample:
    """A :class:`~drivers.samples.DvlSample` (vehicle motion, DVL body-aligned frame).

    ``bottom_lock`` is True when all three components exist and at least ``min_good_beams``
    beams saw the bottom; otherwise the velocity is NaN.
    """
    v = vehicle_velocity_dvl_frame(ens, R_body_to_world)
    nb = ens.good_beams
    lock = bool(np.all(np.isfinite(v))) and nb >= min_good_beams
    if not lock:
        v = np.full(3, np.nan)
    return DvlSample(t_ns=int(t_ns), velocity_body=v, bottom_lock=lock,
                     altitude_m=ens.altitude_m if lock else float("nan"), good_beams=nb,
                     source="pd0")


def from_dvl_velocity(v_dvl: np.ndarray, altitude_m: float, ensemble_number: int = 1,
                      beam_angle_deg: int = 30, frequency_code: int = 4,
                      coord: str = "ship", lock: bool = True,
                      attitude_cdeg: tuple[int, int, int] = (0, 0, 0),
                      temperature_cdegc: int = 1500, speed_of_sound_m_s: int = 1500,
                      rtc: tuple[int, ...] = (13, 1, 1, 0, 0, 0, 0)) -> Pd0Ensemble:
    """A bottom-track-only ensemble (fixed + variable leader + bottom track) from a velocity.

    The inverse of :func:`to_dvl_sample` for the ship/instrument frame (what the emulator of
    ``sim_bridge`` sends): ``v_dvl`` (3,) m/s vehicle velocity in the DVL frame, altitude in m.
    Values are rounded to the wire resolution (1 mm/s, 1 cm).
    """
    if coord not in ("ship", "instrument"):
        raise ValueError("from_dvl_velocity writes ship or instrument coordinates only")
    ex = (COORD_FRAMES.index(coord) << 3) | 0b111
    ang_code = {15: 0, 20: 1, 30: 2}.get(int(beam_angle_deg), 3)
    system_config = (frequency_code & 0b111) | 0x08 | 0x40 | (ang_code << 8) | (0b0100 << 12)
    fixed = {"id": ID_FIXED, "cpu_fw_ver": 51, "cpu_fw_rev": 40, "system_config": system_config,
             "real_sim_flag": 0, "lag_length": 13, "num_beams": 4, "num_cells": 0,
             "pings_per_ensemble": 0, "cell_length_cm": 100, "blank_after_transmit_cm": 88,
             "profiling_mode": 1, "low_corr_threshold": 64, "num_code_reps": 5,
             "percent_good_min": 0, "error_velocity_max_mm_s": 2000, "tpp_minutes": 0,
             "tpp_seconds": 0, "tpp_hundredths": 0, "coord_transform": ex,
             "heading_alignment_cdeg": 0, "heading_bias_cdeg": 0, "sensor_source": 0x7D,
             "sensors_available": 0x3D, "bin1_distance_cm": 0, "transmit_pulse_length_cm": 0,
             "ref_layer_start": 1, "ref_layer_end": 5, "false_target_threshold": 50,
             "spare": 0, "transmit_lag_distance_cm": 0, "cpu_board_serial": bytes(8),
             "system_bandwidth": 0, "system_power": 255, "spare2": 0, "serial_number": 1,
             "beam_angle_deg": int(beam_angle_deg), "_extra": b""}
    yy, mo, dd, hh, mi, ss, hs = rtc
    variable = {"id": ID_VARIABLE, "ensemble_number": ensemble_number & 0xFFFF,
                "rtc_year": yy, "rtc_month": mo, "rtc_day": dd, "rtc_hour": hh,
                "rtc_minute": mi, "rtc_second": ss, "rtc_hundredths": hs,
                "ensemble_msb": (ensemble_number >> 16) & 0xFF, "bit_result": 0,
                "speed_of_sound_m_s": speed_of_sound_m_s, "transducer_depth_dm": 0,
                "heading_cdeg": attitude_cdeg[0] % 36000, "pitch_cdeg": attitude_cdeg[1],
                "roll_cdeg": attitude_cdeg[2], "salinity_ppt": 0,
                "temperature_cdegc": temperature_cdegc, "mpt_minutes": 0, "mpt_seconds": 0,
                "mpt_hundredths": 0, "heading_std_deg": 0, "pitch_std_ddeg": 0,
                "roll_std_ddeg": 0, "adc": (0,) * 8, "error_status_word": 0, "reserved": 0,
                "pressure_dapa": 0, "pressure_variance_dapa": 0, "spare": 0,
                "y2k_rtc": (20, yy, mo, dd, hh, mi, ss, hs), "_extra": b""}
    if lock and np.all(np.isfinite(v_dvl)):
        stbd, fwd, up = frames.body_to_rdi_ship(frames.pd0_bottom_to_vehicle(v_dvl))
        vel = tuple(_mm(x) for x in (stbd, fwd, up)) + (0,)
        slant_cm = max(1, min(0xFFFFFF, round(altitude_m / math.cos(math.radians(
            beam_angle_deg)) * 100.0)))
        rng = (slant_cm & 0xFFFF,) * 4
        msb = ((slant_cm >> 16) & 0xFF,) * 4
        corr, amp, pg = (255,) * 4, (70,) * 4, (100,) * 4
    else:
        vel = (BAD_VELOCITY,) * 4
        rng, msb = (0,) * 4, (0,) * 4
        corr, amp, pg = (0,) * 4, (0,) * 4, (0,) * 4
    bt = {"id": ID_BOTTOM_TRACK, "pings_per_ensemble": 1, "delay_before_reacquire": 0,
          "corr_mag_min": 220, "eval_amp_min": 30, "percent_good_min": 0, "mode": 5,
          "error_velocity_max_mm_s": 1000, "reserved": 0, "range_cm": rng,
          "velocity_mm_s": vel, "correlation": corr, "eval_amp": amp, "percent_good": pg,
          "ref_layer_min_dm": 20, "ref_layer_near_dm": 88, "ref_layer_far_dm": 320,
          "ref_velocity_mm_s": (BAD_VELOCITY,) * 4, "ref_correlation": (0,) * 4,
          "ref_intensity": (0,) * 4, "ref_percent_good": (0,) * 4, "max_depth_dm": 1000,
          "rssi_amplitude": (0,) * 4, "gain": 0, "range_msb": msb, "_extra": b""}
    return Pd0Ensemble(fixed, variable, bt, {}, {}, (ID_FIXED, ID_VARIABLE, ID_BOTTOM_TRACK))


#: the resolution of PD0 velocities (1 mm/s on the wire, :func:`_mm`)
VELOCITY_RESOLUTION_M_S = 0.001


# ---------------------------------------------------------------------------------------------
# the DVL's own velocity noise, from its error velocity
# ---------------------------------------------------------------------------------------------
#: ensembles with an error velocity needed before :func:`bottom_track_noise` gives a figure
NOISE_MIN_ENSEMBLES = 10


def bt_error_velocity_m_s(ens: Pd0Ensemble) -> float:
    """The ensemble's bottom-track error velocity (m/s), NaN when it has none.

    In beam coordinates it is formed from the four beams (:func:`drivers.frames.
    beam_to_instrument`); in the instrument, ship and earth frames it is the fourth velocity
    the instrument sent (RDI marks it bad, −32768, where it could not form it)."""
    v = ens.bt_velocity_m_s
    if ens.coord_frame == "beam":
        if not np.isfinite(v).all():
            return float("nan")
        return float(frames.beam_to_instrument(*v, ens.beam_angle_deg, ens.convex)[3])
    return float(v[3])


@dataclass(frozen=True)
class BottomTrackNoise:
    """A DVL's horizontal velocity noise, read off a recording (:func:`bottom_track_noise`).

    Attributes
    ----------
    ensembles : ensembles with an error velocity.
    sigma_m_s : the noise of one ensemble's horizontal velocity (m/s).
    bt_pings : bottom-track pings averaged into an ensemble (the BT leader's count; 0 unknown).
    sigma_ping_m_s : the noise of one ping, ``sigma_m_s·√bt_pings`` (NaN when unknown).
    interval_s : the median time between those ensembles (NaN without RTC times).
    """

    ensembles: int
    sigma_m_s: float
    bt_pings: int
    sigma_ping_m_s: float
    interval_s: float


def bottom_track_noise(ensembles) -> BottomTrackNoise | None:
    """The horizontal velocity noise of the DVL that wrote ``ensembles``, from its error
    velocity; None with fewer than :data:`NOISE_MIN_ENSEMBLES` that carry one.

    For RDI's 4-beam Janus head the error velocity has the very noise of each horizontal
    component: with independent beam noise σ_b, X = c·a(b₁ − b₂) has σ_b·a√2 and
    E = d(b₁ + b₂ − b₃ − b₄) with d = a/√2 has σ_b·2d = σ_b·a√2 (RDI "ADCP Coordinate
    Transformation", the a, d of :func:`drivers.frames.beam_to_instrument`), while the
    vehicle's own motion over a flat bottom cancels from E. So σ is read off E alone,
    whatever the vehicle did: the robust standard deviation 1.4826·median|E − median E|,
    which the odd wild value does not move. An ensemble averages the bottom-track pings of
    the BT leader's count; one ping's noise is σ·√pings."""
    errors, times = [], []
    pings = 0
    for ens in ensembles:
        e = bt_error_velocity_m_s(ens)
        if not math.isfinite(e):
            continue
        errors.append(e)
        times.append(ens.time_unix_s)
        pings = int((ens.bottom_track or {}).get("pings_per_ensemble", 0)) or pings
    if len(errors) < NOISE_MIN_ENSEMBLES:
        return None
    e = np.asarray(errors)
    sigma = 1.4826 * float(np.median(np.abs(e - np.median(e))))
    dt = np.diff(np.asarray(times))
    dt = dt[np.isfinite(dt) & (dt > 0)]
    interval = float(np.median(dt)) if dt.size else float("nan")
    return BottomTrackNoise(len(errors), sigma, pings,
                            sigma * math.sqrt(pings) if pings else float("nan"), interval)


def _mm(v_m_s: float) -> int:
    """m/s → int16 mm/s, saturating short of the 'bad' marker."""
    return max(-32767, min(32767, round(v_m_s * 1000.0)))


def raw_fields(ens: Pd0Ensemble) -> dict:
    """Instrument-unit fields for display (``uvd decode``): leaders, bottom track, profiles."""
    def clean(d):
        if d is None:
            return None
        return {k: (v.hex() if isinstance(v, bytes) else v) for k, v in d.items()
                if k != "_extra" or v}
    out = {"fixed_leader": clean(ens.fixed), "variable_leader": clean(ens.variable),
           "bottom_track": clean(ens.bottom_track)}
    names = {ID_VELOCITY: "velocity_mm_s", ID_CORRELATION: "correlation",
             ID_ECHO: "echo_intensity", ID_PERCENT_GOOD: "percent_good", ID_STATUS: "status"}
    for tid, arr in ens.profiles.items():
        out[names[tid]] = arr.tolist()
    if ens.other:
        out["other_data_types"] = {
            (f"0x{k:04x}" if isinstance(k, int) else f"0x{k[0]:04x}_{k[1]}"): len(v)
            for k, v in ens.other.items()}
    return out
