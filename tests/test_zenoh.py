"""Zenoh: the daemon over sim-bridge publishes; a second Zenoh session, written only against the
documented key space and the JSON Schema files (docs/zenoh.md), subscribes, queries and
watches liveliness. Loopback only, on a port of its own.
"""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import jsonschema
import pytest
import zenoh

from tests.hil_daemon import reusing_bridge, run_scenario, running_bridge
from uvd.netports import free_port
from uvd.runtime.config import load_config
from uvd.zenoh_callbacks import SessionCallbacks

pytestmark = pytest.mark.slow

SCHEMAS = Path(__file__).parents[1] / "uvd" / "telemetry" / "schemas"


@pytest.fixture(scope="module")
def shared_bridge(tmp_path_factory):
    """One sim-bridge for the module's daemons, each test's own configuration on it."""
    with running_bridge(tmp_path_factory.mktemp("bridge")) as b:
        yield b


class Watcher:
    """The fault-detection side: its own session, the schema files, nothing of the daemon."""

    def __init__(self, endpoint: str, listen: bool = False) -> None:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5(f"{'listen' if listen else 'connect'}/endpoints", json.dumps([endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.samples: dict[str, list[dict]] = defaultdict(list)
        self.invalid: list[tuple[str, str]] = []
        self.validators = {}
        self.callbacks = SessionCallbacks()
        self.sub = self.session.declare_subscriber("uvd/**", self.callbacks(self._on_sample))

    def _validator(self, encoding: str):
        name = encoding.split("schema=", 1)[1]
        if name not in self.validators:
            sch = json.loads((SCHEMAS / f"{name}.json").read_text())
            self.validators[name] = jsonschema.Draft202012Validator(sch)
        return self.validators[name]

    def _on_sample(self, sample) -> None:
        key, enc = str(sample.key_expr), str(sample.encoding)
        try:
            msg = json.loads(sample.payload.to_bytes())
            errors = list(self._validator(enc).iter_errors(msg))
        except Exception as exc:  # noqa: BLE001 - recorded and asserted on
            self.invalid.append((key, f"{type(exc).__name__}: {exc}"))
            return
        if errors:
            self.invalid.append((key, errors[0].message))
        self.samples[key].append(msg)

    def alive(self) -> list[str]:
        """The live tokens, each once, by key: the same token can come back twice when the
        query races its routes (seen once in a fresh clone beside a campaign:
        ``['uvd/rov7/alive', 'uvd/rov7/alive']``; zenoh's duplicates of one token by timing,
        eclipse-zenoh/zenoh#1404 and #2523, where a token is identified by its key)."""
        return sorted({str(r.ok.key_expr) for r in
                       self.session.liveliness().get("uvd/*/alive", timeout=1.0)
                       if r.ok is not None})

    def query(self, selector: str) -> tuple[list[dict], list[dict], float]:
        t0 = time.monotonic()
        ok, err = [], []
        for r in self.session.get(selector, timeout=2.0):
            if r.ok is not None:
                ok.append(json.loads(r.ok.payload.to_bytes()))
            else:
                err.append(json.loads(r.err.payload.to_bytes()))
        return ok, err, time.monotonic() - t0


def test_a_schema_client_sees_state_estimates_health_events_and_params(tmp_path, shared_bridge):
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    changes = {"telemetry": {"zenoh": {"enabled": True, "listen": [endpoint], "key": "rov7",
                                       "state_hz": 10.0, "health_hz": 2.0}},
               "estimation": {"aid": True, "publish_every_s": 0.5}}
    w = Watcher(endpoint)
    info = {}
    try:
        with reusing_bridge(shared_bridge, tmp_path, changes) as (cfg_path, proc):
            cfg = load_config(cfg_path)

            async def scenario(d):
                # the watcher, opened before the daemon listened, connects on its own retry
                # schedule: with eclipse-zenoh 1.10.2 one query 0.5 s in found no token on a
                # quiet machine, on 88767d0's code too; it is asked for until seen, bounded
                end = time.monotonic() + 10.0
                await asyncio.sleep(0.5)
                info["alive"] = await asyncio.to_thread(w.alive)
                while not info["alive"] and time.monotonic() < end:
                    info["alive"] = await asyncio.to_thread(w.alive)
                info["params"] = await asyncio.to_thread(w.query, "uvd/rov7/params")
                info["bad"] = await asyncio.to_thread(w.query,
                                                      "uvd/rov7/params?colour=blue")
                info["bad_what"] = await asyncio.to_thread(w.query,
                                                           "uvd/rov7/params?what=gains")
                # at least 4 s of state from the first sample the watcher got (it may connect
                # late on a loaded machine), bounded
                end = time.monotonic() + 15.0
                while len(w.samples["uvd/rov7/state"]) < 41 and time.monotonic() < end:
                    await asyncio.sleep(0.1)

            d, cycles = run_scenario(cfg, scenario)
        end = time.monotonic() + 5.0  # the token's removal travels to the watcher (bounded)
        while (alive_after := w.alive()) and time.monotonic() < end:
            time.sleep(0.05)
        info["alive_after"] = alive_after
    finally:
        w.callbacks.close(w.session)
    assert not w.invalid, w.invalid[:5]
    state = w.samples["uvd/rov7/state"]
    health = w.samples["uvd/rov7/health"]
    est = w.samples["uvd/rov7/estimate/aid6"]
    events = w.samples["uvd/rov7/event"]
    print(f"state {len(state)}, health {len(health)}, estimate {len(est)}, events "
          f"{len(events)}; params reply in {info['params'][2] * 1e3:.1f} ms")
    for name, got in (("state", state), ("health", health), ("estimate", est),
                      ("event", events)):
        seqs = [m["seq"] for m in got]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), (name, seqs)  # no gaps
    # from the first sample on (the watcher connects once the daemon listens) at the rates
    # configured: state every cycle (10 Hz), health at 2 Hz
    span_s = (state[-1]["t_ns"] - state[0]["t_ns"]) * 1e-9
    rate = (len(state) - 1) / span_s
    assert span_s > 3.0 and 9.0 <= rate <= 11.0, (span_s, rate)
    assert len(health) >= 2.0 * span_s - 2 and len(est) >= 6
    assert all(m["sinks_failing"] == [] for m in health)  # nothing records: none fails
    assert any(m["kind"] == "lifecycle" and "ARMED" in m["text"] for m in events)
    assert est[-1]["masses"] is not None and len(est[-1]["masses"]) == 6
    assert info["alive"] == ["uvd/rov7/alive"] and info["alive_after"] == []
    ok, err, dt = info["params"]
    assert not err and len(ok) == 1 and dt < 0.1
    assert ok[0]["configuration"]["controller"] == "two-step-ambc"
    assert "aid6" in ok[0]["estimates"]
    # B for a client that names a weak thruster; AMBC's own θ̂ beside AID's; a real age
    assert len(ok[0]["configuration"]["thruster_matrix"]) == 6
    assert all(len(row) == 6 for row in ok[0]["configuration"]["thruster_matrix"])
    assert ok[0]["estimates"]["two-step-ambc"]["source"] == "controller"
    assert ok[0]["estimates"]["aid6"]["source"] == "estimator"
    assert 0.0 <= ok[0]["estimates"]["aid6"]["age_s"] < 1.0
    for key in ("bad", "bad_what"):
        ok, err, _ = info[key]
        assert not ok and len(err) == 1 and "uvd/rov7/params" in err[0]["error"]
    assert "colour" in info["bad"][1][0]["error"] and "gains" in info["bad_what"][1][0]["error"]
    assert d.app.hub.stats()["zenoh"]["errors"] == 0


def test_a_sink_told_failing_is_an_event_that_fits_the_schema():
    """The hub's ``"sink"`` record (a recording that fails, or works again) becomes an
    ``event`` sample of kind ``sink`` whose text is the one the operator reads over MAVLink
    too, and which fits ``uvd.event.v1``."""
    from uvd.links.zenoh import _event
    from uvd.telemetry.recording import schema

    rec = {"type": "sink", "t_ns": 5, "sink": "mcap", "ok": False,
           "problem": "/data/rec/uvd-1.mcap: [Errno 28] No space left on device",
           "text": "telemetry sink mcap cannot write: /data/rec/uvd-1.mcap: [Errno 28] No "
                   "space left on device", "records_dropped": 0, "write_errors": 1,
           "bytes_given_up": 0}
    jsonschema.validate(rec, schema("uvd.sink.v1"))
    body = _event("sink", rec)
    assert body["kind"] == "sink" and body["text"] == rec["text"]
    jsonschema.validate({"seq": 0, "t_ns": 5, "vehicle": "rov", **body}, schema("uvd.event.v1"))


def test_a_second_session_is_told_of_a_recording_that_cannot_open(tmp_path, shared_bridge):
    """The daemon's black box cannot open (its folder would lie under a file): a fault-detection
    client's own session (the schema files, nothing of the daemon) gets an ``event`` of kind
    ``sink`` that fits ``uvd.event.v1`` and names the sink and why."""
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    (tmp_path / "a-file").write_text("not a folder\n")
    # the client listens and the daemon connects at its start: an event is not kept for a
    # session that connects later
    changes = {"telemetry": {"zenoh": {"enabled": True, "listen": [], "connect": [endpoint],
                                       "key": "rov8"}},
               "recording": {"enabled": True, "dir": str(tmp_path / "a-file" / "rec")}}
    w = Watcher(endpoint, listen=True)
    try:
        with reusing_bridge(shared_bridge, tmp_path, changes) as (cfg_path, _):
            async def scenario(d):
                end = time.monotonic() + 15.0  # the watcher connects on its own schedule
                while not any(m["kind"] == "sink" for m in w.samples["uvd/rov8/event"]) \
                        and time.monotonic() < end:
                    await asyncio.sleep(0.1)

            run_scenario(load_config(cfg_path), scenario)
    finally:
        w.callbacks.close(w.session)
    assert not w.invalid, w.invalid[:5]
    told = [m for m in w.samples["uvd/rov8/event"] if m["kind"] == "sink"]
    assert len(told) == 1, told
    assert told[0]["text"].startswith("telemetry sink mcap did not open: open: ")
    assert told[0]["record"]["ok"] is False and "a-file" in told[0]["record"]["problem"]


def test_a_session_that_connects_after_the_event_learns_from_health_the_recording_fails(
        tmp_path, shared_bridge):
    """An event is not kept for a session that connects later, so ``health`` carries what the
    last ``sink`` event of each sink said: a client that connects after the black box failed
    to open (its folder would lie under a file) gets no event but every health sample names
    ``mcap`` in ``sinks_failing`` (the schema files, nothing of the daemon)."""
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    (tmp_path / "a-file").write_text("not a folder\n")
    changes = {"telemetry": {"zenoh": {"enabled": True, "listen": [endpoint], "key": "rov9",
                                       "health_hz": 5.0}},
               "recording": {"enabled": True, "dir": str(tmp_path / "a-file" / "rec")}}
    box: dict = {}
    with reusing_bridge(shared_bridge, tmp_path, changes) as (cfg_path, _):
        async def scenario(d):
            end = time.monotonic() + 10.0  # the failed open is told before errors count it
            while d.app.hub.stats()["mcap"]["errors"] < 1 and time.monotonic() < end:
                await asyncio.sleep(0.05)
            await asyncio.sleep(0.5)  # the event is out, and gone, before the client comes
            box["w"] = w = await asyncio.to_thread(Watcher, endpoint)
            end = time.monotonic() + 15.0  # the watcher connects on its own schedule
            while len(w.samples["uvd/rov9/health"]) < 5 and time.monotonic() < end:
                await asyncio.sleep(0.1)
            # and uvd watch, a client process of its own that comes later still
            box["watch"] = await asyncio.to_thread(
                subprocess.run, [sys.executable, "-m", "uvd", "watch", "--connect", endpoint,
                                 "--seconds", "2"], capture_output=True, text=True, timeout=60)

        try:
            run_scenario(load_config(cfg_path), scenario)
        finally:
            if "w" in box:
                box["w"].callbacks.close(box["w"].session)
    w = box["w"]
    assert not w.invalid, w.invalid[:5]
    health = w.samples["uvd/rov9/health"]
    assert len(health) >= 5, health
    assert all(m["sinks_failing"] == ["mcap"] for m in health), [m["sinks_failing"]
                                                                for m in health]
    assert not [m for m in w.samples["uvd/rov9/event"] if m["kind"] == "sink"]
    watch = box["watch"]
    assert watch.returncode == 0, watch.stderr
    assert "rov9 telemetry sinks failing: mcap\n" in watch.stdout, watch.stdout
