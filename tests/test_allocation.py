"""Thruster allocation: u = B f unsaturated, direction-keeping saturation that reports the
saturated thrusters, weighted pseudo-inverse, thrust ⇄ propeller speed (App. A.1)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uvd.control.allocation import (
    DEFAULT_DOF_PRIORITY,
    DOF_NAMES,
    PRIORITY_TIE,
    Allocator,
    accommodate,
    allocate,
    allocate_kernel,
    allocate_prioritised,
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


# --- thruster effectiveness η (accommodate) ---------------------------------------------------

BLUE = Allocator.from_vehicle(load_vehicle("bluerov2-heavy"))


@st.composite
def _eta(draw, n):
    """η per thruster: healthy, weak or dead."""
    return np.array(draw(st.lists(st.one_of(st.just(1.0), st.just(0.0), st.floats(0.05, 1.0)),
                                  min_size=n, max_size=n)))


@settings(max_examples=40, deadline=None)
@given(w=st.lists(st.floats(0.2, 5.0), min_size=8, max_size=8))
def test_healthy_effectiveness_is_the_allocators_own_inverse(w):
    for alloc in (ALLOC, BLUE, Allocator.from_vehicle(load_vehicle("bluerov2-heavy"),
                                                      np.array(w))):
        acc = accommodate(alloc, np.ones(alloc.n_thrusters))
        np.testing.assert_allclose(acc.B_pinv, alloc.B_pinv, atol=1e-9)
        assert acc.actuated.all() and acc.given_up == ()


@settings(max_examples=80, deadline=None)
@given(data=st.data(), u=wrench, which=st.sampled_from(["jhu", "blue"]))
def test_effectiveness_allocation_meets_the_kept_dofs_and_never_uses_a_dead_thruster(
        data, u, which):
    alloc = ALLOC if which == "jhu" else BLUE
    n = alloc.n_thrusters
    eta = data.draw(_eta(n))
    acc = accommodate(alloc, eta)
    B_eta = alloc.B * eta[None, :]
    f = acc.B_pinv @ u
    a = acc.actuated
    # the kept DOFs exactly, with the thrust each thruster really gives (η f)
    np.testing.assert_allclose((B_eta @ f)[a], u[a], atol=1e-8 * (1 + np.abs(u).max()))
    assert np.all(f[eta <= 1e-6] == 0.0)  # a dead thruster is not used
    assert a.sum() <= np.linalg.matrix_rank(B_eta)
    assert set(acc.given_up) == {DOF_NAMES[i] for i in range(6) if not a[i]}
    # priority: each DOF given up has less authority with the higher-priority ones kept than
    # the floor (σ_min of those rows < 0.2 σ_min of the healthy B)
    floor = 0.2 * np.linalg.svd(alloc.B, compute_uv=False)[-1]
    order = [DOF_NAMES.index(x) for x in DEFAULT_DOF_PRIORITY]
    for d in acc.given_up:
        i = DOF_NAMES.index(d)
        above = [j for j in order[:order.index(i)] if a[j]]
        rows = B_eta[above + [i]][:, eta > 1e-6]
        assert rows.shape[1] <= len(above) or \
            np.linalg.svd(rows, compute_uv=False)[-1] < floor
    # saturation: limits on the command respected, the kept DOFs' wrench in direction
    f, sat, scale = allocate_kernel(acc.B_pinv, alloc.max_thrust_n, u)
    assert np.all(np.abs(f) <= alloc.max_thrust_n)
    np.testing.assert_allclose((B_eta @ f)[a], scale * u[a],
                               atol=1e-8 * (1 + np.abs(u).max()))


def test_a_bluerov2_losing_any_one_thruster_keeps_every_dof():
    for k in range(BLUE.n_thrusters):
        eta = np.ones(BLUE.n_thrusters)
        eta[k] = 0.0
        assert accommodate(BLUE, eta).given_up == ()


@pytest.mark.parametrize("dead, given_up", [
    (0, ("surge",)), (1, ("surge",)),  # an aft thruster: yaw kept, surge given up
    (2, ("sway",)),  # the lateral thruster
    (3, ("pitch",)), (4, ("pitch",)), (5, ("pitch",)),  # a vertical: depth and roll kept
])
def test_the_jhu_rov_losing_one_of_six_gives_up_the_dof_of_lowest_priority(dead, given_up):
    """Six thrusters for six DOFs: one lost leaves five. Depth comes first; with a vertical
    thruster lost, the two left keep heave and roll, and pitch is what the default priority
    gives up (the lateral thruster's 5 cm lever is no authority in roll)."""
    eta = np.ones(6)
    eta[dead] = 0.0
    acc = accommodate(ALLOC, eta)
    assert acc.given_up == given_up
    assert acc.actuated[DOF_NAMES.index("heave")]
    # another priority gives up another DOF: sway first when the operator says so
    if dead >= 4:  # an aft vertical (the bow one lost, pitch is heave's: none kept)
        prio = ("heave", "pitch", "roll", "yaw", "surge", "sway")
        assert accommodate(ALLOC, eta, prio).given_up == ("roll",)


def test_a_weak_thruster_is_commanded_more_and_saturation_shows_it():
    eta = np.ones(6)
    eta[3] = 0.5
    acc = accommodate(ALLOC, eta)
    u = np.array([0.0, 0.0, 100.0, 0.0, 0.0, 0.0])
    f_h, f_w = ALLOC.B_pinv @ u, acc.B_pinv @ u
    np.testing.assert_allclose((ALLOC.B * eta) @ f_w, u, atol=1e-9)
    assert acc.given_up == () and abs(f_w[3]) > abs(f_h[3])


@pytest.mark.parametrize("eta", [[1.0] * 5, [1, 1, 1, 1, 1, 1.5], [1, 1, 1, -0.1, 1, 1],
                                 [1, 1, 1, float("nan"), 1, 1]])
def test_effectiveness_out_of_range_is_refused_by_name(eta):
    with pytest.raises(ValueError, match="eta must be 6 numbers in"):
        accommodate(ALLOC, eta)


def test_a_priority_that_is_not_the_six_dofs_is_refused():
    with pytest.raises(ValueError, match="DOF priority must name each"):
        accommodate(ALLOC, np.ones(6), ("heave", "roll", "pitch", "yaw", "surge", "surge"))


# --- saturation resolved by DOF priority (allocate_prioritised) -----------------------------

@settings(max_examples=150, deadline=None)
@given(data=st.data(), u=wrench, which=st.sampled_from(["jhu", "blue"]),
       prio=st.permutations(DOF_NAMES))
def test_prioritised_allocation_keeps_limits_is_exact_unsaturated_and_favours_priority(
        data, u, which, prio):
    """Never beyond a limit; exactly the unconstrained B⁺u (bit for bit, allocate_kernel's)
    when that is within the limits; the DOF wrench fractions it returns are the ones produced;
    and, compared with plain scaling in priority order, the first DOF where they differ gets
    more from it (so the DOF of highest priority is never worse off)."""
    alloc = ALLOC if which == "jhu" else BLUE
    eta = data.draw(_eta(alloc.n_thrusters))
    acc = accommodate(alloc, eta, prio)
    B_eta = alloc.B * eta[None, :]
    fmax = alloc.max_thrust_n
    f, sat, s = allocate_prioritised(alloc, u, prio, B_pinv=acc.B_pinv)
    f0, sat0, c = allocate_kernel(acc.B_pinv, fmax, u)
    assert np.all(np.abs(f) <= fmax)
    if c == 1.0:
        assert np.array_equal(f, f0) and np.array_equal(sat, sat0) and np.all(s == 1.0)
        return
    np.testing.assert_array_equal(sat, np.abs(f) >= fmax * (1 - 1e-12))
    # the fractions it reports are the wrench produced on each DOF asked for
    asked = acc.actuated & (u != 0.0)
    scale = 1.0 + np.abs(u).max()
    np.testing.assert_allclose((B_eta @ f)[asked], s[asked] * u[asked], atol=1e-8 * scale)
    np.testing.assert_allclose((B_eta @ f0)[asked], c * u[asked], atol=1e-8 * scale)
    # in priority order, the first DOF where it and plain scaling differ gets more from it
    for d in (DOF_NAMES.index(x) for x in prio):
        if asked[d] and abs(u[d]) * abs(s[d] - c) > PRIORITY_TIE * np.abs(u).max():
            assert s[d] > c, (prio, s, c)
            break


def test_a_saturated_yaw_no_longer_scales_depth_and_attitude():
    """The JHU ROV without its aft-port thruster: the aft-starboard one alone gives yaw, and a
    yaw moment beyond its limit made plain scaling shrink the verticals' heave, roll and pitch
    with it. By priority they are met in full, yaw gets what its thruster can give, sway in
    full on the lateral thruster."""
    eta = np.array([0.0, 1, 1, 1, 1, 1])
    acc = accommodate(ALLOC, eta)
    u = np.array([0.0, 50.0, 40.0, 5.0, 10.0, 150.0])  # yaw 150 N m > 0.35 m × 300 N
    B_eta = ALLOC.B * eta[None, :]
    f0, _, c = allocate_kernel(acc.B_pinv, ALLOC.max_thrust_n, u)
    f, sat, s = allocate_prioritised(ALLOC, u, B_pinv=acc.B_pinv)
    assert c == pytest.approx(0.7)
    np.testing.assert_allclose((B_eta @ f0)[1:], c * u[1:], atol=1e-9)  # plain: all × 0.7
    np.testing.assert_allclose((B_eta @ f)[1:5], u[1:5], atol=1e-9)  # sway, heave, roll, pitch
    assert (B_eta @ f)[5] == pytest.approx(105.0) and s[5] == pytest.approx(0.7)
    assert sat.tolist() == [False, True, False, False, False, False]


def test_the_lower_priority_dof_gives_way_to_the_higher_on_a_shared_thruster():
    """Without the lateral thruster (sway given up) surge and yaw share the two aft thrusters;
    yaw comes first, surge gets the thrust it leaves — plain scaling shrank both."""
    eta = np.array([1.0, 1, 0, 1, 1, 1])
    acc = accommodate(ALLOC, eta)
    u = np.array([500.0, 0, 0, 0, 0, 70.0])  # aft-port 0.5·500 + 70/0.7 = 350 N > 300 N
    B_eta = ALLOC.B * eta[None, :]
    f, _, s = allocate_prioritised(ALLOC, u, B_pinv=acc.B_pinv)
    _, _, c = allocate_kernel(acc.B_pinv, ALLOC.max_thrust_n, u)
    assert (B_eta @ f)[5] == pytest.approx(70.0) and s[5] == 1.0
    assert s[0] == pytest.approx((300.0 - 100.0) / 250.0) and s[0] < c == pytest.approx(300 / 350)
