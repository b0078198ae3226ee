"""The command line: help, version, the hardware-in-the-loop demo."""

import json
import subprocess
import sys

from uvd import __version__
from uvd.cli import main


def test_help_lists_commands(capsys):
    assert main([]) == 2
    out = capsys.readouterr().out
    for cmd in ("demo", "experiment", "bench"):
        assert cmd in out


def test_version():
    r = subprocess.run([sys.executable, "-m", "uvd", "--version"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == f"uvd {__version__}"


def test_unknown_experiment_is_a_clear_error(capsys):
    assert main(["experiment", "no-such-thing"]) == 2
    assert "unknown experiment 'no-such-thing'" in capsys.readouterr().err


def test_demo_is_hardware_in_the_loop_without_failsafe(tmp_path, capsys):
    """A short ``uvd demo``: sim-bridge + uvd run as two processes, armed, no failsafe."""
    out = tmp_path / "demo.json"
    assert main(["demo", "--duration", "12", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "heading" in text and "position MAE" in text and "Failsafe events: 0" in text
    res = json.loads(out.read_text())
    assert res["failsafe_events"] == [] and res["daemon"]["exit_code"] == 0
    loop = res["loop"]
    assert loop["rate_hz"] == 10.0 and loop["overruns"] == 0 and loop["cycles"] >= 100
    assert {"p50", "p99", "max"} <= set(loop["lateness_us"])
    assert {"p50", "p99"} <= set(loop["compute_us"])
    assert res["tracking"]["samples"] >= 100
    # two-step AMBC keeps the vehicle near the 0.5 m / 135° reference, as in lockstep
    assert res["tracking"]["position_mae"]["x"] < 0.3
    assert res["tracking"]["position_mae"]["heading"] < 0.35
    assert set(res["lockstep"]["ratio"]) == {"x", "y", "z", "roll", "pitch", "heading"}
    assert res["memory"]["daemon_peak_rss_mb"] > 0 and "daemon_rss_growth_mb" in res["memory"]
