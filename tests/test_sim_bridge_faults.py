"""sim-bridge's faults of the vehicle (for fault detection): a real ``sim-bridge --control``
process given ``--at`` commands from its start and further ones on its control channel, with
``at_s`` or at once; bad commands are refused with their name."""

from __future__ import annotations

import time

import pytest

from sim_bridge.bridge import BridgeProcess, write_local_config

pytestmark = pytest.mark.slow


def test_plant_and_thruster_faults_at_chosen_times(tmp_path):
    cfg = write_local_config(tmp_path)
    proc = BridgeProcess(cfg, duration_s=60.0, extra=[
        "--at", "0.2", '{"op": "plant_fault", "drag_scale": 1.5}',
        "--at", "0.2", '{"op": "health", "node": 4, "value": 0.5}']).start(timeout_s=90.0)
    try:
        deadline = time.monotonic() + 10.0
        while (st := proc.call("stats"))["scheduled"] and time.monotonic() < deadline:
            time.sleep(0.1)
        assert st["scheduled"] == 0 and len(st["timed"]) == 2, st["timed"]
        assert all(r["ok"] for r in st["timed"]), st["timed"]
        assert st["plant_fault"]["drag_scale"] == 1.5
        assert st["thruster_health"][3] == 0.5  # node 4 is the fourth amplifier

        ans = proc.call("plant_fault", mass_scale=1.1, g_delta=-20.0, b_delta=[0, 0, 5],
                        at_s=0.3)
        assert ans["ok"] and ans["scheduled_ns"] > ans["t_ns"]
        assert proc.call("stats")["plant_fault"]["mass_scale"] == 1.0  # not yet
        assert proc.call("health", node=4, value=0.0)["ok"]  # at once
        time.sleep(1.0)
        st = proc.call("stats")
        assert st["plant_fault"] == {"drag_scale": 1.0, "mass_scale": 1.1, "g_delta": -20.0,
                                     "b_delta": [0.0, 0.0, 5.0]}
        assert st["thruster_health"][3] == 0.0
        assert st["timed"][-1]["due_ns"] == ans["scheduled_ns"]

        for kw, words in (({"colour": "red"}, "colour"), ({"drag_scale": -1}, "> 0"),
                          ({"b_delta": [1]}, "b_delta"), ({"at_s": "soon"}, "soon")):
            bad = proc.call("plant_fault", **kw)
            assert not bad["ok"] and words in bad["error"], bad
        assert proc.call("plant_fault")["ok"]  # no argument: the vehicle's own again
        assert proc.call("stats")["plant_fault"]["mass_scale"] == 1.0
    finally:
        proc.stop(timeout_s=5.0)
        proc.kill()
