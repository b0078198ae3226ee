"""uvd-fdc's commanded vs realised wrench residual (uvd/fdc/residual.py) and the detector's use
of it, on a synthetic vehicle with a known answer: the jhu-rov's model (2.44) integrated by
uvd.model's own forward dynamics (not the residual's code) under varying thruster commands,
with a fault of known kind and size injected halfway."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uvd.fdc.detector import CusumSettings, VehicleDetector
from uvd.fdc.residual import FrozenModel, SegmentIntegrator, _integrands_into, explain
from uvd.io.vehicle import load_vehicle
from uvd.model.dynamics import UVModel, uv_accel
from uvd.model.params import UVParams, params_from_theta, theta_from

VEHICLE = load_vehicle("jhu-rov")
B = VEHICLE.B
THETA = theta_from(VEHICLE.params)
R_LEVEL = np.eye(3)


def _simulate(seconds: float, *, t_fault: float = math.inf, eta=None, params=None,
              rate: float = 10.0, sub: int = 5, seed: int = 0, noise: float = 0.0):
    """Samples (t, v, R, f) at ``rate`` of the vehicle driven by smooth thruster commands f;
    after ``t_fault`` the thrusters deliver ``eta``·f and the plant has ``params``. R is kept
    level (the model's identity holds for any R; the residual only reads it)."""
    rng = np.random.default_rng(seed)
    healthy = UVModel.from_params(VEHICLE.params)
    faulty = UVModel.from_params(params or VEHICLE.params)
    eta = np.ones(B.shape[1]) if eta is None else np.asarray(eta, float)
    n = B.shape[1]
    freq = 0.011 + 0.007 * np.arange(n)
    phase = np.arange(n) * 1.3

    def f_of(t):
        return 60.0 * np.sin(2 * np.pi * freq * t + phase) + 15.0 * np.sin(0.21 * t + phase)

    def accel(t, v):
        m, e = (faulty, eta) if t >= t_fault else (healthy, np.ones(n))
        return uv_accel(m, v, R_LEVEL, B @ (e * f_of(t)))

    h = 1.0 / (rate * sub)
    v = np.zeros(6)
    out = []
    for k in range(int(seconds * rate * sub) + 1):
        t = k * h
        if k % sub == 0:
            out.append((t, v + noise * rng.standard_normal(6), R_LEVEL, f_of(t)))
        k1 = accel(t, v)
        k2 = accel(t + h / 2, v + h / 2 * k1)
        k3 = accel(t + h / 2, v + h / 2 * k2)
        k4 = accel(t + h, v + h * k3)
        v = v + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return out


def _segments(samples, model=None):
    integ = SegmentIntegrator(model or FrozenModel.from_theta(THETA, B))
    return [s for s in (integ.add(*x) for x in samples) if s is not None]


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_theta_is_decoded_as_the_model_reads_it(seed):
    """The client decodes θ (2.48) from the payload's documented layout alone; the model's
    own decoding gives the same M, D, g, b."""
    theta = np.random.default_rng(seed).standard_normal(241)
    p, m = params_from_theta(theta), FrozenModel.from_theta(theta, B)
    assert np.array_equal(m.M, p.M) and np.array_equal(m.D_flat, np.hstack(list(p.D)))
    assert m.g == p.g and np.array_equal(m.b, p.b)


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 10))
def test_the_compiled_integrands_are_the_formulas(seed, n):
    """The one compiled call of a state sample against (2.4)'s ad_vᵀ(Mv), (Σᵢ|vᵢ|Dᵢ)v and G(R)
    written with numpy (np.cross, the Kronecker product of (2.8)), any θ, v, R and N."""
    rng = np.random.default_rng(seed)
    model = FrozenModel.from_theta(100.0 * rng.standard_normal(241), rng.standard_normal((6, n)))
    v, f = 3.0 * rng.standard_normal(6), 50.0 * rng.standard_normal(n)
    R = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    out = np.full(21 + n, np.nan)
    _integrands_into(out, model.M, model.D_flat, model.g, model.b, v, R, f)
    nu, w = v[:3], v[3:]
    p, h = (model.M @ v)[:3], (model.M @ v)[3:]
    r = R.T @ np.array([0.0, 0.0, 1.0])
    want = np.concatenate([np.cross(p, w), np.cross(p, nu) + np.cross(h, w),
                           model.D_flat @ np.kron(np.abs(v), v),
                           model.g * r, np.cross(model.b, r), r, f])
    np.testing.assert_allclose(out, want, rtol=1e-12, atol=1e-9 * np.abs(want).max())


def test_a_healthy_vehicle_leaves_no_residual():
    segs = _segments(_simulate(60.0))
    assert len(segs) == 6
    for s in segs:
        commanded = np.abs(B @ s.F)
        assert np.all(np.abs(s.e) <= 0.01 * commanded.max() + 1e-6), (s.e, commanded)
    ex = explain(segs, FrozenModel.from_theta(THETA, B), np.zeros(6), np.full(6, 2.0))
    assert max(x.score for x in ex) < 30.0  # no explanation of a change where there is none


FAULTS = [
    ("thruster4", dict(eta=[1, 1, 1, 0.5, 1, 1]), [0.5]),
    ("thruster4", dict(eta=[1, 1, 1, 0.0, 1, 1]), [1.0]),
    ("thruster1", dict(eta=[0.5, 1, 1, 1, 1, 1]), [0.5]),
    ("thruster6", dict(eta=[1, 1, 1, 1, 1, 0.3]), [0.7]),
    ("buoyancy", dict(params=UVParams(M=VEHICLE.params.M, D=VEHICLE.params.D,
                                      g=VEHICLE.params.g + 20.0, b=VEHICLE.params.b)),
     [20.0, 0.0, 0.0, 0.0]),
    ("entanglement", dict(params=UVParams(M=VEHICLE.params.M, D=1.5 * VEHICLE.params.D,
                                          g=VEHICLE.params.g, b=VEHICLE.params.b)), [0.5]),
    ("flooding", dict(params=UVParams(M=1.1 * VEHICLE.params.M, D=VEHICLE.params.D,
                                      g=VEHICLE.params.g, b=VEHICLE.params.b)), [0.1]),
]


@pytest.mark.parametrize("kind,fault,coef", FAULTS, ids=[f[0] + str(i) for i, f in
                                                        enumerate(FAULTS)])
def test_each_fault_is_explained_by_its_own_kind_and_size(kind, fault, coef):
    segs = _segments(_simulate(120.0, t_fault=60.0, noise=0.002, **fault))
    spread = np.full(6, 2.0)  # N s (N m s) per segment: the noise's scale
    ex = explain(segs, FrozenModel.from_theta(THETA, B), np.zeros(6), spread)
    best = ex[0]
    assert best.kind == kind, [(x.kind, round(x.score)) for x in ex[:3]]
    assert best.score > 30.0
    np.testing.assert_allclose(best.coef, coef, atol=0.05 * max(1.0, abs(coef[0])))
    assert abs(best.since - 60.0) <= 10.0


def test_a_gap_drops_the_partial_segment_and_bad_samples_are_refused():
    samples = _simulate(40.0)
    integ = SegmentIntegrator(FrozenModel.from_theta(THETA, B))
    got = [s for s in (integ.add(*x) for x in samples[:50] + samples[70:]) if s is not None]
    assert got and all(not (5.0 < s.t0 < 7.0) for s in got)
    assert all(abs(s.duration - 10.0) < 1e-6 for s in got)
    with pytest.raises(ValueError, match="thrust 6 finite"):
        integ.add(41.0, np.zeros(6), R_LEVEL, [1.0, math.nan, 0, 0, 0, 0])


# -- the detector: the CUSUM finds the change, the residual names it --

FAST = CusumSettings(warmup_s=10.0, baseline_s=150.0)


def _estimate(t: float, *, b1: float = 0.0, g: float = 0.0) -> dict:
    p = VEHICLE.params
    return {"t_ns": int(round(t * 1e9)), "estimator": "aid6", "frozen": False,
            "theta": THETA.tolist(), "masses": np.diag(p.M).tolist(),
            "drags": [float(p.D[i][i, i]) for i in range(6)], "g": float(p.g) + g,
            "b": (np.asarray(p.b) + [b1, 0.0, 0.0]).tolist()}


def _run_detector(samples, t_fault, *, b1=0.0, g=0.0, with_state=True):
    det = VehicleDetector("v", FAST, B=B if with_state else None)
    found = []
    next_est = 0.0
    for t, v, R, f in samples:
        if t >= next_est:
            found += det.update(_estimate(t, b1=b1 if t >= t_fault else 0.0,
                                          g=g if t >= t_fault else 0.0))
            next_est += 1.0
        found += det.update_state({"t_ns": int(round(t * 1e9)), "v": v.tolist(),
                                   "R": R.tolist(), "thrust": f.tolist()})
    return det, found


def test_a_weak_thruster_that_aid_takes_for_buoyancy_is_named():
    """AID puts the missing thrust in b₁ (as measured in `uvd experiment fdc`); the CUSUM
    finds it, and the residual says it is thruster 4 at half its thrust."""
    samples = _simulate(260.0, t_fault=200.0, eta=[1, 1, 1, 0.5, 1, 1], noise=0.002)
    det, found = _run_detector(samples, 200.0, b1=20.0)
    assert det.explains
    assert len(found) == 1, found
    d = found[0]
    assert (d.kind, d.channel) == ("thruster", "thruster4")
    assert d.relative_change == pytest.approx(-0.5, abs=0.05)
    assert 200.0 <= d.t_ns * 1e-9 <= 200.0 + FAST.confirm_s + 10.0
    # without the state stream the estimates alone say buoyancy, as before
    _, alone = _run_detector(samples, 200.0, b1=20.0, with_state=False)
    assert [(x.kind, x.channel) for x in alone] == [("buoyancy", "b1")]


def test_a_buoyancy_change_stays_a_buoyancy_change():
    params = UVParams(M=VEHICLE.params.M, D=VEHICLE.params.D, g=VEHICLE.params.g + 20.0,
                      b=VEHICLE.params.b)
    samples = _simulate(260.0, t_fault=200.0, params=params, noise=0.002)
    _, found = _run_detector(samples, 200.0, g=20.0)
    assert [(x.kind, x.channel) for x in found] == [("buoyancy", "buoyancy")]
    assert found[0].explanation["coef"][0] == pytest.approx(20.0, abs=1.0)


def test_a_malformed_state_or_theta_is_refused_and_the_detector_goes_on():
    """A bad state sample raises a ValueError naming it (uvd-fdc counts and drops it) and is
    never kept for the baseline; an estimate whose θ is not 241 numbers is not used for the
    frozen model; the residual still runs."""
    samples = _simulate(200.0, noise=0.002)
    det = VehicleDetector("v", FAST, B=B)
    for t, v, R, f in samples:
        if abs(t - round(t)) < 1e-9:
            det.update({**_estimate(t), **({"theta": [1.0, None]} if t < 50 else {})})
        if abs(t - 100.0) < 1e-9:
            for bad in ({"v": [0.0] * 5}, {"thrust": ["x"] * 6}, {"R": [[math.nan] * 3] * 3}):
                with pytest.raises(ValueError, match="state sample"):
                    det.update_state({"t_ns": int(t * 1e9), "v": v.tolist(), "R": R.tolist(),
                                      "thrust": f.tolist(), **bad})
        det.update_state({"t_ns": int(round(t * 1e9)), "v": v.tolist(), "R": R.tolist(),
                          "thrust": f.tolist()})
    assert det.ready and det.explains and len(det.segments) >= 3


def test_warm_compiles_what_a_client_s_json_samples_use():
    """uvd-fdc calls warm() at start: a state payload decoded from JSON (lists) then needs no
    new compiled specialisation (no ~1.5 s stall at the first sample or when the baseline
    ends). In a fresh interpreter, so that no other test has compiled it already."""
    import json
    import subprocess
    import sys
    code = """
from uvd.fdc import residual as r
from tests.test_fdc_residual import THETA, B
r.warm()
before = (len(r._finite.signatures), len(r._integrands_into.signatures))
integ = r.SegmentIntegrator(r.FrozenModel.from_theta(THETA, B))
for t in (0.0, 0.1):
    integ.add(t, [0.1] * 6, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], [1.0] * 6)
print(json.dumps([before, (len(r._finite.signatures), len(r._integrands_into.signatures))]))
"""
    out = subprocess.run([sys.executable, "-c", "import json" + code], capture_output=True,
                         text=True, timeout=120, check=True).stdout.splitlines()[-1]
    before, after = json.loads(out)
    assert before == after == [1, 1], out  # one specialisation each, compiled by warm()
