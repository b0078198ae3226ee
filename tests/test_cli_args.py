"""The command line's numbers: a duration, count or rate that is negative, zero where it must
not be, NaN or infinite is refused by its option, exit 2, before anything starts. Found by
trying such values on every command: they gave tracebacks (``uvd demo --duration -1``,
``uvd experiment two-step --hours nan``, ``uvd bench cycle --block 0``), watched for ever
(``uvd watch --seconds -1``, ``uvd-fdc --seconds -1``), ran all but one run
(``uvd campaign --limit -1``), never detected (``uvd-fdc --threshold nan``) or ran and ended at
once (``uvd run --duration -1``, ``uvd sim-bridge --duration -5``)."""

from __future__ import annotations

import pytest

from uvd.cli import main
from uvd.fdc.detector import CusumSettings


@pytest.mark.parametrize("argv, option", [
    (["demo", "--duration", "-1"], "--duration"),
    (["demo", "--duration", "nan"], "--duration"),
    (["run", "--duration", "-1"], "--duration"),
    (["sim-bridge", "--duration", "-5"], "--duration"),
    (["watch", "--seconds", "-1"], "--seconds"),
    (["watch", "--seconds", "nan"], "--seconds"),
    (["eta", "4", "0.5", "--timeout", "inf"], "--timeout"),
    (["experiment", "two-step", "--hours", "-1"], "--hours"),
    (["experiment", "two-step", "--hours", "nan"], "--hours"),
    (["campaign", "smoke", "--limit", "-1"], "--limit"),
    (["campaign", "smoke", "--limit", "0"], "--limit"),
    (["decode", "--format", "pd0", "--max-errors", "-5", "x.pd0"], "--max-errors"),
    (["xval", "--params", "p.toml", "--log", "l.bag", "--substeps", "0"], "--substeps"),
    (["bench", "lockstep", "--hours", "-1"], "--hours"),
    (["bench", "cycle", "--block", "0"], "--block"),
    (["bench", "loop", "--rate", "0"], "--rate"),
    (["bench", "campaign", "--workers", "1", "0"], "--workers"),
])
def test_a_bad_number_is_refused_by_its_option(argv, option, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    bad = "0" if option == "--workers" else argv[argv.index(option) + 1]  # workers: 1 then 0
    assert f"argument {option}: '{bad}' is not " in err, err


def test_the_defaults_and_good_values_still_parse():
    from uvd.cli import build_parser
    p = build_parser()
    assert p.parse_args(["demo"]).duration == 60.0
    assert p.parse_args(["watch"]).seconds == 0.0  # 0: until Ctrl-C
    assert p.parse_args(["campaign", "smoke", "--limit", "3"]).limit == 3
    assert p.parse_args(["decode", "--format", "pd0", "--max-errors", "0", "x"]).max_errors == 0
    assert p.parse_args(["experiment", "two-step", "--hours", "0.5"]).hours == 0.5


@pytest.mark.parametrize("argv, words", [
    (["--seconds", "-1"], "argument --seconds: -1.0 is not a finite number >= 0"),
    (["--threshold", "nan"], "argument --threshold must be a finite number > 0, got nan"),
    (["--segment-s", "-3"], "argument --segment-s must be a finite number > 0, got -3.0"),
    (["--warmup-s", "-1"], "argument --warmup-s must be a finite number >= 0, got -1.0"),
])
def test_uvd_fdc_refuses_a_bad_setting_before_it_connects(argv, words, capsys):
    from uvd.fdc.client import main as fdc_main
    with pytest.raises(SystemExit) as e:
        fdc_main(argv)
    assert e.value.code == 2 and words in capsys.readouterr().err


@pytest.mark.parametrize("bad", [dict(h=float("nan")), dict(baseline_s=0.0), dict(window=0),
                                 dict(window=2.5), dict(segment_s=float("inf")),
                                 dict(reference_lag_s=-1.0), dict(mass_change=True),
                                 dict(h="15")])
def test_cusum_settings_refuse_a_setting_that_would_never_detect(bad):
    with pytest.raises(ValueError, match=f"CusumSettings.{next(iter(bad))} must be"):
        CusumSettings(**bad)


def test_cusum_settings_defaults_and_zero_waits_are_valid():
    assert CusumSettings().h == 15.0
    assert CusumSettings(warmup_s=0.0, reference_lag_s=0.0).warmup_s == 0.0


def test_a_campaign_folder_that_cannot_be_made_is_a_command_line_error(tmp_path, capsys):
    """``uvd campaign NAME --out X`` where X cannot be a folder (under a file here; /proc or
    a read-only disk alike) says so in one line, exit 2 (it was a FileNotFoundError's
    traceback), and runs nothing."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    assert main(["campaign", "smoke", "--out", str(blocker / "out"), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"uvd campaign: error: {blocker / 'out'}: cannot hold the "
                          "campaign's rows"), err
