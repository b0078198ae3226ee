"""``uvd decode``: one JSON object per frame (SI + raw), then a counter summary."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from driver_strategies import DATA

from uvd.cli import main


def _path(rel: str) -> Path:
    p = DATA / rel
    if not p.is_file():
        pytest.fail(f"recording {p} is missing: it belongs to the repository (tests/data/)")
    return p


def _run_json(capsys, fmt: str, path, *extra) -> tuple[int, list[dict], dict]:
    rc = main(["decode", "--format", fmt, str(path), "--json", *extra])
    lines = [json.loads(ln) for ln in capsys.readouterr().out.splitlines()]
    assert lines and lines[-1].get("summary") is True
    return rc, lines[:-1], lines[-1]


def test_decode_pd0_json(capsys):
    rc, frames, summary = _run_json(capsys, "pd0", _path("pd0/adcp_auv_3.pd0"))
    assert rc == 0 and len(frames) == 3 == summary["frames"]
    f = frames[0]
    assert f["ensemble"] == 14 and f["coord_frame"] == "ship" and f["bottom_lock"] is True
    # bottom track (−58, −137, 12) mm/s in RDI ship axes (stbd, fwd, up), negated → body
    assert f["velocity_dvl_m_s"] == pytest.approx([0.137, 0.058, 0.012])
    assert f["raw"]["bottom_track"]["velocity_mm_s"] == [-58, -137, 12, -3]
    assert f["raw"]["variable_leader"]["heading_cdeg"] == 26067
    assert summary["bad_checksums"] == 0 and summary["errors"] == []


def test_decode_corrupted_pd0_reports_damage(capsys):
    rc, frames, summary = _run_json(capsys, "pd0", _path("pd0/LB180210_3_corrupted.PD0"))
    assert rc == 0 and frames
    assert summary["bad_checksums"] >= 1 and summary["bytes_dropped"] > 0
    assert any(e["kind"] == "checksum" and "checksum" in e["message"]
               for e in summary["errors"])


def test_decode_stdbin_json(capsys):
    rc, frames, summary = _run_json(capsys, "phins-stdbin", _path("phins/log_STDBIN_V3.log"))
    assert rc == 0 and len(frames) == 17 and summary["bad_checksums"] == 0
    f = frames[0]
    att = f["raw"]["blocks"]["attitudeHeading"]
    assert f["pitch_rad"] == pytest.approx(-math.radians(att["pitch_deg"]), abs=1e-8)
    assert f["roll_rad"] == pytest.approx(math.radians(att["roll_deg"]), abs=1e-8)
    assert f["external_depth_m"] == -102.0


def test_decode_phins_ascii_json(capsys):
    rc, frames, summary = _run_json(capsys, "phins-ascii",
                                    _path("phins/phins_ascii_samples.txt"))
    assert rc == 0 and summary["frames"] == len(frames) == 44
    assert summary["bad_checksums"] == 4
    speed = next(f for f in frames if f["raw"]["sentence"] == "PIXSE,SPEED_")
    assert speed["velocity_ned_m_s"] == pytest.approx([-1.243, -0.802, -0.0])
    pos = next(f for f in frames if f["raw"]["sentence"] == "PIXSE,POSITI"
               and f["raw"]["longitude_deg"] > 180)
    assert pos["longitude_deg"] == pytest.approx(186.22231161 - 360.0)


def test_decode_digiquartz_text_and_units(tmp_path, capsys):
    f = tmp_path / "dq.txt"
    f.write_bytes(b"garbage*000114.69595\r\n*000116.11828\r\n*0001UN=1\r\n")
    rc, frames, summary = _run_json(capsys, "digiquartz", f)
    assert rc == 0 and len(frames) == 3
    assert frames[0]["depth_m"] == pytest.approx(0.0, abs=1e-3)  # 14.69595 psi = 1 atm
    assert frames[1]["depth_m"] == pytest.approx(1.0, abs=2e-3)  # +1.42233 psi ≈ 1 m water
    assert frames[2]["raw"]["kind"] == "param"
    assert summary["bytes_dropped"] == len(b"garbage") and summary["resyncs"] == 1
    # refused at their options (session 33; before, by the converter, naming its fields)
    with pytest.raises(SystemExit) as stop:
        main(["decode", "--format", "digiquartz", str(f), "--unit", "9"])
    assert stop.value.code == 2
    assert "argument --unit: '9' is not an integer in 1..8" in capsys.readouterr().err
    # a negative tare shifted every depth by it, a non-finite one made every depth None
    for tare in ("-5", "nan", "inf"):
        with pytest.raises(SystemExit) as stop:
            main(["decode", "--format", "digiquartz", str(f), "--atmosphere-pa", tare])
        assert stop.value.code == 2
        assert f"argument --atmosphere-pa: '{tare}' is not a finite number >= 0" in \
            capsys.readouterr().err


def test_decode_missing_file_and_no_frames(tmp_path, capsys):
    assert main(["decode", "--format", "pd0", str(tmp_path / "nope.pd0")]) == 2
    assert "no such file" in capsys.readouterr().err
    # a folder is not a missing file (said so until session 30)
    assert main(["decode", "--format", "pd0", str(tmp_path)]) == 2
    assert f"{tmp_path} is not a file (a recorded stream" in capsys.readouterr().err
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"\x00" * 100)
    assert main(["decode", "--format", "pd0", str(empty)]) == 1
    out = capsys.readouterr().out
    assert "0 frames" in out and "100 of 100 bytes dropped" in out


def test_decode_console_script_pipes():
    """The installed ``uvd`` entry point, piped like in the docs (``… | tail -3``)."""
    exe = Path(sys.executable).parent / "uvd"
    if not exe.exists():
        pytest.skip("uvd console script not installed in this environment")
    proc = subprocess.run([str(exe), "decode", "--format", "pd0",
                           str(_path("pd0/adcp_auv_3.pd0")), "--json"],
                          capture_output=True, timeout=60, check=True)
    lines = proc.stdout.decode().splitlines()
    assert len(lines) == 4 and json.loads(lines[-1])["frames"] == 3


def test_decode_pd0_reports_the_dvls_velocity_noise(capsys):
    """The summary of a DVL's recording names its velocity noise beside the simulated DVL's:
    the Workhorse of RDI_withBT.000 (898 ensembles with an error velocity, 2 bottom-track
    pings every 1.5 s)."""
    assert main(["decode", "--format", "pd0", str(_path("pd0/RDI_withBT.000"))]) == 0
    last = capsys.readouterr().out.splitlines()[-1]
    assert last.startswith("# bottom-track velocity noise") and "898 ensembles" in last
    assert "every 1.50 s): 4.4 mm/s an ensemble, 6.3 mm/s a ping (2 bottom-track" in last
    assert "the simulated DVL (thesis Table A.1): 3.0 mm/s a sample at 6 Hz" in last
    rc, _, summary = _run_json(capsys, "pd0", _path("pd0/RDI_withBT.000"))
    noise = summary["bottom_track_noise"]
    assert rc == 0 and noise["ensembles"] == 898 and noise["bt_pings"] == 2
    assert noise["sigma_m_s"] == pytest.approx(0.0044478, abs=1e-6)
    _, _, few = _run_json(capsys, "pd0", _path("pd0/adcp_auv_3.pd0"))
    assert "bottom_track_noise" not in few  # 3 ensembles: too few for a figure


@pytest.mark.parametrize("fmt, rel, cut, frames, at", [
    ("pd0", "pd0/adcp_auv_3.pd0", 1000, 2, 864),  # three ensembles of 432 B, cut in the third
    ("pd0", "pd0/adcp_auv_3.pd0", 40, 0, 0),  # cut in the first one's header
    ("phins-stdbin", "phins/log_STDBIN_V3.log", 6150, 8, 5832),
])
def test_a_recording_cut_short_reports_its_last_frame_as_one_truncated_stretch(
        capsys, tmp_path, fmt, rel, cut, frames, at):
    # found by probing (session 21): the cut frame was reported as 1 B "truncated" and
    # the rest of it as "garbage: no pd0 sync word"
    f = tmp_path / Path(rel).name
    f.write_bytes(_path(rel).read_bytes()[:cut])
    rc, out, summary = _run_json(capsys, fmt, f)
    assert len(out) == frames == summary["frames"] and rc == (0 if frames else 1)
    assert summary["bytes_dropped"] == cut - at and summary["resyncs"] == 1
    assert summary["errors"] == [{"offset": at, "kind": "truncated", "bytes": cut - at,
                                  "message": f"incomplete {fmt} frame at end"}]
    assert main(["decode", "--format", fmt, str(f)]) == rc
    assert capsys.readouterr().out.splitlines()[-1] == \
        f"#   at byte {at}: truncated ({cut - at} B): incomplete {fmt} frame at end"
