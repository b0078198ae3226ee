"""iXblue PHINS "STDBIN" binary navigation frames, protocol versions 2–5: decode and encode.

Wire format (big-endian; block layout of iXblue's ``memory_blocs_parsers``, see
``ixblue/ixblue_stdbin_decoder``):

====  =======================================================================================
size  header field
====  =======================================================================================
2     ``"IX"``
1     protocol version (2–5)
4     navigation data mask (bit i set → navigation block i present)
4     extended navigation data mask (versions ≥ 3)
4     external sensor data mask
2     navigation data size (versions ≥ 4; nav + extended-nav bytes, header excluded)
2     telegram size (the whole frame, checksum included)
4     navigation data validity time (steps of 100 µs)
4     frame counter
====  =======================================================================================

then the present blocks in mask order — navigation, extended navigation, external sensors —
and a uint32 checksum: the sum of every preceding byte.

Every block the decoder knows is a fixed :class:`~drivers._layout.Layout` (all of iXblue's, so
any present block is either decoded or skipped by its size); if a mask has a bit no block is
known for, the blocks after it cannot be located: they are returned undecoded
(``StdbinFrame.undecoded``) and the frame is still delivered — the attitude and rate blocks
come first. The blocks a controller needs are converted by :func:`to_ins_sample`,
:func:`to_depth_sample` and :func:`to_dvl_sample` with the named sign functions of
:mod:`drivers.frames` (PHINS vessel frame x forward, y port, z up; pitch positive bow-down).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

import numpy as np

from drivers import frames
from drivers._layout import Layout, byte_sum
from drivers.samples import DepthSample, DvlSample, InsSample
from uvd.errors import ChecksumError, FrameError

SYNC = b"IX"
HEADER_SIZE = {2: 21, 3: 25, 4: 27, 5: 27}


def _L(name: str, *fields: tuple[str, str]) -> Layout:
    return Layout(name, tuple(fields), order=">")


def _f3(name: str, a: str, b: str, c: str) -> Layout:
    return _L(name, (a, "f"), (b, "f"), (c, "f"))


_GNSS = (("validityTime_100us", "I"), ("gnss_id", "B"), ("gnss_quality", "B"),
         ("latitude_deg", "d"), ("longitude_deg", "d"), ("altitude_m", "f"),
         ("latitude_stddev_m", "f"), ("longitude_stddev_m", "f"), ("altitude_stddev_m", "f"),
         ("lat_lon_stddev_m2", "f"), ("geoidal_separation_m", "f"))
_EMLOG = (("validityTime_100us", "I"), ("emlog_id", "B"), ("xv1_waterSpeed_ms", "f"),
          ("xv1_speed_stddev_ms", "f"))
_USBL = (("validityTime_100us", "I"), ("usbl_id", "B"), ("beacon_id", "8s"),
         ("latitude_deg", "d"), ("longitude_deg", "d"), ("altitude_m", "f"),
         ("north_stddev_m", "f"), ("east_stddev_m", "f"), ("lat_lon_cov_m2", "f"),
         ("altitude_stddev_m", "f"))
_DVL_GROUND = (("validityTime_100us", "I"), ("dvl_id", "B"), ("xv1_groundspeed_ms", "f"),
               ("xv2_groundspeed_ms", "f"), ("xv3_groundspeed_ms", "f"),
               ("dvl_speedofsound_ms", "f"), ("dvl_altitude_m", "f"), ("xv1_stddev_ms", "f"),
               ("xv2_stddev_ms", "f"), ("xv3_stddev_ms", "f"))
_DVL_WATER = (("validityTime_100us", "I"), ("dvl_id", "B"), ("xv1_waterspeed_ms", "f"),
              ("xv2_waterspeed_ms", "f"), ("xv3_waterspeed_ms", "f"),
              ("dvl_speedofsound_ms", "f"), ("xv1_stddev_ms", "f"), ("xv2_stddev_ms", "f"),
              ("xv3_stddev_ms", "f"))
_LBL = (("validityTime_100us", "I"), ("rfu", "B"), ("beacon_id", "8s"),
        ("beacon_latitude_deg", "d"), ("beacon_longitude_deg", "d"),
        ("beacon_altitude_m", "f"), ("range_m", "f"), ("range_stddev_m", "f"))
_EVENT = (("validityTime_100us", "I"), ("event_id", "B"), ("event_count", "I"))
_VTG = (("validityTime_100us", "I"), ("vtg_id", "B"), ("true_course_deg", "f"),
        ("magnetic_course_deg", "f"), ("speed_over_ground_ms", "f"))
_POSITION = (("latitude_deg", "d"), ("longitude_deg", "d"), ("altitude_ref", "B"),
             ("altitude_m", "f"))
_POS_DEV = (("north_stddev_m", "f"), ("east_stddev_m", "f"), ("north_east_corr", "f"),
            ("altitude_stddev_m", "f"))

#: Navigation data blocks by mask bit (names as in iXblue's decoder).
NAV_BLOCKS: dict[int, tuple[str, Layout]] = {
    0: ("attitudeHeading", _f3("attitudeHeading", "heading_deg", "roll_deg", "pitch_deg")),
    1: ("attitudeHeadingDeviation", _f3("attitudeHeadingDeviation", "heading_stdDev_deg",
                                        "roll_stdDev_deg", "pitch_stdDev_deg")),
    2: ("rtHeaveSurgeSway", _L("rtHeaveSurgeSway", ("rt_heave_withoutBdL", "f"),
                               ("rt_heave_atBdL", "f"), ("rt_surge_atBdL", "f"),
                               ("rt_sway_atBdL", "f"))),
    3: ("smartHeave", _L("smartHeave", ("validityTime_100us", "I"), ("smartHeave_m", "f"))),
    4: ("headingRollPitchRate", _f3("headingRollPitchRate", "heading_rate", "roll_rate",
                                    "pitch_rate")),
    5: ("rotationRateVesselFrame", _f3("rotationRateVesselFrame", "xv1_degsec", "xv2_degsec",
                                       "xv3_degsec")),
    6: ("accelerationVesselFrame", _f3("accelerationVesselFrame", "xv1_msec2", "xv2_msec2",
                                       "xv3_msec2")),
    7: ("position", _L("position", *_POSITION)),
    8: ("positionDeviation", _L("positionDeviation", *_POS_DEV)),
    9: ("speedGeographicFrame", _f3("speedGeographicFrame", "north_msec", "east_msec",
                                    "up_msec")),
    10: ("speedGeographicFrameDeviation", _f3("speedGeographicFrameDeviation",
                                              "north_stddev_msec", "east_stddev_msec",
                                              "up_stddev_msec")),
    11: ("currentGeographicFrame", _L("currentGeographicFrame", ("north_msec", "f"),
                                      ("east_msec", "f"))),
    12: ("currentGeographicFrameDeviation", _L("currentGeographicFrameDeviation",
                                               ("north_stddev_msec", "f"),
                                               ("east_stddev_msec", "f"))),
    13: ("systemDate", _L("systemDate", ("day", "B"), ("month", "B"), ("year", "H"))),
    14: ("sensorStatus", _L("sensorStatus", ("status1", "I"), ("status2", "I"))),
    15: ("insAlgorithmStatus", _L("insAlgorithmStatus", ("status1", "I"), ("status2", "I"),
                                  ("status3", "I"), ("status4", "I"))),
    16: ("insSystemStatus", _L("insSystemStatus", ("status1", "I"), ("status2", "I"),
                               ("status3", "I"))),
    17: ("insUserStatus", _L("insUserStatus", ("status", "I"))),
    18: ("ahrsAlgorithmStatus", _L("ahrsAlgorithmStatus", ("status", "I"))),
    19: ("ahrsSystemStatus", _L("ahrsSystemStatus", ("status1", "I"), ("status2", "I"),
                                ("status3", "I"))),
    20: ("ahrsUserStatus", _L("ahrsUserStatus", ("status", "I"))),
    21: ("heaveSurgeSwaySpeed", _f3("heaveSurgeSwaySpeed", "realtime_heave_speed",
                                   "surge_speed", "sway_speed")),
    22: ("speedVesselFrame", _f3("speedVesselFrame", "xv1_msec", "xv2_msec", "xv3_msec")),
    23: ("accelerationGeographicFrame", _f3("accelerationGeographicFrame", "north_msec2",
                                           "east_msec2", "up_msec2")),
    24: ("courseSpeedoverGround", _L("courseSpeedoverGround", ("course_over_ground", "f"),
                                     ("speed_over_ground", "f"))),
    25: ("temperatures", _f3("temperatures", "mean_temp_fog", "mean_temp_acc",
                            "board_temperature")),
    26: ("attitudeQuaternion", _L("attitudeQuaternion", ("q0", "f"), ("q1", "f"), ("q2", "f"),
                                  ("q3", "f"))),
    27: ("attitudeQuaternionDeviation", _f3("attitudeQuaternionDeviation", "quat_stddev_xi1",
                                           "quat_stddev_xi2", "quat_stddev_xi3")),
    28: ("rawAccelerationVesselFrame", _f3("rawAccelerationVesselFrame", "xv1_msec2",
                                          "xv2_msec2", "xv3_msec2")),
    29: ("accelerationVesselFrameDeviation", _f3("accelerationVesselFrameDeviation",
                                                "xv1_stddev_msec2", "xv2_stddev_msec2",
                                                "xv3_stddev_msec2")),
    30: ("rotationRateVesselFrameDeviation", _f3("rotationRateVesselFrameDeviation",
                                                "xv1_stddev_degsec", "xv2_stddev_degsec",
                                                "xv3_stddev_degsec")),
}

#: Extended navigation data blocks by mask bit (protocol ≥ 3).
EXT_NAV_BLOCKS: dict[int, tuple[str, Layout]] = {
    0: ("rotationAccelerationVesselFrame", _f3("rotationAccelerationVesselFrame",
                                               "xv1_degsec2", "xv2_degsec2", "xv3_degsec2")),
    1: ("rotationAccelerationVesselFrameDeviation", _f3(
        "rotationAccelerationVesselFrameDeviation", "xv1_stddev_degsec2", "xv2_stddev_degsec2",
        "xv3_stddev_degsec2")),
    2: ("rawRotationRateVesselFrame", _f3("rawRotationRateVesselFrame", "xv1_degsec",
                                          "xv2_degsec", "xv3_degsec")),
    3: ("vehicleAttitudeHeading", _f3("vehicleAttitudeHeading", "heading_deg", "roll_deg",
                                      "pitch_deg")),
    4: ("vehicleAttitudeHeadingDeviation", _f3("vehicleAttitudeHeadingDeviation",
                                               "heading_stddev_deg", "roll_stddev_deg",
                                               "pitch_stddev_deg")),
    5: ("vehiclePosition", _L("vehiclePosition", *_POSITION)),
    6: ("vehiclePositionDeviation", _L("vehiclePositionDeviation", *_POS_DEV)),
}

#: External sensor data blocks by mask bit. (iXblue's decoder declares 12 B for the logbook
#: block but reads 40: validity time, id, 32 characters; 40 is what is on the wire.)
EXTERNAL_BLOCKS: dict[int, tuple[str, Layout]] = {
    0: ("utc", _L("utc", ("validityTime_100us", "I"), ("source", "B"))),
    1: ("gnss1", _L("gnss1", *_GNSS)),
    2: ("gnss2", _L("gnss2", *_GNSS)),
    3: ("gnssManual", _L("gnssManual", *_GNSS)),
    4: ("emlog1", _L("emlog1", *_EMLOG)),
    5: ("emlog2", _L("emlog2", *_EMLOG)),
    6: ("usbl1", _L("usbl1", *_USBL)),
    7: ("usbl2", _L("usbl2", *_USBL)),
    8: ("usbl3", _L("usbl3", *_USBL)),
    9: ("depth", _L("depth", ("validityTime_100us", "I"), ("depth_m", "f"),
                    ("depth_stddev_m", "f"))),
    10: ("dvlGroundSpeed1", _L("dvlGroundSpeed1", *_DVL_GROUND)),
    11: ("dvlWaterSpeed1", _L("dvlWaterSpeed1", *_DVL_WATER)),
    12: ("soundVelocity", _L("soundVelocity", ("validityTime_100us", "I"),
                            ("ext_speedofsound_ms", "f"))),
    13: ("dmi", _L("dmi", ("validityTime_100us", "I"), ("pulse_count", "i"))),
    14: ("lbl1", _L("lbl1", *_LBL)),
    15: ("lbl2", _L("lbl2", *_LBL)),
    16: ("lbl3", _L("lbl3", *_LBL)),
    17: ("lbl4", _L("lbl4", *_LBL)),
    18: ("eventMarkerA", _L("eventMarkerA", *_EVENT)),
    19: ("eventMarkerB", _L("eventMarkerB", *_EVENT)),
    20: ("eventMarkerC", _L("eventMarkerC", *_EVENT)),
    21: ("dvlGroundSpeed2", _L("dvlGroundSpeed2", *_DVL_GROUND)),
    22: ("dvlWaterSpeed2", _L("dvlWaterSpeed2", *_DVL_WATER)),
    24: ("turretAngles", _L("turretAngles", ("validityTime_100us", "I"),
                           ("headingbearingdrift_angle_deg", "f"), ("roll_deg", "f"),
                           ("elevationpitch_deg", "f"))),
    25: ("vtg1", _L("vtg1", *_VTG)),
    26: ("vtg2", _L("vtg2", *_VTG)),
    27: ("logBook", _L("logBook", ("validityTime_100us", "i"), ("log_id", "I"),
                       ("custom_text", "32s"))),
}

_SECTIONS = (("navigation", NAV_BLOCKS), ("extended navigation", EXT_NAV_BLOCKS),
             ("external sensor", EXTERNAL_BLOCKS))
_BLOCK_BY_NAME = {name: (sec, bit, lay) for sec, (_, table) in enumerate(_SECTIONS)
                  for bit, (name, lay) in table.items()}
_U32 = struct.Struct(">I")

# INS algorithm status word 1 (iXblue): bit 0 navigation, bit 1 (coarse) alignment, bit 2 fine
# alignment. During coarse alignment the attitude is not yet usable.
ALGO1_NAVIGATION = 1 << 0
ALGO1_ALIGNMENT = 1 << 1
ALGO1_FINE_ALIGNMENT = 1 << 2


@dataclass(frozen=True, slots=True)
class StdbinFrame:
    """One decoded STDBIN frame; ``blocks`` maps iXblue's block names to their fields."""

    version: int
    nav_mask: int
    ext_nav_mask: int
    ext_sensor_mask: int
    validity_time_100us: int
    counter: int
    blocks: dict = field(default_factory=dict)
    nav_size: int | None = None  # V4+: None → computed when encoding
    undecoded: bytes = b""  # bytes after the first block of an unknown mask bit

    @property
    def validity_time_s(self) -> float:
        """Navigation validity time of the INS clock, seconds."""
        return self.validity_time_100us * 1e-4


def _masks_size(nav: int, ext: int, sen: int) -> tuple[int, bool]:
    """(bytes of all present blocks, all bits known)."""
    total = 0
    for mask, (_, table) in zip((nav, ext, sen), _SECTIONS, strict=True):
        m = mask
        bit = 0
        while m:
            if m & 1:
                entry = table.get(bit)
                if entry is None:
                    return total, False
                total += entry[1].size
            m >>= 1
            bit += 1
    return total, True


class StdbinCodec:
    """STDBIN framing for :class:`drivers.framing.StreamDecoder` (and ``decode``/``encode``).

    The header's telegram size must equal what the masks imply (when every bit is known), which
    rejects a false ``"IX"`` in the byte stream before waiting for its bytes.
    """

    name = "phins-stdbin"
    sync = SYNC

    def __init__(self, max_frame: int = 4096):
        self.max_frame = int(max_frame)

    def frame_length(self, buf: bytearray, start: int) -> int | None:
        avail = len(buf) - start
        if avail < 3:
            return None
        version = buf[start + 2]
        hsize = HEADER_SIZE.get(version)
        if hsize is None:
            raise FrameError(f"phins-stdbin: unknown protocol version {version}")
        if avail < hsize:
            return None
        nav, ext, sen, size = _parse_masks(buf, start, version)
        if size < hsize + 4 or size > self.max_frame:
            raise FrameError(f"phins-stdbin: telegram size {size} out of range "
                             f"[{hsize + 4}, {self.max_frame}]")
        need, known = _masks_size(nav, ext, sen)
        if (known and need + hsize + 4 != size) or (not known and need + hsize + 4 > size):
            raise FrameError(f"phins-stdbin: telegram size {size} does not match the masks "
                             f"(nav 0x{nav:08x}, ext 0x{ext:08x}, sensors 0x{sen:08x})")
        return size

    def decode(self, frame: bytes) -> StdbinFrame:
        return decode_frame(frame)

    def encode(self, fr: StdbinFrame) -> bytes:
        return encode_frame(fr)


def _parse_masks(buf, start: int, version: int) -> tuple[int, int, int, int]:
    nav, = _U32.unpack_from(buf, start + 3)
    off = start + 7
    ext = 0
    if version >= 3:
        ext, = _U32.unpack_from(buf, off)
        off += 4
    sen, = _U32.unpack_from(buf, off)
    off += 4
    if version >= 4:
        off += 2
    size, = struct.unpack_from(">H", buf, off)
    return nav, ext, sen, size


def checksum(data: bytes | memoryview) -> int:
    """STDBIN checksum: 32-bit sum of the bytes."""
    return byte_sum(data) & 0xFFFFFFFF


def decode_frame(frame: bytes) -> StdbinFrame:
    """Decode one complete STDBIN frame.

    Raises
    ------
    ChecksumError
        The 32-bit sum does not match.
    FrameError
        Bad sync, version, size or block layout.
    """
    n = len(frame)
    if n < 3 or frame[0:2] != SYNC:
        raise FrameError("phins-stdbin: frame does not start with 'IX'")
    version = frame[2]
    hsize = HEADER_SIZE.get(version)
    if hsize is None:
        raise FrameError(f"phins-stdbin: unknown protocol version {version}")
    if n < hsize + 4:
        raise FrameError(f"phins-stdbin: {n} B is shorter than a V{version} header")
    nav, ext, sen, size = _parse_masks(frame, 0, version)
    if size != n:
        raise FrameError(f"phins-stdbin: frame is {n} B, header says {size}")
    got, = _U32.unpack_from(frame, n - 4)
    want = checksum(memoryview(frame)[:n - 4])
    if got != want:
        raise ChecksumError(f"phins-stdbin: checksum 0x{got:08x} != computed 0x{want:08x} "
                            f"({n} B frame)")
    nav_size = struct.unpack_from(">H", frame, 15)[0] if version >= 4 else None
    validity, counter = struct.unpack_from(">II", frame, hsize - 8)
    blocks: dict = {}
    off = hsize
    end = n - 4
    undecoded = b""
    stop = False
    for mask, (section, table) in zip((nav, ext, sen), _SECTIONS, strict=True):
        if stop:
            break
        m = mask
        bit = 0
        while m:
            if m & 1:
                entry = table.get(bit)
                if entry is None:
                    undecoded = frame[off:end]
                    stop = True
                    break
                name, lay = entry
                if off + lay.size > end:
                    raise FrameError(f"phins-stdbin: {section} block {name} (bit {bit}) runs "
                                     f"past the end of the {n} B frame")
                blocks[name] = lay.decode(frame, off)
                off += lay.size
            m >>= 1
            bit += 1
    if not stop and off != end:
        raise FrameError(f"phins-stdbin: blocks end at byte {off}, checksum at {end}")
    return StdbinFrame(version, nav, ext if version >= 3 else 0, sen, validity, counter, blocks,
                       nav_size, undecoded)


def encode_frame(fr: StdbinFrame) -> bytes:
    """Bytes of a frame from its blocks (masks are derived from the block names).

    ``undecoded`` bytes (blocks after an unknown bit) are appended after the known blocks with
    the frame's own masks, so a decoded frame re-encodes byte for byte.
    """
    version = fr.version
    hsize = HEADER_SIZE.get(version)
    if hsize is None:
        raise ValueError(f"phins-stdbin: cannot encode protocol version {version}")
    masks = [0, 0, 0]
    parts: list[list[tuple[int, bytes]]] = [[], [], []]
    for name, values in fr.blocks.items():
        if name not in _BLOCK_BY_NAME:
            raise ValueError(f"phins-stdbin: unknown block {name!r}")
        sec, bit, lay = _BLOCK_BY_NAME[name]
        if sec == 1 and version < 3:
            raise ValueError(f"phins-stdbin: extended block {name!r} needs protocol ≥ 3")
        masks[sec] |= 1 << bit
        parts[sec].append((bit, lay.encode(values)))
    if fr.undecoded:
        masks = [fr.nav_mask, fr.ext_nav_mask, fr.ext_sensor_mask]
    body = b"".join(b for sec in parts for _, b in sorted(sec)) + fr.undecoded
    size = hsize + len(body) + 4
    if size > 0xFFFF:
        raise ValueError(f"phins-stdbin: frame of {size} B does not fit a 16-bit size")
    head = [SYNC, bytes([version]), _U32.pack(masks[0])]
    if version >= 3:
        head.append(_U32.pack(masks[1]))
    head.append(_U32.pack(masks[2]))
    if version >= 4:
        nav_size = fr.nav_size if fr.nav_size is not None else len(b"".join(
            b for sec in parts[:2] for _, b in sec))
        head.append(struct.pack(">H", nav_size))
    head.append(struct.pack(">HII", size, fr.validity_time_100us & 0xFFFFFFFF,
                            fr.counter & 0xFFFFFFFF))
    data = b"".join(head) + body
    return data + _U32.pack(checksum(data))


# ---------------------------------------------------------------------------------------------
# conversion to the samples navigation uses (App. A frames and signs)
# ---------------------------------------------------------------------------------------------
def ins_valid(fr: StdbinFrame) -> bool:
    """Attitude usable: no coarse-alignment flag in INS algorithm status word 1 (if present)."""
    algo = fr.blocks.get("insAlgorithmStatus")
    return not (algo and algo["status1"] & ALGO1_ALIGNMENT)


def to_ins_sample(fr: StdbinFrame, t_ns: int) -> InsSample | None:
    """Attitude and body rate (App. A) from a frame; ``None`` without an attitude block.

    Rates come from "rotation rate in vessel frame" (x fwd, y port, z up → body); without that
    block they are NaN and ``rates_valid`` is False (navigation then derives them).
    """
    att = fr.blocks.get("attitudeHeading")
    if att is None:
        return None
    rr = fr.blocks.get("rotationRateVesselFrame")
    if rr is not None:
        w = frames.phins_vessel_to_body(math.radians(rr["xv1_degsec"]),
                                        math.radians(rr["xv2_degsec"]),
                                        math.radians(rr["xv3_degsec"]))
        rates_valid = bool(np.all(np.isfinite(w)))
    else:
        w = np.full(3, np.nan)
        rates_valid = False
    roll = frames.phins_roll_to_ours(att["roll_deg"])
    pitch = frames.phins_pitch_to_ours(att["pitch_deg"])
    heading = frames.phins_heading_to_ours(att["heading_deg"])
    ok = ins_valid(fr) and all(math.isfinite(x) for x in (roll, pitch, heading))
    return InsSample(t_ns=int(t_ns), roll=roll, pitch=pitch, heading=heading, omega_body=w,
                     rates_valid=rates_valid, valid=ok, source="phins-stdbin")


def body_velocity(fr: StdbinFrame) -> np.ndarray | None:
    """Vehicle velocity in the body frame (m/s) from "speed in vessel frame", or None."""
    sv = fr.blocks.get("speedVesselFrame")
    if sv is None:
        return None
    return frames.phins_vessel_to_body(sv["xv1_msec"], sv["xv2_msec"], sv["xv3_msec"])


def ned_velocity(fr: StdbinFrame) -> np.ndarray | None:
    """Geographic velocity, NED (m/s), from "speed in geographic frame" (north, east, up)."""
    sg = fr.blocks.get("speedGeographicFrame")
    if sg is None:
        return None
    return frames.enu_to_ned(sg["east_msec"], sg["north_msec"], sg["up_msec"])


def to_depth_sample(fr: StdbinFrame, t_ns: int) -> DepthSample | None:
    """The external depth the PHINS received (metres, positive down), or None."""
    d = fr.blocks.get("depth")
    if d is None:
        return None
    return DepthSample(t_ns=int(t_ns), depth_m=float(d["depth_m"]),
                       valid=math.isfinite(d["depth_m"]), source="phins-stdbin")


def to_dvl_sample(fr: StdbinFrame, t_ns: int) -> DvlSample | None:
    """The external DVL ground speed the PHINS received (DVL frame XV1 fwd, XV2 port, XV3 up)."""
    g = fr.blocks.get("dvlGroundSpeed1")
    if g is None:
        return None
    v = frames.phins_vessel_to_body(g["xv1_groundspeed_ms"], g["xv2_groundspeed_ms"],
                                    g["xv3_groundspeed_ms"])
    ok = bool(np.all(np.isfinite(v)))
    return DvlSample(t_ns=int(t_ns), velocity_body=v if ok else np.full(3, np.nan),
                     bottom_lock=ok, altitude_m=float(g["dvl_altitude_m"]),
                     good_beams=4 if ok else 0, source="phins-stdbin")


def from_state(euler: tuple[float, float, float], omega_body: np.ndarray,
               v_body: np.ndarray | None = None,
               validity_time_100us: int = 0, counter: int = 0, version: int = 3,
               depth_m: float | None = None) -> StdbinFrame:
    """A navigation frame (attitude, rates, rotation rate, speeds, status) from our state.

    ``euler`` is (roll, pitch, heading) in radians (App. A); ``omega_body`` rad/s and
    ``v_body`` m/s in the body frame. The inverse of :func:`to_ins_sample` up to float32.
    Used by the INS emulator of ``sim_bridge``.
    """
    roll, pitch, heading = euler
    w1, w2, w3 = frames.body_to_phins_vessel(np.degrees(np.asarray(omega_body, float)))
    blocks: dict = {
        "attitudeHeading": {"heading_deg": frames.ours_heading_to_phins(heading),
                            "roll_deg": frames.ours_roll_to_phins(roll),
                            "pitch_deg": frames.ours_pitch_to_phins(pitch)},
        "rotationRateVesselFrame": {"xv1_degsec": w1, "xv2_degsec": w2, "xv3_degsec": w3},
        "insAlgorithmStatus": {"status1": ALGO1_NAVIGATION, "status2": 0, "status3": 0,
                               "status4": 0},
    }
    if v_body is not None:
        x, y, z = frames.body_to_phins_vessel(v_body)
        blocks["speedVesselFrame"] = {"xv1_msec": x, "xv2_msec": y, "xv3_msec": z}
    if depth_m is not None:
        blocks["depth"] = {"validityTime_100us": validity_time_100us & 0xFFFFFFFF,
                           "depth_m": float(depth_m), "depth_stddev_m": 0.01}
    return StdbinFrame(version, 0, 0, 0, validity_time_100us, counter, blocks)


def raw_fields(fr: StdbinFrame) -> dict:
    """Instrument-unit fields for display (``uvd decode``)."""
    blocks = {name: {k: (v.rstrip(b"\0").decode("latin-1") if isinstance(v, bytes) else v)
                     for k, v in d.items()} for name, d in fr.blocks.items()}
    out = {"version": fr.version, "nav_mask": f"0x{fr.nav_mask:08x}",
           "ext_nav_mask": f"0x{fr.ext_nav_mask:08x}",
           "ext_sensor_mask": f"0x{fr.ext_sensor_mask:08x}",
           "validity_time_100us": fr.validity_time_100us, "counter": fr.counter,
           "blocks": blocks}
    if fr.undecoded:
        out["undecoded_bytes"] = len(fr.undecoded)
    return out
