"""Navigation state (uvd.estimation.navigation): assembly, dead reckoning, validity, lost lock."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.samples import DepthSample, DvlSample, InsSample
from uvd.estimation.navigation import NavConfig, nav_init, nav_set_position, nav_step
from uvd.geometry import euler_to_R
from uvd.model.lie import J, exp_so3

MS = 1_000_000  # ns per ms


def _ins(t, roll=0.0, pitch=0.0, heading=0.0, omega=(0.0, 0.0, 0.0), rates_valid=True):
    return InsSample(t, roll, pitch, heading, np.array(omega, float), rates_valid=rates_valid)


def _dvl(t, v=(0.0, 0.0, 0.0), lock=True, beams=4):
    return DvlSample(t, np.array(v, float), lock, good_beams=beams)


def test_before_any_sample_everything_invalid_and_finite():
    cfg = NavConfig()
    st_, _ = nav_step(cfg, nav_init(cfg, 3.0, -2.0), 0, None, None, None)
    assert not st_.valid and not st_.ins_valid and not st_.dvl_valid and not st_.depth_valid
    assert math.isinf(st_.ins_age_s) and math.isinf(st_.dvl_age_s)
    assert np.all(np.isfinite(st_.H)) and np.all(np.isfinite(st_.v))
    assert st_.H[0, 3] == 3.0 and st_.H[1, 3] == -2.0


def test_pose_and_velocity_assembled_from_samples():
    cfg = NavConfig()
    mem = nav_init(cfg)
    roll, pitch, heading = 0.1, -0.2, 2.5
    s, mem = nav_step(cfg, mem, 5 * MS, _ins(5 * MS, roll, pitch, heading, (0.01, -0.02, 0.03)),
                      _dvl(4 * MS, (0.5, -0.1, 0.05)), DepthSample(3 * MS, 4.25))
    assert s.valid
    np.testing.assert_allclose(s.H[:3, :3], euler_to_R(roll, pitch, heading), atol=1e-15)
    np.testing.assert_allclose(s.v, [0.5, -0.1, 0.05, 0.01, -0.02, 0.03])
    assert s.H[2, 3] == 4.25
    assert s.dvl_age_s == pytest.approx(1e-3) and s.depth_age_s == pytest.approx(2e-3)
    np.testing.assert_array_equal(s.H[3], [0, 0, 0, 1])


def test_dead_reckoning_rotates_body_velocity_into_world():
    # heading 90° (east), 1 m/s forward for 10 s at 100 Hz → 10 m east, 0 north
    cfg = NavConfig()
    mem = nav_init(cfg, north_m=1.0, east_m=2.0)
    for k in range(1001):
        t = k * 10 * MS
        s, mem = nav_step(cfg, mem, t, _ins(t, heading=math.pi / 2), _dvl(t, (1.0, 0.0, 0.0)),
                          DepthSample(t, 1.0))
    assert s.H[0, 3] == pytest.approx(1.0, abs=1e-9)
    assert s.H[1, 3] == pytest.approx(12.0, abs=1e-9)


def test_dead_reckoning_trapezoid_between_slow_dvl_samples():
    # DVL at 6 Hz, nav at 100 Hz: the held velocity integrates over the gaps
    cfg = NavConfig()
    mem = nav_init(cfg)
    for k in range(601):
        t = k * 10 * MS
        dvl = _dvl(t, (0.3, 0.4, 0.0)) if k % 17 == 0 else None
        s, mem = nav_step(cfg, mem, t, _ins(t), dvl, DepthSample(t, 0.0))
    assert s.H[0, 3] == pytest.approx(0.3 * 6.0, rel=1e-9)
    assert s.H[1, 3] == pytest.approx(0.4 * 6.0, rel=1e-9)


def test_lost_bottom_lock_holds_then_invalidates_and_freezes():
    cfg = NavConfig(dvl_timeout_s=1.0)
    mem = nav_init(cfg)
    t = 0
    s, mem = nav_step(cfg, mem, t, _ins(t), _dvl(t, (1.0, 0.0, 0.0)), DepthSample(t, 0.0))
    positions = []
    for k in range(1, 301):  # 3 s at 100 Hz; lock lost from the first sample on
        t = k * 10 * MS
        s, mem = nav_step(cfg, mem, t, _ins(t), _dvl(t, (9.0, 9.0, 9.0), lock=False),
                          DepthSample(t, 0.0))
        positions.append((t, s.H[0, 3], s.dvl_valid, s.bottom_lock, s.valid))
    assert all(not lock for _, _, _, lock, _ in positions)
    held = [p for p in positions if p[0] <= 1000 * MS]
    after = [p for p in positions if p[0] > 1000 * MS]
    assert all(valid for _, _, valid, _, _ in held)
    assert not any(valid for _, _, valid, _, _ in after)
    assert not any(v for *_, v in after)
    # held velocity (not the unlocked 9 m/s) integrated for exactly the timeout, then frozen
    assert held[-1][1] == pytest.approx(1.0, abs=1e-9)
    assert {round(p[1], 12) for p in after} == {round(held[-1][1], 12)}
    np.testing.assert_allclose(s.v[:3], [1.0, 0.0, 0.0])  # finite, last locked value
    # lock regained: valid again, dead reckoning resumes from the frozen position
    t += 10 * MS
    s, mem = nav_step(cfg, mem, t, _ins(t), _dvl(t, (0.0, 2.0, 0.0)), DepthSample(t, 0.0))
    assert s.valid and s.bottom_lock
    t += 500 * MS
    s, mem = nav_step(cfg, mem, t, _ins(t), _dvl(t, (0.0, 2.0, 0.0)), DepthSample(t, 0.0))
    assert s.H[0, 3] == pytest.approx(1.0, abs=1e-9) and s.H[1, 3] == pytest.approx(1.0)


def test_too_few_good_beams_is_not_a_lock():
    cfg = NavConfig()
    mem = nav_init(cfg)
    s, mem = nav_step(cfg, mem, 0, _ins(0), _dvl(0, (1.0, 0, 0), beams=2), DepthSample(0, 0.0))
    assert not s.bottom_lock and not s.dvl_valid
    s, mem = nav_step(cfg, mem, 1, _ins(1), _dvl(1, (1.0, 0, 0), beams=3), DepthSample(1, 0.0))
    assert s.bottom_lock and s.dvl_valid


@pytest.mark.parametrize("source", ["ins", "dvl", "depth"])
def test_each_timeout(source):
    cfg = NavConfig(ins_timeout_s=0.1, dvl_timeout_s=1.0, depth_timeout_s=0.5)
    timeout = {"ins": 0.1, "dvl": 1.0, "depth": 0.5}[source]
    mem = nav_init(cfg)
    _, mem = nav_step(cfg, mem, 0, _ins(0), _dvl(0), DepthSample(0, 1.0))
    t_ok = int(timeout * 1e9)
    samples = {"ins": _ins(t_ok), "dvl": _dvl(t_ok), "depth": DepthSample(t_ok, 1.0)}
    samples[source] = None
    s, _ = nav_step(cfg, mem, t_ok, samples["ins"], samples["dvl"], samples["depth"])
    assert getattr(s, f"{source}_valid") and s.valid
    t_bad = t_ok + 1000
    samples = {"ins": _ins(t_bad), "dvl": _dvl(t_bad), "depth": DepthSample(t_bad, 1.0)}
    samples[source] = None
    s, _ = nav_step(cfg, mem, t_bad, samples["ins"], samples["dvl"], samples["depth"])
    assert not getattr(s, f"{source}_valid") and not s.valid
    others = {"ins", "dvl", "depth"} - {source}
    assert all(getattr(s, f"{o}_valid") for o in others)


def test_invalid_or_nonfinite_samples_ignored():
    cfg = NavConfig()
    mem = nav_init(cfg)
    s, mem = nav_step(cfg, mem, 0, _ins(0, heading=1.0), _dvl(0, (0.2, 0, 0)),
                      DepthSample(0, 2.0))
    bad_ins = InsSample(1, float("nan"), 0.0, 0.0, np.zeros(3))
    s, mem = nav_step(cfg, mem, 1, bad_ins, _dvl(1, (float("nan"), 0, 0)),
                      DepthSample(1, float("nan")))
    assert np.all(np.isfinite(s.H)) and np.all(np.isfinite(s.v))
    assert s.H[2, 3] == 2.0 and s.v[0] == 0.2
    s, mem = nav_step(cfg, mem, 2, None, None, DepthSample(2, 7.0, valid=False))
    assert s.H[2, 3] == 2.0


def test_rates_derived_from_attitude_when_ins_has_none():
    # constant body rate ω; ASCII INS gives attitude only (omega NaN, rates_valid False)
    cfg = NavConfig()
    mem = nav_init(cfg)
    w = np.array([0.05, -0.03, 0.2])
    R0 = euler_to_R(0.1, 0.05, 1.0)
    nan3 = (float("nan"),) * 3
    from uvd.geometry import R_to_euler
    for k in range(5):
        t = k * 100 * MS
        R = R0 @ exp_so3(w * (t * 1e-9))
        r, p, h = R_to_euler(R)
        s, mem = nav_step(cfg, mem, t, _ins(t, r, p, h, nan3, rates_valid=False),
                          _dvl(t), DepthSample(t, 0.0))
        assert s.rates_degraded
    np.testing.assert_allclose(s.v[3:], w, atol=1e-9)
    # measured rates come back: not degraded any more
    s, mem = nav_step(cfg, mem, 500 * MS, _ins(500 * MS, omega=(0.1, 0, 0)), None, None)
    assert not s.rates_degraded and s.v[3] == 0.1


def test_lever_arm_and_mount_rotation():
    # DVL rotated 45° about z and displaced; ν = R_mount v_dvl − ω × r
    Rm = exp_so3(np.array([0.0, 0.0, math.pi / 4]))
    r = np.array([0.5, -0.2, 0.3])
    cfg = NavConfig(dvl_mount_R=Rm, dvl_lever_arm_m=r)
    omega = np.array([0.1, -0.2, 0.3])
    v_dvl = np.array([1.0, 0.5, -0.1])
    s, _ = nav_step(cfg, nav_init(cfg), 0, _ins(0, omega=omega), _dvl(0, v_dvl),
                    DepthSample(0, 0.0))
    np.testing.assert_allclose(s.v[:3], Rm @ v_dvl - J(omega) @ r, atol=1e-15)


def test_bad_config_rejected_with_names():
    with pytest.raises(ValueError, match="dvl_mount_R"):
        NavConfig(dvl_mount_R=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="dvl_lever_arm_m"):
        NavConfig(dvl_lever_arm_m=np.array([0.0, float("nan"), 0.0]))
    with pytest.raises(ValueError, match="ins_timeout_s"):
        NavConfig(ins_timeout_s=0.0)


def test_memory_not_modified_and_steps_deterministic():
    cfg = NavConfig()
    mem0 = nav_init(cfg)
    s1, mem1 = nav_step(cfg, mem0, 0, _ins(0, 0.1), _dvl(0, (1, 0, 0)), DepthSample(0, 1.0))
    snap = copy.deepcopy(mem1)
    s2, _ = nav_step(cfg, mem1, 10 * MS, _ins(10 * MS, 0.2), _dvl(10 * MS), None)
    s2b, _ = nav_step(cfg, mem1, 10 * MS, _ins(10 * MS, 0.2), _dvl(10 * MS), None)
    for f in snap.__slots__:
        a, b = getattr(snap, f), getattr(mem1, f)
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
        else:
            assert a == b, f
    np.testing.assert_array_equal(s2.H, s2b.H)
    moved = nav_set_position(mem1, 5.0, 6.0)
    assert (moved.north_m, moved.east_m) == (5.0, 6.0) and mem1.north_m == 0.0


@settings(max_examples=200, deadline=None)
@given(st.floats(-1.5, 1.5), st.floats(-1.5, 1.5), st.floats(-3.14, 3.14),
       st.lists(st.floats(-3, 3), min_size=3, max_size=3))
def test_world_velocity_matches_attitude(roll, pitch, heading, v):
    """Δp/Δt of dead reckoning equals R ν for a constant attitude (any attitude)."""
    cfg = NavConfig()
    mem = nav_init(cfg)
    _, mem = nav_step(cfg, mem, 0, _ins(0, roll, pitch, heading), _dvl(0, v), DepthSample(0, 0))
    s, _ = nav_step(cfg, mem, 100 * MS, _ins(100 * MS, roll, pitch, heading), _dvl(100 * MS, v),
                    DepthSample(100 * MS, 0))
    vw = euler_to_R(roll, pitch, heading) @ np.array(v)
    assert s.H[0, 3] == pytest.approx(0.1 * vw[0], abs=1e-12)
    assert s.H[1, 3] == pytest.approx(0.1 * vw[1], abs=1e-12)


def test_dead_reckoning_does_not_drift_on_correlated_yaw_and_sway():
    """RefTraj1 drives heading and y at the same frequency, so yaw rate and sway velocity are
    correlated. With perfect instruments (INS 10 Hz, DVL 6 Hz) the dead-reckoned position must
    only lag, not drift: rotating a held body velocity by a newer attitude would drift ~0.5 m
    in 300 s here (R(ω × ν)·age has a non-zero mean)."""
    from sim_bridge.instruments.models import InstrumentConfig, Instruments
    from uvd.control.trajectory import reftraj1
    from uvd.estimation.navigation import NavConfig, nav_init, nav_step

    traj = reftraj1()
    inst = Instruments(InstrumentConfig(noise=False), np.random.default_rng(0))
    cfg = NavConfig(ins_timeout_s=0.25)
    ref0 = traj.at(0.0)
    inst.dr_north, inst.dr_east = ref0.H[0, 3], ref0.H[1, 3]
    mem = nav_init(cfg, north_m=ref0.H[0, 3], east_m=ref0.H[1, 3])
    newest = [None, None, None]
    worst = 0.0
    for k in range(300 * 100 + 1):  # 100 Hz truth, 10 Hz navigation, 300 s
        t_ns = k * 10_000_000
        ref = traj.at(k * 0.01)
        for i, s in enumerate(inst.sample(t_ns, ref.H, ref.v)):
            if s is not None:
                newest[i] = s
        if k % 10 == 0:
            state, mem = nav_step(cfg, mem, t_ns, *newest)
            newest = [None, None, None]
            if k > 100:
                worst = max(worst, float(np.linalg.norm(state.H[:2, 3] - ref.H[:2, 3])))
    assert state.valid
    assert worst < 0.03, worst  # lag of < one DVL period at ≤ 0.17 m/s, no drift


def _angle(Ra, Rb) -> float:
    c = 0.5 * (np.trace(Ra.T @ Rb) - 1.0)
    return math.acos(min(1.0, max(-1.0, c)))


def test_ins_carried_to_the_cycle_time_on_a_constant_rate_is_exact():
    cfg = NavConfig(ins_timeout_s=0.25)
    mem = nav_init(cfg)
    w = np.array([0.05, -0.03, 0.2])
    R0 = euler_to_R(0.1, 0.05, 1.0)
    from uvd.geometry import R_to_euler
    for k in range(3):
        t_ins = k * 100 * MS
        r, p, h = R_to_euler(R0 @ exp_so3(w * (t_ins * 1e-9)))
        s, mem = nav_step(cfg, mem, t_ins + 60 * MS, _ins(t_ins, r, p, h, w), _dvl(t_ins),
                          DepthSample(t_ins, 0.0))
        assert s.ins_age_s == pytest.approx(0.06)
        np.testing.assert_allclose(s.H[:3, :3], R0 @ exp_so3(w * (t_ins * 1e-9 + 0.06)),
                                   atol=1e-12)
        np.testing.assert_allclose(s.v[3:], w, atol=1e-12)
    # switched off: the sample as it is
    off = NavConfig(ins_timeout_s=0.25, propagate_ins=False)
    s, _ = nav_step(off, nav_init(off), 60 * MS, _ins(0, 0.1, 0.05, 1.0, w), None, None)
    np.testing.assert_allclose(s.H[:3, :3], euler_to_R(0.1, 0.05, 1.0), atol=1e-15)


def test_ins_carried_to_the_cycle_time_follows_a_smooth_trajectory():
    """RefTraj1's attitude and rates, INS at 10 Hz sampled 60 ms before each 10 Hz cycle (an
    INS not synchronised with the loop): carried forward, the attitude and rate at the cycle's
    time are several times closer to the truth than the sample's."""
    from uvd.control.trajectory import reftraj1
    traj = reftraj1()
    errs = {}
    for prop in (False, True):
        cfg = NavConfig(ins_timeout_s=0.25, propagate_ins=prop)
        mem = nav_init(cfg)
        worst_R = worst_w = 0.0
        for k in range(600):
            t_ins = k * 100 * MS + 40 * MS
            ref = traj.at(t_ins * 1e-9)
            from uvd.geometry import R_to_euler
            r, p, h = R_to_euler(ref.H[:3, :3])
            t = t_ins + 60 * MS
            s, mem = nav_step(cfg, mem, t, _ins(t_ins, r, p, h, ref.v[3:]), None, None)
            if k > 2:
                truth = traj.at(t * 1e-9)
                worst_R = max(worst_R, _angle(s.H[:3, :3], truth.H[:3, :3]))
                worst_w = max(worst_w, float(np.linalg.norm(s.v[3:] - truth.v[3:])))
        errs[prop] = (worst_R, worst_w)
    (R_off, w_off), (R_on, w_on) = errs[False], errs[True]
    assert R_off > 0.005  # the sample's 60 ms age is a visible error (0.3° and more)
    assert R_on < R_off / 5 and w_on < w_off / 5, errs


def test_ins_not_carried_with_derived_rates_or_across_a_gap():
    cfg = NavConfig(ins_timeout_s=0.25)
    nan3 = (float("nan"),) * 3
    # rates derived from attitude (ASCII INS): the attitude is the sample's, however old
    mem = nav_init(cfg)
    for k in range(3):
        t = k * 100 * MS
        s, mem = nav_step(cfg, mem, t + 80 * MS, _ins(t, heading=0.02 * k, omega=nan3,
                                                     rates_valid=False), None, None)
    assert s.rates_degraded
    np.testing.assert_allclose(s.H[:3, :3], euler_to_R(0.0, 0.0, 0.04), atol=1e-15)
    # a sample after a gap longer than the INS timeout: no slope from the stale one
    mem = nav_init(cfg)
    _, mem = nav_step(cfg, mem, 0, _ins(0, omega=(0.0, 0.0, 0.0)), None, None)
    s, mem = nav_step(cfg, mem, 1000 * MS + 50 * MS, _ins(1000 * MS, omega=(0.0, 0.0, 0.3)),
                      None, None)
    np.testing.assert_allclose(s.v[3:], [0.0, 0.0, 0.3], atol=1e-15)
    np.testing.assert_allclose(s.H[:3, :3], exp_so3(np.array([0.0, 0.0, 0.3 * 0.05])),
                               atol=1e-12)
    # a stale sample (older than the timeout) is invalid and not carried either
    s, _ = nav_step(cfg, mem, 1000 * MS + 300 * MS, None, None, None)
    assert not s.ins_valid
    np.testing.assert_allclose(s.v[3:], [0.0, 0.0, 0.3], atol=1e-15)
