"""``uvd reset-failsafe``: the operator resets a latched failsafe trigger of a running daemon
from the command line, over its MAVLink link (a real daemon against a live ``sim-bridge``, a
leak flooded and dried there; the command line and a ground station each in their own
thread, as separate stations would be)."""

from __future__ import annotations

import asyncio
import time

import pytest

from tests.hil_daemon import (
    ListSink,
    link_port,
    run_scenario,
    running_bridge,
    station_link,
    until,
)
from tests.mavlink_gcs import Station, mav
from uvd.cli import main
from uvd.netports import free_port
from uvd.runtime.config import load_config
from uvd.runtime.lifecycle import State

pytestmark = pytest.mark.timeout(240)


def test_a_latched_leak_is_reset_from_the_shell_once_dry_and_the_vehicle_arms_again(
        tmp_path, capsys):
    """Flooded: the daemon disarms and latches ``leak``. Still wet, the reset is refused by
    name (exit 1) and arming is denied; dry, the reset is accepted (exit 0, the station told
    "failsafe reset: leak …") and a ground station arms the vehicle again. Before (session
    26) no station and no command could reset a latched trigger: the vehicle stayed disarmed
    until the daemon restarted."""
    seen = {}
    with running_bridge(tmp_path, station_link(tmp_path)) as (cfg_path, proc):
        cfg = load_config(cfg_path)

        def reset(port):
            return main(["reset-failsafe", "--config", str(cfg_path), "--to",
                         f"127.0.0.1:{port}", "--timeout", "10"])

        def fired(d, kind):
            return [e for e in d.supervisor.failsafe_events() if e["type"] == "failsafe"
                    and e["kind"] == kind and e["trigger"] == "leak"]

        async def scenario(d):
            port = link_port(d)
            station = Station(port)
            try:
                await asyncio.to_thread(station.heartbeat)
                assert (await asyncio.to_thread(proc.call, "leak", wet=True))["ok"]
                await until(lambda: fired(d, "fired"), 5.0, "leak")
                await until(lambda: d.supervisor.state is State.STANDBY, 2.0, "disarmed")
                seen["wet"] = await asyncio.to_thread(reset, port)
                seen["arm_wet"] = (await asyncio.to_thread(station.arm)).result
                assert (await asyncio.to_thread(proc.call, "leak", wet=False))["ok"]
                await asyncio.sleep(1.0)  # dry for 10 polls: still latched
                seen["latched_dry"] = "leak" in {a.name for a in d.supervisor.decision.active}
                seen["dry"] = await asyncio.to_thread(reset, port)
                seen["reset_events"] = fired(d, "reset")
                seen["arm_dry"] = (await asyncio.to_thread(station.arm)).result
                t_end = time.monotonic() + 5.0
                while d.supervisor.state is not State.ARMED and time.monotonic() < t_end:
                    await asyncio.sleep(0.05)
                seen["state"] = d.supervisor.state
                seen["nothing_latched"] = await asyncio.to_thread(reset, port)
                # a station written from the specification sends the command itself (31011,
                # param1 0: accepted; anything else refused)
                seen["station_reset"] = (await asyncio.to_thread(station.command, 31011,
                                                                 0)).result
                seen["station_bad"] = (await asyncio.to_thread(station.command, 31011,
                                                               2)).result
            finally:
                station.close()

        sink = ListSink()
        run_scenario(cfg, scenario, timeout_s=150.0, sink=sink)
    out = capsys.readouterr().out
    print(out)
    assert seen["wet"] == 1 and seen["arm_wet"] == mav.MAV_RESULT_DENIED
    refusals = [r["reason"] for r in sink.records if r.get("type") == "command"
                and r["command"] == "Arm" and not r["ok"]
                and str(r.get("source")).startswith("mavlink")]
    assert refusals == ["arming refused: failsafe_clear: failsafe disarm active: leak: leak "
                        "detected (leak latched: reset it once its cause is gone, uvd "
                        "reset-failsafe or MAVLink command 31011)"]  # the operator told how
    assert "failsafe reset: denied\n  ResetFailsafe refused: leak: condition still true: " \
           "leak detected" in out
    assert seen["latched_dry"] and seen["dry"] == 0
    assert "failsafe reset: accepted\n  failsafe reset: leak -> disarm (operator reset)" in out
    assert [e["reason"] for e in seen["reset_events"]] == ["operator reset"]
    assert seen["arm_dry"] == mav.MAV_RESULT_ACCEPTED and seen["state"] is State.ARMED
    assert seen["nothing_latched"] == 0  # none latched: nothing to refuse
    assert (seen["station_reset"], seen["station_bad"]) == (mav.MAV_RESULT_ACCEPTED,
                                                            mav.MAV_RESULT_DENIED)


@pytest.mark.parametrize("how", ["silence", "reboot"])
def test_a_reset_brings_faulted_or_rebooted_amplifiers_back_and_the_vehicle_arms(
        tmp_path, capsys, how):
    """A drive goes to FAULT (node 5's CAN silent for 1.3 s: it misses its commands and
    faults, as a loose connector makes it) — or every drive reboots (sim-bridge's ``reset``:
    pre-operational, unconfigured, as a power glitch leaves them). The daemon disarms on the
    latched ``amplifier_fault``. The operator's reset, disarmed, first brings the amplifiers
    back (started again, a fault reset), then resets the trigger: exit 0, and a station arms
    the vehicle. Before (session 26) nothing sent a fault reset or started a rebooted drive
    after the daemon's start: the reset was refused ("condition still true: node 5:
    drive_fault") for as long as the daemon ran — found by a chaos soak."""
    seen = {}
    with running_bridge(tmp_path, station_link(tmp_path)) as (cfg_path, proc):
        cfg = load_config(cfg_path)

        async def scenario(d):
            port = link_port(d)
            station = Station(port)
            try:
                await asyncio.to_thread(station.heartbeat)
                if how == "silence":
                    assert (await asyncio.to_thread(proc.call, "silence", node=5,
                                                    seconds=1.3))["ok"]
                else:
                    assert (await asyncio.to_thread(proc.call, "reset"))["ok"]
                await until(lambda: any(e["type"] == "failsafe" and e["kind"] == "fired"
                                        and e["trigger"] == "amplifier_fault"
                                        for e in d.supervisor.failsafe_events()), 10.0,
                            "amplifier_fault")
                await until(lambda: d.supervisor.state is State.STANDBY, 5.0, "disarmed")
                await asyncio.sleep(2.0)  # the silence over: the drive stays in FAULT
                seen["faults_before"] = d.supervisor.decision.causes
                t0 = time.monotonic()
                seen["reset"] = await asyncio.to_thread(
                    main, ["reset-failsafe", "--config", str(cfg_path), "--to",
                           f"127.0.0.1:{port}"])
                seen["reset_s"] = time.monotonic() - t0
                seen["arm"] = (await asyncio.to_thread(station.arm)).result
                t_end = time.monotonic() + 5.0
                while d.supervisor.state is not State.ARMED and time.monotonic() < t_end:
                    await asyncio.sleep(0.05)
                seen["state"] = d.supervisor.state
                await asyncio.sleep(1.0)  # tracking again, thrust out
                seen["recoveries"] = d.recovery.recoveries
            finally:
                station.close()

        sink = ListSink()
        d, cycles = run_scenario(cfg, scenario, timeout_s=150.0, sink=sink)
    out = capsys.readouterr().out
    refusals = [r["reason"] for r in sink.records if r.get("type") == "command"
                and not r["ok"] and str(r.get("source")).startswith("mavlink")]
    print(out, f"reset answered in {seen['reset_s']:.2f} s; refused: {refusals}")
    assert "amplifier_fault" in seen["faults_before"], seen
    assert seen["reset"] == 0 and "failsafe reset: amplifier_fault -> disarm (operator " \
        "reset)" in out
    assert seen["arm"] == mav.MAV_RESULT_ACCEPTED and seen["state"] is State.ARMED
    assert seen["recoveries"] == 1 and seen["reset_s"] < 12.0
    last = cycles[-5:]  # armed and driven again: every drive enabled, thrust commanded
    assert all(r["state"] == "ARMED" for r in last)
    assert any(abs(x) > 0 for r in last for x in r["thrust"])


def test_reset_failsafe_refuses_a_silent_link(capsys):
    port = free_port("udp", "::1")  # nobody listens there
    assert main(["reset-failsafe", "--to", f"127.0.0.1:{port}", "--timeout", "0.5"]) == 2
    assert f"no vehicle heartbeat from 127.0.0.1:{port} within 0.5 s" in capsys.readouterr().err
