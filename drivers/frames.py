"""Every frame and sign conversion between an instrument's convention and ours, one function each.

Our frames (thesis App. A, Fig. A.2): world x north, y east, z down; body x bow, y starboard,
z keel; Euler sequence heading about z, then pitch about the new y, then roll about the new x,
so R = Rz(heading) Ry(pitch) Rx(roll) maps body to world (:func:`uvd.geometry.euler_to_R`).
Angles are radians inside uvd; degrees appear only in names at the codec edge (``pitch_deg``).

Instrument conventions handled here:

* **PHINS vessel frame** (STDBIN "in vessel frame" blocks, iXblue "XV1 XV2 XV3"): x forward,
  y port, z up. → ours: (x, −y, −z).  :func:`phins_vessel_to_body`.
* **PHINS pitch** in ``$PIXSE,ATITUD`` and STDBIN attitude: positive bow *down*; ours (App. A,
  rotation about +y starboard) is positive bow *up*. :func:`phins_pitch_to_ours`.
* **PHINS roll**: positive port side up (starboard down), which is ours — no flip
  (:func:`phins_roll_to_ours` exists so the statement has a test).
* **PHINS heading**: degrees 0–360 clockwise from true north, ours — only wrapped to (−π, π]
  (:func:`uvd.geometry.wrap_angle`, the one convention).
* **PHINS heading/roll/pitch rates**: follow the angle conventions; the pitch rate flips.
* **PHINS geographic speed** (``$PIXSE,SPEED_``, STDBIN "speed geographic frame"): east,
  north, up. → NED: (north, east, −up). :func:`enu_to_ned`.
* **RDI PD0 bottom track** reports the motion of the *bottom* relative to the instrument;
  the vehicle moves the opposite way. :func:`pd0_bottom_to_vehicle`.
* **RDI ship / instrument coordinates**: x starboard (ship: forward), … see
  :func:`rdi_ship_to_body`, :func:`rdi_instrument_to_body`.
* **RDI earth coordinates**: east, north, up. → NED via :func:`enu_to_ned`.
* **DVL mounting**: the DVL frame is rotated by ``R_mount`` (DVL → body) and displaced by the
  lever arm ``r`` (body frame, metres, from the vehicle origin to the DVL); the DVL measures
  the velocity of its own point, ν_dvl = ν + ω × r, so ν = R_mount v_dvl − ω × r.
  :func:`dvl_mount_to_body`.
"""

from __future__ import annotations

import math

import numpy as np

from uvd.geometry import euler_to_R, wrap_angle


def phins_heading_to_ours(heading_deg: float) -> float:
    """PHINS heading (degrees, 0–360, clockwise from true north) → ours (radians, (−π, π]).

    Same sense (rotation about +z down); only the unit and the range change.
    """
    return wrap_angle(math.radians(heading_deg))


def ours_heading_to_phins(heading_rad: float) -> float:
    """Inverse of :func:`phins_heading_to_ours` (degrees in [0, 360))."""
    d = math.degrees(heading_rad) % 360.0
    return 0.0 if d >= 360.0 else d


def phins_pitch_to_ours(pitch_deg: float) -> float:
    """PHINS pitch (degrees, positive bow-down) → ours (radians, positive bow-up, App. A).

    The one sign flip of PHINS attitude: pitch about +y starboard is bow-up in App. A.
    """
    return -math.radians(pitch_deg)


def ours_pitch_to_phins(pitch_rad: float) -> float:
    """Inverse of :func:`phins_pitch_to_ours`."""
    return -math.degrees(pitch_rad)


def phins_roll_to_ours(roll_deg: float) -> float:
    """PHINS roll (degrees, positive port-up / starboard-down) → ours (radians); same sense."""
    return math.radians(roll_deg)


def ours_roll_to_phins(roll_rad: float) -> float:
    """Inverse of :func:`phins_roll_to_ours`."""
    return math.degrees(roll_rad)


def phins_attitude_to_R(heading_deg: float, roll_deg: float, pitch_deg: float) -> np.ndarray:
    """PHINS heading/roll/pitch (degrees, PHINS signs) → R ∈ SO(3), body → world (App. A)."""
    return euler_to_R(phins_roll_to_ours(roll_deg), phins_pitch_to_ours(pitch_deg),
                      phins_heading_to_ours(heading_deg))


def phins_vessel_to_body(x_fwd: float, y_port: float, z_up: float) -> np.ndarray:
    """PHINS vessel frame (x forward, y port, z up) → body (x bow, y starboard, z keel).

    Valid for any vector: velocities, rotation rates, accelerations.
    """
    return np.array([x_fwd, -y_port, -z_up], dtype=float)


def body_to_phins_vessel(v_body) -> tuple[float, float, float]:
    """Inverse of :func:`phins_vessel_to_body`."""
    return float(v_body[0]), -float(v_body[1]), -float(v_body[2])


def enu_to_ned(east: float, north: float, up: float) -> np.ndarray:
    """East-north-up (PHINS SPEED_, RDI earth coordinates) → north-east-down."""
    return np.array([north, east, -up], dtype=float)


def ned_to_enu(v_ned) -> tuple[float, float, float]:
    """Inverse of :func:`enu_to_ned`: returns (east, north, up)."""
    return float(v_ned[1]), float(v_ned[0]), -float(v_ned[2])


def pd0_bottom_to_vehicle(v_bottom) -> np.ndarray:
    """PD0 bottom-track velocity (motion of the bottom relative to the DVL) → the DVL's motion.

    The bottom appears to move opposite to the instrument, so the vehicle velocity is the
    negation. Applies in every PD0 coordinate system (beam, instrument, ship, earth).
    """
    return -np.asarray(v_bottom, dtype=float)


def rdi_ship_to_body(starboard: float, forward: float, up: float) -> np.ndarray:
    """RDI ship coordinates → DVL body-aligned frame (x forward, y starboard, z down).

    RDI ship (and instrument) coordinates are right-handed with X to starboard, Y forward and Z
    up (for a down-looking DVL with beam 3 forward). Ours: x = Y, y = X, z = −Z.
    """
    return np.array([forward, starboard, -up], dtype=float)


def body_to_rdi_ship(v_body) -> tuple[float, float, float]:
    """Inverse of :func:`rdi_ship_to_body`: returns (starboard, forward, up)."""
    return float(v_body[1]), float(v_body[0]), -float(v_body[2])


def rdi_instrument_to_body(x: float, y: float, z: float) -> np.ndarray:
    """RDI instrument coordinates (down-looking, beam 3 forward: X stbd, Y fwd, Z up) → body.

    For a DVL mounted as RDI's reference (beam 3 toward the bow, looking down) instrument and
    ship axes coincide; any other mounting is ``NavConfig.dvl_mount_R``.
    """
    return rdi_ship_to_body(x, y, z)


def dvl_mount_to_body(R_mount: np.ndarray, lever_arm_m: np.ndarray, v_dvl: np.ndarray,
                      omega_body: np.ndarray) -> np.ndarray:
    """Velocity of the vehicle origin in the body frame from a DVL measurement.

    ν = R_mount v_dvl − ω × r, with ``R_mount`` (3, 3) the DVL → body rotation, ``lever_arm_m``
    r (3,) metres from the origin to the DVL in the body frame, ``v_dvl`` (3,) m/s the velocity
    of the DVL point in the DVL frame and ``omega_body`` (3,) rad/s.
    """
    R = R_mount
    vx, vy, vz = float(v_dvl[0]), float(v_dvl[1]), float(v_dvl[2])
    wx, wy, wz = float(omega_body[0]), float(omega_body[1]), float(omega_body[2])
    rx, ry, rz = float(lever_arm_m[0]), float(lever_arm_m[1]), float(lever_arm_m[2])
    return np.array([
        R[0, 0] * vx + R[0, 1] * vy + R[0, 2] * vz - (wy * rz - wz * ry),
        R[1, 0] * vx + R[1, 1] * vy + R[1, 2] * vz - (wz * rx - wx * rz),
        R[2, 0] * vx + R[2, 1] * vy + R[2, 2] * vz - (wx * ry - wy * rx),
    ])


def beam_to_instrument(b1: float, b2: float, b3: float, b4: float, beam_angle_deg: float,
                       convex: bool = True) -> tuple[float, float, float, float]:
    """RDI 4-beam Janus beam velocities → instrument (X, Y, Z, error) velocities.

    RDI "ADCP Coordinate Transformation" (P/N 951-6079), eq. for a convex head: with
    a = 1/(2 sin θ), b = 1/(4 cos θ), d = a/√2:
    X = c a (b1 − b2), Y = c a (b4 − b3), Z = b (b1 + b2 + b3 + b4), E = d (b1 + b2 − b3 − b4),
    c = +1 convex, −1 concave. Sign as stored in PD0 (positive toward the transducer).
    """
    th = math.radians(beam_angle_deg)
    a = 1.0 / (2.0 * math.sin(th))
    b = 1.0 / (4.0 * math.cos(th))
    d = a / math.sqrt(2.0)
    c = 1.0 if convex else -1.0
    return (c * a * (b1 - b2), c * a * (b4 - b3), b * (b1 + b2 + b3 + b4),
            d * (b1 + b2 - b3 - b4))


def three_beam_to_instrument(beams: list[float], beam_angle_deg: float,
                             convex: bool = True) -> tuple[float, float, float, float]:
    """3-beam solution: one beam (NaN) missing; fill it assuming zero error velocity.

    The error velocity E ∝ b1 + b2 − b3 − b4 = 0 gives the missing beam from the other three
    (RDI coordinate-transformation booklet, §"3-beam solutions"). Error velocity is NaN.
    """
    b = list(beams)
    bad = [i for i, x in enumerate(b) if not math.isfinite(x)]
    if len(bad) != 1:
        raise ValueError(f"three_beam_to_instrument needs exactly one missing beam, got {bad}")
    i = bad[0]
    if i == 0:
        b[0] = b[2] + b[3] - b[1]
    elif i == 1:
        b[1] = b[2] + b[3] - b[0]
    elif i == 2:
        b[2] = b[0] + b[1] - b[3]
    else:
        b[3] = b[0] + b[1] - b[2]
    x, y, z, _ = beam_to_instrument(b[0], b[1], b[2], b[3], beam_angle_deg, convex)
    return x, y, z, float("nan")
