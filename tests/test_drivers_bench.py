"""Smoke test of ``uvd bench drivers`` (figures are printed, never asserted)."""

from __future__ import annotations

import argparse

from uvd.bench import get


def test_bench_drivers_runs_and_reports_every_figure(tmp_path):
    bench = get("drivers")
    figures = bench.run(argparse.Namespace(duration=0.01, samples=5,
                                           data=tmp_path / "no-recordings-here"))
    assert set(figures["throughput"]) == {"pd0", "phins-stdbin", "phins-ascii", "digiquartz"}
    for v in figures["throughput"].values():
        assert v["frames_per_s"] > 0 and v["frames_per_pass"] > 0
        assert "synthetic" in v["source"]  # the data folder given does not exist
    for v in figures["pty_latency_us"].values():
        assert v["n"] == 5 and v["p50"] > 0
    assert figures["nav_step_us"]["all_samples"]["n"] >= 1000
    assert set(figures["met"]) == {"pd0_throughput", "pty_latency_p50"}
