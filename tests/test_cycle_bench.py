"""A short run of ``uvd bench cycle`` (its figures are printed, never asserted): every part
timed, the parts nested as the cycle nests them, and the run's functions put back after."""

from __future__ import annotations

import argparse

import pytest

from uvd.bench import registry


# the bench warms up first: with an empty kernel cache that compiles for a minute or more
@pytest.mark.timeout(900)
def test_the_cycle_bench_times_every_part_and_puts_the_functions_back():
    import uvd.core
    from sim_bridge.plant import Plant
    from uvd.lockstep import Lockstep

    before = (Lockstep.advance, Plant.steps_held, uvd.core.sense, uvd.core.nav_step)
    bench = registry()["cycle"]
    figures = bench.run(argparse.Namespace(kind="control", vehicle="jhu-rov", minutes=3.0,
                                           block=300))
    assert (Lockstep.advance, Plant.steps_held, uvd.core.sense, uvd.core.nav_step) == before
    assert 1790 <= figures["cycles"] <= 1810  # 3 simulated minutes at 10 Hz
    assert figures["blocks"] == figures["cycles"] // 300
    p = {k: v["median_us"] for k, v in figures["parts_us_per_cycle"].items()}
    for part in ("cycle", "update", "sense", "navigation", "act", "arbiter+lifecycle", "plant",
                 "instruments", "all"):
        assert p[part] > 0.0, part
    assert p["navigation"] < p["sense"] < p["update"] < p["cycle"] <= p["all"]
    assert p["plant"] + p["instruments"] + p["update"] < p["cycle"]
    assert 0.0 < figures["timer_overhead_us"] < 50.0
