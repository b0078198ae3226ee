"""Realtime replay: a recorded HIL run's input played onto a bus and pseudo-terminals for a
second daemon, whose commands are compared with the recording on the wire.

One short recorded run (auto-arm, tracking, no operator command) is played twice: on a
``udp_multicast`` bus on loopback to a second daemon *process* with the recorded
configuration (its commands must match within the documented tolerance), and on a
``virtual`` bus to a daemon in this process with another gain (the summary must show the
difference). A file that cannot be played, and a daemon that never comes, end with a clear
message, not a hang.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import threading
from pathlib import Path

import numpy as np
import pytest

from tests.hil_daemon import run_scenario, running_bridge
from uvd.cli import main
from uvd.netports import free_port
from uvd.runtime.config import load_config
from uvd.runtime.daemon import Daemon
from uvd.runtime.loop import drop_realtime
from uvd.runtime.replay.realtime import (
    TOLERANCE_PERMILLE,
    compare_commands,
    load_wire,
    replay_realtime,
)
from uvd.telemetry.recording import RecordingError

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """(recording file, config path) of a short recorded HIL run: arm, track 4 s."""
    run_dir = tmp_path_factory.mktemp("rt")
    changes = {"recording": {"enabled": True, "dir": str(run_dir / "rec"),
                             "flush_interval_s": 0.1}}
    with running_bridge(run_dir, changes) as (cfg_path, _):
        async def scenario(d):
            await asyncio.sleep(3.0)

        run_scenario(load_config(cfg_path), scenario)
    (path,) = sorted((run_dir / "rec").glob("*.mcap"))
    return path, cfg_path


def _group() -> str:
    a, b = (int(x) for x in np.random.default_rng().integers(1, 0xFFFF, 2))
    return f"ff11::7576:{a:x}:{b:x}"


def test_a_second_daemon_process_commands_what_the_recording_did(recorded, tmp_path,
                                                                 monkeypatch):
    """``--work`` relative to the working directory, as a user types it (before session 32
    the daemon's configuration named relative ports, it refused them, and the replay said
    only "no daemon appeared" after its 60 s wait)."""
    path, _ = recorded
    out = tmp_path / "rt.json"
    monkeypatch.chdir(tmp_path)
    code = main(["replay", str(path), "--realtime", "--can-interface", "udp_multicast",
                 "--channel", _group(), "--can-port", str(free_port("udp", "::1")), "--daemon",
                 "--work", "work", "--json", str(out), "--quiet"])
    res = json.loads(out.read_text())
    pl, c = res["playing"], res["commands"]
    print(pl, {k: v for k, v in c.items() if k != "first_difference"}, res["tracking"])
    assert "error" not in pl
    assert pl["dropped"] == {"can": 0, "serial": 0} and pl["played"]["serial"] > 50
    assert res["daemon_exit"] == 0
    assert c["cycles_compared"] > 30 and c["match"] and code == 0, c
    rec, live = res["tracking"]["recorded"], res["tracking"]["live"]
    assert live["cycles"] > 20
    assert abs(live["position_mne"] - rec["position_mne"]) < 0.1 * rec["position_mne"]


def test_another_gain_on_a_virtual_bus_shows_the_difference(recorded, tmp_path):
    path, cfg_path = recorded
    other = tmp_path / "other.toml"
    other.write_text(Path(cfg_path).read_text().replace("kp = 300.0", "kp = 600.0"))
    assert "kp = 600.0" in other.read_text()
    got: dict = {}
    ready = threading.Event()

    def play():
        try:
            got["res"] = replay_realtime(
                path, tmp_path / "work", interface="virtual", channel=f"rt-{os.getpid()}",
                config=other, wait_s=30.0, ready=lambda p: (got.update(cfg=p), ready.set()))
        finally:
            ready.set()

    player = threading.Thread(target=play)
    player.start()
    assert ready.wait(30.0) and "cfg" in got

    async def main():
        d = Daemon(load_config(got["cfg"]), auto_arm=True)
        task = asyncio.get_running_loop().create_task(d.run())
        while player.is_alive() and not task.done():
            await asyncio.sleep(0.05)
        d.stop("replay over")
        return await asyncio.wait_for(task, 10.0)

    affinity = os.sched_getaffinity(0)
    try:
        assert asyncio.run(asyncio.wait_for(main(), 60.0)) == 0
    finally:
        drop_realtime()
        os.sched_setaffinity(0, affinity)
    player.join(10.0)
    res = got["res"]
    c = res.commands
    print({k: v for k, v in c.items() if k != "first_difference"}, res.tracking)
    assert c["cycles_compared"] > 30 and not c["match"]
    assert c["max_diff_permille"] > 5 * TOLERANCE_PERMILLE
    rec, live = res.tracking["recorded"], res.tracking["live"]
    assert live["cycles"] > 20 and live["thrust_rms_n"] > 1.2 * rec["thrust_rms_n"]


def test_files_that_cannot_be_played_and_a_daemon_that_never_comes(recorded, tmp_path):
    path, _ = recorded
    foreign = tmp_path / "foreign.mcap"
    foreign.write_text("not a recording\n")
    with pytest.raises(RecordingError, match="foreign.mcap: not an MCAP file"):
        load_wire(foreign)
    res = replay_realtime(path, tmp_path / "w", interface="virtual",
                          channel=f"nobody-{os.getpid()}", wait_s=0.5)
    assert res.playing == {"error": "no daemon appeared on the bus within 0.5 s"}


def test_a_daemon_under_test_that_exits_is_said_at_once_with_its_words(recorded, tmp_path):
    """``--daemon`` started a daemon that refused its configuration (exit 2): the replay says
    so at once, with the daemon's last lines, instead of waiting ``--wait`` seconds for its
    first frame and saying "no daemon appeared" (before session 32)."""
    path, cfg_path = recorded
    bad = tmp_path / "bad.toml"
    bad.write_text(cfg_path.read_text().replace("[control]", "[control]\nkpp = 1.0", 1))
    res = replay_realtime(path, tmp_path / "w", interface="udp_multicast", channel=_group(),
                          can_port=free_port("udp", "::1"), config=bad, start_daemon=True,
                          wait_s=120.0)
    err = res.playing["error"]
    assert err.startswith("the daemon under test exited with code 2 before its first frame")
    assert "control.kpp" in err and "unknown key" in err, err
    assert res.daemon_exit == 2


def test_a_damaged_record_ends_what_is_played(recorded, tmp_path):
    """A record whose length runs past the end in the middle of the file: the run is played
    up to its last cycle before it, and the result says where it stopped (it was refused)."""
    import struct

    from uvd.telemetry.recording import read_messages
    path, _ = recorded
    data = bytearray(path.read_bytes())
    pos, messages = 8, []
    while pos < len(data):  # MCAP's framing: an opcode, a uint64 length
        op, length = struct.unpack_from("<BQ", data, pos)
        if op == 0x0F:
            break
        if op == 0x05:
            messages.append(pos)
        pos += 9 + length
    i = len(messages) // 2
    data[messages[i] + 1:messages[i] + 9] = (2**40).to_bytes(8, "little")
    bad = tmp_path / "damaged.mcap"
    bad.write_bytes(bytes(data))
    n_before = sum(1 for topic, _, _ in list(read_messages(path))[:i] if topic == "/uvd/cycle")
    rec = load_wire(bad)
    assert len(rec.cycles) == n_before > 0
    assert rec.damaged.startswith(f"damaged MCAP record at byte {messages[i]} (its length")
    res = replay_realtime(bad, tmp_path / "w", interface="virtual",
                          channel=f"nobody-{os.getpid()}", wait_s=0.5)
    assert res.stopped == f"{rec.damaged}: the run is played up to the {n_before} cycles " \
                          "recorded before it"


def test_a_malformed_cycle_record_ends_what_is_played(recorded, tmp_path):
    """A cycle record that is valid JSON but not what uvd.cycle.v1 promises (its attitude cut
    short), or not an object at all: what is played ends before it, as damage does, named as
    the lockstep replay names it (one judgement, uvd.runtime.replay.records)."""
    from tests.test_recording import _rewrite
    path, _ = recorded
    for edit, why in ((lambda msg: {**msg, "R": msg["R"][:2]},
                       "a /uvd/cycle record at [0-9]+ ns is malformed \\(R is not 3×3 "
                       "numbers\\)"),
                      (lambda msg: [msg], "a /uvd/cycle record at [0-9]+ ns is malformed "
                                          "\\(a JSON list, not an object\\)")):
        n_cycle = iter(range(10**6))
        bad = tmp_path / "malformed.mcap"
        _rewrite(path, bad, lambda k, topic, msg, edit=edit, n_cycle=n_cycle: edit(msg)
                 if topic == "/uvd/cycle" and next(n_cycle) == 20 else msg)
        rec = load_wire(bad)
        assert len(rec.cycles) == 20
        assert re.fullmatch(why, rec.damaged), rec.damaged


def test_both_replays_end_at_the_same_malformed_record_in_the_same_words(recorded, tmp_path):
    """A command record whose arguments are not an object: the lockstep replay ended there,
    the realtime one read on past it (each judged records its own way). One judgement now
    (uvd.runtime.replay.records): both end at it and name it alike."""
    from tests.test_recording import _rewrite
    from uvd.runtime.replay.lockstep import load_recording
    from uvd.telemetry.recording import read_messages
    path, _ = recorded
    every = list(read_messages(path))
    first_cycle = next(i for i, (topic, _, _) in enumerate(every) if topic == "/uvd/cycle")
    k = next(i for i, (topic, _, _) in enumerate(every)
             if topic == "/uvd/command" and i > first_cycle)
    bad = tmp_path / "bad-command.mcap"
    _rewrite(path, bad, lambda i, topic, msg: {**msg, "args": 5} if i == k else msg)
    wire, lockstep = load_wire(bad), load_recording(bad)
    assert wire.damaged == lockstep.damaged == (
        f"a /uvd/command record at {every[k][1]} ns is malformed "
        f"({every[k][2]['command']}: args 5 are not an object)")
    n_before = sum(1 for topic, _, _ in every[:k] if topic == "/uvd/cycle")
    assert len(wire.cycles) == len(lockstep.cycles) == n_before


def test_compare_commands_cycle_by_cycle():
    rec = [{1: 0, 2: 0}, {1: 10, 2: -5}, {1: 30, 2: 0}, {1: 0, 2: 0}, {1: 0, 2: 0}]
    c = compare_commands(rec, rec, cycles=4)
    assert (c["identical"], c["cycles_compared"], c["match"]) == (4, 4, True)
    live = [{1: 0, 2: 0}, {1: 10, 2: -5}, {1: 30 + TOLERANCE_PERMILLE, 2: 0}, {1: 0}]
    c = compare_commands(rec, live, cycles=4)
    assert (c["identical"], c["within_tolerance"], c["cycles_compared"]) == (2, 3, 4)
    assert c["first_difference"]["cycle"] == 2 and c["max_diff_permille"] == float("inf")
    assert not c["match"]


def test_a_daemon_that_stops_costs_one_gate_timeout_not_a_hang():
    """A recording of 1 s with 500 drive frames, each gated on a SYNC of the daemon: the
    'daemon' (a second python-can virtual bus) sends its NMT start and one SYNC, then
    nothing. The player must finish in about the recording's length plus one timeout."""
    import time

    import can

    from uvd.runtime.replay.realtime import RealtimePlayer, WireRecording

    fb = [(10_000_000 + k * 2_000_000, can.Message(arbitration_id=0x181, data=b"\0" * 8,
                                                   is_extended_id=False), (0x080, k // 5))
          for k in range(500)]
    rec = WireRecording(Path("synthetic.mcap"), "", [], fb,
                        {0x000: [0], 0x080: [5_000_000 + 10_000_000 * k for k in range(100)]},
                        frozenset({0x000, 0x080}), [{}], [], [], (1,))
    chan = f"gate-{os.getpid()}"
    with can.Bus(interface="virtual", channel=chan) as ours, \
            can.Bus(interface="virtual", channel=chan) as daemon:
        player = RealtimePlayer(rec, ours, {}, wait_s=5.0, tail_s=0.0, gate_timeout_s=0.2)
        got = {}
        t = threading.Thread(target=lambda: got.update(player.run()))
        t0 = time.monotonic()
        t.start()
        daemon.send(can.Message(arbitration_id=0x000, data=b"\x01\x00", is_extended_id=False))
        time.sleep(0.005)
        daemon.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
        t.join(10.0)
        wall = time.monotonic() - t0
    print(got, f"{wall:.2f} s")
    assert not t.is_alive() and wall < 2.5
    assert got["played"]["can"] == 500 and got["frames_ungated"] >= 490


def test_the_documented_can_log_filter_keeps_the_received_frames_and_plays(tmp_path):
    """docs/recording.md: keep the frames the daemon received (``R``) of a candump log with
    python-can's reader and writer, then python-can's player plays the result."""
    import subprocess
    import sys

    import can

    log, rx = tmp_path / "can.log", tmp_path / "rx.log"
    w = can.Logger(str(log))
    for k in range(20):
        w(can.Message(timestamp=100.0 + 0.01 * k, arbitration_id=0x181 if k % 2 else 0x201,
                      data=bytes([k]) * 8, is_extended_id=False, is_rx=bool(k % 2)))
    w.stop()
    text = (Path(__file__).parents[1] / "docs" / "recording.md").read_text()
    cmd = next(line for line in text.splitlines() if line.startswith("python -c \"import can"))
    code = cmd.split('"')[1]
    subprocess.run([sys.executable, "-c", code, str(log), str(rx)], check=True, timeout=60)
    kept = list(can.LogReader(str(rx)))
    assert [m.arbitration_id for m in kept] == [0x181] * 10
    assert [m.data[0] for m in kept] == list(range(1, 20, 2))
    assert kept[1].timestamp - kept[0].timestamp == pytest.approx(0.02)
    played = subprocess.run([sys.executable, "-m", "can.player", "-i", "virtual", "-c",
                             f"rx-{os.getpid()}", "-v", "--", str(rx)], capture_output=True,
                            text=True, timeout=60)
    assert played.returncode == 0, played.stderr
    sent = [line for line in played.stdout.splitlines() if line.startswith("Timestamp:")]
    assert len(sent) == 10 and all("ID:      181" in line for line in sent)


def test_the_daemon_under_test_of_a_fault_run_starts_without_zenoh_or_its_fdc_source(tmp_path):
    """``uvd demo --fault``'s black box holds ``[faults.fdc] enabled`` (uvd-fdc over Zenoh):
    the daemon under test, which has no Zenoh, refused to start ("faults.fdc.enabled: uvd-fdc's
    samples come over Zenoh") and the run could not be replayed in real time."""
    from uvd.io.toml import dump_toml, read_toml
    from uvd.runtime.config import DEFAULT_CONFIG, load_config
    from uvd.runtime.replay.realtime import live_config
    data = read_toml(DEFAULT_CONFIG)
    data["faults"] = {"fdc": {"enabled": True, "accept": "confirm"}}
    text = dump_toml(data)
    (tmp_path / "recorded.toml").write_text(text)
    assert load_config(tmp_path / "recorded.toml").faults.fdc.enabled  # valid as recorded
    out = live_config(text, tmp_path, interface="virtual", channel="uvd-x",
                      can_port=None)
    cfg = load_config(out)
    assert not cfg.telemetry.zenoh.enabled and not cfg.faults.fdc.enabled
    assert cfg.faults.fdc.accept == "confirm"  # the rest of the table as recorded
