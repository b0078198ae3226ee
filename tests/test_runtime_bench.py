"""``uvd bench loop`` runs both loops and writes the documented keys (figures are not judged
here: timing belongs to the benchmark)."""

from __future__ import annotations

import json

import numpy as np

from uvd.cli import main


def test_bench_loop_keys(tmp_path, capsys):
    out = tmp_path / "loop.json"
    assert main(["bench", "loop", "--rate", "200", "--duration", "0.3", "--warmup", "0",
                 "--cycle", "pdc", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "ours" in text and "naive" in text
    r = json.loads(out.read_text())
    for k in ("p50", "p99", "p999", "max"):
        assert isinstance(r["lateness_us"][k], float)
    for k in ("p50", "p99"):
        assert isinstance(r["compute_us"][k], float)
        assert isinstance(r["naive_asyncio"]["lateness_us"][k], float)
    assert r["cycle"] == "pdc" and r["cycle_errors"] == 0 and isinstance(r["overruns"], int)
    assert r["cycles"] + r["skipped"] >= 50 and r["naive_asyncio"]["cycles"] > 10
    assert r["compute_us"]["p50"] > 1.0       # the PDC cycle really ran
    # the same cycle back to back, for telling code cost from cold caches
    assert r["compute_back_to_back_us"]["n"] == 2000
    assert r["compute_back_to_back_us"]["p50"] > 1.0
    # every overrun sorted by its cause (StallProbe)
    oa = r["overrun_attribution"]
    assert oa["overruns"] == r["overruns"]
    assert sum(oa[k] for k in ("stalled", "preempted", "woke_late", "paused_in_spin",
                               "compute")) == r["overruns"]
    assert oa["stall_ms_total"] >= 0.0
    # the host's steal over the measured run, on every CPU here (not pinned)
    hs = r["host_steal"]
    assert hs["cpus"] == "all"
    if hs["seconds"] is not None:
        assert hs["seconds"] >= 0.0 and 0.0 <= hs["share"] <= 1.0


def test_bench_loop_record_compares_with_and_without_in_one_run(tmp_path):
    """--record: half the measured cycles with the black box, half without, and the file holds
    the recorded half's cycle records and CAN taps."""
    from uvd.telemetry.recording import read_messages

    out = tmp_path / "loop.json"
    assert main(["bench", "loop", "--rate", "200", "--duration", "0.5", "--warmup", "0",
                 "--cycle", "pdc", "--no-naive", "--record", str(tmp_path / "rec"),
                 "--json", str(out)]) == 0
    r = json.loads(out.read_text())["recording"]
    assert r["with_us"]["n"] == r["without_us"]["n"] > 30
    assert r["p50_cost_us"] == r["with_us"]["p50"] - r["without_us"]["p50"]
    (f,) = (tmp_path / "rec").glob("*.mcap")
    counts = {}
    for topic, _, _ in read_messages(f, ["/uvd/cycle", "/uvd/raw/can"]):
        counts[topic] = counts.get(topic, 0) + 1
    assert counts["/uvd/raw/can"] == 7 * counts["/uvd/cycle"] > 7 * 30


def test_overruns_are_sorted_by_cause():
    from uvd.bench.loop import attribute_overruns

    ms = 1_000_000
    period, margin = 1 * ms, ms // 5
    # cycle: on time | host stall | preempted | woke late from the timer | own compute |
    #        a spin that returned 2.6 ms after its deadline
    lateness = [0, 0, 0, 1.0 * ms, 0, 2.6 * ms]
    compute = [0.3 * ms, 1.5 * ms, 1.5 * ms, 0.1 * ms, 1.3 * ms, 0.2 * ms]
    wake = [-margin, -margin, -margin, 1.0 * ms, -margin, -margin]  # coarse return − deadline
    stall = [0, 0.8 * ms, 0.8 * ms, 0, 0.1 * ms, 0]
    preempted = [False, False, True, False, False, False]
    a = attribute_overruns(np.array(lateness, dtype=np.int64), np.array(compute, dtype=np.int64),
                           np.array(wake, dtype=np.int64), np.array(stall, dtype=np.int64),
                           np.array(preempted), period, margin,
                           page_faults=np.array([0, 0, 0, 0, 7, 0]))
    assert a["overruns"] == 5
    assert (a["stalled"], a["preempted"], a["woke_late"], a["paused_in_spin"],
            a["compute"]) == (1, 1, 1, 1, 1)
    assert a["spin_overshoot_ms_in_overruns"] == 2.6
    assert a["stall_ms_total"] == 1.7 and a["stall_ms_in_overruns"] == 1.7
    assert a["max_stall_us"] == 800.0 and a["cycles_with_stall_over_100us"] == 2
    assert a["compute_examples_us"] == [{"cycle": 4, "lateness": 0.0, "compute": 1300.0,
                                         "stall": 100.0, "late_wake": 0.0, "page_faults": 7}]


def test_stall_probe_sees_the_time_a_cycle_does_not_run(tmp_path):
    """A cycle that blocks 5 ms (the thread not running, as when the host pauses the vCPU)
    shows a stall of those 5 ms, less the sleep call's own CPU time (tens of µs); the
    span's CPU time does not include it."""
    import asyncio
    import time

    from uvd.bench.loop import StallProbe
    from uvd.runtime.clock import MonotonicClock
    from uvd.runtime.loop import FixedRateLoop, LoopSettings

    settings = LoopSettings(rate_hz=100.0)
    probe = StallProbe(MonotonicClock(), 64)
    loop = FixedRateLoop(lambda t, dt: time.sleep(0.005), settings, clock=probe)
    loop.after_cycle.append(probe.after_cycle)
    try:
        asyncio.run(loop.run(max_cycles=10))
    finally:
        probe.close()
    assert probe.n == 10
    stalls = probe.stalls_ns()
    assert np.all(stalls >= 4_500_000), stalls


def test_fixed_work_control_cycle_does_work():
    """The control cycle of ``--cycle fixed-work`` costs tens of µs (sized to ~80), not the
    ~1 µs of a call that does nothing."""
    import time

    from uvd.bench.loop import CYCLES

    cycle = CYCLES["fixed-work"]()
    took = []
    for _ in range(21):
        t = time.perf_counter_ns()
        cycle(t, 1e-3)
        took.append(time.perf_counter_ns() - t)
    assert np.median(took) > 10_000, took


def _alternating(rng, pairs: int, per_block: int, cond_scale: float):
    """Lateness samples of 2·pairs + 1 alternating blocks (even baseline, odd condition) whose
    scale drifts from block to block as a host's background does, the condition's tail
    multiplied by ``cond_scale``."""
    n_blocks = 2 * pairs + 1
    drift = np.exp(rng.normal(0.0, 0.4, size=n_blocks // 2 + 1)).repeat(2)[:n_blocks]
    lat, block = [], []
    for j in range(n_blocks):
        x = rng.exponential(2000.0 * drift[j], size=per_block)
        lat.append(x * (cond_scale if j % 2 else 1.0))
        block.append(np.full(per_block, j))
    lat, block = np.concatenate(lat), np.concatenate(block)
    return lat, block, np.ones(lat.size, dtype=bool), n_blocks


def test_p99_change_interval_tells_no_change_from_a_large_one():
    """The paired block bootstrap of ``uvd bench loop``'s phases: with nothing changed its 95 %
    interval holds 0 and, with enough pairs, lies inside ±10 %; a condition that raises the
    tail by 50 % gives an interval around +50 % that excludes ±10 %; a run too short to tell
    says so (None), never a verdict."""
    from uvd.bench.loop import p99_change_ci
    rng = np.random.default_rng(5)
    same = p99_change_ci(*_alternating(rng, 60, 3000, 1.0), resamples=400)
    for ci, within in (("ci95", "within_10pct"), ("median_block_ci95",
                                                 "median_block_within_10pct")):
        lo, hi = same[ci]
        assert lo < 0.0 < hi and same[within] is True
    more = p99_change_ci(*_alternating(rng, 60, 3000, 1.5), resamples=400)
    for ci, within in (("ci95", "within_10pct"), ("median_block_ci95",
                                                 "median_block_within_10pct")):
        lo, hi = more[ci]
        assert 0.3 < lo < 0.5 < hi < 0.7 and more[within] is False
    short = p99_change_ci(*_alternating(rng, 3, 300, 1.0), resamples=400)
    assert short["within_10pct"] is None
    assert p99_change_ci(*_alternating(rng, 1, 300, 1.0))["ci95"] is None


def test_peers_start_as_remote_peers_not_as_the_real_time_loop():
    """A benchmark's peer (Zenoh subscriber, MAVLink fuzz sender) forked by the loop's thread at
    SCHED_FIFO on its own CPU would inherit both: ``as_remote_peer`` starts it at normal
    scheduling off the loop's CPUs, and gives the loop's thread its own back."""
    import os
    import subprocess
    import sys
    import threading

    from uvd.bench.loop import as_remote_peer
    if (os.cpu_count() or 1) < 2:
        import pytest
        pytest.skip("needs two CPUs")
    seen: dict = {}

    def body() -> None:
        os.sched_setaffinity(0, {1})
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
            seen["fifo"] = True
        except PermissionError:
            seen["fifo"] = False
        with as_remote_peer([1]):
            child = subprocess.run(
                [sys.executable, "-c", "import os; print(sorted(os.sched_getaffinity(0)), "
                 "os.sched_getscheduler(0))"], capture_output=True, text=True, timeout=60)
        seen["child"] = child.stdout.split()
        seen["after"] = (sorted(os.sched_getaffinity(0)), os.sched_getscheduler(0))
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))

    t = threading.Thread(target=body)
    t.start()
    t.join(60)
    others = sorted(set(range(os.cpu_count())) - {1})
    assert " ".join(seen["child"][:-1]) == str(others)
    assert int(seen["child"][-1]) == os.SCHED_OTHER
    assert seen["after"] == ([1], os.SCHED_FIFO if seen["fifo"] else os.SCHED_OTHER)
