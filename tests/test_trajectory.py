"""Reference trajectories: Table 5.1 values, analytic derivatives vs finite differences, the
desired state (H_d, v_d, v̇_d) of §5.2.4.1, sequences with a C² blend, the quasi-static step-1
trajectory (§5.3.5)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uvd.control.trajectory import (
    CosineTerm,
    CosineTrajectory,
    SequenceTrajectory,
    pitch_only,
    quasi_static,
    reftraj1,
    reftraj2,
    setpoint,
)
from uvd.geometry import euler_to_R
from uvd.model.lie import hat6, inv_H

DEG = math.pi / 180

times = st.floats(min_value=0.0, max_value=3000.0, allow_nan=False)


def _fd(f, t, h=1e-4):
    return (f(t + h) - f(t - h)) / (2 * h)


def test_reftraj1_is_table_5_1():
    tr = reftraj1(center=(0, 0, 0, 0, 0, 0))
    expect = [(0.50, 0.242), (0.50, 0.210), (0.30, 0.185), (6.9 * DEG, 0.5), (8.6 * DEG, 0.6),
              (135 * DEG, 0.210)]
    for k, (amp, w) in enumerate(expect):
        (term,) = tr.terms[k]
        assert term.amplitude == pytest.approx(amp)
        assert term.frequency_rad_s == pytest.approx(w)
    eta0, d1, _ = tr.dof(0.0)
    np.testing.assert_allclose(eta0, [a for a, _ in expect])
    np.testing.assert_allclose(d1, 0.0, atol=1e-15)
    # half a period of x later, x = -0.5 m
    eta, _, _ = tr.dof(math.pi / 0.242)
    assert eta[0] == pytest.approx(-0.5)
    assert tr.at(0.0).open_loop_wrench is None and tr.at(0.0).closed_loop is None


def test_reftraj2_is_table_5_1_with_open_loop_torques():
    tr = reftraj2(center=(0, 0, 0, 0, 0, 0))
    expect = {0: (0.50, 0.185), 1: (0.50, 0.286), 2: (0.30, 0.242), 5: (135 * DEG, 0.0824)}
    for k, (amp, w) in expect.items():
        (term,) = tr.terms[k]
        assert (term.amplitude, term.frequency_rad_s) == pytest.approx((amp, w))
    assert tr.terms[3] == () and tr.terms[4] == ()
    ref = tr.at(0.0)
    np.testing.assert_allclose(ref.open_loop_wrench, [0, 0, 0, 35.0, 30.0, 0])
    np.testing.assert_array_equal(ref.closed_loop, [True, True, True, False, False, True])
    # torque frequencies 0.55 and 0.65 rad/s: zero a quarter period later
    assert tr.open_loop_wrench(math.pi / 2 / 0.55)[3] == pytest.approx(0.0, abs=1e-12)
    assert tr.open_loop_wrench(math.pi / 2 / 0.65)[4] == pytest.approx(0.0, abs=1e-12)
    assert tr.open_loop_wrench(math.pi / 0.65)[4] == pytest.approx(-30.0)


def test_quasi_static_reads_the_thesis_frequencies_as_periods():
    tr = quasi_static(center=(1, 2, 3, 0, 0, 0.5))
    eta, d1, _ = tr.dof(0.0)
    np.testing.assert_allclose(eta, [1, 2, 3, 0.15, 0.2, 0.5])
    np.testing.assert_allclose(tr.dof(34.0)[0][4], 0.2)      # pitch period 34 s
    np.testing.assert_allclose(tr.dof(42.0)[0][3], 0.15)     # roll period 42 s
    np.testing.assert_allclose(tr.dof(17.0)[0][4], -0.2)
    # slow: peak angular rate 0.2·2π/34 < 0.04 rad/s
    rates = np.array([tr.dof(t)[1][3:5] for t in np.linspace(0, 100, 201)])
    assert np.abs(rates).max() < 0.04


def test_setpoint_and_pitch_only():
    ref = setpoint((1, 2, 3, 0.1, 0.2, 0.3)).at(12.0)
    np.testing.assert_allclose(ref.H[:3, :3], euler_to_R(0.1, 0.2, 0.3))
    np.testing.assert_allclose(ref.H[:3, 3], [1, 2, 3])
    np.testing.assert_allclose(ref.v, 0.0)
    np.testing.assert_allclose(ref.vdot, 0.0)
    tr = pitch_only(5 * DEG, 3 * DEG)
    pitches = np.array([tr.dof(t)[0][4] for t in np.linspace(0, 30, 301)])
    assert pitches.min() == pytest.approx(2 * DEG, abs=1e-3)
    assert pitches.max() == pytest.approx(8 * DEG, abs=1e-6)


@settings(max_examples=40, deadline=None)
@given(t=times)
def test_dof_derivatives_match_finite_differences(t):
    tr = reftraj1()
    _, d1, d2 = tr.dof(t)
    np.testing.assert_allclose(d1, _fd(lambda s: tr.dof(s)[0], t), atol=1e-7)
    np.testing.assert_allclose(d2, _fd(lambda s: tr.dof(s)[1], t), atol=1e-7)


@settings(max_examples=40, deadline=None)
@given(t=times)
def test_desired_velocity_is_the_body_velocity_of_H_d(t):
    """Ḣ_d = H_d v̂_d (2.30) and v̇_d = d/dt v_d, by central differences."""
    tr = reftraj1()
    ref = tr.at(t)
    Hdot = _fd(lambda s: tr.at(s).H, t)
    np.testing.assert_allclose(inv_H(ref.H) @ Hdot, hat6(ref.v), atol=1e-7)
    np.testing.assert_allclose(ref.vdot, _fd(lambda s: tr.at(s).v, t), atol=1e-7)


@settings(max_examples=30, deadline=None)
@given(amps=st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6),
       ws=st.lists(st.floats(0.01, 2.0), min_size=6, max_size=6),
       phs=st.lists(st.floats(-3.0, 3.0), min_size=6, max_size=6), t=times)
def test_any_cosine_trajectory_is_consistent(amps, ws, phs, t):
    """For any amplitudes (|roll|, |pitch| ≤ 1 rad, away from the Euler singularity), the
    desired velocity and acceleration are the derivatives of the desired pose."""
    terms = tuple((CosineTerm(a, w, p),) for a, w, p in zip(amps, ws, phs, strict=True))
    tr = CosineTrajectory(center=(0, 0, 1, 0, 0, 0), terms=terms)
    ref = tr.at(t)
    Hdot = _fd(lambda s: tr.at(s).H, t, 1e-5)
    np.testing.assert_allclose(inv_H(ref.H) @ Hdot, hat6(ref.v), atol=2e-6)
    np.testing.assert_allclose(ref.vdot, _fd(lambda s: tr.at(s).v, t, 1e-5), atol=2e-6)


def test_sequence_switches_with_a_c2_blend():
    a = quasi_static()
    b = reftraj1()
    seq = SequenceTrajectory(segments=((100.0, a), (float("inf"), b)), blend_s=30.0)
    # before the switch it is a, after the blend it is b on its own clock
    np.testing.assert_allclose(seq.dof(50.0)[0], a.dof(50.0)[0])
    for k in range(3):
        np.testing.assert_allclose(seq.dof(140.0)[k], b.dof(40.0)[k])
    # continuity of η, η̇, η̈ across the switch and the end of the blend
    for t0 in (100.0, 130.0):
        lo, hi = seq.dof(t0 - 1e-7), seq.dof(t0 + 1e-7)
        for k in range(3):
            np.testing.assert_allclose(lo[k], hi[k], atol=1e-5)
    # inside the blend the derivatives are still the derivatives
    for t in (101.0, 115.0, 129.0):
        _, d1, d2 = seq.dof(t)
        np.testing.assert_allclose(d1, _fd(lambda s: seq.dof(s)[0], t), atol=1e-6)
        np.testing.assert_allclose(d2, _fd(lambda s: seq.dof(s)[1], t), atol=1e-6)
    assert seq.segment_at(99.0) == 0 and seq.segment_at(101.0) == 1


def test_bad_trajectories_are_rejected():
    with pytest.raises(ValueError):
        CosineTrajectory(center=(0, 0, 0))
    with pytest.raises(ValueError):
        SequenceTrajectory(segments=())
