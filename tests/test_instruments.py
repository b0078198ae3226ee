"""Simulated instruments: Table A.1 rates and noise, seeded determinism, DVLNAV drift."""

import math
from pathlib import Path

import numpy as np
import pytest

from drivers.samples import R_to_euler, euler_to_R
from sim_bridge.instruments.models import InstrumentConfig, Instruments
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
    from uvd.experiments.lockstep import lockstep_config
    from uvd.runtime.config import ConfigValidationError, SimInstrumentsSection, load_config

    root = Path(__file__).resolve().parents[1]
    assert instrument_config(SimInstrumentsSection()) == InstrumentConfig()
    declared = {f.name for f in dataclasses.fields(SimInstrumentsSection)}
    assert declared == {f.name for f in dataclasses.fields(InstrumentConfig)} - {"ins_offset_s"}
    assert lockstep_config(load_config(root / "config" / "sim.toml")).instruments == \
        InstrumentConfig()
    fast = lockstep_config(load_config(root / "config" / "sim-bluerov2.toml"), seed=3)
    assert (fast.instruments.ins_rate_hz, fast.instruments.dvl_rate_hz,
            fast.instruments.depth_rate_hz, fast.seed, fast.control_rate_hz) == \
        (50.0, 8.0, 10.0, 3, 50.0)
    bad = tmp_path / "bad.toml"
    bad.write_text((root / "config" / "sim.toml").read_text()
                   + "\n[simulation.instruments]\nins_rate_hz = 0\n")
    with pytest.raises(ConfigValidationError, match=r"simulation\.instruments\.ins_rate_hz: "
                                                    r"0\.0 is out of range"):
        load_config(bad)
