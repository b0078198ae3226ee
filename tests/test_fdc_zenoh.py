"""uvd-fdc's fault samples reach the daemon only from the authorised client: a router loaded
from config/zenoh/router.json5 (its ACL: only the user ``fdc`` puts on ``uvd/*/fault/**``),
the daemon's own Zenoh face (``[faults.fdc] enabled``, its command queue), and two other
sessions — the ``fdc`` client and a session with a vehicle's credentials, which may put on
``uvd/**`` but not on a fault key. The refused put never reaches the daemon's queue; the
authorised one arrives as a FaultReport; a malformed one is counted and dropped.
"""

from __future__ import annotations

import asyncio
import json
import shutil
import time

import pytest
import zenoh

from tests.test_zenoh_security import _client, _wait, fleet
from uvd.runtime import commands as cmd

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None,
                                reason="openssl makes the test's certificates")


def _sample(thruster: int, eta: float) -> bytes:
    return json.dumps({"vehicle": "rov7", "kind": "thruster", "t_ns": 123, "channel":
                       f"thruster{thruster}", "magnitude": 40.0, "relative_change": eta - 1.0,
                       "confidence": 2.5, "explanation": {"coef": [1.0 - eta],
                                                          "since_t_ns": 100}}).encode()


def test_only_the_authorised_fdc_client_gets_a_fault_sample_to_the_daemon(tmp_path):
    router, endpoint, cfg = fleet(tmp_path, {"faults": {"fdc": {"enabled": True}}})
    from uvd.links.zenoh import zenoh_sink
    from uvd.telemetry.sink import TelemetryHub
    queue = cmd.CommandQueue()
    sink = zenoh_sink(cfg, TelemetryHub(), commands=queue)
    got: list = []

    def drain() -> list:
        got.extend(p.command for p in queue.drain())
        return got

    try:
        asyncio.run(sink.open())
        fdc = zenoh.open(_client("fdc", tmp_path, endpoint, "fdc-secret"))
        other = zenoh.open(_client("vehicle", tmp_path, endpoint, "rov-secret"))
        time.sleep(0.5)  # the daemon's subscription travels to the router

        other.put("uvd/rov7/fault/thruster", _sample(2, 0.0))  # not fdc: refused by the router
        other.put("uvd/rov7/event", b"{}")  # the same session's put on its own key space works
        fdc.put("uvd/rov7/fault/thruster", _sample(4, 0.5))  # the authorised client
        assert _wait(lambda: drain(), 5.0), "the authorised fault sample never arrived"
        time.sleep(1.0)  # what the router let through has arrived by now
        drain()
        assert got == [cmd.FaultReport("thruster", "thruster4", -0.5, 123, 2.5, 100)], got
        assert sink.faults_received == 1

        fdc.put("uvd/rov7/fault/thruster", b'{"kind": "thruster"}')  # malformed: dropped
        assert _wait(lambda: sink.faults_dropped == 1, 5.0)
        assert drain() == got[:1] and len(got) == 1
        fdc.close()
        other.close()
    finally:
        asyncio.run(sink.aclose())
        router.close()


def test_a_malformed_fault_sample_is_named():
    from uvd.links.zenoh import fault_report
    with pytest.raises(ValueError, match="uvd/a/fault/x: fault sample is not JSON"):
        fault_report("uvd/a/fault/x", b"{")
    with pytest.raises(ValueError, match="fault sample's t_ns is '5' .*an integer"):
        fault_report("uvd/a/fault/x", json.dumps({"kind": "thruster", "channel": "thruster1",
                                                   "t_ns": "5", "confidence": 1.0}).encode())
    with pytest.raises(ValueError, match="relative_change is 'x'"):
        fault_report("k", json.dumps({"kind": "thruster", "channel": "thruster1", "t_ns": 5,
                                      "confidence": 1.0, "relative_change": "x"}).encode())
