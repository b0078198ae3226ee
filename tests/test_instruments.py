"""Simulated instruments: Table A.1 rates and noise, seeded determinism, DVLNAV drift."""

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_bridge.instruments.models import InstrumentConfig, Instruments
from uvd.geometry import R_to_euler, euler_to_R, wrap_angle
from uvd.model.lie import make_H


def run(cfg, seconds=60.0, seed=0, v=None):
    v = np.array([0.2, 0.0, 0.0, 0.0, 0.0, 0.0]) if v is None else v
    ins = Instruments(cfg, np.random.default_rng(seed))
    H = make_H(euler_to_R(0.1, -0.05, 1.0), np.array([0.0, 0.0, 2.0]))
    out = {"ins": [], "dvl": [], "depth": []}
    for k in range(int(seconds * 100) + 1):
        a, b, c = ins.sample(k * 10_000_000, H, v)
        for key, s in zip(out, (a, b, c), strict=True):
            if s is not None:
                out[key].append(s)
    return out, ins


def test_rates_are_table_a1():
    out, _ = run(InstrumentConfig(), seconds=60.0)
    assert len(out["ins"]) == 601 and len(out["dvl"]) == 361 and len(out["depth"]) == 421


def test_noise_levels_are_table_a1():
    out, _ = run(InstrumentConfig(), seconds=600.0)
    heading = np.array([s.heading for s in out["ins"]])
    pitch = np.array([s.pitch for s in out["ins"]])
    rates = np.array([s.omega_body for s in out["ins"]])
    vel = np.array([s.velocity_body for s in out["dvl"]])
    depth = np.array([s.depth_m for s in out["depth"]])
    assert np.degrees(heading.std()) == pytest.approx(0.13, rel=0.1)
    assert np.degrees(pitch.std()) == pytest.approx(0.01, rel=0.1)
    assert np.degrees(rates.std(axis=0)) == pytest.approx([0.01] * 3, rel=0.1)
    assert vel.std(axis=0) == pytest.approx([0.003] * 3, rel=0.1)
    assert depth.mean() == pytest.approx(2.0, abs=1e-4)
    assert depth.std() == pytest.approx(0.00075, rel=0.1)


def test_noise_off_is_exact_and_seeded_runs_repeat():
    out, _ = run(InstrumentConfig(noise=False), seconds=2.0)
    s = out["ins"][0]
    assert (s.roll, s.pitch, s.heading) == pytest.approx((0.1, -0.05, 1.0), abs=1e-12)
    a, _ = run(InstrumentConfig(), seconds=2.0, seed=7)
    b, _ = run(InstrumentConfig(), seconds=2.0, seed=7)
    assert [x.heading for x in a["ins"]] == [x.heading for x in b["ins"]]


def test_dvlnav_drift_within_half_a_percent_of_distance():
    v = np.array([0.5, 0.0, 0.0, 0.0, 0.0, 0.0])
    _, ins = run(InstrumentConfig(), seconds=600.0, v=v, seed=3)
    travelled = 0.5 * 600.0
    heading = 1.0
    R = euler_to_R(0.1, -0.05, heading)
    true = R @ v[:3] * 600.0
    err = math.hypot(ins.dr_north - true[0], ins.dr_east - true[1])
    assert err <= 0.005 * travelled + 0.2  # scale error ≤ 0.5 % plus the sample-hold start-up


def test_euler_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(200):
        e = rng.uniform([-3, -1.5, -3], [3, 1.5, 3])
        np.testing.assert_allclose(R_to_euler(euler_to_R(*e)), e, atol=1e-9)


def test_simulation_instruments_section_is_instrument_config(tmp_path):
    """``[simulation.instruments]`` declares exactly InstrumentConfig's fields with the same
    defaults (Table A.1: the JHU ROV's instruments unless a configuration says otherwise);
    sim-bridge and lockstep build their instruments from it."""
    import dataclasses

    from sim_bridge.instruments.models import InstrumentConfig, instrument_config
    from uvd.lockstep import lockstep_config
    from uvd.runtime.config import ConfigValidationError, SimInstrumentsSection, load_config

    root = Path(__file__).resolve().parents[1]
    assert instrument_config(SimInstrumentsSection()) == InstrumentConfig()
    declared = {f.name for f in dataclasses.fields(SimInstrumentsSection)}
    assert declared == {f.name for f in dataclasses.fields(InstrumentConfig)} - {"ins_offset_s",
                                                                           "dvl_resolution_m_s"}
    assert lockstep_config(load_config(root / "config" / "sim.toml")).instruments == \
        InstrumentConfig(dvl_resolution_m_s=0.001)  # what PD0 carries, as sim-bridge sends
    fast = lockstep_config(load_config(root / "config" / "sim-bluerov2.toml"), seed=3)
    assert (fast.instruments.ins_rate_hz, fast.instruments.dvl_rate_hz,
            fast.instruments.depth_rate_hz, fast.seed, fast.control_rate_hz) == \
        (50.0, 8.0, 10.0, 3, 50.0)
    # the cycle on the INS frame (trigger = "ins") there, on the fixed schedule in sim.toml
    assert fast.ins_trigger and not lockstep_config(load_config(root / "config" / "sim.toml")
                                                    ).ins_trigger
    bad = tmp_path / "bad.toml"
    bad.write_text((root / "config" / "sim.toml").read_text()
                   + "\n[simulation.instruments]\nins_rate_hz = 0\n")
    with pytest.raises(ConfigValidationError, match=r"simulation\.instruments\.ins_rate_hz: "
                                                    r"0\.0 is out of range"):
        load_config(bad)


def _noise_per_frame(ins: Instruments, t_ns, epoch_ns=None, other_draws=None):
    """Sample a still vehicle at the times ``t_ns`` (the epoch set at ``epoch_ns``, on the
    first sample after it); {(instrument, frame since the epoch, its due time since the
    epoch in ms): noise}."""
    H = make_H(euler_to_R(0.0, 0.0, 0.5), np.array([0.0, 0.0, 2.0]))
    out = {}
    since = 0 if epoch_ns is None else epoch_ns
    for t in t_ns:
        if epoch_ns is not None and t >= epoch_ns and ins._before_epoch:
            ins.set_epoch(epoch_ns)
        a, b, c = ins.sample(t, H, np.zeros(6))
        if other_draws is not None:
            other_draws.normal(size=3)  # a CAN pressure sensor on the same generator
        for name, s, p, val in (("ins", a, ins._ins, lambda s: s.heading - 0.5),
                                ("dvl", b, ins._dvl, lambda s: s.velocity_body[1]),
                                ("depth", c, ins._depth, lambda s: s.depth_m - 2.0)):
            if s is not None and not ins._before_epoch:
                f = p.k - 1
                due_ms = round((p.offset_ns + f * 1e9 / p.rate_hz - since) / 1e6)
                out[(name, f, due_ms)] = val(s)
    return out


def test_frame_keyed_noise_and_times_are_the_same_on_frame_f_however_the_runs_differ():
    """The demo's comparison (sim_bridge.instruments.models, "Noise streams"): lockstep samples
    on a 10 ms grid from its epoch t = 0; sim-bridge also on a 10 ms grid, but held 2.31 s in
    its cradle first (before the epoch), with other draws on its generator, and a 70 ms stall
    that skips frames. Every frame after the epoch that both runs made falls due at the same
    time after the epoch and carries the same noise."""
    cfg = InstrumentConfig(ins_rate_hz=50.0, dvl_rate_hz=8.0, depth_rate_hz=10.0)
    lock = _noise_per_frame(Instruments(cfg, np.random.default_rng(1), frame_seed=4),
                            range(0, 3_000_000_000, 10_000_000))
    epoch = 2_310_000_000
    bridge_t = [t for t in range(0, 5_320_000_000, 10_000_000)
                if not 3_000_000_000 < t < 3_070_000_000]
    bridge = Instruments(cfg, np.random.default_rng(2), frame_seed=4)
    bridge.set_epoch(None)
    hil = _noise_per_frame(bridge, bridge_t, epoch, other_draws=bridge.rng)
    common = [k for k in lock if k in hil]
    assert len(common) > 0.95 * len(lock)  # all but the stall's and the INS's frame 0
    assert ("dvl", 0, 0) in common and ("ins", 0, 0) not in hil
    assert {n for n, _, _ in common} == {"ins", "dvl", "depth"}
    assert all(lock[k] == hil[k] for k in common)
    assert ("dvl", 1, 125) in common and ("depth", 3, 300) in common
    other = _noise_per_frame(Instruments(cfg, np.random.default_rng(1), frame_seed=5),
                             range(0, 3_000_000_000, 10_000_000))
    assert not any(other[k] == lock[k] for k in common)  # another seed, another draw


def test_one_stream_noise_is_drawn_as_before():
    """Without ``frame_seed`` every draw comes from the one generator in the order samples
    fall due — the thesis experiments' streams (docs/RESULTS.md) stay as they were."""
    cfg = InstrumentConfig()
    ins = Instruments(cfg, np.random.default_rng(9))
    H = make_H(np.eye(3), np.array([0.0, 0.0, 2.0]))
    a, b, c = ins.sample(0, H, np.zeros(6))
    ins.set_epoch(None)  # no effect on the one stream
    a2, _, _ = ins.sample(100_000_000, H, np.zeros(6))
    ref = np.random.default_rng(9)
    scale = 1.0 + ref.uniform(-1, 1) * cfg.xy_scale_error
    heading, roll, pitch = ref.normal(0, cfg.heading_std_rad), ref.normal(
        0, cfg.roll_pitch_std_rad), ref.normal(0, cfg.roll_pitch_std_rad)
    omega = ref.normal(0, cfg.rate_std_rad_s, 3)
    dvl = ref.normal(0, cfg.dvl_std_m_s, 3)
    depth = ref.normal(0, cfg.depth_std_m)
    heading2 = ref.normal(0, cfg.heading_std_rad)
    assert ins._dr_scale == scale
    assert a.heading == wrap_angle(heading)  # the one convention (uvd.geometry)
    assert (a.roll, a.pitch) == (roll, pitch)
    assert np.array_equal(a.omega_body, omega) and np.array_equal(b.velocity_body, dvl)
    assert c.depth_m == 2.0 + depth
    assert a2.heading == wrap_angle(heading2)


def test_dvl_resolution_rounds_as_the_pd0_wire_does():
    from drivers import pd0
    cfg = InstrumentConfig(dvl_resolution_m_s=pd0.VELOCITY_RESOLUTION_M_S)
    ins = Instruments(cfg, np.random.default_rng(0))
    H = make_H(np.eye(3), np.array([0.0, 0.0, 2.0]))
    v = np.array([0.1234567, -0.0456789, 0.0071234, 0.0, 0.0, 0.0])
    _, dvl, _ = ins.sample(0, H, v)
    ens = pd0.from_dvl_velocity(dvl.velocity_body + 1e-9, 2.0)  # what the bridge's wire carries
    wire = pd0.to_dvl_sample(pd0.decode_ensemble(pd0.encode_ensemble(ens)), 0).velocity_body
    assert np.allclose(dvl.velocity_body * 1000, np.round(dvl.velocity_body * 1000), atol=1e-9)
    assert np.allclose(wire, dvl.velocity_body, atol=1e-12)
    assert not np.allclose(dvl.velocity_body, v[:3], atol=1e-4)  # the noise is there


def test_lockstep_on_the_ins_frame_hands_same_instant_frames_to_the_next_cycle():
    """``[loop] trigger = "ins"``: the daemon's cycle runs on the INS frame as it arrives, and
    the DVL's and depth's frames sampled at that plant instant arrive after it (sim-bridge
    writes each on its own port after the INS frame) — the next cycle has them. The demo's
    lockstep run models that (``LockstepConfig.ins_trigger``); the experiments' default does
    not. BlueROV2 at 50 Hz: DVL at 8 Hz (frames at 0, 130, 250, 380, 500 ms on the 10 ms plant
    grid), depth at 10 Hz."""
    from dataclasses import replace

    from uvd.lockstep import Lockstep, LockstepConfig, lockstep_config
    from uvd.runtime.build import build_core, start_pose
    from uvd.runtime.config import load_config
    from uvd.runtime.cycle import unsupervised

    assert LockstepConfig().ins_trigger is False
    cfg = load_config(Path(__file__).resolve().parents[1] / "config" / "sim-bluerov2.toml")
    vehicle = cfg.load_vehicle()
    H0, v0 = start_pose(cfg)

    def stamps(ls_cfg):
        """{cycle time: (latest DVL stamp, latest depth stamp)} in ms, after each cycle."""
        sim = Lockstep(vehicle, unsupervised(build_core(cfg, vehicle)), ls_cfg, H0=H0, v0=v0)
        out = {}
        for k in range(30):
            sim.advance()
            nav = sim.state.nav
            out[20 * k] = (nav.dvl_t_ns // 1_000_000, nav.depth_t_ns // 1_000_000)
        return out

    on = lockstep_config(cfg, seed=0)
    assert on.ins_trigger
    late, same = stamps(on), stamps(replace(on, ins_trigger=False))
    # a DVL frame sampled between INS frames (130 ms) reaches the cycle after it in both
    assert same[120][0] == late[120][0] == 0 and same[140][0] == late[140][0] == 130
    # one sampled at an INS frame's instant (380 ms) reaches that cycle, or the next one
    assert same[380][0] == 380 and late[380][0] == 250 and late[400][0] == 380
    # depth (every 100 ms, always an INS instant) likewise, keeping its own stamp
    assert same[100][1] == 100 and late[100][1] == 0 and late[120][1] == 100
    assert [late[t][1] for t in range(120, 600, 100)] == [100, 200, 300, 400, 500]


@pytest.mark.parametrize("frame_seed", [None, 3])
def test_an_ins_frames_six_normals_in_one_draw_are_the_six_draws_bit_for_bit(frame_seed):
    """``Instruments._ins_noise`` draws heading, roll, pitch and ω in one
    ``standard_normal(6)`` (scaled); the twin below draws them one ``normal(0, s)`` at a time,
    as before. Every sample of 20 s on a turning, moving pose is the same to the bit."""
    cfg = InstrumentConfig(ins_rate_hz=50.0)
    fast = Instruments(cfg, np.random.default_rng(5), frame_seed=frame_seed)
    slow = Instruments(cfg, np.random.default_rng(5), frame_seed=frame_seed)
    assert fast._ins_stds is not None
    slow._ins_stds = None  # the per-draw path (also a zero std's)
    for k in range(2001):
        t = k * 0.01
        H = make_H(euler_to_R(0.3 * math.sin(t), -0.2 * t, 3.0 * t),
                   np.array([0.1 * t, 0.0, 2.0]))
        v = np.array([0.2, 0.0, 0.01, 0.01 * math.cos(t), -0.2, 3.0])
        for a, b in zip(fast.sample(k * 10_000_000, H, v), slow.sample(k * 10_000_000, H, v),
                        strict=True):
            assert (a is None) == (b is None)
            if a is not None:
                for name in a.__slots__:
                    assert np.asarray(getattr(a, name)).tobytes() == \
                        np.asarray(getattr(b, name)).tobytes(), (k, name)
    assert (fast.dr_north, fast.dr_east) == (slow.dr_north, slow.dr_east)
    # numpy's normal(0, s) is 0 + s·z: a z of −0.0 gives +0.0, and so does the scaled draw
    z = np.array([-0.0, 1.0])
    z *= np.array([1e-3, 1e-3])
    z += 0.0
    assert not np.signbit(z[0]) and np.signbit(0.0 + 1e-3 * -0.0) == np.signbit(z[0])


def test_a_zero_std_keeps_the_per_draw_path():
    """A zero std draws nothing for that value (the stream of the others as before)."""
    assert Instruments(InstrumentConfig(heading_std_rad=0.0),
                       np.random.default_rng(0))._ins_stds is None
    assert Instruments(InstrumentConfig(noise=False), np.random.default_rng(0))._ins_stds is None


def _period(k: int, n: int = 10, dt: float = 0.01):
    """The plant's trace over period k (n steps of dt): a pose turning through ±π in heading,
    rolling and pitching, moving and sinking."""
    H = np.empty((n, 4, 4))
    v = np.empty((n, 6))
    for i in range(n):
        t = (k * n + i + 1) * dt
        H[i] = make_H(euler_to_R(0.4 * math.sin(0.7 * t), 0.3 * math.cos(0.5 * t), 0.9 * t),
                      np.array([0.3 * t, -0.1 * t, 2.0 + 0.5 * math.sin(0.2 * t)]))
        v[i] = (0.3 + 0.1 * math.sin(t), -0.1, 0.05 * math.cos(0.2 * t), 0.2 * math.cos(t),
                -0.1 * math.sin(0.5 * t), 0.9)
    return H, v


@pytest.mark.parametrize("cfg", [
    InstrumentConfig(),
    InstrumentConfig(ins_rate_hz=7.0, dvl_rate_hz=5.5, depth_rate_hz=13.0, ins_offset_s=0.03,
                     dvl_resolution_m_s=0.001),
    InstrumentConfig(noise=False),
    InstrumentConfig(heading_std_rad=0.0, rate_std_rad_s=0.0),
    InstrumentConfig(dvl_std_m_s=0.0, depth_std_m=0.0, roll_pitch_std_rad=0.0,
                     ins_rate_hz=25.0),
    # DVL samples before the first INS frame: DVLNAV rotates by the true attitude
    InstrumentConfig(ins_rate_hz=5.0, ins_offset_s=0.15, dvl_rate_hz=20.0),
], ids=["table-a1", "odd-rates-offset-resolution", "no-noise", "zero-heading-rate-std",
        "zero-dvl-depth-rp-std", "dvl-before-the-first-ins"])
def test_a_period_sampled_in_one_compiled_walk_is_the_samples_one_at_a_time_bit_for_bit(cfg):
    """``sample_trace`` (lockstep's compiled walk over a control period) against
    ``sample_steps`` (``sample`` at each due step): over 90 s of a vehicle turning through
    ±π, every newest sample, field by field to the bit, the dead reckoning, the schedules and
    the noise stream's state after each period are the same."""
    walk = Instruments(cfg, np.random.default_rng(11))
    steps = Instruments(cfg, np.random.default_rng(11))
    assert walk.can_sample_trace
    H0, v0 = _period(-1)
    for inst in (walk, steps):  # primed as Lockstep primes them
        inst.sample(0, H0[-1], v0[-1])
    made = np.zeros(3, dtype=int)
    for k in range(900):
        H, v = _period(k)
        t0 = k * 100_000_000
        a = walk.sample_trace(t0, 10_000_000, H, v)
        b = steps.sample_steps(t0, 10_000_000, H, v)
        for j, (x, y) in enumerate(zip(a, b, strict=True)):
            assert (x is None) == (y is None), (k, j)
            if x is not None:
                made[j] += 1
                assert type(x) is type(y)
                for name in x.__slots__:
                    assert np.asarray(getattr(x, name)).tobytes() == \
                        np.asarray(getattr(y, name)).tobytes(), (k, j, name)
                    assert type(getattr(x, name)) is type(getattr(y, name)), (k, j, name)
        assert (walk.dr_north, walk.dr_east) == (steps.dr_north, steps.dr_east), k
        assert {type(x) for x in (walk.dr_north, walk.dr_east, steps.dr_north,
                                  steps.dr_east)} == {float}, k  # the same type either way
        for p, q in ((walk._ins, steps._ins), (walk._dvl, steps._dvl),
                     (walk._depth, steps._depth)):
            assert (p.k, p.next_ns) == (q.k, q.next_ns), k
        assert walk._last_dr_ns == steps._last_dr_ns
        assert walk.rng.bit_generator.state == steps.rng.bit_generator.state, k
    rates = (cfg.ins_rate_hz, cfg.dvl_rate_hz, cfg.depth_rate_hz)
    # a sample of each instrument in (nearly) every period its rate gives one
    assert all(m >= min(900, 90 * r) - 1 for m, r in zip(made, rates, strict=True)), made
    assert walk.dr_north != 0.0 and walk.dr_east != 0.0


def test_with_a_fault_or_frame_keyed_noise_lockstep_samples_one_at_a_time():
    from sim_bridge.instruments.faults import FaultyInstruments, SensorFaults
    faults = SensorFaults(clock=lambda: 0)
    inst = FaultyInstruments(InstrumentConfig(), np.random.default_rng(0), faults)
    assert inst.can_sample_trace
    faults.set("dvl", "stuck")
    assert not inst.can_sample_trace
    faults.set("dvl", "ok")
    assert inst.can_sample_trace
    assert not Instruments(InstrumentConfig(), np.random.default_rng(0),
                           frame_seed=4).can_sample_trace



def test_lockstep_samples_instruments_of_another_class_through_their_own_sample():
    """A wrapper that changes the samples and hands everything else to the instruments inside
    (``__getattr__``, as :class:`sim_bridge.tank.TankInstruments`) is sampled through its own
    ``sample``: neither the compiled walk nor ``sample_steps`` of the instruments inside may
    bypass it, though it declares nothing. Its first period's samples are the plain run's with
    its change, the noise bit for bit."""
    from dataclasses import replace

    from uvd.lockstep import Lockstep, LockstepConfig
    from uvd.runtime.build import build_core, start_pose
    from uvd.runtime.config import load_config
    from uvd.runtime.cycle import unsupervised

    class OneMetreDeeper:
        def __init__(self, inner):
            self.inner = inner

        def __getattr__(self, name):
            return getattr(self.inner, name)

        def sample(self, t_ns, H, v):
            ins, dvl, depth = self.inner.sample(t_ns, H, v)
            return ins, dvl, (None if depth is None
                              else replace(depth, depth_m=depth.depth_m + 1.0))

    cfg = load_config(Path(__file__).resolve().parents[1] / "config" / "sim.toml")
    vehicle = cfg.load_vehicle()
    H0, v0 = start_pose(cfg)

    def sim():
        return Lockstep(vehicle, unsupervised(build_core(cfg, vehicle)),
                        LockstepConfig(control_rate_hz=cfg.loop.rate_hz, seed=5), H0=H0, v0=v0)

    plain, wrapped = sim(), sim()
    assert plain.instruments.can_sample_trace  # the plain run takes the compiled walk
    wrapped.instruments = OneMetreDeeper(wrapped.instruments)
    # the first period (0.1 s) samples no depth (7 Hz): the second cycle's inputs, and so
    # both runs' second period, are the same; that period samples all three
    for _ in range(2):
        plain.advance()
        wrapped.advance()
    (ins_a, dvl_a, depth_a), (ins_b, dvl_b, depth_b) = plain._pending, wrapped._pending
    assert None not in plain._pending and None not in wrapped._pending
    assert depth_b.depth_m == depth_a.depth_m + 1.0 and depth_b.t_ns == depth_a.t_ns
    assert (ins_b.t_ns, ins_b.roll, ins_b.pitch, ins_b.heading) == \
        (ins_a.t_ns, ins_a.roll, ins_a.pitch, ins_a.heading)
    assert np.array_equal(dvl_b.velocity_body, dvl_a.velocity_body)


@settings(max_examples=400, deadline=None)
@given(st.one_of(
    st.floats(allow_nan=False, allow_infinity=False),
    st.floats(-50.0, 50.0),
    # the halfway points (k + ½)·2π and their neighbours: the even multiple's side
    st.builds(lambda k, d: float(np.nextafter((k + 0.5) * 2.0 * math.pi, d)),
              st.integers(-40, 40), st.sampled_from([-math.inf, 0.0, math.inf])),
    st.builds(lambda k: (k + 0.5) * 2.0 * math.pi, st.integers(-40, 40))))
def test_the_compiled_walks_wrap_is_uvd_geometrys_wrap_angle(a):
    from sim_bridge.instruments._kernels import _remainder, _wrap_angle
    assert _remainder(a, 2.0 * math.pi) == math.remainder(a, 2.0 * math.pi)
    assert np.float64(_wrap_angle(a)).tobytes() == np.float64(wrap_angle(a)).tobytes()


def test_the_compiled_walks_wrap_of_no_angle_is_nan():
    from sim_bridge.instruments._kernels import _wrap_angle
    assert all(math.isnan(_wrap_angle(x)) for x in (math.nan, math.inf, -math.inf))
