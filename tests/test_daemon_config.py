"""``uvd run`` with a wrong configuration fails fast, naming the key; the daemon's settings
come from one source of truth."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from uvd.cli import main
from uvd.runtime.build import build_core, nav_config, start_pose
from uvd.runtime.config import DEFAULT_CONFIG, load_config

SIM = DEFAULT_CONFIG.read_text()


def bad(tmp_path: Path, old: str, new: str) -> Path:
    assert old in SIM, old
    p = tmp_path / "bad.toml"
    p.write_text(SIM.replace(old, new, 1))
    return p


@pytest.mark.parametrize("old,new,key,reason", [
    ("kd = 100.0", "kd = 100.0\nkpp = 1.0", "control.kpp", "unknown key"),
    ("kp = 300.0", 'kp = "high"', "control.kp", "expected a number"),
    ("kp = 300.0", "kp = -5.0", "control.kp", "out of range"),
    ('port = "/tmp/uvd-sim/ins"', "", "sensors.ins.port", "missing required key"),
])
def test_a_wrong_config_fails_fast_naming_the_key(tmp_path, capsys, old, new, key, reason):
    path = bad(tmp_path, old, new)
    t0 = time.monotonic()
    assert main(["run", "--config", str(path)]) == 2
    assert time.monotonic() - t0 < 2.0  # validation only: nothing was started
    err = capsys.readouterr().err
    assert "nothing started" in err
    line = next(x for x in err.splitlines() if f": {key}:" in x)
    assert line.startswith(f"{path}: {key}: ") and reason in line


@pytest.mark.untimed
def test_the_real_process_exits_2_before_opening_anything(tmp_path):
    path = bad(tmp_path, "kp = 300.0", "kp = -5.0")
    r = subprocess.run([sys.executable, "-m", "uvd", "run", "--config", str(path), "--arm"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert f"{path}: control.kp: -5.0 is out of range" in r.stderr
    assert not Path("/tmp/uvd-sim/ins").exists() or "BOOT" not in r.stderr


@pytest.mark.untimed
def test_sim_bridge_refuses_a_wrong_config_too(tmp_path):
    path = bad(tmp_path, 'interface = "udp_multicast"', 'interface = "no-such-bus"')
    r = subprocess.run([sys.executable, "-m", "uvd", "sim-bridge", "--config", str(path)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "can.interface" in r.stderr


def test_a_local_configuration_in_a_relative_folder_is_a_valid_one(tmp_path, monkeypatch):
    """``write_local_config("rec")`` (``uvd demo --record rec``) names every file by its
    absolute path: a device's port must be one. Before (session 32) it wrote ``rec/ins``
    and the demo's own configuration was refused."""
    from sim_bridge.bridge import write_local_config
    monkeypatch.chdir(tmp_path)
    cfg = load_config(write_local_config("rec"))
    rec = tmp_path / "rec"
    assert cfg.sensors.ins.port == str(rec / "ins") and cfg.sensors.leak.path == str(rec / "leak")
    assert cfg.telemetry.jsonl.path == str(rec / "telemetry.jsonl")


@pytest.mark.untimed
def test_an_absent_device_stops_the_start_with_exit_1(tmp_path):
    """A port that does not exist is not a configuration error (the adapter may be plugged
    later) but the drivers cannot come up: the start times out, exit 1, naming the port."""
    from sim_bridge.bridge import write_local_config
    cfg = write_local_config(tmp_path, changes={"daemon": {"start_timeout_s": 1.0}})
    r = subprocess.run([sys.executable, "-m", "uvd", "run", "--config", str(cfg)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    assert "start failed" in r.stderr and str(tmp_path / "ins") in r.stderr
    # the log's first line says which configuration ran; only the embedded default, whose
    # instruments are sim-bridge's, adds where they come from
    first = r.stderr.splitlines()[0]
    assert first == f"INFO uvd.daemon: configuration {cfg}: vehicle jhu-rov, two-step-ambc " \
                    "at 10 Hz", first
    assert "uvd sim-bridge" not in r.stderr


def test_the_embedded_default_says_its_instruments_are_sim_bridges(caplog):
    import logging

    from uvd.commands.run import _say_configuration
    from uvd.runtime.config import DEFAULT_CONFIG, load_config
    with caplog.at_level(logging.INFO, logger="uvd.daemon"):
        _say_configuration(load_config(None), embedded=True)
    assert [r.getMessage() for r in caplog.records] == [
        f"configuration {DEFAULT_CONFIG}: vehicle jhu-rov, two-step-ambc at 10 Hz",
        "the embedded default is the simulated vehicle: its instruments and drives are "
        "`uvd sim-bridge`'s (start that first; `uvd demo` runs both)"]


@pytest.mark.untimed
def test_a_start_that_failed_leaves_the_last_runs_estimate_alone(tmp_path):
    """``[estimation] save_path`` holds an earlier run's θ̂; a start that fails before any
    cycle (the INS port absent) must not overwrite it with the first guess it loaded."""
    from sim_bridge.bridge import write_local_config
    from uvd.estimation.aid import INITP_6DOF
    from uvd.io.params import save_params
    from uvd.model.params import params_from_theta
    saved = tmp_path / "aid.toml"
    theta = INITP_6DOF.theta.copy()
    theta[0] *= 1.5
    save_params(params_from_theta(theta), saved, title="an earlier run's estimate")
    before = saved.read_bytes()
    cfg = write_local_config(tmp_path, changes={
        "daemon": {"start_timeout_s": 1.0},
        "estimation": {"aid": True, "save_path": str(saved)}})
    r = subprocess.run([sys.executable, "-m", "uvd", "run", "--config", str(cfg)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and "start failed" in r.stderr, r.stderr
    assert saved.read_bytes() == before


def test_navigation_timeouts_are_the_failsafe_thresholds():
    cfg = load_config(DEFAULT_CONFIG)
    nav = nav_config(cfg)
    assert (nav.ins_timeout_s, nav.dvl_timeout_s, nav.depth_timeout_s) == (
        cfg.failsafe.ins_stale_s, cfg.failsafe.dvl_stale_s, cfg.failsafe.depth_stale_s)
    assert cfg.failsafe.ins_stale_s == 0.25  # 2.5 periods of the 10 Hz PHINS
    core_cfg = build_core(cfg)
    assert core_cfg.nav.ins_timeout_s == nav.ins_timeout_s
    assert core_cfg.controller.name == "two-step-ambc"
    assert core_cfg.controller.params.step1_duration_s == 0.0
    H0, v0 = start_pose(cfg)
    ref0 = core_cfg.reference.at(0.0)
    assert abs(H0 - ref0.H).max() < 1e-12 and not v0.any()  # the run starts on RefTraj1


def _with_eds(config: Path, eds: Path, out: Path) -> Path:
    from uvd.io.toml import dump_toml, read_toml
    data = read_toml(config)
    data.setdefault("can", {}).setdefault("amplifiers", {})["eds"] = str(eds)
    out.write_text(dump_toml(data))
    return out


def _cut_eds(tmp_path: Path) -> Path:
    """The shipped amplifier object dictionary cut in the middle of a line."""
    from drivers.can.config import DEFAULT_AMPLIFIER_EDS
    cut = tmp_path / "cut.eds"
    cut.write_bytes(DEFAULT_AMPLIFIER_EDS.read_bytes()[:3000])
    return cut


@pytest.mark.untimed
def test_sim_bridge_names_an_object_dictionary_that_does_not_read(tmp_path):
    # found by probing (session 21): sim-bridge ended in canopen's ValueError traceback
    # (uvd run and uvd zero-thrust named it already, through drivers' load_od)
    from uvd.runtime.config import DEFAULT_CONFIG as SIM_PATH
    cut = _cut_eds(tmp_path)
    for eds, what in [(cut, f"cannot read '{cut}': Source contains parsing errors: "
                            f"'{cut}' [line 56]: 'BaudRate_1'"),
                      (tmp_path / "none.eds", f"no object dictionary file at "
                                              f"'{tmp_path / 'none.eds'}'")]:
        cfg = _with_eds(SIM_PATH, eds, tmp_path / "uvd.toml")
        r = subprocess.run([sys.executable, "-m", "uvd", "sim-bridge", "--config", str(cfg),
                            "--duration", "1"], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-2000:]
        assert f"ConfigError: emulated node 1 eds: {what}" in r.stdout + r.stderr


def test_a_can_start_failure_after_the_bus_opened_ends_without_a_traceback(tmp_path):
    """An object dictionary that reads but maps no command (an empty file) fails the CAN
    start after the bus is open: exit 1 naming it; the bus is closed after the App's workers
    are gone (it was a RuntimeError traceback: cannot schedule new futures after shutdown)."""
    from hil_daemon import running_bridge
    empty = tmp_path / "empty.eds"
    empty.write_text("")
    with running_bridge(tmp_path / "run") as (cfg_path, _proc):
        cfg = _with_eds(cfg_path, empty, tmp_path / "uvd.toml")
        r = subprocess.run([sys.executable, "-m", "uvd", "run", "--config", str(cfg),
                            "--duration", "5"], capture_output=True, text=True, timeout=240)
    assert "Traceback" not in r.stderr, r.stderr[-2000:]
    assert r.returncode == 1
    assert "start failed (ConfigError: [can.amplifiers] eds: node 1: no enabled RPDO maps " \
           "both controlword 0x6040 and target torque 0x6071" in r.stderr


def test_a_second_sim_bridge_of_a_vehicle_running_does_not_start(tmp_path):
    """Found by probing (session 33): a second ``uvd sim-bridge`` of the same configuration
    (one forgotten in another terminal) started, answered as the same six CAN nodes beside the
    first's and took its instrument links over. Now it ends at once (exit 2), naming the
    process that holds the bus — or a link, for a configuration that shares only those — and
    the first's links are untouched."""
    import os

    from hil_daemon import running_bridge

    from sim_bridge.bridge import write_local_config
    from uvd.io.toml import read_toml
    with running_bridge(tmp_path / "A") as (cfg_a, first):
        pid, ins = first.ready["pid"], first.ready["ports"]["ins"]
        # the same bus and links (the same file), then only the links (its own bus)
        links_only = write_local_config(tmp_path / "C", changes={
            "sensors": read_toml(cfg_a)["sensors"]})
        for cfg, what in ((cfg_a, "emulates the drives on udp_multicast "),
                          (links_only, f"serves the instrument link {ins['link']}")):
            r = subprocess.run([sys.executable, "-m", "uvd", "sim-bridge", "--config",
                                str(cfg), "--duration", "5"], capture_output=True, text=True,
                               timeout=120)
            assert r.returncode == 2, (r.stdout + r.stderr)[-2000:]
            assert f"another sim-bridge (process {pid}) already {what}" in r.stdout, r.stdout
            assert os.readlink(ins["link"]) == ins["device"]
        assert first.call("ping")["ok"]


def test_a_second_daemon_on_a_can_bus_in_use_does_not_start(tmp_path):
    """``uvd run`` by hand beside an armed daemon on the same CAN bus (its instruments its own,
    as networked ones would be) fails its start before it opens the bus, naming the daemon
    that holds it; the armed one flies on untouched. Before the claim (session 25) the second
    daemon's start put all six drives in NMT pre-operational and the armed one disarmed on
    amplifier_fault. The claim is the kernel's: the first daemon gone, the bus is free."""
    from hil_daemon import running_bridge

    from sim_bridge.bridge import write_local_config
    from uvd.io.toml import read_toml
    with running_bridge(tmp_path / "A") as (cfg_a, _pa), \
            running_bridge(tmp_path / "B") as (_cfg_b, _pb):
        twin = write_local_config(tmp_path / "B", changes={
            "can": read_toml(cfg_a)["can"], "mavlink": {"enabled": False},
            "telemetry": {"jsonl": {"enabled": False}, "zenoh": {"enabled": False}}})
        first_log = tmp_path / "first.log"
        with first_log.open("w") as err:
            first = subprocess.Popen([sys.executable, "-m", "uvd", "run", "--config",
                                      str(cfg_a), "--arm", "--duration", "120"], stderr=err)
        try:
            deadline = time.monotonic() + 120.0
            while "→ ARMED" not in first_log.read_text() and time.monotonic() < deadline:
                time.sleep(0.1)
            assert "→ ARMED" in first_log.read_text(), first_log.read_text()[-2000:]
            r = subprocess.run([sys.executable, "-m", "uvd", "run", "--config", str(twin),
                                "--duration", "30"], capture_output=True, text=True,
                               timeout=240)
            time.sleep(1.0)  # a cycle of the first daemon after the second's start (10 Hz)
            assert first.poll() is None
            log = first_log.read_text()
        finally:
            first.terminate()
            first.wait(timeout=20)
        assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr[-2000:]
        assert (f"start failed (TransportError: can: another daemon (process {first.pid}) "
                "already drives udp_multicast ") in r.stderr, r.stderr[-2000:]
        # at its start, never in STANDBY (where it would have configured the amplifiers)
        assert "lifecycle BOOT → SHUTDOWN" in r.stderr and "STANDBY" not in r.stderr
        assert "failsafe fired" not in log and "CAN fault" not in log, log[-2000:]
        assert first.returncode == 0
        r = subprocess.run([sys.executable, "-m", "uvd", "run", "--config", str(twin),
                            "--duration", "1"], capture_output=True, text=True, timeout=240)
        assert r.returncode == 0, r.stderr[-2000:]
        assert "lifecycle BOOT → STANDBY" in r.stderr, r.stderr[-2000:]
