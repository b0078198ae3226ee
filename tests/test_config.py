"""Configuration: TOML → frozen dataclasses; every error names the file, the key and the reason;
``docs/config.md`` is generated from the schema; ``uvd check-config``; reloadable keys."""

from __future__ import annotations

import copy
import dataclasses
import math
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from uvd.cli import main
from uvd.io.vehicle import vehicle_path
from uvd.runtime.config import (
    DEFAULT_CONFIG,
    Config,
    ConfigValidationError,
    load_config,
    parse_config,
    render_config_doc,
)
from uvd.runtime.schema import describe, leaf_keys, reloadable_changes, with_values

ROOT = Path(__file__).resolve().parents[1]

MINIMAL = """
[sensors.ins]
port = "/dev/ttyUSB0"
[sensors.dvl]
port = "/dev/ttyUSB1"
[sensors.depth]
port = "/dev/ttyUSB2"
"""


def write(tmp_path: Path, text: str, name="uvd.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def errors_of(tmp_path, text) -> tuple[ConfigValidationError, dict[str, str]]:
    p = write(tmp_path, text)
    with pytest.raises(ConfigValidationError) as ei:
        load_config(p)
    exc = ei.value
    assert exc.source == str(p)
    for line in str(exc).splitlines():
        assert line.startswith(f"{p}: "), line  # every line names the file
    return exc, dict(exc.errors)


def test_example_configs_are_valid_and_frozen():
    sim = load_config(ROOT / "config" / "sim.toml")
    assert sim.vehicle.name == "jhu-rov" and sim.loop.rate_hz == 10.0
    assert sim.control.controller == "two-step-ambc" and sim.control.robust_adaptation
    assert sim.can.bus.interface == "udp_multicast" and sim.can.depth.enabled
    assert sim.sensors.ins.port.startswith("/tmp/") and sim.source.endswith("sim.toml")
    rov = load_config(ROOT / "config" / "jhu-rov.toml")
    assert rov.loop.sched_fifo_priority == 50 and rov.loop.cpu_affinity == (1,)
    assert rov.can.bus.interface == "socketcan" and rov.can.amplifiers.node_ids == (1, 2, 3, 4,
                                                                                    5, 6)
    assert DEFAULT_CONFIG == ROOT / "config" / "sim.toml"
    assert load_config().source == str(DEFAULT_CONFIG)
    with pytest.raises(dataclasses.FrozenInstanceError):
        sim.control.kp = 1.0


def test_defaults_fill_in():
    cfg = parse_config(__import__("tomllib").loads(MINIMAL))
    assert cfg.loop.rate_hz == 10.0 and cfg.control.kp == 300.0 and cfg.control.kd == 100.0
    assert cfg.control.robust_adaptation is True
    assert cfg.failsafe.ins_stale_s == 0.1 and cfg.failsafe.dvl_stale_s == 1.0
    assert cfg.failsafe.depth_stale_s == 0.5 and cfg.failsafe.depth_stuck_s == 2.0
    assert cfg.sensors.depth.baud == 9600 and cfg.sensors.depth.conversion.water == "fresh"


def test_the_four_classic_mistakes_name_their_keys(tmp_path):
    exc, errs = errors_of(tmp_path, """
[loop]
rate_hz = 100.0
turbo = true                      # unknown key
[control]
kp = -5.0                         # out of range
kd = "high"                       # wrong type
[sensors.ins]
format = "phins-stdbin"           # port missing
[sensors.dvl]
port = "/dev/ttyUSB1"
[sensors.depth]
port = "/dev/ttyUSB2"
""")
    assert set(errs) == {"loop.turbo", "control.kp", "control.kd", "sensors.ins.port"}
    assert errs["loop.turbo"].startswith("unknown key")
    assert "out of range" in errs["control.kp"] and "≥ 0" in errs["control.kp"]
    assert errs["control.kd"] == "expected a number, got string 'high'"
    assert errs["sensors.ins.port"].startswith("missing required key")
    assert f"{tmp_path / 'uvd.toml'}: control.kp: -5.0 is out of range" in str(exc)


@pytest.mark.parametrize("snippet,key,words", [
    ("[loop]\nrate_hz = 0", "loop.rate_hz", "out of range"),
    ("[loop]\nrate_hz = true", "loop.rate_hz", "expected a number"),
    ("[loop]\nsched_fifo_priority = 1.5", "loop.sched_fifo_priority", "expected an integer"),
    ("[loop]\ncpu_affinity = [0, \"x\"]", "loop.cpu_affinity[1]", "expected an integer"),
    ("[loop]\ntimer = \"hrtimer\"", "loop.timer", "not one of"),
    ("[control]\ncontroller = \"lqr\"", "control.controller", "not one of"),
    ("[control]\nkp = 1e9", "control.kp", "out of range"),
    ("[failsafe]\nins_stale_s = 0", "failsafe.ins_stale_s", "out of range"),
    ("[failsafe]\ndisabled = [\"ins_stale\", \"warp\"]", "failsafe.disabled", "unknown trigger"),
    ("[sensors.gps]\nport = \"/dev/ttyS0\"", "sensors.gps", "unknown key"),
    ("[can.log]\nmax_bytes = -1", "can.log.max_bytes", "out of range (must be ≥ 0)"),
    ("[telemetry]\nqueue_size = 2", "telemetry.queue_size", "out of range"),
    ("vehicle = \"jhu-rov\"", "vehicle", "expected a table"),
    ("[vehicle]\nname = \"submarine\"", "vehicle.name", "neither a built-in vehicle"),
    ("[vehicle]\nname = \"missing.toml\"", "vehicle.name", "not found"),
    # an infinity was taken where no maximum stood (10 keys, found by trying ±inf on every
    # number): a depth conversion of inf, a failsafe threshold that trips always
    ("[sensors.depth.conversion]\nrho_kg_m3 = inf", "sensors.depth.conversion.rho_kg_m3",
     "expected a finite number, got inf"),
    ("[failsafe]\nm_hat_min_eig = inf", "failsafe.m_hat_min_eig", "expected a finite number"),
    ("[can]\nreopen_after_s = inf", "can.reopen_after_s", "expected a finite number"),
    # what the daemon refused only when it built its Zenoh face, check-config said OK to:
    # a key that is a pattern (its fault subscription would be every vehicle's) and
    # endpoints zenoh cannot parse
    ("[telemetry.zenoh]\nenabled = true\nkey = \"*\"", "telemetry.zenoh.key",
     "'*' is not a single key chunk"),
    ("[telemetry.zenoh]\nenabled = true\nkey = \"rov/7\"", "telemetry.zenoh.key",
     "is not a single key chunk"),
    ("[telemetry.zenoh]\nlisten = [\"garbage\"]", "telemetry.zenoh.listen[0]",
     "'garbage' is not <protocol>/<address>"),
    ("[telemetry.zenoh]\nconnect = [\"tcp/127.0.0.1:7447\", \"tcp/10.0.0.1\"]",
     "telemetry.zenoh.connect[1]", "has no port 1-65535"),
    # a port to send to is 1-65535; one to bind may be 0, the kernel's pick (test below)
    ("[mavlink]\nconnect = [\"127.0.0.1:0\"]", "mavlink.connect[0]", "and a port 1-65535"),
    ("[mavlink]\nlisten = \"127.0.0.1:70000\"", "mavlink.listen", "and a port 0-65535"),
    # found by probing (session 24): check-config said OK to a loop too slow for the drives'
    # command timeout, which would fault every drive between two commands
    ("[loop]\nrate_hz = 1", "can.amplifiers.command_timeout_ms",
     "300 ms is shorter than three cycles of [loop] rate_hz 1 (3000 ms): the drives would "
     "time out at the first missed deadline"),
    # session 32: 200 ms at 10 Hz, shipped until then — one 150 ms stall of the daemon faulted
    # every drive (tests/test_hil_process.py)
    ("[loop]\nrate_hz = 10\n[can.amplifiers]\ncommand_timeout_ms = 200",
     "can.amplifiers.command_timeout_ms",
     "200 ms is shorter than three cycles of [loop] rate_hz 10 (300 ms)"),
    # session 33: AID steps once a cycle, and its observer's Euler step diverges at a·dt ≥ 2
    ("[estimation]\naid = true\ngains = [30, 5000, 20000, 2000, 2000]", "estimation.gains",
     "the observer gain a = 30 at a step of 0.1 s makes a·dt = 3 ≥ 2: AID's velocity estimate "
     "((4.10), (4.23)) diverges; a must stay under 2/dt = 20 ([loop] rate_hz 10)"),
])
def test_single_mistakes(tmp_path, snippet, key, words):
    _, errs = errors_of(tmp_path, snippet + "\n" + MINIMAL)
    assert key in errs, errs
    assert words in errs[key]


def test_drives_left_unconfigured_are_warned_of_their_own_deadline(tmp_path):
    from uvd.runtime.can_component import deadline_warnings
    # uvd writes no deadline then: check-config has nothing to refuse; the daemon reads the
    # drives' own at start (tests/test_can_contract.py) and warns of the ones that are wrong
    snippet = "[loop]\nrate_hz = 10\n[can.amplifiers]\nconfigure = false\ncommand_timeout_ms = 200"
    cfg = load_config(write(tmp_path, snippet + "\n" + MINIMAL))  # no error
    assert cfg.can.amplifiers.command_timeout_ms == 200
    _, errs = errors_of(tmp_path, snippet.replace("false", "true") + "\n" + MINIMAL)
    assert "200 ms is shorter" in errs["can.amplifiers.command_timeout_ms"]
    lines = deadline_warnings({1: 200, 2: 200, 3: 300, 4: None, 5: 0, 6: 1000}, 10.0)
    assert lines == [
        "amplifier 5 keeps its own RPDO deadline (0x1400:05; [can.amplifiers] configure = "
        "false): 0 (off): a drive keeps its last command when the daemon stops sending (its "
        "heartbeat consumer, 0x1016, is then the only guard)",
        "amplifiers 1, 2 keep their own RPDO deadline (0x1400:05; [can.amplifiers] configure "
        "= false): 200 ms is shorter than three cycles of [loop] rate_hz 10 (300 ms): the "
        "drives would time out at the first missed deadline"]
    assert deadline_warnings({1: 200, 2: None}, 50.0) == []


def test_two_instruments_on_one_serial_device_are_refused(tmp_path):
    # found by probing (session 33): an INS and a DVL on one device passed check-config
    _, errs = errors_of(tmp_path, MINIMAL.replace('"/dev/ttyUSB1"', '"/dev/ttyUSB0"'))
    assert errs["sensors.dvl.port"] == ("'/dev/ttyUSB0' is sensors.ins.port's device too: two "
                                        "readers on one device would each get part of its "
                                        "bytes"), errs
    dev = tmp_path / "ttyUSB0"
    dev.write_text("")
    (tmp_path / "by-id").symlink_to(dev)  # as /dev/serial/by-id/… names /dev/ttyUSB0
    linked = MINIMAL.replace('"/dev/ttyUSB0"', f'"{dev}"').replace(
        '"/dev/ttyUSB2"', f'"{tmp_path / "by-id"}"')
    _, errs = errors_of(tmp_path, linked)
    assert "is sensors.ins.port's device too" in errs["sensors.depth.port"], errs


def test_two_of_the_daemons_listeners_on_one_udp_port_are_refused(tmp_path):
    # found by probing (session 33): an INS on MAVLink's port passed check-config, and the
    # start failed 5 s later on "Address already in use"
    ins = MINIMAL.replace('"/dev/ttyUSB0"', '"udp://127.0.0.1:14551"')
    _, errs = errors_of(tmp_path, ins + '[mavlink]\nenabled = true\nlisten = "127.0.0.1:14551"\n')
    assert errs["mavlink.listen"] == ("udp 127.0.0.1:14551 is sensors.ins.port's too: the "
                                      "daemon's second listener there would fail to bind at "
                                      "start"), errs
    wild = MINIMAL.replace('"/dev/ttyUSB0"', '"udp://0.0.0.0:8110"').replace(
        '"/dev/ttyUSB1"', '"udp://127.0.0.1:8110"')
    _, errs = errors_of(tmp_path, wild)
    assert "is sensors.ins.port's too" in errs["sensors.dvl.port"], errs
    zen = MINIMAL.replace('"/dev/ttyUSB0"', '"udp://127.0.0.1:7447"')
    _, errs = errors_of(tmp_path, zen + '[telemetry.zenoh]\nenabled = true\n'
                        'listen = ["udp/127.0.0.1:7447"]\n')
    assert "is sensors.ins.port's too" in errs["telemetry.zenoh.listen[0]"], errs
    ok = MINIMAL.replace('"/dev/ttyUSB0"', '"udp://127.0.0.1:8110"').replace(
        '"/dev/ttyUSB1"', '"udp://127.0.0.1:8111"')
    load_config(write(tmp_path, ok + '[mavlink]\nenabled = true\nlisten = "127.0.0.1:14551"\n'
                      '[telemetry.zenoh]\nenabled = true\nlisten = ["tcp/127.0.0.1:8110"]\n'))


def test_port_forms(tmp_path):
    ok = MINIMAL.replace('"/dev/ttyUSB0"', '"udp://0.0.0.0:8110"').replace(
        '"/dev/ttyUSB1"', '"tcp://10.0.0.5:8112"')
    cfg = load_config(write(tmp_path, ok))
    assert cfg.sensors.ins.port == "udp://0.0.0.0:8110"
    _, errs = errors_of(tmp_path, MINIMAL.replace('"/dev/ttyUSB0"', '"ttyUSB0"'))
    assert "absolute device path" in errs["sensors.ins.port"]
    _, errs = errors_of(tmp_path, MINIMAL.replace('"/dev/ttyUSB0"', '"udp://h:70000"'))
    assert "1..65535" in errs["sensors.ins.port"]


def test_depth_source_rules(tmp_path):
    no_port = MINIMAL.replace('[sensors.depth]\nport = "/dev/ttyUSB2"\n', "[sensors.depth]\n")
    _, errs = errors_of(tmp_path, no_port)
    assert "source = \"serial\"" in errs["sensors.depth.port"]
    can_src = no_port.replace("[sensors.depth]\n", "[sensors.depth]\nsource = \"can\"\n")
    _, errs = errors_of(tmp_path, can_src)
    assert "[can.depth] enabled = true" in errs["sensors.depth.source"]
    cfg = load_config(write(tmp_path, can_src + "\n[can.depth]\nenabled = true\n"))
    assert cfg.sensors.depth.source == "can" and cfg.sensors.depth.port is None


def test_driver_sections_plug_in_and_their_errors_name_keys(tmp_path):
    # the [can] tables (declared in uvd/runtime/config.py for the driver's plain dataclasses)
    _, errs = errors_of(tmp_path, MINIMAL + "[can.amplifiers]\nnode_ids = [1, 2, 200]\n")
    assert "out of range (must be ≥ 1 and ≤ 127)" in errs["can.amplifiers.node_ids[2]"]
    _, errs = errors_of(tmp_path, MINIMAL + "[can]\ninterface = \"udp_multicast\"\n"
                                            "channel = \"239.1.1.1\"\n")
    assert "can.channel" in errs and "could leave this machine" in errs["can.channel"]
    _, errs = errors_of(tmp_path, MINIMAL + "[can]\ninterface = \"socketcann\"\n")
    assert "not a python-can interface" in errs["can.interface"]
    _, errs = errors_of(tmp_path, MINIMAL + "[can.amplifiers]\nnode_ids = [1, 2, 3, 4, 5]\n")
    assert "5 node ids for the 6 thrusters" in errs["can.amplifiers.node_ids"]
    # the Digiquartz driver's DepthConverter is a plain dataclass section: its refusals
    # ("DepthConverter.water must …") name the key
    _, errs = errors_of(tmp_path, MINIMAL + "[sensors.depth.conversion]\nwater = \"brine\"\n")
    assert errs["sensors.depth.conversion.water"].startswith("must be 'fresh' or 'sea'")
    # a negative tare: every depth off by it (session 19; nan and inf the schema refuses)
    _, errs = errors_of(tmp_path, MINIMAL + "[sensors.depth.conversion]\natmosphere_pa = -5.0\n")
    assert errs["sensors.depth.conversion.atmosphere_pa"].startswith(
        "must be a finite pressure >= 0 Pa")
    for key, value in (("rho_kg_m3", "-1.0"), ("g_m_s2", "0.0"), ("latitude_deg", "91.0")):
        _, errs = errors_of(tmp_path, MINIMAL + f"[sensors.depth.conversion]\n{key} = {value}\n")
        assert errs[f"sensors.depth.conversion.{key}"].endswith(f"got {value}"), errs


def test_vehicle_file_relative_to_the_config(tmp_path):
    src = vehicle_path("jhu-rov")
    (tmp_path / "v").mkdir()
    (tmp_path / "v" / "mine.toml").write_text(src.read_text())
    cfg = load_config(write(tmp_path, "[vehicle]\nname = \"v/mine.toml\"\n" + MINIMAL))
    assert cfg.vehicle_ref() == str(tmp_path / "v" / "mine.toml")
    assert cfg.load_vehicle().n_thrusters == 6


def test_unreadable_and_invalid_toml(tmp_path):
    with pytest.raises(ConfigValidationError, match="cannot read"):
        load_config(tmp_path / "nope.toml")
    p = write(tmp_path, "[loop\nrate_hz = 1")
    with pytest.raises(ConfigValidationError, match="not valid TOML"):
        load_config(p)


def test_docs_config_md_is_generated_from_the_schema():
    doc = render_config_doc()
    committed = (ROOT / "docs" / "config.md").read_text()
    assert committed == doc + "\n", "docs/config.md is stale: run " \
                                    "`uvd check-config --doc-out docs/config.md`"
    # every key of every table is documented with its default
    n_keys = 0
    for table, _doc, keys in describe(Config):
        assert f"## `[{table}]`" in doc
        for k in keys:
            n_keys += 1
            assert f"| `{k.key.rsplit('.', 1)[-1]}` |" in doc
    assert n_keys > 60
    for unit in ("| Hz |", "| s |", "| µs |", "| bit/s |"):
        assert unit in doc


def test_reloadable_changes(tmp_path):
    old = load_config(ROOT / "config" / "sim.toml")
    text = (ROOT / "config" / "sim.toml").read_text()
    text = text.replace("kp = 300.0", "kp = 250.0").replace("rate_hz = 10.0", "rate_hz = 20.0")
    text = text.replace("ins_stale_s = 0.25", "ins_stale_s = 0.2")
    new = load_config(write(tmp_path, text))
    merged, applied, refused = reloadable_changes(old, new)
    assert sorted(applied) == ["control.kp", "failsafe.ins_stale_s"]
    assert refused == ["loop.rate_hz"]
    assert merged.control.kp == 250.0 and merged.loop.rate_hz == 10.0
    assert merged.failsafe.ins_stale_s == 0.2 and merged.source == old.source
    same, a, r = reloadable_changes(old, old)
    assert same is old and a == [] and r == []


def test_check_config_command(tmp_path, capsys, monkeypatch):
    assert main(["check-config", str(ROOT / "config" / "sim.toml")]) == 0
    out = capsys.readouterr().out
    assert "OK" in out and "two-step-ambc" in out and "AID" not in out
    monkeypatch.chdir(tmp_path)  # the working directory, where save_path lands, is empty
    assert main(["check-config", str(ROOT / "config" / "jhu-rov.toml")]) == 0
    assert "AID on (from INITP, saved to aid-params.toml; resume: later runs go on from it)" \
        in capsys.readouterr().out
    bad = write(tmp_path, MINIMAL + "[control]\nkp = -1\n")
    assert main(["check-config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}: control.kp: -1.0 is out of range" in err and "1 error" in err
    doc = tmp_path / "config.md"
    assert main(["check-config", "--doc-out", str(doc)]) == 0
    assert doc.read_text() == render_config_doc() + "\n"
    assert main(["check-config"]) == 2
    assert main(["check-config", "--print", str(ROOT / "config" / "sim.toml")]) == 0
    assert '"rate_hz": 10.0' in capsys.readouterr().out


def test_check_config_as_a_process(tmp_path):
    bad = write(tmp_path, "[loop]\nrate_hz = \"fast\"\n" + MINIMAL)
    r = subprocess.run([sys.executable, "-m", "uvd", "check-config", str(bad)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert f"{bad}: loop.rate_hz: expected a number, got string 'fast'" in r.stderr


def test_aid_initial_params_is_checked_at_load(tmp_path):
    from uvd.estimation.aid import INITP_6DOF
    from uvd.io.params import save_params
    from uvd.model.params import UVParams

    _, errs = errors_of(tmp_path, "[estimation]\naid = true\ninitial_params = \"none.toml\"\n"
                        + MINIMAL)
    assert "cannot read parameters" in errs["estimation.initial_params"]
    assert str(tmp_path / "none.toml") in errs["estimation.initial_params"]
    (tmp_path / "bad.toml").write_text("[parameters]\nm = [1, 1]\n")
    _, errs = errors_of(tmp_path, "[estimation]\ninitial_params = \"bad.toml\"\n" + MINIMAL)
    assert "missing key" in errs["estimation.initial_params"]
    # M not positive definite: AID cannot start from it (Theorem 4.3.1)
    M = np.array(INITP_6DOF.M)
    M[0, 0] = -1.0
    save_params(UVParams(M=M, D=INITP_6DOF.D, g=INITP_6DOF.g, b=INITP_6DOF.b),
                tmp_path / "neg.toml")
    _, errs = errors_of(tmp_path, "[estimation]\ninitial_params = \"neg.toml\"\n" + MINIMAL)
    assert "not positive definite" in errs["estimation.initial_params"]
    # a good file, relative to the config file's folder
    save_params(INITP_6DOF, tmp_path / "good.toml")
    cfg = load_config(write(tmp_path, "[estimation]\naid = true\ninitial_params = "
                                      "\"good.toml\"\n" + MINIMAL))
    assert cfg.estimation.initial_params_path(tmp_path) == tmp_path / "good.toml"
    _, errs = errors_of(tmp_path, "[estimation]\npublish_every_s = 0\n" + MINIMAL)
    assert "estimation.publish_every_s" in errs
    _, errs = errors_of(tmp_path, "[estimation]\ngains = [10, 0, 1, 1, 1]\n" + MINIMAL)
    assert "gamma1 must be finite and > 0" in errs["estimation.gains"]
    _, errs = errors_of(tmp_path, "[estimation]\ngains = [10, 1, 1]\n" + MINIMAL)
    assert "exactly 5 values" in errs["estimation.gains"]
    # the configured gains and θ̂(0) reach the daemon's estimator
    from uvd.estimation.aid import AID6Gains
    from uvd.runtime.build import build_core
    resume = UVParams(M=INITP_6DOF.M, D=INITP_6DOF.D, g=7.0, b=INITP_6DOF.b)
    save_params(resume, tmp_path / "resume.toml")
    cfg = load_config(write(tmp_path, "[estimation]\naid = true\ninitial_params = "
                                      "\"resume.toml\"\ngains = [1, 2, 3, 4, 5]\n" + MINIMAL))
    (spec,) = build_core(cfg).estimators
    assert spec.params.gains == AID6Gains(1.0, 2.0, 3.0, 4.0, 5.0)
    np.testing.assert_array_equal(spec.init_state.theta, resume.theta)
    assert spec.init_state.theta[237] == 7.0  # g, not INITP's


def test_aid_resume_goes_on_from_the_last_runs_file(tmp_path, monkeypatch, capsys):
    """``resume``: the first run starts from initial_params/INITP, later runs from save_path
    (the working directory's, where the daemon wrote it); a bad file there is an error."""
    from uvd.estimation.aid import INITP_6DOF
    from uvd.io.params import save_params
    from uvd.model.params import UVParams
    from uvd.runtime.build import build_core

    work = tmp_path / "state"
    work.mkdir()
    monkeypatch.chdir(work)
    _, errs = errors_of(tmp_path, "[estimation]\naid = true\nresume = true\n" + MINIMAL)
    assert "needs save_path" in errs["estimation.resume"]

    text = "[estimation]\naid = true\nresume = true\nsave_path = \"aid.toml\"\n" + MINIMAL
    cfg_path = write(tmp_path, text)
    cfg = load_config(cfg_path)  # the first run: no file yet
    assert cfg.estimation.start_path(tmp_path) is None
    np.testing.assert_array_equal(build_core(cfg).estimators[0].init_state.theta,
                                  INITP_6DOF.theta)
    assert main(["check-config", str(cfg_path)]) == 0
    assert "AID on (from INITP, saved to aid.toml; resume: later runs go on from it)" \
        in capsys.readouterr().out

    last = UVParams(M=INITP_6DOF.M, D=INITP_6DOF.D, g=3.0, b=INITP_6DOF.b)
    save_params(last, work / "aid.toml")  # what a run leaves
    cfg = load_config(cfg_path)
    assert cfg.estimation.start_path(tmp_path) == work / "aid.toml"
    np.testing.assert_array_equal(build_core(cfg).estimators[0].init_state.theta, last.theta)
    assert main(["check-config", str(cfg_path)]) == 0
    assert f"AID on (from the last run's {work / 'aid.toml'}, saved to aid.toml)" \
        in capsys.readouterr().out

    # the file wins over initial_params (still checked: it is the start once the file goes)
    save_params(INITP_6DOF, tmp_path / "init.toml")
    both = text.replace("resume = true", "resume = true\ninitial_params = \"init.toml\"")
    cfg = load_config(write(tmp_path, both))
    assert cfg.estimation.start_path(tmp_path) == work / "aid.toml"
    (work / "aid.toml").unlink()
    assert cfg.estimation.start_path(tmp_path) == tmp_path / "init.toml"

    # a damaged file is not silently replaced by INITP: the start is refused, naming it
    (work / "aid.toml").write_text("[parameters]\nM = 3\n")
    _, errs = errors_of(tmp_path, text)
    assert str(work / "aid.toml") in errs["estimation.save_path"]
    assert "move it away to start afresh" in errs["estimation.save_path"]


def test_the_mavlink_link_may_listen_on_a_port_the_kernel_picks(tmp_path):
    """``[mavlink] listen`` port 0: bound to one the kernel picks (the connect stations answer
    where its datagrams come from; tests bind so, never racing another process for a port)."""
    cfg = load_config(write(tmp_path, MINIMAL + '[mavlink]\nenabled = true\nlisten = '
                                                '"127.0.0.1:0"\n'))
    assert cfg.mavlink.listen == "127.0.0.1:0"


#: a value of every wrong kind: negative, huge, not finite, empty, a NUL character (TOML's
#: \u0000, which the operating system refuses in a path with a ValueError), another type, a
#: list, a table, a file name too long for the file system (an OSError where a path is looked at)
HOSTILE = (-1, 10**30, 1e308, math.nan, "", "\x00", True, [], [math.nan] * 6, {"a": 1}, 0.5,
           "x" * 300, "x" * 300 + ".toml")


def test_a_missing_bare_name_lists_the_shipped_configurations(tmp_path, monkeypatch):
    """``--config sim-bluerov`` (a typo of a shipped name): said to be neither a file nor a
    shipped configuration, with their names; a missing path is only a missing file."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigValidationError) as exc:
        load_config("sim-bluerov")
    assert str(exc.value).endswith("sim-bluerov: cannot read: No such file or directory, nor a "
                                   "shipped configuration's name (jhu-rov, sim, sim-bluerov2)")
    with pytest.raises(ConfigValidationError) as exc:
        load_config(tmp_path / "sub" / "sim-bluerov")
    assert str(exc.value).endswith("cannot read: No such file or directory")
    assert load_config("sim-bluerov2").vehicle.name == "bluerov2-heavy"


def test_a_name_the_system_refuses_is_told_apart_from_an_absent_file(tmp_path):
    """``refused_name``: the one check before a configured TOML file is looked for."""
    from uvd.io.toml import refused_name
    (tmp_path / "here.toml").write_text("")
    assert refused_name(tmp_path / "here.toml") is None
    assert refused_name(tmp_path / "absent.toml") is None
    assert refused_name(tmp_path / "here.toml" / "below.toml") is None  # not a folder
    assert "too long" in refused_name(tmp_path / ("x" * 300 + ".toml")).lower()
    cfg = tmp_path / "uvd.toml"
    cfg.write_text(f'[vehicle]\nname = "{"x" * 300}.toml"\n')
    with pytest.raises(ConfigValidationError, match=r"vehicle\.name: vehicle file 'x+.*too long"):
        load_config(cfg)


def test_every_key_takes_any_value_or_refuses_it_by_name(tmp_path):
    """Each key of the schema set to each :data:`HOSTILE` value in config/sim.toml with AID
    resuming from its file: the
    configuration loads or is refused with a ConfigValidationError naming the key (or, for a
    driver's own dataclass, the table that builds it; a rule across keys may name another key
    beside it) — never another exception; and so is it on the loaded configuration. Before
    session 30, a NUL character in ``[estimation] initial_params`` raised ValueError, and a
    vehicle file name or ``save_path`` too long OSError."""
    base = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    base.setdefault("estimation", {}).update(aid=True, resume=True,
                                             save_path=str(tmp_path / "aid.toml"))
    loaded = parse_config(copy.deepcopy(base), source="hostile.toml")
    refused = 0
    for leaf in leaf_keys(Config):
        *tables, name = leaf.key.split(".")
        for value in HOSTILE:
            data = copy.deepcopy(base)
            node = data
            for t in tables:
                node = node.setdefault(t, {})
            node[name] = value
            try:
                parse_config(data, source="hostile.toml")
            except ConfigValidationError as exc:
                refused += 1
                # the key, its name in a rule across keys ("[loop] rate_hz 0.5"), or its table
                assert name in str(exc) or f"{'.'.join(tables)}:" in str(exc), \
                    (leaf.key, value, str(exc))
            # the same value set on the running configuration (a parameters file kept over
            # MAVLink, a reload): errors, never an exception (a driver's dataclass's own
            # ValueError escaped until session 30)
            _, errors = with_values(loaded, {leaf.key: value})
            # each names the key, one of its items (key[2]) or its table, or a rule across
            # keys names it ("estimation.resume: needs save_path")
            assert all(k.split("[")[0] in (leaf.key, ".".join(tables)) or name in why
                       for k, why in errors), (leaf.key, errors)
    assert refused > len(leaf_keys(Config)) * 6  # most of them are refused
