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
from uvd.zenoh_callbacks import SessionCallbacks

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
    # found by fuzzing the daemon's fault path: a since_t_ns past a float's range reached the
    # cycle, where confirming the claim raised OverflowError (the daemon refused the command
    # with that text); a NaN confidence was taken
    good = {"kind": "thruster", "channel": "thruster4", "t_ns": 5, "confidence": 1.0,
            "relative_change": -0.5}
    with pytest.raises(ValueError, match=r"explanation.since_t_ns 10{400} is beyond 64 bits"):
        fault_report("k", json.dumps({**good, "explanation": {"since_t_ns": 10 ** 400}}
                                     ).encode())
    with pytest.raises(ValueError, match="t_ns 9223372036854775808 is beyond 64 bits"):
        fault_report("k", json.dumps({**good, "t_ns": 2 ** 63}).encode())
    with pytest.raises(ValueError, match="confidence is nan"):
        fault_report("k", json.dumps({**good, "confidence": float("nan")}).encode())
    # below the schema's minimum 1 (no detection by uvd-fdc's own measure): -5 was acted on
    # under accept = "auto" on a running daemon
    for conf in (-5.0, 0.0, 0.999):
        with pytest.raises(ValueError, match=f"confidence {conf!r} is below 1 "
                                             r"\(uvd.fault.v1's minimum\); dropped"):
            fault_report("k", json.dumps({**good, "confidence": conf}).encode())
    assert fault_report("k", json.dumps({**good, "t_ns": 2 ** 63 - 1}).encode()).t_ns == \
        2 ** 63 - 1
    # nested past the parser's depth: a RecursionError escaped into zenoh's thread, uncounted
    with pytest.raises(ValueError, match="fault sample is not JSON .*recursion"):
        fault_report("k", b"[" * 100_000 + b"]" * 100_000)
    # a kind outside the schema's enum, a channel of megabytes: were taken, and told whole
    with pytest.raises(ValueError, match="kind 'a{64}' is not one of entanglement, "
                                         "drag-decrease, flooding, lost-part, buoyancy, thruster"):
        fault_report("k", json.dumps({**good, "kind": "a" * 10**6}).encode())
    with pytest.raises(ValueError, match=r"channel is 1000000 characters \(at most 64\)"):
        fault_report("k", json.dumps({**good, "channel": "t" * 10**6}).encode())
    for kind in ("entanglement", "drag-decrease", "flooding", "lost-part", "buoyancy"):
        assert fault_report("k", json.dumps({**good, "kind": kind}).encode()).kind == kind


def _sample_from_the_schema(thruster: int, eta: float) -> bytes:
    """A uvd-fdc fault sample built from docs/zenoh.md's schema file alone (no uvd import): the
    required fields it names, the thruster convention its descriptions give (channel
    ``thruster<i>``, relative_change η − 1), checked against it before it is put."""
    from pathlib import Path

    import jsonschema
    path = Path(__file__).parents[1] / "uvd" / "telemetry" / "schemas" / "uvd.fault.v1.json"
    schema = json.loads(path.read_text())
    sample = {"vehicle": "rov7", "kind": "thruster", "t_ns": 5_000_000_000,
              "channel": f"thruster{thruster}", "magnitude": -12.0,
              "relative_change": eta - 1.0, "confidence": 3.0,
              "explanation": {"coef": [1.0 - eta], "since_t_ns": 1_000_000_000}}
    assert set(schema["required"]) <= set(sample)
    jsonschema.validate(sample, schema)
    return json.dumps(sample).encode()


def test_a_sample_built_from_the_documented_schema_is_decided_by_accept(tmp_path):
    """The fdc client's sample, written against uvd.fault.v1 only, goes through the router to
    the daemon's Zenoh face; the FaultReport it becomes is then decided by the cycle of a JHU
    ROV in each ``accept`` mode: advisory tells and leaves η, auto sets thruster 4's η 0.5,
    confirm (the default) keeps it, awaiting the daemon's own residual, which has no evidence
    yet."""
    from tests.test_fdc_source import _cfg, _run, _sim
    router, endpoint, cfg = fleet(tmp_path, {"faults": {"fdc": {"enabled": True}}})
    from uvd.links.zenoh import zenoh_sink
    from uvd.telemetry.sink import TelemetryHub
    queue = cmd.CommandQueue()
    sink = zenoh_sink(cfg, TelemetryHub(), commands=queue)
    got: list = []
    try:
        asyncio.run(sink.open())
        fdc = zenoh.open(_client("fdc", tmp_path, endpoint, "fdc-secret"))
        time.sleep(0.5)  # the daemon's subscription travels to the router
        fdc.put("uvd/rov7/fault/thruster", _sample_from_the_schema(4, 0.5))
        assert _wait(lambda: got.extend(p.command for p in queue.drain()) or got, 5.0)
        fdc.close()
    finally:
        asyncio.run(sink.aclose())
        router.close()
    (report,) = got
    assert report == cmd.FaultReport("thruster", "thruster4", -0.5, 5_000_000_000, 3.0,
                                     1_000_000_000)
    for accept, ok, eta in [("advisory", True, None), ("auto", True, [1, 1, 1, 0.5, 1, 1]),
                            ("confirm", True, None)]:
        sim = _sim(_cfg(accept))
        _run(sim, 0.5)
        res = sim.command(report)
        data = sim.supervisor.data
        assert res.ok is ok, (accept, res.reason)
        assert (None if data.thruster_eta is None else data.thruster_eta.tolist()) == eta
        assert {"advisory": "advisory, not acted on", "auto": "accepted (auto)",
                "confirm": "awaiting the daemon's residual"}[accept] in res.reason


def test_the_fdc_client_reads_hold_reason_from_the_estimates(tmp_path):
    """A JHU ROV in lockstep with AID on loses thruster 4 (pitch given up); the estimate records
    its cycle produces go out on the daemon's Zenoh face, and the fdc client — a plain
    subscriber through the router, checking each sample against uvd.zestimate.v1 — reads which
    DOF's rows are held, and "" again once the thruster is back."""
    from dataclasses import replace
    from pathlib import Path

    import jsonschema

    from uvd.lockstep import of_config
    from uvd.runtime.config import DEFAULT_CONFIG, load_config
    from uvd.telemetry.records import estimate_records
    schema = json.loads((Path(__file__).parents[1] / "uvd" / "telemetry" / "schemas"
                         / "uvd.zestimate.v1.json").read_text())
    vcfg = load_config(DEFAULT_CONFIG)
    vcfg = replace(vcfg, estimation=replace(vcfg.estimation, aid=True))
    sim = of_config(vcfg)

    def records(seconds):
        for _ in range(round(seconds / sim.dt_control)):
            sim.advance()
        return estimate_records(sim.core_cfg, sim.state, sim.t_ns)

    router, endpoint, cfg = fleet(tmp_path)
    from uvd.links.zenoh import zenoh_sink
    from uvd.telemetry.sink import TelemetryHub
    sink = zenoh_sink(cfg, TelemetryHub())
    seen: list[dict] = []
    try:
        asyncio.run(sink.open())
        fdc = zenoh.open(_client("fdc", tmp_path, endpoint, "fdc-secret"))
        callbacks = SessionCallbacks()
        fdc.declare_subscriber("uvd/rov7/estimate/**", callbacks(
            lambda s: seen.append(json.loads(s.payload.to_bytes()))))
        time.sleep(0.5)  # the subscription travels to the router
        assert sim.command(cmd.SetThrusterEta(4, 0.0, source="test")).ok
        asyncio.run(sink.write(records(1.0)))
        assert _wait(lambda: len(seen) >= 1, 5.0), "no estimate reached the fdc client"
        assert sim.command(cmd.SetThrusterEta(4, 1.0)).ok
        asyncio.run(sink.write(records(1.0)))
        assert _wait(lambda: len(seen) >= 2, 5.0)
        assert callbacks.close(fdc) == 0
    finally:
        asyncio.run(sink.aclose())
        router.close()
    for s in seen:
        jsonschema.validate(s, schema)
    assert seen[0]["hold_reason"].startswith("pitch given up"), seen[0]["hold_reason"]
    assert seen[1]["hold_reason"] == ""
