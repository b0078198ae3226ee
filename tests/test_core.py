"""The pure control cycle: safety rules, estimator timing, determinism."""

import numpy as np
import pytest

from drivers.samples import DepthSample, DvlSample, InsSample
from uvd import core
from uvd.control.allocation import Allocator
from uvd.control.pdc import PDGains, PDState, pdc_step
from uvd.control.trajectory import setpoint
from uvd.estimation.navigation import NavConfig
from uvd.io.vehicle import load_vehicle
from uvd.model.thrusters import speed_from_thrust

VEHICLE = load_vehicle("jhu-rov")


def _samples(t_ns, depth=1.0, heading=0.0):
    return dict(ins=InsSample(t_ns=t_ns, roll=0.0, pitch=0.0, heading=heading,
                              omega_body=np.zeros(3)),
                dvl=DvlSample(t_ns=t_ns, velocity_body=np.zeros(3), bottom_lock=True),
                depth=DepthSample(t_ns=t_ns, depth_m=depth))


def _recording_estimator(log):
    def step(vs, u, params, st, dt):
        log.append((dt, u.copy()))
        return st + 1
    return core.EstimatorSpec("probe", step, None, 0)


def _cfg(controller_step=pdc_step, estimators=()):
    return core.CoreConfig(nav=NavConfig(ins_timeout_s=0.25),
                           controller=core.ControllerSpec("pdc", controller_step, PDGains(),
                                                          PDState()),
                           reference=setpoint([0.0, 0.0, 2.0, 0.0, 0.0, 0.5]),
                           allocator=Allocator.from_vehicle(VEHICLE),
                           k_thrust=VEHICLE.k_thrust, estimators=estimators)


def test_tracks_the_setpoint_direction_and_is_deterministic():
    cfg = _cfg()
    outs = []
    for _ in range(2):
        out, _ = core.step(cfg, core.CoreInputs(t_ns=0, **_samples(0)), core.core_init(cfg), 0.1)
        outs.append(out)
    a, b = outs
    assert a.status == "ok"
    np.testing.assert_array_equal(a.thrust_n, b.thrust_n)
    # vehicle at 1 m, reference at 2 m (z down): push down; heading error +0.5 rad: yaw positive
    assert a.u_cmd[2] > 0 and a.u_cmd[5] > 0
    np.testing.assert_allclose(VEHICLE.B @ a.thrust_n, a.u_cmd, atol=1e-9)


def test_invalid_navigation_means_zero_thrust_and_no_estimation():
    log = []
    cfg = _cfg(estimators=(_recording_estimator(log),))
    out, st = core.step(cfg, core.CoreInputs(t_ns=0), core.core_init(cfg), 0.1)  # no samples
    assert out.status == "nav-invalid"
    assert not out.thrust_n.any() and log == [] and st.est == (0,)


def test_disarmed_means_zero_thrust_but_estimators_run():
    log = []
    cfg = _cfg(estimators=(_recording_estimator(log),))
    out, st = core.step(cfg, core.CoreInputs(t_ns=0, armed=False, **_samples(0)),
                        core.core_init(cfg), 0.1)
    assert out.status == "disarmed" and not out.thrust_n.any()
    assert st.est == (1,) and len(log) == 1


def test_non_finite_controller_output_never_reaches_the_thrusters():
    def broken(vs, ref, params, st, dt):
        return np.array([np.nan, 0, 0, 0, 0, 0]), "poisoned"

    cfg = _cfg(controller_step=broken)
    out, st = core.step(cfg, core.CoreInputs(t_ns=0, **_samples(0)), core.core_init(cfg), 0.1)
    assert out.status == "non-finite"
    assert np.all(out.thrust_n == 0.0) and st.ctrl != "poisoned"


def test_non_finite_sensor_input_is_not_used():
    cfg = _cfg()
    s = _samples(0)
    s["ins"] = InsSample(t_ns=0, roll=np.nan, pitch=0.0, heading=0.0, omega_body=np.zeros(3))
    out, _ = core.step(cfg, core.CoreInputs(t_ns=0, **s), core.core_init(cfg), 0.1)
    assert np.all(np.isfinite(out.thrust_n))
    assert out.status != "ok" or np.all(np.isfinite(out.nav.H))


@pytest.mark.parametrize("big", [1e38, 1e200, 1.7e308])
def test_finite_but_huge_inputs_never_raise_and_never_reach_the_thrusters(big):
    """Full AMBC with robust projection and 6-DOF AID (the loop benchmark's cycle) on sensor
    values and propeller speeds that are finite but absurd: the update overflows inside
    AID's and the projection's eigenvalue steps. Before those were guarded, 1e200 raised
    LinAlgError out of ``core.step``."""
    from uvd.bench.loop import ambc_aid_config

    cfg = ambc_aid_config()
    st = core.core_init(cfg)
    for k in range(6):
        t, s = 10**9 + k * 100_000_000, (-1) ** k
        inputs = core.CoreInputs(
            t_ns=t, ins=InsSample(t_ns=t, roll=s * big, pitch=big, heading=-big,
                                  omega_body=np.full(3, s * big)),
            dvl=DvlSample(t_ns=t, velocity_body=np.full(3, s * big), bottom_lock=True),
            depth=DepthSample(t_ns=t, depth_m=big), propeller_speed_rad_s=np.full(6, s * big))
        with np.errstate(all="ignore"):
            out, st = core.step(cfg, inputs, st, 0.1)
        assert np.all(np.isfinite(out.thrust_n))
        assert np.all(np.abs(out.thrust_n) <= cfg.allocator.max_thrust_n)


def test_estimators_see_the_real_gap_after_a_navigation_outage():
    log = []
    cfg = _cfg(estimators=(_recording_estimator(log),))
    st = core.core_init(cfg)
    t = 0
    for k in range(3):
        t = k * 100_000_000
        _, st = core.step(cfg, core.CoreInputs(t_ns=t, **_samples(t)), st, 0.1)
    for k in range(3, 30):  # 2.7 s with no samples: navigation goes invalid
        t = k * 100_000_000
        _, st = core.step(cfg, core.CoreInputs(t_ns=t), st, 0.1)
    n_before = len(log)
    t = 30 * 100_000_000
    _, st = core.step(cfg, core.CoreInputs(t_ns=t, **_samples(t)), st, 0.1)
    assert len(log) == n_before + 1
    assert log[-1][0] > 1.0  # the estimator is told the gap, not one period
    assert all(abs(dt - 0.1) < 1e-12 for dt, _ in log[1:3])


def test_applied_wrench_comes_from_propeller_speed_when_reported():
    log = []
    cfg = _cfg(estimators=(_recording_estimator(log),))
    f = np.array([30.0, 30.0, 0.0, 0.0, 0.0, 0.0])
    omega = speed_from_thrust(f, VEHICLE.k_thrust)
    out, _ = core.step(cfg, core.CoreInputs(t_ns=0, propeller_speed_rad_s=omega, **_samples(0)),
                       core.core_init(cfg), 0.1)
    np.testing.assert_allclose(log[0][1], VEHICLE.B @ f)
    np.testing.assert_allclose(out.u_applied, VEHICLE.B @ f)
