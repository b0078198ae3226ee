"""A client flooding ``uvd/<vehicle>/fault/**`` never fills the daemon's one command queue:
the daemon's Zenoh face (its real sink and command queue) and a second Zenoh session on
loopback putting fault samples as fast as it can, while the cycle takes none (the worst case:
a cycle slower than the flood). Found by probing a running daemon: 10 400 samples in 4 s filled
the queue (7 791 refused as "command queue full"), and a ground station's DISARM in the middle
of it was refused — the vehicle stayed armed."""

from __future__ import annotations

import asyncio
import json
import logging
import time

import zenoh

from uvd.links.zenoh import FAULTS_WAITING_MAX, ZenohSink, zenoh_config
from uvd.netports import free_port
from uvd.runtime import commands as cmd

SAMPLE = json.dumps({"vehicle": "rov9", "kind": "thruster", "t_ns": 5, "channel": "thruster4",
                     "magnitude": -12.0, "relative_change": -0.5, "confidence": 3.0})
KEY = "uvd/rov9/fault/thruster"


async def _until(pred, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while not pred() and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
    return pred()


async def _put_until(fdc, payload: str, pred) -> None:
    """Put ``payload`` until ``pred()`` (the route up, a place free): bounded, 100 × 0.1 s."""
    for _ in range(100):
        fdc.put(KEY, payload)
        if await _until(pred, 0.1):
            return


def test_a_flood_of_fault_samples_leaves_the_queue_to_the_operators_disarm(caplog):
    port = free_port()
    queue = cmd.CommandQueue()
    sink = ZenohSink("rov9", zenoh_config(listen=[f"tcp/127.0.0.1:{port}"]), faults=queue.put)
    out = {}

    async def main() -> None:
        await sink.open()
        try:
            with zenoh.open(zenoh_config(connect=[f"tcp/127.0.0.1:{port}"])) as fdc:
                await _put_until(fdc, SAMPLE, lambda: sink.faults_received > 0)
                assert sink.faults_received > 0, "no fault sample reached the daemon's face"
                # the flood is what reaches the daemon: a put that may block is never dropped
                # by the sending session (its default drops a sample when its queue is full:
                # 635 of 2000 arrived on a loaded machine)
                flood = fdc.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK)
                for _ in range(2000):
                    flood.put(SAMPLE)
                await _until(lambda: sink.faults_flooded >= 1000, 10.0)
                out["flood"] = (sink.faults_received, sink.faults_flooded, sink.faults_dropped,
                                queue.stats())
                # the operator disarms in the middle of the flood
                out["disarm"] = queue.put(cmd.Disarm(cause="ground station",
                                                     source="mavlink 255/190"))
                out["disarm_answered_at_once"] = out["disarm"].done()  # "queue full"
                # the cycle takes what waits: the fault path has its places again
                for p in queue.drain():
                    p.future.set_result(cmd.CommandResult(True))
                before = sink.faults_received
                await _put_until(fdc, SAMPLE, lambda: sink.faults_received > before)
                out["after"] = sink.faults_received - before
        finally:
            await sink.aclose()

    with caplog.at_level(logging.WARNING, logger="uvd.links.zenoh"):
        asyncio.run(asyncio.wait_for(main(), 60.0))
    received, flooded, dropped, stats = out["flood"]
    assert received == FAULTS_WAITING_MAX, out  # the cycle took none: no more were queued
    assert flooded >= 1000 and dropped == flooded, out
    assert stats == {"accepted": FAULTS_WAITING_MAX, "dropped": 0,
                     "waiting": FAULTS_WAITING_MAX}, stats
    assert not out["disarm_answered_at_once"], out["disarm"].result(0)
    assert out["disarm"].result(0) == cmd.CommandResult(True)  # the cycle took it
    assert out["after"] >= 1, out
    told = [r.getMessage() for r in caplog.records
            if "already wait for the cycle" in r.getMessage()]
    assert told and told[0] == (f"{KEY}: {FAULTS_WAITING_MAX} fault samples already wait for "
                                "the cycle; dropped (1 so far)"), told
    assert len(told) <= 1 + flooded // 1000  # not a line per sample


def test_a_sample_below_the_schemas_confidence_is_dropped_not_queued(caplog):
    """A second session's sample with confidence -5 (uvd.fault.v1's minimum is 1: uvd-fdc's
    sum over its threshold) reached the cycle and, under accept = "auto", set η."""
    port = free_port()
    queue = cmd.CommandQueue()
    sink = ZenohSink("rov9", zenoh_config(listen=[f"tcp/127.0.0.1:{port}"]), faults=queue.put)
    low = json.dumps({**json.loads(SAMPLE), "confidence": -5.0})

    async def main() -> None:
        await sink.open()
        try:
            with zenoh.open(zenoh_config(connect=[f"tcp/127.0.0.1:{port}"])) as fdc:
                await _put_until(fdc, low, lambda: sink.faults_dropped > 0)
        finally:
            await sink.aclose()

    with caplog.at_level(logging.WARNING, logger="uvd.links.zenoh"):
        asyncio.run(asyncio.wait_for(main(), 30.0))
    assert sink.faults_dropped >= 1 and sink.faults_received == 0
    assert queue.stats()["accepted"] == 0
    assert f"{KEY}: fault sample's confidence -5.0 is below 1 (uvd.fault.v1's minimum); " \
        "dropped" in [r.getMessage() for r in caplog.records]


def test_a_flood_of_malformed_samples_is_counted_each_and_told_not_line_by_line(caplog):
    """2000 malformed samples (a client with a wrong schema, say): each counted dropped and
    none queued; the log tells the first and every 1000th with the count so far (it wrote a
    line per sample: a flooding client flooded the journal)."""
    port = free_port()
    queue = cmd.CommandQueue()
    sink = ZenohSink("rov9", zenoh_config(listen=[f"tcp/127.0.0.1:{port}"]), faults=queue.put)
    bad = json.dumps({**json.loads(SAMPLE), "t_ns": "5"})

    async def main() -> None:
        await sink.open()
        try:
            with zenoh.open(zenoh_config(connect=[f"tcp/127.0.0.1:{port}"])) as fdc:
                await _put_until(fdc, bad, lambda: sink.faults_dropped > 0)
                before = sink.faults_dropped
                for _ in range(2000):
                    fdc.put(KEY, bad)
                await _until(lambda: sink.faults_dropped >= before + 2000, 20.0)
        finally:
            await sink.aclose()

    with caplog.at_level(logging.WARNING, logger="uvd.links.zenoh"):
        asyncio.run(asyncio.wait_for(main(), 60.0))
    dropped = sink.faults_dropped
    assert dropped >= 2001 and sink.faults_received == 0 and sink.faults_flooded == 0, dropped
    assert queue.stats()["accepted"] == 0
    told = [r.getMessage() for r in caplog.records if "fault sample's t_ns" in r.getMessage()]
    why = f"{KEY}: fault sample's t_ns is '5' (uvd.fault.v1 wants an integer); dropped"
    assert told[0] == why, told
    assert told[1:] == [f"{why} ({n} malformed so far)" for n in range(1000, dropped + 1, 1000)]
