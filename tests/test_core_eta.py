"""Thruster effectiveness η as an input of the cycle (CoreInputs.thruster_eta): allocation
inside the update, DOFs given up named and out of the closed loop, doubt → zero thrust."""

import numpy as np
import pytest

from tests.test_core import _cfg, _samples
from uvd import core
from uvd.control.allocation import Allocator
from uvd.io.vehicle import load_vehicle

VEHICLE = load_vehicle("jhu-rov")


def _step(cfg, eta, mode=core.Mode.CONTROL, **kw):
    return core.step(cfg, core.CoreInputs(t_ns=0, mode=mode, thruster_eta=eta, **_samples(0),
                                          **kw), core.core_init(cfg), 0.1)


def test_healthy_effectiveness_is_bit_identical_to_none():
    cfg = _cfg()
    a, sa = _step(cfg, None)
    b, sb = _step(cfg, np.ones(6))
    np.testing.assert_array_equal(a.thrust_n, b.thrust_n)
    np.testing.assert_array_equal(a.u_cmd, b.u_cmd)
    assert b.given_up == ()


def test_a_dead_vertical_thruster_is_not_used_and_pitch_is_given_up():
    cfg = _cfg()
    eta = np.array([1, 1, 1, 0.0, 1, 1])
    out, st = _step(cfg, eta)
    assert out.status == "ok" and out.thrust_n[3] == 0.0
    assert out.given_up == ("pitch",)
    assert list(out.reference.closed_loop) == [True, True, True, True, False, True]
    # the wrench reported is what the thrusters give: B diag(η) f; heave met as asked
    np.testing.assert_allclose((VEHICLE.B * eta) @ out.thrust_n, out.u_cmd, atol=1e-9)
    healthy, _ = _step(cfg, None)
    assert out.u_cmd[2] == pytest.approx(healthy.u_cmd[2], rel=1e-9)
    np.testing.assert_array_equal(st.u_last, out.u_cmd)


def test_a_weak_thruster_is_commanded_more():
    cfg = _cfg()
    eta = np.array([1, 1, 1, 0.5, 1, 1])
    out, _ = _step(cfg, eta)
    healthy, _ = _step(cfg, None)
    assert out.given_up == ()
    np.testing.assert_allclose(out.u_cmd, healthy.u_cmd, atol=1e-9)  # the same wrench …
    assert abs(out.thrust_n[3]) > abs(healthy.thrust_n[3])  # … asking more of thruster 4


@pytest.mark.parametrize("eta", [[1, 1, 1], [1, 1, 1, 2.0, 1, 1], [1, 1, 1, np.nan, 1, 1],
                                 "x"])
def test_an_effectiveness_that_is_not_one_of_these_thrusters_means_zero_thrust(eta):
    out, _ = _step(_cfg(), eta)
    assert not out.thrust_n.any()


def test_hold_depth_uses_the_vertical_thrusters_at_their_effectiveness():
    cfg = _cfg()
    vertical = Allocator.from_vehicle(VEHICLE).vertical()
    eta = np.array([1, 1, 1, 1, 0.5, 1])
    out, _ = _step(cfg, eta, mode=core.Mode.HOLD_DEPTH)
    assert out.status == "ok" and not out.thrust_n[~vertical].any()
    healthy, _ = _step(cfg, None, mode=core.Mode.HOLD_DEPTH)
    np.testing.assert_allclose(out.u_cmd, healthy.u_cmd, atol=1e-9)


def test_the_estimators_see_the_wrench_the_thrusters_give():
    from tests.test_core import _recording_estimator
    log = []
    cfg = _cfg(estimators=(_recording_estimator(log),))
    omega = np.full(6, 100.0)
    eta = np.array([1, 1, 1, 0.5, 1, 1])
    _step(cfg, eta, propeller_speed_rad_s=omega)
    f = VEHICLE.k_thrust * omega * np.abs(omega)
    np.testing.assert_allclose(log[0][1], (VEHICLE.B * eta) @ f, rtol=1e-12)


def test_a_priority_that_is_not_the_six_dofs_is_refused_at_configuration():
    base = _cfg()
    with pytest.raises(ValueError, match="DOF priority"):
        core.CoreConfig(nav=base.nav, controller=base.controller, reference=base.reference,
                        allocator=base.allocator, k_thrust=base.k_thrust,
                        dof_priority=("heave",))


def test_with_a_fault_saturation_is_resolved_by_dof_priority():
    """A wrench beyond the thrusters left: healthy, the one direction-keeping scale; with η
    set, allocation by priority — depth and attitude in full, yaw what its one thruster gives
    (the operator's manual wrench, so the asked wrench is known)."""
    from uvd.control.allocation import accommodate, allocate_kernel, allocate_prioritised
    cfg = _cfg()
    u = np.array([0.0, 50.0, 40.0, 5.0, 10.0, 150.0])
    eta = np.array([0.0, 1, 1, 1, 1, 1])
    out, _ = _step(cfg, eta, mode=core.Mode.MANUAL, manual_wrench=u)
    acc = accommodate(cfg.allocator, eta, cfg.dof_priority)
    f, sat, _ = allocate_prioritised(cfg.allocator, u, cfg.dof_priority, B_pinv=acc.B_pinv)
    np.testing.assert_array_equal(out.thrust_n, f)
    np.testing.assert_array_equal(out.saturated, sat)
    np.testing.assert_allclose(out.u_cmd[1:5], u[1:5], atol=1e-9)  # sway, heave, roll, pitch
    assert out.u_cmd[5] == pytest.approx(105.0)
    # healthy but for a wrench past every limit: the plain scale, bit for bit
    big = 10 * u
    healthy, _ = _step(cfg, None, mode=core.Mode.MANUAL, manual_wrench=big)
    f0, _, c = allocate_kernel(cfg.allocator.B_pinv, cfg.allocator.max_thrust_n, big)
    assert c < 1.0
    np.testing.assert_array_equal(healthy.thrust_n, f0)


def test_the_adaptive_controller_judges_saturation_on_the_allocation_in_use():
    """AMBC's freeze on saturation watches the thrust commanded: with the aft-port thruster
    dead, a 150 N m yaw moment is 429 N on the aft-starboard one alone — saturated — though
    the healthy B⁺ would split it in 214 N each (not saturated)."""
    from uvd.control.ambc import ambc_params, ambc_spec
    from uvd.control.trajectory import setpoint
    from uvd.estimation.navigation import NavConfig
    alloc = Allocator.from_vehicle(VEHICLE)
    spec = ambc_spec(ambc_params("decoupled", allocator=alloc), np.zeros(16))
    cfg = core.CoreConfig(nav=NavConfig(ins_timeout_s=0.25), controller=spec,
                          reference=setpoint([0.0, 0.0, 1.0, 0.0, 0.0, 0.5]), allocator=alloc,
                          k_thrust=VEHICLE.k_thrust)
    healthy, st_h = _step(cfg, None)
    assert healthy.u_cmd[5] == pytest.approx(150.0) and not st_h.ctrl.saturated
    eta = np.array([0.0, 1, 1, 1, 1, 1])
    dead, st_d = _step(cfg, eta)
    assert dead.saturated[1] and st_d.ctrl.saturated
    np.testing.assert_array_equal(cfg.controller_params_for(eta).B_pinv,
                                  cfg.accommodation_for(eta)[0].B_pinv)
    assert cfg.controller_params_for(eta) is cfg.controller_params_for(eta.copy())  # cached
