"""``uvd eta``: the operator sets and clears a thruster's effectiveness on a running daemon
from the command line, over the daemon's MAVLink link (a real daemon against a live
``sim-bridge``; the command line runs in its own thread as a separate station would)."""

from __future__ import annotations

import asyncio

import pytest

from tests.hil_daemon import link_port, run_scenario, running_bridge, station_link
from uvd.cli import main
from uvd.netports import free_port
from uvd.runtime.config import load_config

pytestmark = pytest.mark.timeout(240)


def test_uvd_eta_sets_and_clears_a_thruster_on_a_running_daemon(tmp_path, capsys):
    seen = {}
    with running_bridge(tmp_path, station_link(tmp_path)) as (cfg_path, _):
        cfg = load_config(cfg_path)

        async def scenario(d):
            def cli(*argv):
                return main(["eta", *argv, "--config", str(cfg_path), "--to",
                             f"127.0.0.1:{link_port(d)}", "--timeout", "10"])
            seen["kill"] = await asyncio.to_thread(cli, "4", "0")
            await asyncio.sleep(0.3)
            seen["eta_killed"] = d.supervisor.data.thruster_eta.tolist()
            seen["clear"] = await asyncio.to_thread(cli, "4", "clear")
            await asyncio.sleep(0.3)
            seen["eta_cleared"] = d.supervisor.data.thruster_eta
            seen["bad"] = await asyncio.to_thread(cli, "9", "0")

        run_scenario(cfg, scenario, timeout_s=150.0)
    out = capsys.readouterr().out
    print(out)
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
