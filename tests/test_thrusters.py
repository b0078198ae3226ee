"""Thruster dynamics: saturation, propeller lag, reversal stiction (§5.3.4), f = kω|ω|; dead band
and asymmetry (off by default)."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

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


# dead band and asymmetry (off by default; ambc-6dof-unstable turns them on, §5.3.2)
_CMD = st.floats(min_value=-99.0, max_value=99.0, allow_nan=False)


@given(cmd=_CMD, band=st.floats(min_value=0.1, max_value=30.0))
def test_dead_band_turns_nothing_below_it_and_the_command_above(cmd, band):
    b = bank(ThrusterEffects(lag=False, stiction=False, saturation=False, dead_band_n=band))
    f = b.step(np.array([cmd, cmd]), 0.01)[0]
    if abs(cmd) < band:
        assert f == 0.0 and b.omega[0] == 0.0
    else:
        assert f == pytest.approx(cmd, rel=1e-12)


@given(cmd=st.floats(min_value=0.01, max_value=99.0), ratio=st.floats(min_value=0.2,
                                                                       max_value=2.0))
def test_reverse_thrust_is_ratio_times_forward_at_the_same_speed(cmd, ratio):
    b = bank(ThrusterEffects(lag=False, stiction=False, saturation=False, reverse_ratio=ratio))
    f = b.step(np.array([cmd, -cmd]), 0.01).copy()
    assert f[0] == pytest.approx(cmd, rel=1e-12)            # forward: the steady-state law
    assert f[1] == pytest.approx(-ratio * cmd, rel=1e-12)   # reverse: scaled
    assert b.omega[1] == pytest.approx(-b.omega[0], rel=1e-12)  # the speed does not show it


@given(cmds=st.lists(_CMD, min_size=1, max_size=30))
def test_new_effects_at_their_defaults_change_nothing(cmds):
    """dead_band_n = 0 and reverse_ratio = 1 reproduce the bank without them bit for bit, so
    every vehicle and experiment that does not ask for them is unchanged."""
    a = bank()
    b = bank(ThrusterEffects(dead_band_n=0.0, reverse_ratio=1.0))
    for c in cmds:
        fa = a.step(np.array([c, -c]), 0.01).copy()
        fb = b.step(np.array([c, -c]), 0.01)
        assert np.array_equal(fa, fb) and np.array_equal(a.omega, b.omega)


@pytest.mark.parametrize("kw", [{"dead_band_n": -1.0}, {"dead_band_n": float("nan")},
                                {"reverse_ratio": 0.0}, {"reverse_ratio": float("inf")}])
def test_bad_effect_settings_are_refused_by_name(kw):
    with pytest.raises(ValueError, match=next(iter(kw))):
        ThrusterEffects(**kw)
