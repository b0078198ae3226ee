"""The command line: help, version, the hardware-in-the-loop demo, stopped by a signal."""

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.procs import assert_gone, children
from uvd import __version__
from uvd.cli import Stopped, main, unwinding_signals


def test_help_lists_commands(capsys):
    assert main([]) == 2
    out = capsys.readouterr().out
    for cmd in ("demo", "experiment", "bench"):
        assert cmd in out


@pytest.mark.untimed
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


def test_signals_unwind_a_command_as_ctrl_c_does():
    """A real SIGTERM (then SIGHUP) inside :func:`unwinding_signals` raises Stopped, which is
    a KeyboardInterrupt (every command's Ctrl-C path applies); the handlers before are back
    after it."""
    before = signal.getsignal(signal.SIGTERM)
    for sig in (signal.SIGTERM, signal.SIGHUP):
        cleaned = []
        with pytest.raises(Stopped) as err, unwinding_signals():
            try:
                os.kill(os.getpid(), sig)
                time.sleep(5.0)  # the handler raises within this
            finally:
                cleaned.append(sig)
        assert err.value.signum == sig and isinstance(err.value, KeyboardInterrupt)
        assert cleaned == [sig]
    assert signal.getsignal(signal.SIGTERM) == before


def _parser_running(handler):
    import argparse
    parser = argparse.ArgumentParser(prog="uvd")
    sub = parser.add_subparsers(dest="command")
    sub.add_parser("x").set_defaults(handler=handler)
    return lambda: parser


def test_a_lock_broken_by_ctrl_c_is_still_an_interruption(monkeypatch, capsys):
    """The chain CPython gives when Ctrl-C lands in a Condition's wait at the wrong moment
    (measured once in ``uvd demo``'s queue of log lines, session 32): KeyboardInterrupt, then
    while handling it RuntimeError "release unlocked lock". The command ends as interrupted
    (130, one line); a RuntimeError of its own is still raised."""
    import uvd.cli

    def broken_by_ctrl_c(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise RuntimeError("release unlocked lock")  # noqa: B904 - as CPython raises it

    def a_bug(args):
        raise RuntimeError("a bug")

    broken = _parser_running(broken_by_ctrl_c)
    monkeypatch.setattr(uvd.cli, "build_parser", broken)
    assert main(["x"]) == 130
    assert capsys.readouterr().err == "uvd x: interrupted\n"
    monkeypatch.setattr(uvd.cli, "build_parser", _parser_running(a_bug))
    with pytest.raises(RuntimeError, match="a bug"):
        main(["x"])


@contextlib.contextmanager
def _armed_demo(*args: str, cwd: Path | None = None):
    """``uvd demo --duration 60 ARGS`` in a session of its own, once armed (both processes
    up): ``(process, its children)``; all of them killed after, whatever happened."""
    proc = subprocess.Popen([sys.executable, "-m", "uvd", "demo", "--duration", "60", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, cwd=cwd)
    kids: list[int] = []
    try:
        deadline = time.monotonic() + 240.0
        for line in proc.stdout:  # "armed ... after start": both processes up
            if "armed" in line and "after start" in line or time.monotonic() > deadline:
                break
        kids += children(proc.pid)
        assert len(kids) >= 2, f"the demo's processes: {kids}"
        yield proc, kids
    finally:
        for k in kids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(k, signal.SIGKILL)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10.0)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_a_demo_stopped_by_a_signal_leaves_no_process_behind(tmp_path, sig):
    """``kill PID`` of a running ``uvd demo`` (the signal to the demo alone, not its process
    group, as a job runner or a user's kill sends it): the daemon it started is stopped as
    systemd would, sim-bridge too. SIGTERM: the demo unwinds and ends by that signal; SIGKILL
    (a tool's timeout), which nothing in the demo sees: sim-bridge ends as its input closes,
    the daemon on the SIGTERM the kernel sends when its parent ends (``--stop-with-parent``).
    Before (session 25), either left the daemon running for the rest of its 360 s bound."""
    with _armed_demo() as (proc, kids):
        os.kill(proc.pid, sig)
        out, err = proc.communicate(timeout=30.0)
        assert proc.returncode == -sig, err[-2000:]
        if sig == signal.SIGTERM:
            assert "uvd demo: stopped by SIGTERM" in err, err[-2000:]
        assert_gone(kids)


@pytest.mark.parametrize("who", ["daemon", "sim-bridge"])
def test_a_process_that_dies_during_the_demo_is_said_so(who):
    """Found by probing (session 33), SIGKILL to one of the demo's processes during the run.
    The daemon: the report ended in "SIGTERM → daemon exit code -9 in 0.00 s" — no SIGTERM of
    the demo's had ended it — and a memory growth of "+nan MB" (its window was the whole run's,
    past the daemon's end). sim-bridge: nothing said; the demo watched on to the end of its
    60 s, "sim-bridge RSS nan MB" every 10 s. Now either is said at once, the run ends there
    (exit 1), and the report's last line says which process ended and how."""
    with _armed_demo() as (proc, kids):
        word = b"\0run\0" if who == "daemon" else b"\0sim-bridge\0"
        victim = next(k for k in kids if word in Path(f"/proc/{k}/cmdline").read_bytes())
        time.sleep(4.0)
        os.kill(victim, signal.SIGKILL)
        t_kill = time.monotonic()
        out, err = proc.communicate(timeout=120.0)
        took = time.monotonic() - t_kill
        assert_gone(kids)
    assert proc.returncode == 1, err[-2000:]
    assert took < 30.0, took  # not the rest of the 60 s run
    name = "The daemon" if who == "daemon" else "sim-bridge, the simulated vehicle,"
    lines = out.strip().splitlines()
    assert lines[-1].startswith(f"{name} ended by itself ") and lines[-1].endswith(
        " s after arming: exit code -9 (killed by SIGKILL)"), out[-3000:]
    if who == "daemon":
        assert "uvd demo: the daemon exited during the run:" in out, out[-3000:]
        assert not any(ln.startswith("SIGTERM →") for ln in lines), out[-3000:]
    else:
        assert "uvd demo: sim-bridge, the simulated vehicle, exited during the run (exit code " \
               "-9 (killed by SIGKILL)): stopping the daemon" in out, out[-3000:]
        assert lines[-2].startswith("SIGTERM → daemon exit code 0 in "), out[-3000:]
    memory = next(ln for ln in lines if ln.startswith("Memory: "))
    assert "nan" not in memory.partition("sim-bridge")[0], memory


def test_ctrl_c_ends_the_demo_in_order_with_the_figures_of_the_seconds_run(tmp_path):
    """Ctrl-C in the terminal (SIGINT to the demo's whole process group) 3 s after arming:
    the daemon stops in order — sim-bridge, the vehicle's hardware in a session of its own,
    runs on until the demo stops it last, so the daemon still finds its amplifiers to disable,
    and its MAVLink receiver waits to be ended — then the demo prints the figures of the
    seconds run and ends with 130; no process is left. Before (session 32) it printed only
    "interrupted", and the daemon's log had "did not finish" (the amplifiers gone with the
    Ctrl-C) and "receiver process ended; starting another". ``--record`` is given relative to
    the working directory, as a user types it (before session 32: refused, the configuration
    it wrote had relative device paths)."""
    out, rec = tmp_path / "demo.json", tmp_path / "rec"
    with _armed_demo("--json", str(out), "--record", "rec", cwd=tmp_path) as (proc, kids):
        time.sleep(3.0)
        os.killpg(proc.pid, signal.SIGINT)
        text, err = proc.communicate(timeout=60.0)
        assert proc.returncode == 130, err[-2000:]
        assert "Interrupted after" in text and "position MAE" in text, text[-2000:]
        assert "the daemon exited during the run" not in text, text[-2000:]
        assert "Ctrl-C, then SIGTERM → daemon exit code 0" in text, text[-2000:]
        res = json.loads(out.read_text())
        assert res["interrupted"]["of_s"] == 60.0 and 2.5 < res["interrupted"]["after_s"] < 30
        assert res["tracking"]["samples"] >= 25 and res["daemon"]["exit_code"] == 0
        assert res["memory"]["daemon_peak_rss_mb"] > 50, res["memory"]  # not NaN: it ended
        assert set(res["lockstep"]["ratio"]) == {"x", "y", "z", "roll", "pitch", "heading"}
        log = (rec / "daemon.log").read_text()
        assert "ARMED → SHUTDOWN (shutdown: SIGINT)" in log, log[-2000:]
        assert "did not finish" not in log and "receiver process ended" not in log, log[-2000:]
        assert json.loads((rec / "demo.json").read_text())["interrupted"] == res["interrupted"]
        assert_gone(kids)


def _no_file_may_grow() -> None:
    """In the child: RLIMIT_FSIZE 1 byte — a write past it fails in the kernel (EFBIG), as
    on a full disk — with SIGXFSZ ignored (its default would end the process)."""
    import resource
    resource.setrlimit(resource.RLIMIT_FSIZE, (1, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)


def test_a_demo_recorded_where_a_run_is_already_is_refused(tmp_path, capsys):
    """Found by probing (session 33): a second `uvd demo --record rec` overwrote the first
    run's demo.json, telemetry, truth and logs (its MCAP stayed, beside the second's). Now it
    is refused before anything starts, the first run untouched; an empty or new folder is
    taken."""
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "demo.json").write_text("{}")
    (rec / "uvd-20261130T053813-000.mcap").write_bytes(b"x")
    assert main(["demo", "--duration", "1", "--record", str(rec)]) == 2
    assert capsys.readouterr().err == (
        f"uvd demo: --record {rec}: it holds a run already (demo.json, "
        "uvd-20261130T053813-000.mcap); give another folder, or remove that one: nothing "
        "started\n")
    assert sorted(p.name for p in rec.iterdir()) == ["demo.json", "uvd-20261130T053813-000.mcap"]
    from uvd.commands.demo import _a_run_in
    assert _a_run_in(tmp_path / "new") is None and _a_run_in(tmp_path / "empty") is None
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    assert _a_run_in(tmp_path / "other") is None


def test_a_run_too_long_for_memory_is_an_error_not_a_traceback(capsys):
    """Found by probing (session 33): `uvd experiment ambc-robust --hours 1e9` and `uvd demo
    --duration 1e9` ended in numpy's _ArrayMemoryError traceback. Any command: one line, exit
    1; the demo's duration, whose lockstep twins are computed before the run, has a ceiling
    (a day) and is refused at the command line."""
    assert main(["experiment", "ambc-robust", "--hours", "1e9", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("uvd experiment: error: out of memory (Unable to allocate ") \
        and err.endswith("): a shorter run, or a machine with more memory\n"), err
    with pytest.raises(SystemExit) as stop:
        main(["demo", "--duration", "1e9"])
    assert stop.value.code == 2
    assert "argument --duration: '1e9' is not a positive number up to 86400" in \
        capsys.readouterr().err


@pytest.mark.untimed
def test_a_failed_write_is_an_error_that_says_so_not_a_traceback(tmp_path):
    """A command whose output cannot be written (a full disk) ends with exit 1 and one line;
    a --json OUT names its path and leaves no temporary file. Both were tracebacks
    (session 25: `uvd demo --record` on a full disk, writing demo.json)."""
    doc = tmp_path / "config.md"
    r = subprocess.run([sys.executable, "-m", "uvd", "check-config", "--doc-out", str(doc)],
                       capture_output=True, text=True, timeout=120,
                       preexec_fn=_no_file_may_grow)
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert r.stderr == f"uvd check-config: error: [Errno 27] cannot write {doc}: File too " \
        "large\n"
    assert not doc.exists() and not list(tmp_path.glob("*.tmp"))
    out = tmp_path / "figures.json"
    r = subprocess.run([sys.executable, "-c", "import sys\nfrom uvd.jsonio import write_json\n"
                        "try:\n    write_json(sys.argv[1], {'x': list(range(100))})\n"
                        "except OSError as exc:\n    print(exc)", str(out)],
                       capture_output=True, text=True, timeout=120,
                       preexec_fn=_no_file_may_grow)
    assert r.stdout.strip() == f"[Errno 27] cannot write {out}: File too large", r.stderr
    assert not out.exists() and not list(tmp_path.glob("*.tmp"))


def test_a_write_interrupted_by_ctrl_c_leaves_the_old_file_and_no_temporary(tmp_path):
    """``uvd.jsonio.write_whole`` (every result file, parameter file and doc the commands
    write): a KeyboardInterrupt mid-write leaves the old file as it was and no temporary."""
    from uvd.jsonio import write_whole
    path, tmp = tmp_path / "params.toml", tmp_path / ".params.toml.tmp"
    path.write_text("old\n")

    def write(t):
        t.write_text("half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_whole(path, write, tmp)
    assert path.read_text() == "old\n" and not tmp.exists()


@pytest.mark.untimed
def test_a_temporary_path_that_is_a_folder_is_the_error_told_and_stays(tmp_path):
    """``write_whole`` whose temporary path is a folder (left by something else): the write's
    own error is told, naming the file, not the failed removal of the temporary (which hid
    it: IsADirectoryError from ``unlink``); the folder and the old file stay as they were."""
    from uvd.jsonio import write_whole
    path, tmp = tmp_path / "params.toml", tmp_path / ".params.toml.tmp"
    path.write_text("old\n")
    (tmp / "inside").mkdir(parents=True)
    with pytest.raises(OSError, match=f"cannot write {path}: Is a directory"):
        write_whole(path, lambda t: t.write_text("new\n"), tmp)
    assert path.read_text() == "old\n" and (tmp / "inside").is_dir()


def test_a_whole_write_forces_the_data_before_the_rename_and_the_rename_after(
        tmp_path, monkeypatch):
    """``write_whole`` against a power cut of the machine (which no test can make): the new
    file's data is forced to the disk before it is renamed over the old one, and the folder
    (the rename) after — the order that leaves the old file or the new one, never an empty
    one. The calls are watched as the real ones run (``os.fsync`` and ``os.replace`` of the
    module, called through); so is the MAVLink parameters file, written through it."""
    import os
    import stat

    import uvd.jsonio as jsonio
    from uvd.links.mavlink.params import read_params_file, write_params_file

    calls: list[tuple[str, str]] = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        mode = os.fstat(fd).st_mode
        calls.append(("fsync", "folder" if stat.S_ISDIR(mode) else "file"))
        return real_fsync(fd)

    def replace(a, b):
        calls.append(("replace", Path(b).name))
        return real_replace(a, b)

    monkeypatch.setattr(jsonio.os, "fsync", fsync)
    monkeypatch.setattr(jsonio.os, "replace", replace)
    jsonio.write_json(tmp_path / "out.json", {"x": 1})
    assert calls == [("fsync", "file"), ("replace", "out.json"), ("fsync", "folder")], calls
    calls.clear()
    write_params_file(tmp_path / "params.toml", {"control.kp": 310.0})
    assert calls == [("fsync", "file"), ("replace", "params.toml"), ("fsync", "folder")], calls
    assert read_params_file(tmp_path / "params.toml") == {"control.kp": 310.0}
    assert sorted(x.name for x in tmp_path.iterdir()) == ["out.json", "params.toml"]


def _files_may_grow_to(limit: int):
    """In the child: RLIMIT_FSIZE ``limit`` bytes (a disk with room for that much), SIGXFSZ
    ignored."""
    def preexec() -> None:
        import resource
        resource.setrlimit(resource.RLIMIT_FSIZE,
                           (limit, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    return preexec


@pytest.mark.untimed
def test_check_config_doc_out_that_cannot_be_written_leaves_the_old_docs_whole(tmp_path):
    """--doc-out over existing docs on a disk too full for them: exit 1, one line naming the
    file that could not be written, the old file whole and no temporary file. Before, the
    error named no file and config.md was left cut short (written in place)."""
    from uvd.runtime.config import render_config_doc

    docs = tmp_path / "docs"
    docs.mkdir()
    doc, mav = docs / "config.md", docs / "mavlink.md"
    doc.write_text("old config reference\n")
    # a mavlink.md larger than the new config.md: room for the one, not for the other
    from uvd.links.mavlink.params import BEGIN, END
    old_mav = f"# MAVLink\n{BEGIN}\nold table\n{END}\n" + "notes\n" * 8000
    mav.write_text(old_mav)
    new_doc = render_config_doc() + "\n"
    assert len(old_mav) > len(new_doc.encode())
    cmd = [sys.executable, "-m", "uvd", "check-config", "--doc-out", str(doc)]

    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120,
                       preexec_fn=_files_may_grow_to(100))
    assert r.returncode == 1 and r.stderr == \
        f"uvd check-config: error: [Errno 27] cannot write {doc}: File too large\n", r.stderr
    assert doc.read_text() == "old config reference\n" and mav.read_text() == old_mav
    assert sorted(p.name for p in docs.iterdir()) == ["config.md", "mavlink.md"]

    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120,
                       preexec_fn=_files_may_grow_to(len(new_doc.encode())))
    assert r.returncode == 1 and r.stderr == \
        f"uvd check-config: error: [Errno 27] cannot write {mav}: File too large\n", r.stderr
    assert r.stdout == f"uvd check-config: wrote {doc}\n"
    assert doc.read_text(encoding="utf-8") == new_doc and mav.read_text() == old_mav
    assert sorted(p.name for p in docs.iterdir()) == ["config.md", "mavlink.md"]

    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert mav.read_text().endswith("notes\n" * 8000) and "old table" not in mav.read_text()
