"""The command line: help, version, the interim demo."""

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


def test_demo_tracks_reftraj1_without_saturation(tmp_path, capsys):
    out = tmp_path / "demo.json"
    assert main(["demo", "--duration", "30", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "heading" in text and "position MAE" in text
    res = json.loads(out.read_text())
    assert res["cycles_not_ok"] == 0 and res["saturated_fraction"] == 0.0
    # PD with k_p = 300 keeps the vehicle near the 0.5 m / 135° reference
    assert res["tracking"]["position_mae"]["x"] < 0.3
    assert res["tracking"]["position_mae"]["heading"] < 0.35
