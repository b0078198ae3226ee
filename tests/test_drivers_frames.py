"""Each sign / frame conversion of drivers.frames, one test each, against physical cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers import frames
from uvd.geometry import R_to_euler, euler_to_R
from uvd.model.lie import J, exp_so3

E = np.eye(3)


def test_phins_pitch_bow_down_is_our_negative_pitch():
    # bow down 10° (PHINS +10) → body x axis points below the horizon: world z (down) > 0
    pitch = frames.phins_pitch_to_ours(10.0)
    assert pitch == pytest.approx(-math.radians(10.0))
    R = euler_to_R(0.0, pitch, 0.0)
    # R[:, 0] is the bow direction in NED: bow down means its down component is positive
    assert R[2, 0] == pytest.approx(-math.sin(pitch)) and R[2, 0] > 0
    assert frames.ours_pitch_to_phins(pitch) == pytest.approx(10.0)


def test_phins_roll_port_up_is_our_positive_roll():
    roll = frames.phins_roll_to_ours(5.0)  # port up = starboard down
    R = euler_to_R(roll, 0.0, 0.0)
    assert R[2, 1] > 0  # body y (starboard) points down-ish
    assert frames.ours_roll_to_phins(roll) == pytest.approx(5.0)


def test_phins_heading_clockwise_from_north_wrapped():
    assert frames.phins_heading_to_ours(90.0) == pytest.approx(math.pi / 2)
    assert frames.phins_heading_to_ours(270.0) == pytest.approx(-math.pi / 2)
    assert frames.phins_heading_to_ours(180.0) == pytest.approx(math.pi)
    R = euler_to_R(0.0, 0.0, frames.phins_heading_to_ours(90.0))
    np.testing.assert_allclose(R[:, 0], [0, 1, 0], atol=1e-12)  # bow points east
    assert frames.ours_heading_to_phins(-math.pi / 2) == pytest.approx(270.0)


# the wrap itself (one convention, (−π, π]) is tested in tests/test_geometry.py


def test_phins_vessel_frame_y_port_z_up():
    # forward 1, to port 2, up 3 → x 1, starboard −2, keel −3
    np.testing.assert_array_equal(frames.phins_vessel_to_body(1.0, 2.0, 3.0), [1, -2, -3])
    assert frames.body_to_phins_vessel([1.0, -2.0, -3.0]) == (1.0, 2.0, 3.0)
    # turning the bow to starboard is +z (keel) in our body frame, −z (up) in the vessel frame
    w = frames.phins_vessel_to_body(0.0, 0.0, -0.1)
    assert w[2] == pytest.approx(0.1)


def test_enu_to_ned():
    np.testing.assert_array_equal(frames.enu_to_ned(1.0, 2.0, 3.0), [2, 1, -3])
    assert frames.ned_to_enu([2.0, 1.0, -3.0]) == (1.0, 2.0, 3.0)


def test_pd0_bottom_track_is_negated():
    np.testing.assert_array_equal(frames.pd0_bottom_to_vehicle([0.1, -0.2, 0.3]),
                                  [-0.1, 0.2, -0.3])


def test_rdi_ship_axes():
    # RDI ship: X starboard, Y forward, Z up → ours x forward, y starboard, z down
    np.testing.assert_array_equal(frames.rdi_ship_to_body(1.0, 2.0, 3.0), [2, 1, -3])
    assert frames.body_to_rdi_ship([2.0, 1.0, -3.0]) == (1.0, 2.0, 3.0)
    np.testing.assert_array_equal(frames.rdi_instrument_to_body(1.0, 2.0, 3.0), [2, 1, -3])


def test_dvl_mount_rotation_and_lever_arm():
    # DVL 1 m forward of the origin, yawing at 0.5 rad/s: it sees a sideways velocity
    # of ω × r = 0.5 m/s to starboard while the origin is still
    r = np.array([1.0, 0.0, 0.0])
    w = np.array([0.0, 0.0, 0.5])
    v_dvl = np.cross(w, r)
    np.testing.assert_allclose(frames.dvl_mount_to_body(E, r, v_dvl, w), 0.0, atol=1e-15)
    # rotated mount: DVL x along body y
    Rm = exp_so3(np.array([0.0, 0.0, math.pi / 2]))
    np.testing.assert_allclose(frames.dvl_mount_to_body(Rm, np.zeros(3), [1.0, 0, 0],
                                                        np.zeros(3)), [0, 1, 0], atol=1e-15)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-3, 3), min_size=12, max_size=12))
def test_dvl_mount_formula(x):
    Rm = exp_so3(np.array(x[0:3]))
    r, v, w = np.array(x[3:6]), np.array(x[6:9]), np.array(x[9:12])
    np.testing.assert_allclose(frames.dvl_mount_to_body(Rm, r, v, w), Rm @ v - J(w) @ r,
                               atol=1e-12)


def test_phins_attitude_to_R_matches_euler_sequence():
    R = frames.phins_attitude_to_R(30.0, 2.0, -3.0)
    roll, pitch, heading = R_to_euler(R)
    assert (math.degrees(roll), math.degrees(pitch), math.degrees(heading)) == \
        pytest.approx((2.0, 3.0, 30.0))
    np.testing.assert_allclose(R @ R.T, E, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-5, 5), min_size=4, max_size=4), st.sampled_from([20.0, 30.0]),
       st.booleans())
def test_beam_to_instrument_inverts_the_janus_geometry(v, angle, convex):
    """Beam velocities generated from an instrument velocity recover it (4- and 3-beam)."""
    th = math.radians(angle)
    c = 1.0 if convex else -1.0
    x, y, z = v[:3]
    # inverse of RDI's transformation (positive beam velocity toward the transducer)
    b1 = c * x * math.sin(th) + z * math.cos(th)
    b2 = -c * x * math.sin(th) + z * math.cos(th)
    b3 = -c * y * math.sin(th) + z * math.cos(th)
    b4 = c * y * math.sin(th) + z * math.cos(th)
    X, Y, Z, err = frames.beam_to_instrument(b1, b2, b3, b4, angle, convex)
    assert (X, Y, Z) == pytest.approx((x, y, z), abs=1e-9)
    assert err == pytest.approx(0.0, abs=1e-9)
    beams = [b1, b2, b3, b4]
    missing = int(abs(v[3]) * 1e3) % 4
    beams[missing] = float("nan")
    X3, Y3, Z3, e3 = frames.three_beam_to_instrument(beams, angle, convex)
    assert (X3, Y3, Z3) == pytest.approx((x, y, z), abs=1e-9) and math.isnan(e3)


def test_three_beam_needs_exactly_one_missing():
    with pytest.raises(ValueError, match="exactly one"):
        frames.three_beam_to_instrument([1.0, float("nan"), float("nan"), 1.0], 30.0)


@given(st.floats(5.0, 45.0), st.booleans())
@settings(max_examples=60, deadline=None)
def test_janus_error_velocity_carries_the_noise_of_each_horizontal_component(angle, convex):
    """drivers.pd0.bottom_track_noise reads a DVL's horizontal noise off its error velocity:
    for any beam angle, X, Y and E weigh independent beam noise alike (equal norms of their
    rows of the beam → instrument transform), and E weighs no motion (its row is orthogonal
    to the beams' response to any X, Y, Z velocity)."""
    rows = np.array([frames.beam_to_instrument(*np.eye(4)[i], angle, convex)
                     for i in range(4)]).T  # rows X, Y, Z, E over beams 1…4
    nx, ny, _, ne = np.linalg.norm(rows, axis=1)
    assert nx == pytest.approx(ne, rel=1e-12) and ny == pytest.approx(ne, rel=1e-12)
    # the beams' response to a velocity (X, Y, Z): each beam sees it along its own axis,
    # tilted θ from Z (beams 1/2 in ±X, 4/3 in ±Y for a convex head; mirrored if concave)
    sn, cs, sg = math.sin(math.radians(angle)), math.cos(math.radians(angle)), \
        (1.0 if convex else -1.0)
    response = np.array([[sg * sn, 0, cs], [-sg * sn, 0, cs], [0, -sg * sn, cs],
                         [0, sg * sn, cs]])
    np.testing.assert_allclose(rows[:3] @ response, np.eye(3), atol=1e-12)  # the right one
    assert np.abs(rows[3] @ response).max() < 1e-12
