"""The command line's numbers: a duration, count or rate that is negative, zero where it must
not be, NaN or infinite is refused by its option, exit 2, before anything starts. Found by
trying such values on every command: they gave tracebacks (``uvd demo --duration -1``,
``uvd experiment two-step --hours nan``, ``uvd bench cycle --block 0``), watched for ever
(``uvd watch --seconds -1``, ``uvd-fdc --seconds -1``), ran all but one run
(``uvd campaign --limit -1``), never detected (``uvd-fdc --threshold nan``) or ran and ended at
once (``uvd run --duration -1``, ``uvd sim-bridge --duration -5``). And the outputs: every
option naming where a result goes is checked the same way (a path under a file made 14 commands
run their work and then lose it to a traceback)."""

from __future__ import annotations

from pathlib import Path

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
    (["campaign", "smoke", "--workers", "0"], "--workers"),
    # session 33: 1000 workers on 2 cores were still starting two minutes later; a day's
    # ceiling on the demo, whose lockstep twins are computed first (1e9 s: 75 GiB, traceback)
    (["campaign", "smoke", "--workers", "1000"], "--workers"),
    (["demo", "--duration", "1e9"], "--duration"),
    # session 33: under a second no cycle ran and most experiments ended in an IndexError
    (["experiment", "two-step", "--hours", "1e-9"], "--hours"),
    (["bench", "lockstep", "--hours", "1e-9"], "--hours"),
    # session 33: an OverflowError traceback (select's time_t), a kernel that ran on for
    # minutes after its SIGTERM, a day-long ceiling on a sweep of lockstep runs
    (["eta", "4", "0.5", "--timeout", "1e308"], "--timeout"),
    (["xval", "--params", "p.toml", "--log", "l.bag", "--substeps", "1000000000"], "--substeps"),
    (["tune", "--aid-sweep", "1e9"], "--aid-sweep"),
    (["replay", "--realtime", "--wait", "1e308", "r.mcap"], "--wait"),  # OverflowError
    # named DepthConverter's fields rather than the options (session 33)
    (["decode", "--format", "digiquartz", "--unit", "99", "x.dq"], "--unit"),
    (["decode", "--format", "digiquartz", "--latitude", "1e9", "x.dq"], "--latitude"),
    (["decode", "--format", "digiquartz", "--atmosphere-pa", "-5", "x.dq"], "--atmosphere-pa"),
    (["replay", "--realtime", "--can-port", "70000", "r.mcap"], "--can-port"),
    (["decode", "--format", "pd0", "--max-errors", "-5", "x.pd0"], "--max-errors"),
    (["xval", "--params", "p.toml", "--log", "l.bag", "--substeps", "0"], "--substeps"),
    (["bench", "lockstep", "--hours", "-1"], "--hours"),
    (["bench", "cycle", "--block", "0"], "--block"),
    (["bench", "loop", "--rate", "0"], "--rate"),
    (["bench", "campaign", "--workers", "1", "0"], "--workers"),
    (["experiment", "two-step", "--seed", "-1"], "--seed"),
    (["demo", "--seed", "-1"], "--seed"),
    (["sim-bridge", "--seed", "-1"], "--seed"),
    (["tune", "--aid-sweep", "-1"], "--aid-sweep"),
    (["eta", "4", "0.5", "--system", "300"], "--system"),
    (["eta", "4", "0.5", "--system", "0"], "--system"),
    (["eta", "4", "0.5", "--to", "127.0.0.1"], "--to"),
    (["eta", "4", "0.5", "--to", "localhost:14551"], "--to"),
    (["eta", "4", "0.5", "--to", "127.0.0.1:70000"], "--to"),
])
def test_a_bad_number_is_refused_by_its_option(argv, option, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    bad = "0" if argv[:2] == ["bench", "campaign"] else argv[argv.index(option) + 1]  # 1 then 0
    assert f"argument {option}: '{bad}' is not " in err, err


@pytest.mark.parametrize("argv, words", [
    (["--connect", "garbage"], "argument --connect: 'garbage' is not <protocol>/<address>"),
    (["--connect", "tcp/127.0.0.1:99999"], "'tcp/127.0.0.1:99999' has no port 1-65535"),
    (["--vehicle", ""], "argument --vehicle: '' is empty"),
    (["--vehicle", "rov/7"], "'rov/7' is not a single key chunk"),
    (["--vehicle", "**"], "'**' is not a single key chunk"),
])
def test_the_zenoh_clients_refuse_an_endpoint_or_vehicle_zenoh_cannot_take(argv, words,
                                                                            capsys):
    """``uvd watch`` and uvd-fdc: ``--connect garbage`` and ``--vehicle ''`` were zenoh's
    ZError tracebacks, ``--connect tcp/127.0.0.1:99999`` a watch that waited for ever."""
    from uvd.fdc.client import main as fdc_main
    for run in (lambda: main(["watch", *argv]), lambda: fdc_main(argv)):
        with pytest.raises(SystemExit) as e:
            run()
        assert e.value.code == 2
        assert words in capsys.readouterr().err


def test_the_zenoh_clients_name_a_bad_config_file_and_an_unreachable_router(tmp_path, capsys):
    from uvd.fdc.client import main as fdc_main
    from uvd.netports import free_port
    bad = tmp_path / "bad.json5"
    bad.write_text("{ not json5")
    closed = tmp_path / "client.json5"  # client mode: zenoh.open fails at once without one
    closed.write_text(f'{{mode: "client", connect: {{endpoints: '
                      f'["tcp/127.0.0.1:{free_port()}"]}}}}')
    for run, who in ((lambda a: main(["watch", "--seconds", "1", *a]), "uvd watch"),
                     (lambda a: fdc_main(["--seconds", "1", *a]), "uvd-fdc")):
        assert run(["--zenoh-config", str(tmp_path / "none.json5")]) == 2
        assert (f"{who}: error: --zenoh-config {tmp_path / 'none.json5'}: No such file"
                in capsys.readouterr().err)
        assert run(["--zenoh-config", str(bad)]) == 2
        assert f"{who}: error: --zenoh-config {bad}: " in capsys.readouterr().err
        assert run(["--zenoh-config", str(closed)]) == 2
        err = capsys.readouterr().err
        assert f"{who}: error: cannot open the Zenoh session: Unable to connect" in err, err
        assert ".rs:" not in err  # zenoh's Rust source locations left out


def test_a_client_that_reaches_nothing_says_so_and_goes_on(capsys):
    """A peer ``uvd watch`` or uvd-fdc whose endpoint nobody listens on (a wrong port, no
    daemon yet) printed its "watching …" line and then nothing, for as long as it ran. After
    3 s each says that it reached nothing and keeps trying; with a Zenoh session listening
    there, neither does — unless the vehicle it watches is not up there (a misspelt
    ``--vehicle``, which waited in silence too): then it names those that are."""
    import zenoh

    from uvd.fdc.client import main as fdc_main
    from uvd.netports import free_port
    port = free_port()
    argv = ["--connect", f"tcp/127.0.0.1:{port}", "--seconds", "4"]
    says = f"nothing reached through tcp/127.0.0.1:{port} in 3 s"
    assert main(["watch", *argv]) == 0
    assert f"uvd watch: {says}" in capsys.readouterr().err
    assert fdc_main(argv) == 0
    assert f"uvd-fdc: {says}" in capsys.readouterr().out
    # a run that ends first says it as it stops, without "still trying" (session 33: one of
    # 3 s said "… in 3 s …; still trying" and ended; one of 1 s said nothing)
    short = ["--connect", f"tcp/127.0.0.1:{port}", "--seconds", "1"]
    ends = (f"nothing reached through tcp/127.0.0.1:{port} in 1 s (is the daemon running, its "
            "[telemetry.zenoh] listen that endpoint?)\n")
    assert main(["watch", *short]) == 0
    assert capsys.readouterr().err.endswith(f"uvd watch: {ends}")
    assert fdc_main(short) == 0
    out = capsys.readouterr().out
    assert f"uvd-fdc: {ends}" in out and "still trying" not in out, out
    conf = zenoh.Config()
    conf.insert_json5("listen/endpoints", f'["tcp/127.0.0.1:{port}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as there:
        token = there.liveliness().declare_token("uvd/sub9/alive")  # a vehicle up there
        assert main(["watch", *argv, "--vehicle", "sub8"]) == 0  # misspelt: it is told
        assert fdc_main([*argv, "--vehicle", "sub9"]) == 0
        token.undeclare()
    got = capsys.readouterr()
    assert "nothing reached" not in got.err + got.out
    assert f"uvd watch: no vehicle 'sub8' through tcp/127.0.0.1:{port} in 3 s; up there: sub9 " \
           "(--vehicle NAME, or * for every vehicle); still trying" in got.err, got.err
    assert "no vehicle" not in got.out, got.out


def test_eta_refuses_thruster_0_and_an_ipv6_address_it_cannot_reach(capsys):
    """Thrusters count from 1; pymavlink's UDP is IPv4 only, so ``--to [::1]:P`` is refused
    in words (it was pymavlink's "UDP ports must be specified as host:port")."""
    with pytest.raises(SystemExit) as e:
        main(["eta", "0", "0.5"])
    assert e.value.code == 2
    assert "argument thruster: '0' is not an integer >= 1" in capsys.readouterr().err
    assert main(["eta", "4", "0.5", "--to", "[::1]:14551", "--timeout", "1"]) == 2
    assert "[::1]:14551: uvd eta speaks IPv4 only" in capsys.readouterr().err


def test_the_defaults_and_good_values_still_parse():
    from uvd.cli import build_parser
    p = build_parser()
    assert p.parse_args(["demo"]).duration == 60.0
    assert p.parse_args(["watch"]).seconds == 0.0  # 0: until Ctrl-C
    assert p.parse_args(["campaign", "smoke", "--limit", "3"]).limit == 3
    assert p.parse_args(["decode", "--format", "pd0", "--max-errors", "0", "x"]).max_errors == 0
    assert p.parse_args(["experiment", "two-step", "--hours", "0.5"]).hours == 0.5
    assert p.parse_args(["experiment", "two-step", "--seed", "0"]).seed == 0
    eta = p.parse_args(["eta", "4", "0.5", "--to", "127.0.0.1:14551", "--system", "1"])
    assert (eta.thruster, eta.to, eta.system) == (4, "127.0.0.1:14551", 1)
    assert p.parse_args(["eta", "4", "0.5"]).system == 255


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


#: every option naming where a command writes a result: a file (--json, …) or a folder
OUTPUT_OPTIONS = {"--json": "file", "--history": "file", "--doc-out": "file", "--out": None,
                  "--summary-json": "file", "--truth-log": "file", "--plots": "folder",
                  "--record": "folder", "--work": "folder"}


def _subparsers(parser, path=()):
    import argparse
    yield path, parser
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sp in a.choices.items():
                yield from _subparsers(sp, (*path, name))


def test_every_output_option_is_checked_before_anything_starts():
    """Every option that names where a result goes is an output type: found by pointing each
    at a path under a file, 14 of them ran their work (an experiment, a demo, a campaign, an
    identification) and then lost it to a NotADirectoryError's traceback."""
    from uvd.cli import build_parser
    from uvd.cliargs import output_file, output_folder
    seen = []
    for path, sp in _subparsers(build_parser()):
        for a in sp._actions:
            for opt in a.option_strings:
                if opt in OUTPUT_OPTIONS and a.type is not None:  # decode --json: a flag
                    assert a.type in (output_file, output_folder), (path, opt, a.type)
                    seen.append((*path, opt))
    assert len(seen) >= 20, seen  # 12 commands' and every bench's --json/--history


@pytest.mark.parametrize("argv, option", [
    (["experiment", "two-step", "--json", "{F}/x.json"], "--json"),
    (["experiment", "two-step", "--plots", "{F}/plots"], "--plots"),
    (["experiment", "two-step", "--record", "{F}"], "--record"),
    (["demo", "--json", "{F}/sub/x.json"], "--json"),
    (["demo", "--record", "{F}/run"], "--record"),
    (["campaign", "smoke", "--out", "{F}/out", "--workers", "1"], "--out"),
    (["campaign", "smoke", "--json", "{F}/s.json"], "--json"),
    (["identify", "--log", "x.bag", "--out", "{F}/p.toml"], "--out"),
    (["report", "x.mcap", "--out", "{F}/rep"], "--out"),
    (["replay", "--lockstep", "x.mcap", "--json", "{F}/r.json"], "--json"),
    (["xval", "--params", "p.toml", "--log", "l.bag", "--plots", "{F}"], "--plots"),
    (["bench", "plant", "--history", "{F}/h.jsonl"], "--history"),
    (["check-config", "--doc-out", "{F}/config.md"], "--doc-out"),
    (["run", "--summary-json", "{F}/s.json"], "--summary-json"),
    (["sim-bridge", "--truth-log", "{F}/t.bin"], "--truth-log"),
])
def test_an_output_under_a_file_is_refused_by_its_option(argv, option, tmp_path, capsys):
    """A path under a file (here; a read-only disk alike) cannot be made: refused by its option,
    exit 2, before anything starts — with nothing made."""
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    argv = [a.replace("{F}", str(blocker)) for a in argv]
    before = sorted(tmp_path.rglob("*"))
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}: " in err and f"{blocker} is a file, not a folder" in err, err
    assert sorted(tmp_path.rglob("*")) == before


def test_a_folder_given_for_a_file_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["experiment", "two-step", "--json", str(tmp_path)])
    assert e.value.code == 2
    assert f"argument --json: '{tmp_path}' is a folder, not a file" in capsys.readouterr().err


def test_missing_folders_of_an_output_are_made(tmp_path):
    """The other half of the one rule: what does not exist yet is made when written."""
    out = tmp_path / "new" / "deeper" / "config.md"
    assert main(["check-config", "--doc-out", str(out)]) == 0
    assert out.read_text().startswith("#")


def test_an_unwritable_folder_is_refused(tmp_path):
    """A folder this user cannot write in: a read-only one (not to root), and /proc/self, in
    which not even root can make anything — root passes access() there, and ``uvd report
    --out /proc/self/x`` ended at its first write, exit 1 with the OS's words (sessions
    30-32): now it is refused before anything runs, whoever runs it."""
    import argparse
    import os

    from uvd.cliargs import output_file, output_folder
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        cases = [(Path("/proc/self"), "is not writable|nothing can be made in")]
        if os.geteuid() != 0:
            cases.append((ro, "is not writable"))
        for folder, words in cases:
            for make, path in ((output_file, folder / "x.json"),
                               (output_folder, folder / "a" / "b")):
                with pytest.raises(argparse.ArgumentTypeError, match=f"{folder} ({words})"):
                    make(str(path))
        assert not any(p.name.startswith(".uvd-probe-") for p in tmp_path.iterdir())
        output_folder(str(tmp_path / "a" / "b"))  # a writable place: no probe left behind
        assert [p.name for p in tmp_path.iterdir()] == ["ro"]
    finally:
        ro.chmod(0o700)


def test_a_default_campaign_folder_that_cannot_be_made_is_an_error(tmp_path, capsys,
                                                                    monkeypatch):
    """Without --out the rows go to campaigns/<name>; where that cannot be a folder (a file
    named campaigns here) the store says so in one line, exit 2, and runs nothing."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "campaigns").write_text("")
    assert main(["campaign", "smoke", "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("uvd campaign: error: campaigns/smoke: cannot hold the campaign's "
                          "rows"), err


def test_zenoh_names_rules():
    from uvd.zenoh_names import endpoint_problem, vehicle_key_problem
    for good in ("jhu-rov", "rov_7", "bluerov2-heavy", "sim00"):
        assert vehicle_key_problem(good) is None
    for bad in ("", "*", "**", "a/b", "a b", "$x", "a?b", "a#b", "a\tb"):
        assert vehicle_key_problem(bad) is not None, bad
    for good in ("tcp/127.0.0.1:7447", "tcp/[::1]:7447", "tls/localhost:7448",
                 "udp/127.0.0.1:7447#iface=lo", "tcp/127.0.0.1:1?prio=1", "unixsock-stream/x"):
        assert endpoint_problem(good) is None, good
    for bad in ("garbage", "", "tcp/", "tcp/127.0.0.1", "tcp/127.0.0.1:0",
                "tcp/127.0.0.1:65536", "tcp/:7447", "/127.0.0.1:7447", "tcp /x:1"):
        assert endpoint_problem(bad) is not None, bad


@pytest.mark.parametrize("name", ["fault-tolerance", "fault-tolerance-every",
                                  "fault-tolerance-hil", "aid-rot", "aid-6dof", "fdc-fleet",
                                  "aid-truth"])
def test_an_experiment_too_short_for_its_figures_says_so(name, capsys):
    """``uvd experiment NAME --hours 0.01`` (36 s): tried on every experiment, five were
    tracebacks (an empty window's numpy ValueError, an IndexError, a KeyError) where fdc-fleet
    said it was too short; now each names what it needs before anything runs. aid-truth
    (session 24): ``--hours 0.0001`` was least squares' traceback after the run; it asks for
    a minute, as the other identification experiments do."""
    assert main(["experiment", name, "--hours", "0.01", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"uvd experiment: error: {name}: --hours 0.01 is too short" in err, err


def test_the_command_line_loads_no_numeric_kernels_to_build_its_parser():
    """``uvd watch``, ``uvd eta`` and the like start in about a third of a second: building the
    parser (every command and bench registers its options) imports neither numba, SciPy nor
    python-can (with them, 0.58 s; the daemon's cycle and the benches import them when they
    run). A fresh interpreter, since this one has them all."""
    import subprocess
    import sys
    code = ("import sys; from uvd.cli import build_parser; build_parser(); "
            "print(' '.join(m for m in ('numba', 'scipy', 'can', 'uvd.estimation.aid', "
            "'sim_bridge.plant') if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "", f"imported to build the parser: {r.stdout.strip()}"
