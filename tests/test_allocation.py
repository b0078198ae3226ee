"""Thruster allocation: u = B f unsaturated, direction-keeping saturation that reports the
saturated thrusters, weighted pseudo-inverse, thrust ⇄ propeller speed (App. A.1)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uvd.control.allocation import (
    Allocator,
    allocate,
    applied_wrench,
    speed_command,
    thrust_from_measured_speed,
    weighted_pinv,
)
from uvd.io.vehicle import load_vehicle

VEH = load_vehicle("jhu-rov")
ALLOC = Allocator.from_vehicle(VEH)

wrench = st.lists(st.floats(-2000.0, 2000.0, allow_nan=False), min_size=6, max_size=6).map(
    np.array)


@settings(max_examples=60, deadline=None)
@given(u=wrench)
def test_unsaturated_allocation_is_exact_and_saturation_keeps_direction(u):
    f, sat, scale = allocate(ALLOC, u)
    fmax = ALLOC.max_thrust_n
    assert np.all(np.abs(f) <= fmax * (1 + 1e-12))
    np.testing.assert_allclose(ALLOC.B @ f, scale * u, atol=1e-9 * (1 + np.abs(u).max()))
    if scale < 1.0:
        # same direction, at least one thruster at its limit, and exactly those reported
        assert sat.any()
        np.testing.assert_allclose(np.abs(f[sat]), fmax[sat], rtol=1e-9)
        assert np.all(np.abs(f[~sat]) < fmax[~sat])
    else:
        assert scale == 1.0 and not sat.any()
        np.testing.assert_allclose(ALLOC.B @ f, u, atol=1e-9 * (1 + np.abs(u).max()))


def test_a_large_wrench_saturates_and_is_scaled():
    u = np.array([5000.0, 0, 0, 0, 0, 0])
    f, sat, scale = allocate(ALLOC, u)
    assert scale < 0.2 and sat.sum() >= 1
    direction = ALLOC.B @ f
    np.testing.assert_allclose(direction / np.linalg.norm(direction), [1, 0, 0, 0, 0, 0],
                               atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(w=st.lists(st.floats(0.1, 10.0), min_size=6, max_size=6), u=wrench,
       z=st.lists(st.floats(-10.0, 10.0), min_size=6, max_size=6))
def test_weighted_pinv_is_a_right_inverse_of_least_weighted_norm(w, u, z):
    B = ALLOC.B
    w = np.array(w)
    P = weighted_pinv(B, w)
    np.testing.assert_allclose(B @ P, np.eye(6), atol=1e-9)
    f = P @ u
    # any other solution f + n (B n = 0) has a larger Σ w f²; B is 6×6 here, so the null
    # space is {0} — build a wider matrix to exercise it
    B2 = np.hstack([B, B[:, :2]])
    w2 = np.concatenate([w, [1.0, 2.0]])
    P2 = weighted_pinv(B2, w2)
    f2 = P2 @ u
    np.testing.assert_allclose(B2 @ f2, u, atol=1e-8 * (1 + np.abs(u).max()))
    N = np.linalg.svd(B2)[2][6:].T  # null-space basis
    alt = f2 + N @ np.array(z[:2])
    assert np.sum(w2 * f2 ** 2) <= np.sum(w2 * alt ** 2) + 1e-6
    assert f.shape == (6,)


def test_weights_are_validated():
    with pytest.raises(ValueError):
        weighted_pinv(ALLOC.B, np.array([1, 1, 1, 1, 1, 0.0]))


def test_thrust_speed_round_trip_and_applied_wrench():
    f = np.array([-250.0, -4.0, 0.0, 3.0, 120.0, 300.0])
    w = speed_command(ALLOC, f)
    assert np.all(np.sign(w) == np.sign(f))
    np.testing.assert_allclose(thrust_from_measured_speed(ALLOC, w), f, atol=1e-12)
    np.testing.assert_allclose(applied_wrench(ALLOC, w), ALLOC.B @ f, atol=1e-9)
