"""Per-axis tuning: the rule k_p = m ω², k_d = 2ζωm (uvd.control.tuning, docs/tuning.md), the
sampled closed loop it predicts, ``uvd tune``, and three vehicles of very different scale —
the JHU ROV, the BlueROV2 Heavy, and an arbitrary one written here — so that nothing is tuned
to either built-in vehicle."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from uvd.cli import main
from uvd.commands.tune import tune_figures
from uvd.control.tuning import (
    closed_loop,
    delay_limited_bandwidth,
    pd_gains_for,
    scaled_adaptation_gains,
)
from uvd.io.vehicle import load_vehicle
from uvd.runtime.config import load_config

ROOT = Path(__file__).resolve().parents[1]

#: an arbitrary vehicle: 3 t, long and flat, slow thrusters; no relation to either built-in one
ARBITRARY = """
name = "arbitrary"
[parameters]
m = [3000.0, 4200.0, 5100.0, 900.0, 2600.0, 2900.0]
d = [-900.0, -4000.0, -6000.0, -1500.0, -5000.0, -3000.0]
g = 40.0
b = [0.0, 0.0, 2500.0]
[thruster_defaults]
k_thrust = 0.05
max_thrust_n = 3000.0
time_constant_s = 0.3
stiction_n = 20.0
[[thrusters]]
name = "a"
position_m = [-2.0, -0.8, 0.0]
direction = [1.0, 0.0, 0.0]
[[thrusters]]
name = "b"
position_m = [-2.0, 0.8, 0.0]
direction = [1.0, 0.0, 0.0]
[[thrusters]]
name = "c"
position_m = [1.5, 0.0, 0.2]
direction = [0.0, 1.0, 0.0]
[[thrusters]]
name = "d"
position_m = [-1.5, 0.0, 0.2]
direction = [0.0, 1.0, 0.0]
[[thrusters]]
name = "e"
position_m = [1.8, 0.0, 0.0]
direction = [0.0, 0.0, 1.0]
[[thrusters]]
name = "f"
position_m = [-1.2, -1.0, 0.0]
direction = [0.0, 0.0, 1.0]
[[thrusters]]
name = "g"
position_m = [-1.2, 1.0, 0.0]
direction = [0.0, 0.0, 1.0]
"""


def test_the_rule_scales_the_gains_with_each_axis_mass():
    m = np.array([20.0, 21.0, 32.0, 0.45, 0.37, 0.59])
    kp, kd = pd_gains_for(m, 3.0, 0.7)
    np.testing.assert_allclose(kp, 9.0 * m)
    np.testing.assert_allclose(kd, 4.2 * m)
    with pytest.raises(ValueError):
        pd_gains_for(m, 0.0, 0.7)


@pytest.mark.parametrize("m", [0.05, 0.4, 20.0, 1043.0, 5e5])
def test_sampled_loop_of_the_rule_is_the_same_at_every_scale(m):
    """Without drag and stiffness the sampled poles depend on ω, ζ, dt, τ and the delay only:
    an axis of 50 g m² and one of 500 t get the same damping from the rule."""
    kp, kd = pd_gains_for(np.array([m]), 3.0, 0.8)
    loop = closed_loop(m, kp[0], kd[0], dt=0.02, lag_s=0.05, delay_cycles=1)
    ref = closed_loop(1.0, 9.0, 4.8, dt=0.02, lag_s=0.05, delay_cycles=1)
    assert loop.pole_radius == pytest.approx(ref.pole_radius, abs=1e-9)
    assert loop.zeta_sampled == pytest.approx(ref.zeta_sampled, abs=1e-9)
    assert loop.omega_n == pytest.approx(3.0) and loop.zeta == pytest.approx(0.8)


def test_sampled_loop_matches_a_step_by_step_simulation():
    """The largest pole modulus is the decay rate of the sampled loop, simulated directly:
    the plant m ẍ = f, τ ḟ = u − f on a fine grid, u from a one-cycle-old sample, held."""
    m, kp, kd, dt, tau = 0.365, 20.0, 10.0, 0.02, 0.05   # the oscillating pitch
    loop = closed_loop(m, kp, kd, dt, tau, delay_cycles=1)
    sub = 200
    h = dt / sub
    x, v, f, u = 0.01, 0.0, 0.0, 0.0
    prev = (x, v)
    peaks = []
    for _ in range(400):
        u, prev = -(kp * prev[0] + kd * prev[1]), (x, v)
        for _step in range(sub):
            x, v, f = x + h * v, v + h * f / m, f + h * (u - f) / tau
        peaks.append(abs(x) + abs(v) / 10)
    rate = (max(peaks[300:]) / max(peaks[200:300])) ** (1.0 / 100)
    assert rate == pytest.approx(loop.pole_radius, abs=0.01)
    assert loop.zeta_sampled < 0.1              # the oscillation the issue saw
    assert closed_loop(m, kp, kd, dt, tau, delay_cycles=0).zeta_sampled > 0.25


def test_bluerov2_heavy_is_the_published_figures():
    v = load_vehicle("bluerov2-heavy")
    p = v.params
    rigid = np.array([13.5, 13.5, 13.5, 0.26, 0.23, 0.37])
    added = np.array([6.3567, 7.1206, 18.6863, 0.1858, 0.1348, 0.2215])
    np.testing.assert_allclose(np.diag(p.M), rigid + added, atol=6e-4)
    np.testing.assert_array_equal([p.D[i][i, i] for i in range(6)],
                                  [-141, -217, -190, -1.19, -0.47, -1.5])
    assert p.is_decoupled() and p.b[2] > 0
    assert v.n_thrusters == 8 and np.linalg.matrix_rank(v.B) == 6
    assert np.all(v.max_thrust_n == 40.0)


@pytest.mark.parametrize("base,vehicle,rate", [
    ("sim.toml", "jhu-rov", 10.0),
    ("sim-bluerov2.toml", "bluerov2-heavy", 50.0),
    ("sim.toml", "ARBITRARY", 20.0),
])
def test_the_rule_damps_every_axis_of_three_vehicles(tmp_path, base, vehicle, rate):
    if vehicle == "ARBITRARY":
        (tmp_path / "arbitrary.toml").write_text(ARBITRARY)
        vehicle = "arbitrary.toml"
    text = (ROOT / "config" / base).read_text()
    v = load_vehicle(vehicle if vehicle != "arbitrary.toml" else tmp_path / vehicle)
    ids = ", ".join(str(i + 1) for i in range(v.n_thrusters))
    text = text.replace(text[text.index("node_ids = ["):].split("]")[0] + "]",
                        f"node_ids = [{ids}]")
    text = text.replace(text[text.index("[vehicle]"):].split("\n")[1],
                        f'name = "{vehicle}"')
    text = text.replace(text[text.index("rate_hz = "):].split("\n")[0], f"rate_hz = {rate}")
    (tmp_path / "c.toml").write_text(text)
    cfg = load_config(tmp_path / "c.toml")
    f = tune_figures(cfg)
    lag = max(t.time_constant_s for t in v.thrusters)
    assert f["bandwidth"] == [pytest.approx(delay_limited_bandwidth(1 / rate, lag,
                                                                    f["delay_cycles"]))] * 6
    w = f["bandwidth"][0]
    for row in f["suggested"]:
        assert row["pole_radius"] < 1.0, row
        # an axis whose own hydrostatic stiffness is below m ω² gets the rule's damping; a
        # stiffer one (the JHU ROV's and this vehicle's roll) is an oscillator of its own,
        # faster than the delays allow the PD to damp fully (docs/tuning.md)
        soft = row["stiffness"] <= row["m"] * w ** 2
        assert row["zeta_sampled"] > (0.5 if soft else 0.2), row


def test_bluerov2_config_gains_are_the_rule_and_uvd_tune_prints_them(capsys, tmp_path):
    cfg = load_config(ROOT / "config" / "sim-bluerov2.toml")
    assert cfg.loop.trigger == "ins" and tune_figures(cfg)["delay_cycles"] == 0
    # the gains are the fixed schedule's bandwidth (a frame one period old), kept with the
    # synchronous trigger: they stay damped should the loop run on the fixed schedule
    f = tune_figures(cfg, omega=delay_limited_bandwidth(0.02, 0.05, 1))
    for c, s in zip(f["configured"], f["suggested"], strict=True):
        assert c["kp"] == pytest.approx(s["kp"], rel=2e-3)
        assert c["kd"] == pytest.approx(s["kd"], rel=2e-3)
    assert f["stable"]
    out_json = tmp_path / "tune.json"
    assert main(["tune", "--config", str(ROOT / "config" / "sim-bluerov2.toml"),
                 "--json", str(out_json)]) == 0
    out = capsys.readouterr().out
    assert "bluerov2-heavy at 50 Hz" in out and "frame age 0 period(s)" in out
    assert "ω [5, 5, 5, 5, 5, 5] rad/s" in out      # fresh frames: the rule allows more
    assert out_json.is_file()
    assert main(["tune", "--damping", "0.7", "0.7"]) == 2
    assert "--damping: one value or six, got 2" in capsys.readouterr().err
    for bad in ("inf", "nan", "0", "-1"):           # was a LinAlgError traceback for inf
        with pytest.raises(SystemExit) as exit_:
            main(["tune", "--damping", bad])
        assert exit_.value.code == 2
        assert f"argument --damping: '{bad}' is not a positive finite number" in \
            capsys.readouterr().err
    # finite but beyond the loop (session 33: both were a LinAlgError traceback too)
    for argv, words in ((["--bandwidth", "1e308"], "--bandwidth 1e+308 rad/s is at or above "
                         "the loop's Nyquist frequency (π × [loop] rate_hz 10 = 31.4 rad/s)"),
                        (["--bandwidth", "1", "2", "3", "4", "5", "40"], "--bandwidth 40 rad/s"),
                        (["--damping", "1e308"], "--damping 1e+308: its derivative gain 2ζωm "
                         "overflows")):
        assert main(["tune", *argv]) == 2
        assert words in capsys.readouterr().err
    assert main(["tune", "--bandwidth", "31", "--damping", "1e300"]) == 0  # below both: said
    assert "UNSTABLE" in capsys.readouterr().out


def test_adaptation_gains_keep_the_thesis_relative_rates_on_any_vehicle():
    jhu = load_vehicle("jhu-rov").params
    m_ref, d_ref = np.diag(jhu.M), [jhu.D[i][i, i] for i in range(6)]
    same = scaled_adaptation_gains(m_ref, d_ref, m_ref, d_ref)
    np.testing.assert_allclose(same["gamma_m"], 1000.0)     # the thesis's own, §5.3.2
    np.testing.assert_allclose(same["gamma_d"], 5000.0)
    brov = load_vehicle("bluerov2-heavy").params
    m = np.diag(brov.M)
    g = scaled_adaptation_gains(m, [brov.D[i][i, i] for i in range(6)], m_ref, d_ref)
    np.testing.assert_allclose(g["gamma_m"] / m, 1000.0 / m_ref)   # γ/m as on the JHU ROV
    np.testing.assert_allclose(g["mass_floor"], m / 10.0)
    assert np.all(g["mass_floor"] < m)


@pytest.mark.timeout(600)
def test_aid_sweep_prints_gain_factors_from_a_simulated_run(capsys, tmp_path):
    """``uvd tune --aid-sweep S``: §4.5's logarithmic sweep over a short lockstep run of the
    configuration (its INS silent halfway, so the record holds a failsafe and a re-arm); the
    chosen pair is the grid's best, the printed line pastes into [estimation]."""
    import json

    from uvd.experiments.aid_gains import convergence_error

    truth = load_vehicle("bluerov2-heavy").params
    assert convergence_error(truth.theta, truth) == 0.0
    out_json = tmp_path / "tune.json"
    assert main(["tune", "--config", str(ROOT / "config" / "sim-bluerov2.toml"),
                 "--aid-sweep", "3", "--json", str(out_json)]) == 0
    out = capsys.readouterr().out
    sw = json.loads(out_json.read_text())["aid_sweep"]
    # 150 cycles at 50 Hz less those the INS outage left without navigation
    # factors {1, 3, 10}² × {§4.6 per DOF, six bands of per-parameter rates}
    assert 100 < sw["cycles"] < 150 and len(sw["grid"]) == 63
    assert len(sw["excitation"]) == 16
    err = [np.inf if r["error"] is None else r["error"] for r in sw["grid"]]  # JSON: inf → null
    assert all(r["error"] is None for r in sw["grid"] if r["frozen"])  # a frozen AID: inf
    best = sw["grid"][int(np.argmin(err))]
    assert sw["best"] == [best["translation"], best["rotation"]]
    assert sw["best_band"] == best["band"] and sw["best_scale"] == best["scale"]
    assert (sw["error_at_1_1"] is None or np.isfinite(sw["best_error"])
            and sw["best_error"] <= sw["error_at_1_1"])
    line = next(x for x in out.splitlines() if x.startswith("gain_factors = "))
    assert json.loads(line.split("=", 1)[1]) == sw["best"]
    if sw["best_scale"] is not None:
        line = next(x for x in out.splitlines() if x.startswith("decoupled_gain_scale = "))
        assert np.allclose(json.loads(line.split("=", 1)[1]), sw["best_scale"], rtol=1e-3)
    assert "each DOF's scaled by its mass" in out
