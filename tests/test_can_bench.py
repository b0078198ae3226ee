"""A very short run of ``uvd bench can`` (the benchmark prints figures, never asserts)."""

from __future__ import annotations

import argparse

import pytest

from uvd.bench import registry


@pytest.mark.timeout(120)
def test_bench_can_smoke():
    bench = registry()["can"]
    figures = bench.run(argparse.Namespace(duration=1.0, rate=100.0, samples=50,
                                           realtime=False))
    assert figures["decode_check"] is True
    assert figures["encode_send_virtual_us"]["n"] == 50
    assert figures["exchange"]["cycles"] == 100 and figures["start_ok"]
    assert figures["round_trip_ms"]["n"] > 0
    assert set(figures["command_timeout"]["emulator_zeroed_after_ms"]) == {"1", "2", "3", "4",
                                                                          "5", "6"}
    assert len(figures["fault_detection"]) == 5
