"""``uvd eta``: the operator sets and clears a thruster's effectiveness on a running daemon
from the command line, over the daemon's MAVLink link (a real daemon against a live
``sim-bridge``; the command line runs in its own thread as a separate station would)."""

from __future__ import annotations

import asyncio
import os

import pytest

from tests.hil_daemon import link_port, run_scenario, running_bridge, station_link
from uvd.cli import main
from uvd.netports import free_port
from uvd.runtime.config import load_config

pytestmark = pytest.mark.timeout(240)


def test_uvd_eta_sets_and_clears_a_thruster_on_a_running_daemon(tmp_path, capsys):
    seen = {}
    keys = {}
    for name in ("daemon", "other"):  # the daemon's link signed; a station with another key
        keys[name] = tmp_path / f"{name}.key"
        keys[name].write_text(os.urandom(32).hex())
        keys[name].chmod(0o600)
    link = station_link(tmp_path)
    link["mavlink"]["signing_key_file"] = str(keys["daemon"])
    with running_bridge(tmp_path, link) as (cfg_path, _):
        cfg = load_config(cfg_path)
        text = cfg_path.read_text()
        assert text.count(str(keys["daemon"])) == 1
        other, unsigned = tmp_path / "other.toml", tmp_path / "unsigned.toml"
        other.write_text(text.replace(str(keys["daemon"]), str(keys["other"])))
        unsigned.write_text(text.replace(str(keys["daemon"]), ""))

        async def scenario(d):
            def cli(*argv, config=cfg_path, timeout="10"):
                return main(["eta", *argv, "--config", str(config), "--to",
                             f"127.0.0.1:{link_port(d)}", "--timeout", timeout])
            # a station whose key is not the daemon's, or that has none: told so, not "no
            # vehicle heartbeat" and a bare "denied"
            seen["other"] = await asyncio.to_thread(cli, "4", "0", config=other, timeout="1")
            seen["unsigned"] = await asyncio.to_thread(cli, "4", "0", config=unsigned)
            seen["kill"] = await asyncio.to_thread(cli, "4", "0")
            await asyncio.sleep(0.3)
            seen["eta_killed"] = d.supervisor.data.thruster_eta.tolist()
            seen["clear"] = await asyncio.to_thread(cli, "4", "clear")
            await asyncio.sleep(0.3)
            seen["eta_cleared"] = d.supervisor.data.thruster_eta
            seen["bad"] = await asyncio.to_thread(cli, "9", "0")

        run_scenario(cfg, scenario, timeout_s=150.0)
    captured = capsys.readouterr()
    out, err = captured.out, captured.err
    print(out, err)
    assert seen["other"] == 2 and "no vehicle heartbeat from 127.0.0.1:" in err
    assert "within 1 s that this station's key verifies: " in err
    assert "message(s) came signed with another key (the --config's [mavlink] " \
           "signing_key_file is not the daemon's)" in err
    assert seen["unsigned"] == 1 and "thruster 4 eta 0: denied — COMMAND_LONG refused: " \
        "unsigned; the daemon's link is signed: give the --config that holds its [mavlink] " \
        "signing_key_file" in out
    assert seen["kill"] == 0 and seen["eta_killed"] == [1, 1, 1, 0, 1, 1]
    assert "thruster 4 eta 0: accepted — thruster 4 eta 0 (mavlink 255/190); given up: pitch" \
        in out
    assert seen["clear"] == 0 and seen["eta_cleared"] is None
    assert "thruster 4 eta 1: accepted — thruster 4 eta 1 (mavlink 255/190); given up: none" \
        in out
    assert seen["bad"] == 1 and "thruster 9 eta 0: denied" in out


def test_uvd_eta_refuses_what_is_not_an_effectiveness_and_a_silent_link(capsys):
    assert main(["eta", "4", "1.5"]) == 2
    assert main(["eta", "4", "half"]) == 2
    port = free_port("udp", "::1")  # nobody listens there
    assert main(["eta", "4", "0", "--to", f"127.0.0.1:{port}", "--timeout", "0.5"]) == 2
    err = capsys.readouterr().err
    assert "not in [0, 1]" in err and "not a number nor 'clear'" in err
    assert f"no vehicle heartbeat from 127.0.0.1:{port} within 0.5 s" in err


def test_the_eta_echoed_is_the_float32_mavlink_carries():
    from uvd.commands.eta import _eta
    assert _eta("1e-320") == 0.0 and _eta("clear") == 1.0 and _eta("0.5") == 0.5
    assert f"{_eta('0.1'):g}" == "0.1" and _eta("0.1") != 0.1  # float32's 0.1, printed as 0.1
