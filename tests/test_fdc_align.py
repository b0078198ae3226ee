"""uvd.fdc.align: a vehicle's estimate and state samples reach the detector in the order of
their time stamps, whatever order they arrived in."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.test_fdc_residual import B, _estimate, _simulate
from uvd.fdc.align import Aligned
from uvd.fdc.detector import CusumSettings, VehicleDetector


def _streams(est_t, state_t):
    return ([("estimate", t) for t in est_t], [("state", t) for t in state_t])


def _canonical(est, state):
    return sorted(est + state, key=lambda x: (x[1], x[0] != "estimate"))


@st.composite
def _arrivals(draw):
    """Two streams of increasing stamps and one interleaving of their arrivals (each stream in
    its own order, as Zenoh keeps a publisher's order on one key)."""
    est_t = sorted(set(draw(st.lists(st.integers(0, 60), max_size=15))))
    state_t = sorted(set(draw(st.lists(st.integers(0, 60), max_size=40))))
    est, state = _streams(est_t, state_t)
    picks = draw(st.permutations([0] * len(est) + [1] * len(state)))
    queues, order = [list(est), list(state)], []
    for p in picks:
        order.append(queues[p].pop(0))
    return est, state, order


@settings(max_examples=200, deadline=None)
@given(_arrivals())
def test_any_interleaving_gives_the_time_stamp_order(case):
    est, state, order = case
    al = Aligned(now=0.0)
    out = []
    for stream, t in order:
        out += al.push(stream, t, (stream, t), now=0.0)
    out += al.push("estimate", 1000, "end", now=0.0)  # both streams move on past them
    out += al.push("state", 1000, "end", now=0.0)
    assert [item for _, item in out] == _canonical(est, state) + ["end", "end"]
    assert al.late == {"estimate": 0, "state": 0} and al.forced == 0


def test_a_stream_never_heard_or_far_behind_stops_holding_the_other():
    al = Aligned(now=0.0, quiet_s=5.0, lag_s=60.0)
    s = int(1e9)
    assert al.push("estimate", 10 * s, "e10", now=0.0) == []  # no state yet: held
    assert al.pop(now=4.9) == []
    assert al.pop(now=5.1) == [("estimate", "e10")]  # none came in 5 s: no state stream
    # states begin with older stamps: late, dropped (the residual integrates in time order)
    assert al.push("state", 5 * s, "s5", now=5.5) == []
    assert al.late["state"] == 1
    # heard now: it holds the estimates however long the receiver waits ...
    assert al.push("estimate", 20 * s, "e20", now=6.0) == []
    assert al.push("state", 11 * s, "s11", now=6.0) == [("state", "s11")]
    assert al.pop(now=1e6) == []
    # ... until it is more than lag_s of sample time behind them (a stream that stopped)
    assert al.push("estimate", 71 * s, "e71", now=7.0) == []  # 60 s ahead of s11, not more
    assert al.push("estimate", 72 * s, "e72", now=7.0) == [
        ("estimate", "e20"), ("estimate", "e71"), ("estimate", "e72")]


def test_a_paused_aligner_holds_everything_and_a_bound_forces_release():
    al = Aligned(now=0.0, max_held=3)
    al.paused = True
    for t in range(5):
        assert al.push("state", t, t, now=0.0) == []
    al.paused = False
    # the bound: those beyond it go unaligned
    assert al.pop(now=0.0) == [("state", 0), ("state", 1)]
    assert al.forced == 2


def test_the_detector_decides_the_same_from_a_late_state_stream():
    """The case a loaded machine made: the state stream arrives 30 s of sample time behind the
    estimates. Through the aligner the detector names thruster 4 as with the samples in time
    order; fed in arrival order it kept the CUSUM's kind (buoyancy)."""
    samples = _simulate(260.0, t_fault=200.0, eta=[1, 1, 1, 0.5, 1, 1], noise=0.002)
    ests = [(t, _estimate(t, b1=20.0 if t >= 200 else 0.0)) for t in range(261)]
    states = [(t, {"t_ns": int(round(t * 1e9)), "v": v.tolist(), "R": R.tolist(),
                   "thrust": f.tolist()}) for t, v, R, f in samples]
    arrivals, j = [], 0
    for t, e in ests:  # each estimate, then the states 30 s older than it
        arrivals.append(("estimate", e))
        while j < len(states) and states[j][0] <= t - 30.0:
            arrivals.append(("state", states[j][1]))
            j += 1
    arrivals += [("state", s) for _, s in states[j:]]
    cfg = CusumSettings(warmup_s=10.0, baseline_s=150.0)

    def run(aligned: bool):
        det, al, found = VehicleDetector("v", cfg, B=B), Aligned(now=0.0), []
        for stream, p in arrivals:
            released = al.push(stream, p["t_ns"], p, now=0.0) if aligned else [(stream, p)]
            for s, q in released:
                found += det.update(q) if s == "estimate" else det.update_state(q)
        return found

    raw, aligned = run(False), run(True)
    assert [d.kind for d in raw] == ["buoyancy"]  # what the client reported under load
    assert [(d.kind, d.channel) for d in aligned] == [("thruster", "thruster4")]
    assert aligned[0].relative_change == pytest.approx(-0.5, abs=0.02)
    assert raw[0].magnitude == 20.0 / cfg.b_resolution_nm  # b₁ constant: σ its resolution
