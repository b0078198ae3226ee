"""uvd-fdc's client (and ``uvd watch``) as a separate process between two Zenoh sessions on
loopback (a publisher of estimates, a listener for faults), in real time and beside busy
processes. The detector
itself, in this process: tests/test_fdc_detector.py."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from tests.test_fdc_detector import _payload
from uvd.netports import free_port
from uvd.zenoh_callbacks import SessionCallbacks


@pytest.mark.slow
def test_the_client_reports_and_publishes_a_fault(tmp_path):
    import zenoh

    port = free_port()
    conf = _listening_peer(port)
    faults = []
    callbacks = SessionCallbacks()
    with zenoh.open(conf) as s:
        token = s.liveliness().declare_token("uvd/sub1/alive")
        # BLOCK: what is counted below is every sample, and a busy machine must not drop one
        pub = s.declare_publisher("uvd/sub1/estimate/aid6",
                                  congestion_control=zenoh.CongestionControl.BLOCK)
        s.declare_subscriber("uvd/*/fault/*", callbacks(lambda x: faults.append(
            (str(x.key_expr), json.loads(x.payload.to_bytes())))))
        proc = subprocess.Popen(
            [sys.executable, "-m", "uvd.fdc.client", "--connect", f"tcp/127.0.0.1:{port}",
             "--warmup-s", "10", "--baseline-s", "100", "--seconds", "30",
             "--stats", str(tmp_path / "stats.json")],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        lines = _Lines(proc)
        try:  # the client has subscribed (its line, and our publisher sees it): a fixed sleep
            # of 3 s lost the first 19 samples beside four busy processes
            deadline = time.monotonic() + 60.0
            while not (any("watching" in x for x in lines) and pub.matching_status.matching) \
                    and time.monotonic() < deadline:
                time.sleep(0.05)
            rng = np.random.default_rng(3)
            for k in range(300):  # 300 simulated seconds, a drag step at 200 s
                scale = {"drags": 1.5} if k >= 200 else None
                if k != 150:  # one sample lost: a gap in seq
                    pub.put(json.dumps({**_payload(float(k), rng, scale=scale), "seq": k,
                                        "wall_time": time.time()}))
                time.sleep(0.01)
            deadline = time.monotonic() + 10.0
            while not faults and time.monotonic() < deadline:
                time.sleep(0.1)
            # the operator's η (the fault accommodated, or repaired and cleared): a new
            # baseline of the vehicle as it is now, against which a later fault is found
            cleared = json.dumps({
                "kind": "command", "text": "SetThrusterEta from mavlink 255/190: ok — "
                "thruster 4 eta 1 (mavlink 255/190); given up: none",
                "record": {"type": "command", "t_ns": 300_000_000_000,
                           "command": "SetThrusterEta", "ok": True, "source": "mavlink",
                           "args": {"thruster": 4, "eta": 1.0, "source": "mavlink"}}})
            s.put("uvd/sub1/event", cleared)
            _wait_for_line(lines, "sub1: thruster effectiveness changed (SetThrusterEta from")
            s.put("uvd/sub1/event", cleared)  # cleared again: no change, no new baseline
            for k in range(300, 600):  # the drags stay 1.5×; the masses 1.1× from 500 s
                scale = {"drags": 1.5, **({"masses": 1.1} if k >= 500 else {})}
                pub.put(json.dumps({**_payload(float(k), rng, scale=scale), "seq": k,
                                    "wall_time": time.time()}))
                time.sleep(0.01)
            deadline = time.monotonic() + 10.0
            while len(faults) < 2 and time.monotonic() < deadline:
                time.sleep(0.1)
            pub.put(b"not json")  # counted and dropped, never a crash
            pub.put(b"[1, 2]")  # JSON, not an object: the same
            _wait_for_line(lines, "not a JSON object")
            token.undeclare()
            _wait_for_line(lines, "sub1: gone")
        finally:
            proc.terminate()
            proc.wait(timeout=10)
    assert callbacks.close(s) == 0  # the session closed with the block; its threads end
    lines.wait_end()
    out = "".join(lines)
    print(out)
    assert len(faults) == 2, faults
    key, d = faults[0]
    assert key == "uvd/sub1/fault/entanglement" and d["channel"].startswith("drag")
    assert faults[1][0] == "uvd/sub1/fault/flooding" and 500e9 <= faults[1][1]["t_ns"] <= 503e9
    schema = json.loads((Path(__file__).parents[1] / "uvd" / "telemetry" / "schemas"
                         / "uvd.fault.v1.json").read_text())
    jsonschema.Draft202012Validator(schema).validate(d)
    assert 200e9 <= d["t_ns"] <= 203e9
    assert "FAULT sub1: entanglement" in out and "not JSON" in out and "sub1: gone" in out
    assert out.count("thruster effectiveness changed") == 1, out
    stats = json.loads((tmp_path / "stats.json").read_text())  # --stats: what arrived
    key = "uvd/sub1/estimate/aid6"
    assert stats["received"] == {key: 599} and stats["lost"] == {key: 1}
    assert stats["dropped"] == {key: 2} and f"dropped 2 malformed samples ({key} 2)" in out
    assert stats["latency_ms"]["n"] == 599 and 0 < stats["latency_ms"]["p50"] < 1000


@pytest.fixture
def busy_machine():
    """Two processes spinning beside the test, as other work shares a vehicle's computer (or
    this machine); each ends by itself after 120 s and is stopped when the test ends."""
    spin = "import time\nend = time.monotonic() + 120\nwhile time.monotonic() < end: pass"
    procs = [subprocess.Popen([sys.executable, "-c", spin]) for _ in range(2)]
    yield
    for p in procs:
        p.kill()
        p.wait()


@pytest.mark.slow
def test_a_flood_of_malformed_samples_is_counted_each_and_told_once_a_thousand(tmp_path):
    """2500 samples on one estimate key that are not JSON, and one that is JSON but not an
    object: each counted dropped; told at the first and every 1000th of the key for each
    reason (it printed a line per sample), and in the count at the end."""
    import zenoh

    port = free_port()
    conf = _listening_peer(port)
    key = "uvd/sub2/estimate/aid6"
    with zenoh.open(conf) as s:
        pub = s.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
        proc, lines = _watching_client(["-m", "uvd.fdc.client", "--connect",
                                        f"tcp/127.0.0.1:{port}", "--seconds", "60", "--stats",
                                        str(tmp_path / "stats.json")], pub)
        try:
            for _ in range(2500):
                pub.put(b"not json")
            pub.put(b"[1, 2]")
            _wait_for_line(lines, "not a JSON object")
        finally:
            proc.terminate()
            proc.wait(timeout=10)
    lines.wait_end()
    told = [x.strip() for x in lines if x.startswith(f"{key}: not JSON")]
    assert len(told) == 3 and told[0].endswith("; dropped"), told
    assert [x.rsplit("; dropped", 1)[1] for x in told[1:]] == [" (1000 so far)",
                                                               " (2000 so far)"], told
    assert f"{key}: not a JSON object; dropped\n" in lines
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert stats["dropped"] == {key: 2501}
    assert f"uvd-fdc: dropped 2501 malformed samples ({key} 2501)\n" in lines


@pytest.mark.slow
def test_uvd_watch_tells_a_flood_of_unreadable_samples_once_a_thousand():
    """``uvd watch`` (a client like uvd-fdc) printed a line per unreadable sample: 2500 state
    samples that are not JSON and one that is a list are now told at the first and every
    1000th, an event without text once, and all counted when Ctrl-C ends it."""
    import signal

    import zenoh

    port = free_port()
    conf = _listening_peer(port)
    state, event = "uvd/sub3/state", "uvd/sub3/event"
    with zenoh.open(conf) as s:
        pub = s.declare_publisher(state, congestion_control=zenoh.CongestionControl.BLOCK)
        proc, lines = _watching_client(["-m", "uvd", "watch", "--connect",
                                        f"tcp/127.0.0.1:{port}", "--seconds", "60"], pub)
        try:
            for _ in range(2500):
                pub.put(b"not json")
            pub.put(b"[1, 2]")
            s.put(event, b"{}")
            _wait_for_line(lines, f"{event}: unreadable event")
            _wait_for_line(lines, "(2000 so far)")
            proc.send_signal(signal.SIGINT)  # Ctrl-C
            assert proc.wait(timeout=20) == 0
        finally:
            proc.kill()
            proc.wait()
    lines.wait_end()
    told = [x.strip() for x in lines if x.startswith(f"{state}: unreadable state sample")]
    assert len(told) == 3 and told[0].endswith("; dropped"), told
    assert [x.rsplit("; dropped", 1)[1] for x in told[1:]] == [" (1000 so far)",
                                                               " (2000 so far)"], told
    assert f"{event}: unreadable event ('text'); dropped\n" in lines, lines[-5:]
    assert (f"uvd watch: dropped 2502 unreadable samples ({event} 1, {state} 2501)\n"
            in lines), lines[-5:]


@pytest.mark.slow
def test_uvd_watch_tells_what_health_holds_when_it_changes():
    """``uvd watch`` prints a vehicle's failsafe triggers, amplifier faults and failing sinks
    from its ``health`` samples when they change — so a watcher that comes after the events
    that said so is told what holds — once per change, not once per sample; a health sample
    whose list is not a list of names is unreadable, told and dropped."""
    import signal

    import zenoh

    port = free_port()
    conf = _listening_peer(port)
    key = "uvd/sub4/health"

    def health(triggers, faults, sinks):
        return json.dumps({"triggers": triggers, "amplifier_faults": faults,
                           "sinks_failing": sinks}).encode()

    with zenoh.open(conf) as s:
        pub = s.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
        proc, lines = _watching_client(["-m", "uvd", "watch", "--connect",
                                        f"tcp/127.0.0.1:{port}", "--seconds", "60"], pub)
        try:
            for _ in range(3):  # what holds when the watcher comes: told once
                pub.put(health(["ins_stale", "leak"], ["node 4: overcurrent"], ["mcap"]))
            pub.put(health(["leak"], ["node 4: overcurrent"], ["mcap"]))
            pub.put(health([], [], []))
            pub.put(json.dumps({"triggers": "leak"}).encode())
            _wait_for_line(lines, "unreadable health sample")
            proc.send_signal(signal.SIGINT)  # Ctrl-C
            assert proc.wait(timeout=20) == 0
        finally:
            proc.kill()
            proc.wait()
    lines.wait_end()
    told = [x.strip() for x in lines if x.strip().startswith("sub4 ")]
    assert told == ["sub4 failsafe triggers active: ins_stale, leak",
                    "sub4 amplifier faults: node 4: overcurrent",
                    "sub4 telemetry sinks failing: mcap",
                    "sub4 failsafe triggers active: leak",
                    "sub4 failsafe triggers active: none",
                    "sub4 amplifier faults: none",
                    "sub4 telemetry sinks failing: none"], told
    assert any(x.startswith(f"{key}: unreadable health sample (triggers is not a list of names)")
               for x in lines), lines[-5:]


def _listening_peer(port: int):
    """A Zenoh peer's configuration that listens on loopback ``port``, nothing scouted: the
    publisher a client under test connects to."""
    import zenoh
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def _watching_client(argv: list[str], pub) -> tuple[subprocess.Popen, list[str]]:
    """A Zenoh client process (``python`` ``argv``) and its lines as they come, once it says
    it is watching and ``pub`` reaches it (at most 60 s: a busy machine takes its time)."""
    proc = subprocess.Popen([sys.executable, *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines = _Lines(proc)
    deadline = time.monotonic() + 60.0
    while not (any("watching" in x for x in lines) and pub.matching_status.matching) \
            and time.monotonic() < deadline:
        time.sleep(0.05)
    return proc, lines


def _wait_for_line(lines: list[str], text: str, timeout_s: float = 30.0) -> None:
    """Until a line holding ``text`` has come (a busy machine takes its time), or timeout_s."""
    deadline = time.monotonic() + timeout_s
    while not any(text in x for x in lines) and time.monotonic() < deadline:
        time.sleep(0.05)


class _Lines(list):
    """The lines ``proc`` prints, collected by a thread as they come."""

    def __init__(self, proc) -> None:
        import threading
        super().__init__()
        self._reader = threading.Thread(
            target=lambda: self.extend(iter(proc.stdout.readline, "")), daemon=True)
        self._reader.start()

    def wait_end(self, timeout_s: float = 10.0) -> None:
        """Until the process's output has ended (it has exited) and every line is in: a
        fixed 0.2 s counted on the reader thread being scheduled in it."""
        self._reader.join(timeout_s)
        assert not self._reader.is_alive(), "the process's output did not end"


@pytest.mark.slow
def test_the_client_names_a_weak_thruster_from_state_and_params(tmp_path, busy_machine):
    """A vehicle written from the schemas alone (a second Zenoh session: estimates, state and
    a params queryable answering its thruster matrix) loses half of thruster 4; AID-like
    estimates move b₁ (what AID does, docs/zenoh.md); uvd-fdc reports kind thruster, naming
    thruster 4 at η ≈ 0.5, with the residual's explanation, valid against uvd.fault.v1.

    Beside two busy processes: the client's two subscriptions then deliver their samples far
    apart (the state stream was measured 26 s of sample time behind the estimates), and the
    verdict must not depend on it (uvd.fdc.align). b₁ is constant over the baseline: its σ is
    its resolution, so the report's σ is finite and meaningful."""
    import zenoh

    from tests.test_fdc_residual import B, _estimate, _simulate

    port = free_port()
    conf = _listening_peer(port)
    samples = _simulate(260.0, t_fault=200.0, eta=[1, 1, 1, 0.5, 1, 1], noise=0.002)
    faults, asked = [], []

    def on_params(q):
        asked.append(str(q.selector))
        q.reply("uvd/sub2/params", json.dumps({"vehicle": "sub2", "t_ns": 0, "estimates": {},
                                               "configuration": {"thruster_matrix":
                                                                 B.tolist()}}))

    callbacks = SessionCallbacks()
    with zenoh.open(conf) as s:
        token = s.liveliness().declare_token("uvd/sub2/alive")
        s.declare_queryable("uvd/sub2/params", callbacks(on_params))
        # BLOCK: this vehicle runs 20× faster than real time, and what is tested is the
        # client's verdict on every sample, however late (the daemon's DROP loses none at
        # its real rate, docs/zenoh.md)
        block = zenoh.CongestionControl.BLOCK
        est = s.declare_publisher("uvd/sub2/estimate/aid6", congestion_control=block)
        state = s.declare_publisher("uvd/sub2/state", congestion_control=block)
        s.declare_subscriber("uvd/*/fault/*", callbacks(lambda x: faults.append(
            (str(x.key_expr), json.loads(x.payload.to_bytes())))))
        proc = subprocess.Popen(
            [sys.executable, "-m", "uvd.fdc.client", "--connect", f"tcp/127.0.0.1:{port}",
             "--warmup-s", "10", "--baseline-s", "150", "--seconds", "90",
             "--stats", str(tmp_path / "stats.json")],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        lines = _Lines(proc)
        try:  # the client has subscribed to both streams (its line, and our publishers see it)
            deadline = time.monotonic() + 60.0
            while not (any("watching" in x for x in lines) and est.matching_status.matching
                       and state.matching_status.matching) and time.monotonic() < deadline:
                time.sleep(0.05)
            next_est, seq = 0.0, 0
            for i, (t, v, R, f) in enumerate(samples):
                if t >= next_est:
                    b1 = 20.0 if t >= 200.0 else 0.0
                    est.put(json.dumps({**_estimate(t, b1=b1), "seq": seq,
                                        "vehicle": "sub2", "wall_time": time.time()}))
                    next_est, seq = next_est + 1.0, seq + 1
                    if i == 0:
                        deadline = time.monotonic() + 10.0  # it asks for B
                        while not asked and time.monotonic() < deadline:
                            time.sleep(0.05)
                        time.sleep(0.3)
                state.put(json.dumps({"seq": i, "t_ns": int(round(t * 1e9)), "vehicle": "sub2",
                                      "wall_time": time.time(), "v": v.tolist(),
                                      "R": R.tolist(), "thrust": f.tolist()}))
                if i % 20 == 0:
                    time.sleep(0.01)
            deadline = time.monotonic() + 60.0
            while not faults and time.monotonic() < deadline:
                time.sleep(0.1)
            token.undeclare()
        finally:
            proc.terminate()
            proc.wait(timeout=10)
    assert callbacks.close(s) == 0  # the session closed with the block; its threads end
    lines.wait_end()
    out = "".join(lines)
    print(out)
    stats = json.loads((tmp_path / "stats.json").read_text())
    print(stats)
    assert stats["lost"] == {} and stats["late"] == {"estimate": 0, "state": 0}
    assert asked and "what=configuration" in asked[0]
    assert len(faults) == 1, faults
    key, d = faults[0]
    assert key == "uvd/sub2/fault/thruster" and d["channel"] == "thruster4", d
    assert d["relative_change"] == pytest.approx(-0.5, abs=0.05)
    assert abs(d["explanation"]["since_t_ns"] * 1e-9 - 200.0) <= 10.0
    schema = json.loads((Path(__file__).parents[1] / "uvd" / "telemetry" / "schemas"
                         / "uvd.fault.v1.json").read_text())
    jsonschema.Draft202012Validator(schema).validate(d)
    assert "FAULT sub2: thruster (thruster4" in out
    assert "e+" not in out.split("FAULT sub2")[1].split("\n")[0]  # no 10¹³ σ




@pytest.mark.parametrize("event, what", [
    ({"kind": "command", "record": {"command": "SetThrusterEta", "ok": True,
                                    "args": {"thruster": 4, "eta": 0.5}}}, (4, 0.5)),
    ({"kind": "command", "record": {"command": "SetThrusterEta", "ok": False,
                                    "args": {"thruster": 9, "eta": 0.5}}}, None),
    ({"kind": "command", "record": {"command": "FaultReport", "ok": True, "reason":
                                    "uvd-fdc: thruster 4 eta 0.48 (confidence 8.78); confirmed: "
                                    "… → thruster 4 eta 0.476 (uvd-fdc); given up: none"}},
     True),
    ({"kind": "command", "record": {"command": "FaultReport", "ok": True, "reason":
                                    "uvd-fdc: thruster 7 eta 0.27 (confidence 24.3); awaiting "
                                    "the daemon's residual (…)"}}, None),
    ({"kind": "failsafe", "record": {"kind": "accommodated", "reason":
                                     "uvd-fdc: thruster 7 eta 0.27 (confidence 24.3); "
                                     "confirmed: … → thruster 7 eta 0.271 (uvd-fdc); given up: "
                                     "none"}}, True),
    ({"kind": "failsafe", "record": {"kind": "accommodated", "reason":
                                     "thruster 1 eta 0 (amplifier); given up: surge"}}, True),
    ({"kind": "failsafe", "record": {"kind": "fired", "reason": "leak"}}, None),
    ({"kind": "command", "record": {"command": "SetThrusterEta", "ok": True}}, True),
    ({"kind": "lifecycle", "record": "not a table"}, None),
])
def test_the_eta_an_event_sets_is_read_from_its_record(event, what):
    from uvd.fdc.client import eta_set
    assert eta_set(event) == what
