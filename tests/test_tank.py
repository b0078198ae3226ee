"""The tank's options (sim_bridge/tank.py): each does exactly what it says, and off is off."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_bridge.instruments.models import InstrumentConfig, Instruments
from sim_bridge.plant import Plant
from sim_bridge.tank import (
    CommandShaper,
    TankEffects,
    TankInstruments,
    TankPlant,
    advance_speeds,
    buoyancy_wrench,
    tether_wrench,
)
from uvd.geometry import euler_to_R
from uvd.io.vehicle import load_vehicle
from uvd.model.dynamics import gravity_wrench

VEH = load_vehicle("jhu-rov")
angle = st.floats(-0.6, 0.6)


def _pose(roll, pitch, heading, p=(1.0, -2.0, 3.0)):
    H = np.eye(4)
    H[:3, :3] = euler_to_R(roll, pitch, heading)
    H[:3, 3] = p
    return H


@settings(max_examples=40, deadline=None)
@given(angle, angle, st.floats(-3.0, 3.0), angle, angle, angle)
def test_mounting_bias_rotates_the_attitude_by_exactly_the_bias(r, p, h, br, bp, bh):
    H = _pose(r, p, h)
    v = np.array([0.1, 0.0, 0.0, 0.02, -0.03, 0.05])
    R_b = euler_to_R(br, bp, bh)
    cfg = InstrumentConfig(noise=False)
    plain = Instruments(cfg, np.random.default_rng(0)).sample(0, H, v)[0]
    ins = TankInstruments(Instruments(cfg, np.random.default_rng(0)),
                          TankEffects(mounting_bias_rad=(br, bp, bh))).sample(0, H, v)[0]
    np.testing.assert_allclose(euler_to_R(ins.roll, ins.pitch, ins.heading),
                               euler_to_R(plain.roll, plain.pitch, plain.heading) @ R_b,
                               atol=1e-12)
    np.testing.assert_allclose(ins.omega_body, R_b.T @ plain.omega_body, atol=1e-15)


@pytest.mark.parametrize("n", [1, 2, 5])
def test_latency_delays_every_instrument_by_exactly_n_of_its_samples(n):
    cfg = InstrumentConfig(noise=False)
    plain = Instruments(cfg, np.random.default_rng(0))
    late = TankInstruments(Instruments(cfg, np.random.default_rng(0)),
                           TankEffects(latency_samples=(n, n, n)))
    got: list[list] = [[], [], []]
    want: list[list] = [[], [], []]
    for k in range(1, 301):  # 3 s at 100 Hz, the vehicle moving
        t_ns = k * 10_000_000
        H = _pose(0.01 * k / 30, -0.02 * k / 30, 0.05 * k / 30, p=(0.0, 0.0, 0.001 * k))
        v = np.array([0.001 * k, 0, 0, 0, 0, 0.0001 * k])
        for i, (a, b) in enumerate(zip(plain.sample(t_ns, H, v), late.sample(t_ns, H, v),
                                       strict=True)):
            assert (a is None) == (b is None)
            if a is not None:
                want[i].append(a)
                got[i].append(b)
    for w, g in zip(want, got, strict=True):
        assert len(w) > 2 * n
        for k, s in enumerate(g):
            src = w[max(0, k - n)]
            assert s.t_ns == w[k].t_ns  # stamped on arrival
            for f in ("roll", "pitch", "heading", "depth_m"):
                if hasattr(s, f):
                    assert getattr(s, f) == getattr(src, f)
            for f in ("omega_body", "velocity_body"):
                if hasattr(s, f):
                    assert np.array_equal(getattr(s, f), getattr(src, f))


def test_tether_pulls_toward_the_anchor_with_its_tension_at_its_attachment():
    e = TankEffects(tether_n=10.0, tether_anchor_m=(-3.0, 1.0, -2.0),
                    tether_attach_m=(-0.5, 0.0, -0.3))
    H = _pose(0.1, -0.2, 0.7)
    origin = np.array([1.0, -2.0, 3.0])
    w = tether_wrench(e, H, origin)
    R = H[:3, :3]
    assert np.linalg.norm(w[:3]) == pytest.approx(10.0)
    to_anchor = origin + np.array(e.tether_anchor_m) - (H[:3, 3] + R @ np.array(e.tether_attach_m))
    np.testing.assert_allclose(R @ w[:3], 10.0 * to_anchor / np.linalg.norm(to_anchor))
    np.testing.assert_allclose(w[3:], np.cross(e.tether_attach_m, w[:3]))


@settings(max_examples=30, deadline=None)
@given(angle, angle, st.floats(-3.0, 3.0), st.floats(-2.0, 2.0))
def test_buoyancy_lost_with_depth_is_a_change_of_g_and_b_in_2_44(r, p, h, dz):
    kappa, rb = 20.0, np.array([0.01, -0.02, -0.1])
    e = TankEffects(buoyancy_n_per_m=kappa, buoyancy_centre_m=tuple(rb))
    H = _pose(r, p, h, p=(0.0, 0.0, 1.0 + dz))
    dg = kappa * dz
    np.testing.assert_allclose(buoyancy_wrench(e, H, 1.0),
                               gravity_wrench(dg, dg * rb, H[:3, :3]), atol=1e-12)


def test_advance_speed_is_the_bodys_velocity_along_each_thruster_axis():
    pos = np.array([[-0.55, -0.35, 0.0], [0.5, 0.0, 0.0]])
    dirs = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    # surge 0.2 m/s and yaw rate 0.1 rad/s: the port thruster sees 0.2 + 0.1*0.35
    # pitch rate 0.1 rad/s: the bow vertical thruster (x 0.5) moves keel-up at -0.05 m/s
    np.testing.assert_allclose(advance_speeds(pos, dirs, np.array([0.2, 0, 0, 0, 0, 0.1])),
                               [0.2 + 0.035, 0.0])
    np.testing.assert_allclose(advance_speeds(pos, dirs, np.array([0, 0, 0, 0, 0.1, 0])),
                               [0.0, -0.05])


def test_advance_loss_takes_k_a_omega_u_a_off_each_thruster():
    v0 = np.array([0.3, 0.0, 0.1, 0.0, 0.0, 0.0])
    cmd = np.array([40.0, 40.0, 10.0, 30.0, 30.0, 30.0])
    ka = 0.5
    a = Plant(VEH, v0=v0)
    b = TankPlant(Plant(VEH, v0=v0), TankEffects(advance_loss=ka))
    a.step(cmd)
    b.step(cmd)
    omega = b.thrusters.omega
    assert np.array_equal(a.thrusters.omega, omega)
    ua = advance_speeds(b.positions, b.directions, v0)
    np.testing.assert_allclose(b.u - a.u, -VEH.B @ (ka * np.abs(omega) * ua), atol=1e-9)
    assert (b.u - a.u)[0] < 0  # moving forward costs forward thrust


def test_command_shaper_hysteresis_and_reversal_hold():
    sh = CommandShaper(TankEffects(hysteresis_n=(10.0, 2.0)), 1, 0.01)
    out = [sh(np.array([c]))[0] for c in (0, 6, 12, 8, 3, 1, 6, -11, -1.5)]
    assert out == [0, 0, 12, 8, 3, 0, 0, -11, 0]
    sh = CommandShaper(TankEffects(reversal_hold_s=0.03), 1, 0.01)
    out = [sh(np.array([c]))[0] for c in (5, 5, -5, -5, -5, -5, 5, 5, 5, 5, 5)]
    assert out == [5, 5, 0, 0, 0, -5, 0, 0, 0, 5, 5]


def test_wider_reversal_band_scales_the_stiction():
    p = TankPlant(Plant(VEH), TankEffects(reversal_band_scale=3.0))
    np.testing.assert_allclose(p.thrusters.stiction, 3.0 * np.array(
        [t.stiction_n for t in VEH.thrusters]))


def test_options_off_leave_a_lockstep_run_bit_identical():
    from uvd import core
    from uvd.control.pdc import PDGains, PDState, pdc_step
    from uvd.control.trajectory import reftraj1
    from uvd.experiments._control_runner import run_control

    spec = core.ControllerSpec("pdc", pdc_step, PDGains(kp=300.0, kd=100.0), PDState())
    a = run_control(VEH, spec, reftraj1(), 20.0, seed=3)
    b = run_control(VEH, spec, reftraj1(), 20.0, seed=3, tank=TankEffects())
    c = run_control(VEH, spec, reftraj1(), 20.0, seed=3,
                    tank=TankEffects(mounting_bias_rad=(0.0, math.radians(1.0), 0.0)))
    for k in ("eta_true", "eta_nav", "u_cmd", "u_applied", "thrust_cmd"):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k
    assert not np.array_equal(a.u_cmd, c.u_cmd)  # an option on changes the run


@pytest.mark.parametrize("bad", [dict(tether_n=-1.0), dict(reversal_band_scale=0.0),
                                 dict(hysteresis_n=(1.0, 2.0)), dict(latency_samples=(1, -1, 0)),
                                 dict(mounting_bias_rad=(0.0, math.nan, 0.0)),
                                 dict(latency_samples=(0.5, 0, 0))])
def test_bad_options_are_refused_by_name(bad):
    with pytest.raises(ValueError, match="TankEffects"):
        TankEffects(**bad)


def test_compiled_step_applies_the_tether_and_buoyancy_wrenches_of_the_reference_functions():
    e = TankEffects(tether_n=10.0, buoyancy_n_per_m=20.0)
    a = Plant(VEH)
    b = TankPlant(Plant(VEH), e)
    H = _pose(0.1, -0.15, 0.4, p=(0.3, -0.2, 0.7))
    a.H, b.plant.H = H.copy(), H.copy()
    cmd = np.array([20.0, -20.0, 10.0, 30.0, -30.0, 30.0])
    a.step(cmd)
    b.step(cmd)
    want = tether_wrench(e, H, np.zeros(3)) + buoyancy_wrench(e, H, 0.0)
    np.testing.assert_allclose(b.u - a.u, want, atol=1e-9)
    assert not np.array_equal(a.H, b.H)
