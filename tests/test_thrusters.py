"""Thruster dynamics: saturation, propeller lag, reversal stiction (§5.3.4), f = kω|ω|."""

import numpy as np
import pytest

from sim_bridge.thrusters import ThrusterBank, ThrusterEffects
from uvd.model.thrusters import ThrusterSpec, speed_from_thrust, thrust_from_speed, thruster_matrix


def bank(effects=None, n=2):
    effects = ThrusterEffects() if effects is None else effects
    specs = [ThrusterSpec(f"t{i}", (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), k_thrust=0.005,
                          max_thrust_n=100.0, time_constant_s=0.2, stiction_n=5.0)
             for i in range(n)]
    return ThrusterBank(specs, effects)


def test_steady_state_law_round_trip():
    f = np.array([-250.0, -1.0, 0.0, 3.0, 300.0])
    np.testing.assert_allclose(thrust_from_speed(speed_from_thrust(f, 0.005), 0.005), f)


def test_lag_is_first_order_with_the_time_constant():
    b = bank(ThrusterEffects(stiction=False, saturation=False))
    target = 50.0
    w_target = speed_from_thrust(target, 0.005)
    for _ in range(20):  # 0.2 s = one time constant
        b.step(np.full(2, target), 0.01)
    assert b.omega[0] == pytest.approx(w_target * (1 - np.exp(-1)), rel=1e-9)
    for _ in range(300):
        b.step(np.full(2, target), 0.01)
    assert b.thrust[0] == pytest.approx(target, rel=1e-6)


def test_saturation_clips_each_thruster():
    b = bank(ThrusterEffects(lag=False, stiction=False))
    assert b.step(np.array([500.0, -500.0]), 0.01) == pytest.approx([100.0, -100.0])


def test_reversal_stiction_holds_thrust_at_zero_until_5_newtons():
    b = bank(ThrusterEffects(lag=False))
    b.step(np.array([20.0, 20.0]), 0.01)
    assert b.thrust[0] == pytest.approx(20.0)
    for cmd in (-1.0, -3.0, -4.99):  # reversed but below the breakaway command
        assert b.step(np.array([cmd, cmd]), 0.01)[0] == 0.0
    assert b.step(np.array([-5.0, -5.0]), 0.01)[0] == pytest.approx(-5.0)
    assert b.step(np.array([-2.0, -2.0]), 0.01)[0] == pytest.approx(-2.0)  # same sign: no stick
    off = bank(ThrusterEffects(lag=False, stiction=False))
    off.step(np.array([20.0, 20.0]), 0.01)
    assert off.step(np.array([-3.0, -3.0]), 0.01)[0] == pytest.approx(-3.0)


def test_health_scales_thrust_and_nan_is_no_command():
    b = bank(ThrusterEffects(lag=False))
    b.health[1] = 0.0
    f = b.step(np.array([30.0, 30.0]), 0.01)
    assert f[0] == pytest.approx(30.0) and f[1] == 0.0
    assert np.all(np.isfinite(b.step(np.array([np.nan, np.inf]), 0.01)))


def test_thruster_matrix_columns_are_force_and_moment():
    s = ThrusterSpec("a", (1.0, 2.0, 0.0), (0.0, 0.0, 2.0))
    B = thruster_matrix([s])
    np.testing.assert_allclose(B[:, 0], [0, 0, 1, 2, -1, 0])
