"""The sensor-synchronous cycle (``[loop] trigger = "ins"``) with the real daemon against the
real sim-bridge: each cycle runs on an INS frame just decoded; when the INS falls silent the
fixed-rate schedule takes over, ``ins_stale`` fires on its threshold (zero thrust) and
clears when frames return, and the cycles are woken by frames again."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from tests.hil_daemon import run_scenario, running_bridge, until
from uvd.runtime.config import load_config
from uvd.runtime.lifecycle import State

pytestmark = pytest.mark.timeout(120)


def _fired(d) -> list[dict]:
    return [e for e in d.supervisor.failsafe_events() if e["type"] == "failsafe"
            and e["kind"] == "fired" and e["trigger"] == "ins_stale"]


def test_ins_trigger_with_the_real_instruments_and_its_fixed_rate_fallback(tmp_path):
    info: dict = {}
    with running_bridge(tmp_path, changes={"loop": {"trigger": "ins"}}) as (cfg_path, proc):
        cfg = load_config(cfg_path)
        period = 1.0 / cfg.loop.rate_hz
        threshold = cfg.failsafe.ins_stale_s

        async def scenario(d):
            info["woken_before"] = d.app.loop.woken
            ans = await asyncio.to_thread(proc.call, "sensor", name="ins", mode="silence",
                                          seconds=threshold + 1.0)
            assert ans["ok"], ans
            info["t_inj"] = ans["t_ns"]
            await until(lambda: _fired(d), threshold + 2.0, "ins_stale")
            info["woken_silent"] = d.app.loop.woken
            await asyncio.sleep(0.5)
            info["woken_still_silent"] = d.app.loop.woken
            await until(lambda: d.supervisor.state is State.ARMED, threshold + 5.0,
                        "ARMED again")
            info["woken_back"] = d.app.loop.woken
            await asyncio.sleep(0.5)
            info["woken_end"] = d.app.loop.woken

        d, cycles = run_scenario(cfg, scenario, tracking_s=1.5)
    assert info["woken_before"] >= 10                 # tracking: cycles started by frames
    assert info["woken_still_silent"] == info["woken_silent"]   # silent: the fixed schedule
    assert info["woken_end"] - info["woken_back"] >= 3           # frames back: woken again
    fired = _fired(d)[0]
    assert fired["action"] == "zero-thrust"
    # the cycles kept running through the silence, one a period on the fixed schedule
    silent = np.array([r["t_ns"] for r in cycles
                       if info["t_inj"] + threshold * 1e9 < r["t_ns"] < fired["t_ns"] + 5e8])
    gaps = np.diff(silent) * 1e-9
    assert len(gaps) >= 3 and np.median(gaps) == pytest.approx(period, rel=0.05)
    ages = [r["ages"][0] for r in cycles if r["t_ns"] < info["t_inj"]][-10:]
    assert max(ages) < 0.5 * period       # a synchronous cycle's INS sample is fresh


@pytest.mark.parametrize("trigger", ["ins", "fixed"])
def test_a_synchronous_cycle_takes_dvl_and_depth_frames_received_up_to_its_ins_frame(
        tmp_path, trigger):
    """The cut follows the receive stamps: a frame received after the cycle's INS frame
    waits for the next cycle (or is taken by a cycle with no INS frame); the fixed schedule
    takes whatever arrived."""
    from drivers.samples import DepthSample, DvlSample, InsSample
    from sim_bridge.bridge import write_local_config
    from uvd.runtime.daemon import Daemon

    cfg = load_config(write_local_config(tmp_path, changes={
        "loop": {"trigger": trigger}, "mavlink": {"enabled": False},
        "telemetry": {"zenoh": {"enabled": False}}}))
    d = Daemon(cfg)  # not run: no port is opened

    def ins(t):
        return InsSample(t_ns=t, roll=0.0, pitch=0.0, heading=0.0, omega_body=np.zeros(3))

    before = DvlSample(t_ns=900, velocity_body=np.zeros(3), bottom_lock=True)
    after = DepthSample(t_ns=1100, depth_m=1.0)
    d.hardware.instruments.ins_box.put(ins(1000))
    d.hardware.instruments.dvl_box.put(before)
    d.hardware.instruments.depth_box.put(after)
    inp = d.read(1200)
    assert inp.ins.t_ns == 1000 and inp.dvl is before
    sync = trigger == "ins"
    assert (inp.depth is None) if sync else (inp.depth is after)
    counters = d.hardware.instruments.counters
    assert counters["depth_deferred"] == int(sync) and counters["dvl_deferred"] == 0
    d.hardware.instruments.ins_box.put(ins(2000))
    inp = d.read(2100)                    # the next INS frame's cycle takes it
    assert (inp.depth is after) if sync else (inp.depth is None)
    d.hardware.instruments.depth_box.put(DepthSample(t_ns=2500, depth_m=1.1))
    inp = d.read(3100)                    # no INS frame (the fallback schedule): all is taken
    assert inp.ins is None and inp.depth.t_ns == 2500
    assert d.hardware.instruments.counters["depth_deferred"] == int(sync)
