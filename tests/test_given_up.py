"""A horizontal DOF given up: the controller's reference slides horizontally to the vehicle,
along both horizontal axes, so the drift it cannot correct is not turned into depth error nor
chased by the thrusters left (issue 33, uvd.control.given_up)."""

import numpy as np
import pytest

from tests.test_core import _cfg, _samples
from uvd import core
from uvd.control.given_up import (
    ACCEL_MAX_PERIODS,
    controlled_dofs,
    measured_acceleration,
    slide_reference,
    world_velocity,
)
from uvd.control.trajectory import reftraj1, setpoint
from uvd.control.types import Reference, VehicleState
from uvd.geometry import euler_to_R

PITCH, ROLL, HEADING = np.radians(10.0), np.radians(-7.0), 0.6


def _H(p, roll, pitch, heading):
    H = np.eye(4)
    H[:3, :3] = euler_to_R(roll, pitch, heading)
    H[:3, 3] = p
    return H


def _case():
    ref = Reference(_H([1.0, 2.0, 3.0], ROLL, PITCH, HEADING),
                    np.array([0.3, -0.2, 0.1, 0.01, 0.02, 0.03]), np.arange(6.0))
    vs = VehicleState(_H([2.5, 2.6, 3.4], 0.0, 0.05, 0.5), np.array([0.4, 0.3, -0.2, 0, 0, 0]))
    return ref, vs


@pytest.mark.parametrize("given", [(0,), (1,), (0, 1)])
def test_what_is_left_of_the_error_is_on_the_heave_axis_and_the_slide_is_horizontal(given):
    ref, vs = _case()
    act = np.ones(6, dtype=bool)
    act[list(given)] = False
    out = slide_reference(ref, vs, act)
    R = ref.H[:3, :3]
    moved = out.H[:3, 3] - ref.H[:3, 3]
    assert moved[2] == 0.0 and np.linalg.norm(moved) > 0.1  # horizontal, and it moved
    body = R.T @ (vs.H[:3, 3] - out.H[:3, 3])  # the controller's error, desired frame
    # surge or sway given up, horizontal position is: no error left along either axis
    np.testing.assert_allclose(body[:2], 0.0, atol=1e-12)
    assert abs(body[2]) > 0.1  # the heave error stays (the vehicle is 0.4 m off in depth)
    # velocity alike: the linear velocity error has nothing along body surge and sway
    dv = R.T @ (vs.H[:3, :3] @ vs.v[:3]) - out.v[:3]
    np.testing.assert_allclose(dv[:2], 0.0, atol=1e-12)
    assert (out.v[:3] - ref.v[:3]) @ (R.T @ [0.0, 0.0, 1.0]) == pytest.approx(0.0, abs=1e-12)
    # attitude, angular velocity, angular acceleration untouched
    np.testing.assert_array_equal(out.H[:3, :3], R)
    np.testing.assert_array_equal(out.v[3:], ref.v[3:])
    np.testing.assert_array_equal(out.vdot[3:], ref.vdot[3:])


def test_a_vehicle_at_the_right_depth_drifted_along_the_given_up_axis_has_no_error_left():
    ref, _ = _case()
    a = ref.H[:3, 0].copy()
    a[2] = 0.0  # the horizontal direction of the desired surge axis
    vs = VehicleState(_H(ref.H[:3, 3] + 1.5 * a, ROLL, PITCH, HEADING), np.zeros(6))
    out = slide_reference(ref, vs, [False, True, True, True, True, True])
    np.testing.assert_allclose(out.H[:3, 3], vs.H[:3, 3], atol=1e-12)


@pytest.mark.parametrize("act", [[True] * 6, [True, True, True, True, False, True],
                                 [False, True, False, True, True, True]])
def test_nothing_horizontal_given_up_or_heave_given_up_leaves_the_reference(act):
    ref, vs = _case()
    assert slide_reference(ref, vs, act) is ref


def test_a_surge_axis_near_vertical_or_a_non_finite_state_leaves_the_reference():
    ref, vs = _case()
    steep = Reference(_H([0, 0, 1.0], 0.0, np.radians(85.0), 0.0), ref.v, ref.vdot)
    assert slide_reference(steep, vs, [False] + [True] * 5) is steep
    bad = VehicleState(vs.H, np.full(6, np.nan))
    assert slide_reference(ref, bad, [False] + [True] * 5) is ref


def test_the_core_does_not_push_a_pitched_vehicle_off_depth_for_drift_it_cannot_correct():
    """JHU ROV, aft-starboard thruster dead (surge given up); the reference 1 m ahead in world
    x at the vehicle's depth, pitch and heading: the error is drift along the given-up axis
    only. The controller (PDC) gets the slid reference: no heave, sway or torque asked; the
    trajectory's reference is what the outputs report (tracking is measured against it)."""
    target = [1.0, 0.0, 1.0, 0.0, float(PITCH), 0.0]
    cfg = _cfg()
    cfg = core.CoreConfig(nav=cfg.nav, controller=cfg.controller, reference=setpoint(target),
                          allocator=cfg.allocator, k_thrust=cfg.k_thrust)
    s = _samples(0, depth=1.0)
    s["ins"] = type(s["ins"])(t_ns=0, roll=0.0, pitch=float(PITCH), heading=0.0,
                              omega_body=np.zeros(3))
    eta = np.array([1, 0.0, 1, 1, 1, 1])
    out, _ = core.step(cfg, core.CoreInputs(t_ns=0, thruster_eta=eta, **s),
                       core.core_init(cfg), 0.1)
    assert out.status == "ok" and out.given_up == ("surge",)
    np.testing.assert_allclose(out.u_cmd[1:], 0.0, atol=1e-9)
    assert out.reference.H[0, 3] == pytest.approx(1.0)  # the trajectory's, not the slid one
    # the same vehicle healthy: surge is asked for the error
    healthy, _ = core.step(cfg, core.CoreInputs(t_ns=0, **s), core.core_init(cfg), 0.1)
    assert healthy.u_cmd[0] > 1.0


def _drifting(t):
    """A vehicle at RefTraj1's depth (and its vertical speed) whose horizontal motion is its
    own — a drift the trajectory does not have — and whose attitude differs from the
    trajectory's: (world position, velocity, acceleration, R)."""
    z = reftraj1().at(t)
    p = np.array([0.4 * t + 0.3 * np.sin(0.9 * t), -0.2 * t ** 2 + np.cos(0.5 * t), z.H[2, 3]])
    wz = (z.H[:3, :3] @ z.v[:3])[2]
    pdot = np.array([0.4 + 0.27 * np.cos(0.9 * t), -0.4 * t - 0.5 * np.sin(0.5 * t), wz])
    pddot = np.array([-0.243 * np.sin(0.9 * t), -0.4 - 0.25 * np.cos(0.5 * t), 0.0])  # z unused
    return p, pdot, pddot, euler_to_R(0.1 * np.sin(t), -0.05, 0.3 + 0.2 * t)


@pytest.mark.parametrize("given", [(0,), (1,)])
def test_the_slid_references_acceleration_is_the_derivative_of_its_velocity(given):
    """A vehicle at the desired depth drifting horizontally on its own (accelerating, the
    heading turning): the slid reference's body velocity ᵈv_d(t) is then the vehicle's world
    velocity in the desired frame, and its ᵈv̇_d must be that velocity's derivative — the
    model-based controllers feed M ᵈv̇_d forward (uvd.control.given_up's docstring: without it
    the JHU ROV's depth error was 8x its fault-free one). Central differences over ±1 ms at six
    instants of RefTraj1; the trajectory's own ᵈv̇_d differs from it by far more."""
    act = np.ones(6, dtype=bool)
    act[list(given)] = False
    traj = reftraj1()

    def slid(t, with_accel=True):
        p, pdot, pddot, R = _drifting(t)
        H = np.eye(4)
        H[:3, :3], H[:3, 3] = R, p
        vs = VehicleState(H, np.concatenate([R.T @ pdot, [0.0, 0.0, 0.0]]))
        return slide_reference(traj.at(t), vs, act, pddot if with_accel else None)

    h = 1e-3
    for t in (3.0, 11.0, 17.5, 26.0, 40.0, 61.0):
        out = slid(t)
        numeric = (slid(t + h).v - slid(t - h).v) / (2 * h)
        np.testing.assert_allclose(out.vdot[:3], numeric[:3], atol=2e-6)
        np.testing.assert_allclose(out.vdot[3:], traj.at(t).vdot[3:], atol=0)
        assert np.abs(traj.at(t).vdot[:3] - numeric[:3]).max() > 1e-2
        # no acceleration measured: the drift's taken as unaccelerated, the turning kept
        _, _, pddot, _ = _drifting(t)
        R_d = out.H[:3, :3]
        np.testing.assert_allclose(slid(t, False).vdot[:3] - out.vdot[:3],
                                   -R_d.T @ [pddot[0], pddot[1], 0.0], atol=1e-12)


def test_the_measured_acceleration_is_the_velocity_difference_of_two_close_cycles():
    v0, v1 = np.array([0.1, -0.2, 0.0]), np.array([0.15, -0.1, 0.02])
    a = measured_acceleration((1_000_000_000, v0), (1_100_000_000, v1), 0.1)
    np.testing.assert_allclose(a, (v1 - v0) / 0.1)
    assert measured_acceleration(None, (0, v1), 0.1) is None
    assert measured_acceleration((0, v0), (0, v1), 0.1) is None  # no time between them
    far = int(ACCEL_MAX_PERIODS * 0.1 * 1e9) + 1
    assert measured_acceleration((0, v0), (far, v1), 0.1) is None  # a navigation gap
    assert measured_acceleration((0, v0), (far - 2, v1), 0.1) is not None
    assert measured_acceleration((0, v0), (100_000_000, np.full(3, np.nan)), 0.1) is None
    vs = VehicleState(_H([0, 0, 0], 0.0, 0.0, np.pi / 2), np.array([1.0, 0, 0, 0, 0, 0]))
    np.testing.assert_allclose(world_velocity(vs), [0.0, 1.0, 0.0], atol=1e-12)


def test_the_core_carries_the_velocity_only_while_its_reference_slides():
    """The cycle's state keeps (t, world velocity) for the next cycle's acceleration while
    surge or sway is given up, and nothing otherwise (the healthy cycle carries no more)."""
    cfg = _cfg()
    s = _samples(0, depth=1.0)
    eta = np.array([1, 0.0, 1, 1, 1, 1])
    _, st = core.step(cfg, core.CoreInputs(t_ns=0, thruster_eta=eta, **s), core.core_init(cfg),
                      0.1)
    assert st.slid_v is not None and st.slid_v[0] == 0 and np.isfinite(st.slid_v[1]).all()
    _, healthy = core.step(cfg, core.CoreInputs(t_ns=0, **s), core.core_init(cfg), 0.1)
    assert healthy.slid_v is None


@pytest.mark.parametrize(("act", "controlled"), [
    ([False, True, True, True, True, True], [False, False, True, True, True, True]),
    ([True, False, True, True, True, True], [False, False, True, True, True, True]),
    ([True, True, True, True, False, True], [True, True, True, True, False, True]),
    ([False, True, False, True, True, True], [False, True, False, True, True, True]),
    ([True] * 6, [True] * 6)])
def test_surge_or_sway_given_up_takes_both_out_of_the_controllers_loop(act, controlled):
    """Horizontal position given up: the controller acts on neither horizontal translation
    (the slid reference leaves the kept one no error, only a feed-forward of the drift); with
    heave given up nothing slides and only the DOFs no thruster reaches are out."""
    assert controlled_dofs(act).tolist() == controlled
