"""Propeller-lag compensation (uvd.control.allocation.lag_compensate) against the plant's own
thruster model, its saturation, its fall-backs, and its use by the core."""

import dataclasses
import math

import numpy as np
import pytest

from drivers.samples import DepthSample, DvlSample, InsSample
from sim_bridge.thrusters import ThrusterBank, ThrusterEffects
from uvd import core
from uvd.control.allocation import Allocator, allocate, lag_compensate
from uvd.control.pdc import PDGains, PDState, pdc_step
from uvd.control.trajectory import setpoint
from uvd.estimation.navigation import NavConfig
from uvd.io.vehicle import load_vehicle

VEH = load_vehicle("jhu-rov")
ALLOC = Allocator.from_vehicle(VEH)
DT = 0.1
ALPHA = -math.expm1(-DT / VEH.thrusters[0].time_constant_s)


def _bank(omega0, stiction=False):
    bank = ThrusterBank(VEH.thrusters, ThrusterEffects(lag=True, stiction=stiction,
                                                       saturation=True))
    bank.omega[:] = omega0
    return bank


def _hold(bank, cmd, substeps):
    for _ in range(substeps):
        thrust = bank.step(cmd, DT / substeps)
    return thrust.copy()


def test_allocator_takes_tau_from_the_vehicle_file():
    np.testing.assert_array_equal(ALLOC.time_constant_s,
                                  [t.time_constant_s for t in VEH.thrusters])
    assert ALLOC.time_constant_s[0] == 0.15


@pytest.mark.parametrize("substeps", [1, 10, 100])
@pytest.mark.parametrize("seed", range(5))
def test_thrust_reaches_the_desired_value_after_one_period(seed, substeps):
    """The plant's lag model (exact discretisation, any plant rate): after the compensated
    command is held for one period every thruster produces f_des, to 1e-9 N."""
    rng = np.random.default_rng(seed)
    omega0 = rng.uniform(-120.0, 120.0, 6)
    f_now = ALLOC.k_thrust * omega0 * np.abs(omega0)
    f_des = np.clip(f_now + rng.uniform(-25.0, 25.0, 6), -290.0, 290.0)
    cmd, s = lag_compensate(ALLOC, f_des, omega0, DT)
    assert s == 1.0
    assert np.all(np.abs(cmd) <= ALLOC.max_thrust_n)
    thrust = _hold(_bank(omega0), cmd, substeps)
    np.testing.assert_allclose(thrust, f_des, rtol=0, atol=1e-9)
    # the same command without compensation falls short (the lag the fix removes)
    plain = _hold(_bank(omega0), f_des, substeps)
    assert np.abs(plain - f_des).max() > 1.0


def test_exact_with_stiction_on_when_there_is_no_reversal_and_after_one():
    omega0 = np.array([50.0, 60.0, -40.0, 30.0, 20.0, -10.0])
    f_des = ALLOC.k_thrust * omega0 * np.abs(omega0) * 1.2
    bank = _bank(omega0, stiction=True)
    bank._last_sign[:] = np.sign(omega0)
    cmd, _ = lag_compensate(ALLOC, f_des, omega0, DT)
    np.testing.assert_allclose(_hold(bank, cmd, 10), f_des, rtol=0, atol=1e-9)
    # a reversal: the propeller is stopped (ω = 0); a command above the 5 N stiction breaks it
    # free and the thrust reaches the (reversed) target in one period
    f_rev = -np.sign(f_des) * 3.0
    stopped = np.zeros(6)
    cmd, s = lag_compensate(ALLOC, f_rev, stopped, DT)
    assert s == 1.0 and np.all(np.abs(cmd) >= 5.0)
    bank.omega[:] = 0.0
    np.testing.assert_allclose(_hold(bank, cmd, 10), f_rev, rtol=0, atol=1e-9)


def test_saturation_is_respected_with_one_common_fraction():
    rng = np.random.default_rng(3)
    for _ in range(50):
        omega0 = rng.uniform(-250.0, 250.0, 6)
        f_des = rng.uniform(-300.0, 300.0, 6)
        cmd, s = lag_compensate(ALLOC, f_des, omega0, DT)
        assert np.all(np.abs(cmd) <= ALLOC.max_thrust_n)
        assert ALPHA * (1 - 1e-12) <= s <= 1.0
        # every propeller covers the same fraction s of the way to its target
        w_des = np.sign(f_des) * np.sqrt(np.abs(f_des) / ALLOC.k_thrust)
        thrust = _hold(_bank(omega0), cmd, 10)
        w_end = np.sign(thrust) * np.sqrt(np.abs(thrust) / ALLOC.k_thrust)
        np.testing.assert_allclose(w_end, omega0 + s * (w_des - omega0), rtol=0, atol=1e-6)
        if s < 1.0:  # limited by a thruster at its limit
            assert np.isclose(np.abs(cmd).max(), 300.0, rtol=1e-12)


def test_measured_speed_beyond_the_limit_is_clamped():
    omega0 = np.full(6, 400.0)  # a noisy reading above ω_max = 250 rad/s
    cmd, s = lag_compensate(ALLOC, np.full(6, 100.0), omega0, DT)
    assert np.all(np.isfinite(cmd)) and np.all(np.abs(cmd) <= 300.0) and 0 < s <= 1


@pytest.mark.parametrize("omega", [None, np.full(6, np.nan), np.r_[np.zeros(5), np.inf],
                                   np.zeros(5), np.zeros((2, 6))])
def test_missing_or_non_finite_speeds_fall_back_to_plain_allocation(omega):
    f_des = np.linspace(-50.0, 50.0, 6)
    cmd, s = lag_compensate(ALLOC, f_des, omega, DT)
    np.testing.assert_array_equal(cmd, f_des)
    assert math.isnan(s)


@pytest.mark.parametrize("dt", [0.0, -0.1, np.nan, np.inf])
def test_bad_period_or_non_finite_thrust_fall_back(dt):
    f_des = np.linspace(-50.0, 50.0, 6)
    cmd, s = lag_compensate(ALLOC, f_des, np.zeros(6), dt)
    np.testing.assert_array_equal(cmd, f_des)
    assert math.isnan(s)
    bad = f_des.copy()
    bad[2] = np.nan
    cmd, s = lag_compensate(ALLOC, bad, np.zeros(6), DT)
    assert math.isnan(s) and np.isnan(cmd[2])  # unchanged: the core's zero-thrust rule acts


def test_no_lag_declared_means_no_change():
    a0 = dataclasses.replace(ALLOC, time_constant_s=np.zeros(6))
    f_des = np.linspace(-50.0, 50.0, 6)
    cmd, s = lag_compensate(a0, f_des, np.full(6, 30.0), DT)
    np.testing.assert_allclose(cmd, f_des, rtol=1e-12, atol=1e-12)
    cmd, s = lag_compensate(dataclasses.replace(ALLOC, time_constant_s=None), f_des,
                            np.zeros(6), DT)
    np.testing.assert_array_equal(cmd, f_des)
    assert math.isnan(s)


# ------------------------------------------------------------------------------- in the core
def _samples(t_ns):
    return dict(ins=InsSample(t_ns=t_ns, roll=0.0, pitch=0.0, heading=0.0,
                              omega_body=np.zeros(3)),
                dvl=DvlSample(t_ns=t_ns, velocity_body=np.zeros(3), bottom_lock=True),
                depth=DepthSample(t_ns=t_ns, depth_m=1.0))


def _cfg(on: bool):
    return core.CoreConfig(nav=NavConfig(ins_timeout_s=0.25),
                           controller=core.ControllerSpec("pdc", pdc_step, PDGains(), PDState()),
                           reference=setpoint([0.0, 0.0, 1.1, 0.0, 0.0, 0.05]),
                           allocator=ALLOC, k_thrust=VEH.k_thrust, lag_compensation=on)


def test_core_sends_the_lead_command_and_reports_the_wrench_reached():
    omega = np.array([10.0, -10.0, 5.0, 20.0, 15.0, -5.0])
    inp = core.CoreInputs(t_ns=0, propeller_speed_rad_s=omega, **_samples(0))
    off, _ = core.step(_cfg(False), inp, core.core_init(_cfg(False)), DT)
    on, _ = core.step(_cfg(True), inp, core.core_init(_cfg(True)), DT)
    assert off.status == on.status == "ok" and math.isnan(off.lead_fraction)
    assert on.lead_fraction == 1.0
    np.testing.assert_allclose(on.u_cmd, off.u_cmd)  # the wrench asked for is the same
    f_des = allocate(ALLOC, off.u_cmd)[0]
    assert np.abs(on.thrust_n - f_des).max() > 1.0
    np.testing.assert_allclose(_hold(_bank(omega), on.thrust_n, 10), f_des, atol=1e-9)


@pytest.mark.parametrize("omega", [None, np.array([np.nan, 0, 0, 0, 0, 0])])
def test_core_without_usable_speeds_uses_plain_allocation(omega):
    inp = core.CoreInputs(t_ns=0, propeller_speed_rad_s=omega, **_samples(0))
    off, _ = core.step(_cfg(False), inp, core.core_init(_cfg(False)), DT)
    on, _ = core.step(_cfg(True), inp, core.core_init(_cfg(True)), DT)
    assert on.status == "ok"
    np.testing.assert_array_equal(on.thrust_n, off.thrust_n)
    assert math.isnan(on.lead_fraction)


def test_core_disarmed_or_invalid_navigation_is_zero_thrust_even_with_spinning_propellers():
    omega = np.full(6, 100.0)  # compensation would brake them with a reverse command
    cfg = _cfg(True)
    out, _ = core.step(cfg, core.CoreInputs(t_ns=0, armed=False, propeller_speed_rad_s=omega,
                                            **_samples(0)), core.core_init(cfg), DT)
    assert out.status == "disarmed" and not out.thrust_n.any()
    out, _ = core.step(cfg, core.CoreInputs(t_ns=0, propeller_speed_rad_s=omega),
                       core.core_init(cfg), DT)
    assert out.status == "nav-invalid" and not out.thrust_n.any()
