"""uvd-fdc's CUSUM detector on estimate payloads, in this process (no session, no wall
clock): channels, baselines, the reference and its interval, the autocorrelation time, and
the lockstep watch's feed. The client between two Zenoh sessions is tests/test_fdc.py."""

from __future__ import annotations

import json
import math
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from uvd.fdc.detector import (
    CusumSettings,
    VehicleDetector,
    autocorrelation_time,
    channels_of,
    deviation,
)

MU = {"masses": [640, 800, 1050, 96, 146, 108], "drags": [-1250, -1420, -3080, -726, -781, -467],
      "g": 3.6, "b": [1.7, 3.1, 302.0]}
FAST = CusumSettings(warmup_s=10.0, baseline_s=100.0)


def _payload(t_s: float, rng, *, scale: dict | None = None, noise: float = 0.005) -> dict:
    p = {"t_ns": int(t_s * 1e9), "estimator": "aid6", "frozen": False}
    for key in ("masses", "drags", "b"):
        base = np.asarray(MU[key], float) * (scale or {}).get(key, 1.0)
        p[key] = (base * (1 + noise * rng.standard_normal(base.size))).tolist()
    p["g"] = MU["g"] * (scale or {}).get("g", 1.0) + 0.05 * rng.standard_normal()
    return p


def test_channels_are_masses_drag_magnitudes_g_and_b():
    ch = channels_of(_payload(0.0, np.random.default_rng(0), noise=0.0))
    assert set(ch) == {*(f"mass{i}" for i in range(1, 7)), *(f"drag{i}" for i in range(1, 7)),
                       "g", "b1", "b2", "b3"}
    assert ch["drag6"] == 467.0 and ch["mass1"] == 640.0


@pytest.mark.parametrize("seed", range(5))
def test_stationary_estimates_raise_no_alarm(seed):
    rng = np.random.default_rng(seed)
    det = VehicleDetector("v", FAST)
    alarms = [d for k in range(5000) for d in det.update(_payload(k * 1.0, rng))]
    assert det.ready and alarms == []


@pytest.mark.parametrize("key,factor,kind,channel", [
    ("drags", 1.5, "entanglement", "drag"), ("masses", 1.1, "flooding", "mass"),
    ("masses", 0.9, "lost-part", "mass"), ("g", 6.0, "buoyancy", "g")])
def test_a_step_is_found_quickly_with_its_kind(key, factor, kind, channel):
    rng = np.random.default_rng(1)
    det = VehicleDetector("v", FAST)
    for k in range(200):
        assert det.update(_payload(k * 1.0, rng)) == []
    found = []
    for k in range(200, 260):
        found += det.update(_payload(k * 1.0, rng, scale={key: factor}))
        if found:
            break
    assert len(found) == 1, found
    d = found[0]
    assert d.kind == kind and d.channel.startswith(channel) and d.confidence >= 1.0
    assert (d.t_ns * 1e-9 - 200) <= 3.0  # within three samples of the step
    assert det.update(_payload(261.0, rng, scale={key: factor})) == []  # reported once


def test_a_slow_wander_below_half_a_fault_never_alarms_and_a_fault_still_does():
    """AID's estimates wander over hours further than a baseline's spread (masses 2.6 % in a
    fault-free 4 h, docs/zenoh.md): a wander below δ/2 of every channel never accumulates,
    however long (here ±3 % and 0.5 % noise over 20 000 samples), while the fault the CUSUM
    is sized for is found within a few samples."""
    rng = np.random.default_rng(3)
    det = VehicleDetector("v", FAST)
    found = []
    for k in range(20_000):
        drift = 0.03 * math.sin(2 * math.pi * k / 7000.0) if k > 200 else 0.0  # ±3 %
        found += det.update(_payload(k * 1.0, rng, scale={"masses": 1 + drift,
                                                          "drags": 1 - drift}))
    assert det.ready and found == []
    for k in range(20_000, 20_020):
        found += det.update(_payload(k * 1.0, rng, scale={"masses": 1.1}))
    assert [d.kind for d in found] == ["flooding"] and found[0].t_ns * 1e-9 <= 20_005


@pytest.mark.parametrize("lag_s,alarms", [(1200.0, False), (math.inf, True)])
def test_a_steady_drift_is_followed_by_the_reference_and_a_step_is_still_found(lag_s, alarms):
    """AID's m̂₃ and m̂₄ rose steadily (4.8 and 3.7 % an hour) over 4 fault-free hours of the
    JHU ROV on RefTraj2 at twice Table A.1's noise, and a CUSUM against the first baseline
    alarmed on it (uvd.fdc.detector, "The reference"). Against the reference 20 minutes
    behind, a drift of 5 % an hour for 5.5 h (+28 %) raises nothing, while a mass step of 10 %
    on top of it is found within a few samples; against the first baseline
    (``reference_lag_s`` infinite) the same drift alarms."""
    rng = np.random.default_rng(8)
    det = VehicleDetector("v", CusumSettings(warmup_s=10.0, baseline_s=100.0,
                                             reference_lag_s=lag_s))
    found = []
    for k in range(20_000):
        drift = 0.05 * k / 3600.0
        found += det.update(_payload(k * 1.0, rng, scale={"masses": 1 + drift}))
        if found:
            break
    assert det.ready and bool(found) is alarms
    if alarms:
        assert found[0].kind == "flooding" and found[0].relative_change > 0.05
        return
    for k in range(20_000, 20_020):
        found += det.update(_payload(k * 1.0, rng, scale={"masses": (1 + 0.05 * k / 3600) * 1.1}))
    assert [d.kind for d in found] == ["flooding"] and found[0].t_ns * 1e-9 <= 20_005
    assert found[0].relative_change == pytest.approx(0.1 + 0.017, abs=0.02)  # step + 20 min


@given(*(st.floats(-1e6, 1e6) for _ in range(3)))
def test_the_deviation_is_the_distance_beyond_both_baseline_and_reference(x, mu, ref):
    """0 between μ and the reference; outside, the signed distance to the nearer of them — so
    never larger than either deviation alone, with their sign; x − μ when they coincide."""
    d = deviation(x, mu, ref)
    if min(mu, ref) <= x <= max(mu, ref):
        assert d == 0.0
    else:
        assert d == min(x - mu, x - ref, key=abs)
        assert np.sign(d) == np.sign(x - mu) == np.sign(x - ref) != 0
    assert deviation(x, mu, mu) == x - mu


def test_an_excursion_that_returns_to_the_baseline_is_not_a_fault_and_a_step_still_is():
    """AID's b̂₃ of the JHU ROV on RefTraj1 at ~2× Table A.1's noise rises ~3 % in the first
    hour and a half and comes back (uvd.fdc.detector, "The interval"): the reference follows
    the rise, and the return, a deviation from the reference but none from the baseline, alarmed
    in 5 of the 7 fdc-false-alarms runs of that kind. Here the masses rise 8 % over 2.7 h, slowly
    enough for the reference, and fall back to the baseline in 10 minutes — beyond δ/2 from the
    reference (checked), inside the interval between baseline and reference: nothing; a mass
    step of −10 % afterwards is found within three samples."""
    rng = np.random.default_rng(12)
    det = VehicleDetector("v", CusumSettings(warmup_s=10.0, baseline_s=100.0,
                                             reference_lag_s=1200.0))
    found, below_ref = [], 0
    for k in range(14_000):
        up = 0.08 * min(max(k - 300, 0) / 9600.0, 1.0)
        down = min(max(k - 9900, 0) / 600.0, 1.0)
        p = _payload(k * 1.0, rng, scale={"masses": 1 + up * (1 - down)})
        found += det.update(p)
        if det.ready and p["masses"][2] - det.ref["mass3"] < -det.delta["mass3"] / 2:
            below_ref += 1  # where a deviation from the reference alone would accumulate
    assert det.ready and found == [] and below_ref > 300
    for k in range(14_000, 14_020):
        found += det.update(_payload(k * 1.0, rng, scale={"masses": 0.9}))
    assert [d.kind for d in found] == ["lost-part"] and found[0].t_ns * 1e-9 <= 14_003
    assert found[0].relative_change == pytest.approx(-0.1, abs=0.02)


def test_a_change_from_a_baseline_of_zero_has_no_relative_change():
    """A channel whose baseline is exactly 0 (a daemon that does not estimate g) has no
    relative change: the detection says null, in strict JSON valid against uvd.fault.v1 — not
    Infinity, which no JSON parser has to accept."""
    rng = np.random.default_rng(6)
    det = VehicleDetector("v", FAST)
    for k in range(200):
        assert det.update({**_payload(k * 1.0, rng), "g": 0.0}) == []
    found = []
    for k in range(200, 230):
        found += det.update({**_payload(k * 1.0, rng), "g": 30.0})
        if found:
            break
    assert [(d.kind, d.channel) for d in found] == [("buoyancy", "g")]
    d = found[0].as_dict()
    assert d["relative_change"] is None
    schema = json.loads((Path(__file__).parents[1] / "uvd" / "telemetry" / "schemas"
                         / "uvd.fault.v1.json").read_text())
    jsonschema.Draft202012Validator(schema).validate(json.loads(json.dumps(d, allow_nan=False)))


@pytest.mark.parametrize("phi", [0.0, 0.8, 0.95])
def test_the_autocorrelation_time_of_an_ar1_series(phi):
    """τ = (1 + φ)/(1 − φ) for x_k = φ x_{k−1} + ε_k."""
    rng = np.random.default_rng(4)
    x = np.zeros(20_000)
    for k in range(1, x.size):
        x[k] = phi * x[k - 1] + rng.standard_normal()
    assert autocorrelation_time(x) == pytest.approx((1 + phi) / (1 - phi), rel=0.25)


def test_frozen_estimates_are_ignored_and_reset_learns_again():
    rng = np.random.default_rng(2)
    det = VehicleDetector("v", FAST)
    frozen = {**_payload(0.0, rng), "frozen": True}
    assert det.update(frozen) == [] and det.t0_ns is None
    for k in range(150):
        det.update(_payload(k * 1.0, rng))
    assert det.ready
    det.reset()
    assert not det.ready and det.t0_ns is None

@pytest.mark.parametrize("B", [[[1.0, 2.0]], np.full((6, 6), np.nan), np.zeros((6, 0))])
def test_a_malformed_thruster_matrix_is_refused_by_name(B):
    with pytest.raises(ValueError, match="thruster matrix: 6 × N finite"):
        VehicleDetector("v", FAST, B=B)


def test_the_lockstep_watch_feeds_the_detector_the_numbers_of_the_state_payload():
    """uvd.experiments.fdc.watch hands the detector a cycle's v, R and thrust as arrays instead
    of the JSON of its whole state payload: the detector must get the very same numbers."""
    from uvd.experiments.fdc import SimVehicle
    from uvd.fdc.residual import state_sample
    from uvd.links.zenoh import state_payload

    v = SimVehicle("thruster-50", 0.2, seed=3)  # thruster 4 at 50 % from cycle 120 on
    n = v.B.shape[1]
    compared = 0
    for _ in range(3):  # the first cycle's estimate, then two every v.every cycles
        v.next_estimates()
        records = v.cycles
        assert len(records) == len(v.outs) > 0
        for (t_ns, out), rec in zip(v.outs, records, strict=True):
            assert rec["t_ns"] == t_ns
            via_json = json.loads(json.dumps(state_payload(rec)))
            direct = state_sample(out.nav.v, out.nav.H[:3, :3], out.thrust_n, n)
            for a, b in zip(state_sample(via_json["v"], via_json["R"], via_json["thrust"], n),
                            direct, strict=True):
                assert a.tobytes() == b.tobytes()
            compared += 1
    assert compared == 1 + 2 * v.every and v.t_fault_ns is not None


@pytest.mark.parametrize("config,every", [("sim.toml", 1), ("sim-bluerov2.toml", 3)])
def test_the_lockstep_watch_feeds_the_state_at_the_rate_the_daemon_publishes_it(
        config, every, monkeypatch):
    """uvd-fdc gets the state the daemon's Zenoh sink publishes, ``[telemetry.zenoh]
    state_hz`` (20 Hz by the sink's own rule, uvd.links.zenoh.next_publication_ns), not
    every cycle: each 100 ms cycle of the JHU ROV, every third 20 ms cycle of the BlueROV2."""
    from uvd.experiments.fdc import SimVehicle, watch
    from uvd.fdc.detector import VehicleDetector
    from uvd.runtime.config import DEFAULT_CONFIG

    fed = []
    real = VehicleDetector.update_state

    def spy(self, payload):
        fed.append(payload["t_ns"])
        return real(self, payload)

    monkeypatch.setattr(VehicleDetector, "update_state", spy)
    v = SimVehicle(None, 0.0, seed=1, config=DEFAULT_CONFIG.parent / config)
    watch(v, 0.5)
    cycle_ns = round(1e9 / v.rate)
    assert v.k > 10 * every and len(fed) > 10  # watch ends within one batch of estimates
    assert set(np.diff(fed)) == {every * cycle_ns}
    assert len(fed) == len(range(0, v.k, every))
