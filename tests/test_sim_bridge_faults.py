"""sim-bridge's faults of the vehicle (for fault detection): a real ``sim-bridge --control``
process given ``--at`` commands from its start and further ones on its control channel, with
``at_s`` or at once; bad commands are refused with their name."""

from __future__ import annotations

import re
import time

import pytest

from sim_bridge.bridge import BridgeProcess, write_local_config
from uvd.errors import TransportError

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

        # 3 s ahead: the next call's answer is back long before (0.3 s was a race with a
        # loaded machine's scheduling), then polled until it is applied
        ans = proc.call("plant_fault", mass_scale=1.1, g_delta=-20.0, b_delta=[0, 0, 5],
                        at_s=3.0)
        assert ans["ok"] and ans["scheduled_ns"] > ans["t_ns"]
        assert proc.call("stats")["plant_fault"]["mass_scale"] == 1.0  # not yet
        assert proc.call("health", node=4, value=0.0)["ok"]  # at once
        deadline = time.monotonic() + 15.0
        while (st := proc.call("stats"))["scheduled"] and time.monotonic() < deadline:
            time.sleep(0.1)
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
        # every command is checked when given, not when it comes due (a CAN or instrument
        # command scheduled wrongly was a logged warning when due), and a value no amplifier
        # could have is refused at once too (a health of NaN or 7 was taken)
        for op, kw, words in (
                ("health", {"node": 9, "value": 0.5, "at_s": 5}, "node 9 is not one of"),
                ("health", {"node": 4, "value": float("nan")}, "gain in [0, 1], not nan"),
                ("health", {"node": 4, "value": 7, "at_s": 5}, "gain in [0, 1], not 7"),
                ("helth", {"node": 4, "at_s": 5}, "unknown op 'helth'"),
                ("sensor", {"name": "gps", "mode": "silence", "at_s": 5},
                 "unknown instrument 'gps'"),
                ("sensor", {"name": "dvl", "mode": "sulk", "at_s": 5}, "unknown mode 'sulk'"),
                # a Digiquartz line has no NaN: the emulator's encoding raised in the plant's
                # task, which ended unseen, every instrument silent for good (session 26)
                ("sensor", {"name": "depth", "mode": "nan", "seconds": 0.3},
                 "a Digiquartz line carries no NaN"),
                ("fault", {"node": 4, "name": "warp", "at_s": 5}, "unknown fault 'warp'"),
                ("silence", {"node": 4, "seconds": -1, "at_s": 5}, "seconds must be"),
                ("bus_off", {"seconds": 0, "at_s": 5}, "seconds must be")):
            bad = proc.call(op, **kw)
            assert not bad["ok"] and words in bad["error"], (op, kw, bad)
        st = proc.call("stats")
        assert st["scheduled"] == 0 and st["thruster_health"][3] == 0.0
    finally:
        proc.stop(timeout_s=5.0)
        proc.kill()


@pytest.mark.untimed  # refused before anything runs
@pytest.mark.parametrize("at, command, words", [
    # quote-free words: the error reaches the test inside a dict's repr (its quotes escaped),
    # and sim-bridge's stderr copy of it may not be read yet (seen under load)
    ("20", '{"op": "helth", "node": 4}', "helth: unknown op"),
    # the known ops named are the bridge's and its CAN emulators' (plant_fault was missing)
    ("20", '{"op": "plantfault"}', "known: bus_off, depth, fault, health, leak, ping, place, "
                                   "plant_fault, pressure_valid, release, reset, sensor, "
                                   "silence, stats, truth, unsilence, writes"),
    ("20", "drag_scale=1.5", "not JSON (Expecting value: line 1 column 1"),
    ("20", '{"op": "health", "node": 9, "value": 0.5}',
     "node 9 is not one of [1, 2, 3, 4, 5, 6]"),
    ("20", '{"drag_scale": 1.5}', "not a JSON object with an"),  # was the KeyError's bare 'op'
    ("20", '[1]', "not a JSON object with an"),
    # after the end of the run: it was never carried out, silently (session 24)
    ("60", '{"op": "ping"}', "60 s is not within --duration 30 s"),
])
def test_a_bad_at_command_stops_sim_bridge_at_its_start(tmp_path, at, command, words):
    """``sim-bridge --at S JSON`` with a command it could not carry out, or S after the end
    of ``--duration``: exit at start with the command named (it ran, and logged a warning
    when its time came, or never)."""
    proc = BridgeProcess(write_local_config(tmp_path), duration_s=30.0,
                         extra=["--at", at, command])
    try:
        with pytest.raises(TransportError, match=re.escape(words)):
            proc.start(timeout_s=90.0)
    finally:
        proc.kill()


@pytest.mark.untimed  # refused before anything runs
@pytest.mark.parametrize("options, words", [
    (["--realtime", "200"], "argument --realtime: '200' is not an integer in 1..99"),
    (["--realtime", "0"], "argument --realtime: '0' is not an integer in 1..99"),
    (["--cpu", "-1"], "argument --cpu: '-1' is not an integer in 0..1023"),
    (["--cpu", "99999999999999999999"],
     "argument --cpu: '99999999999999999999' is not an integer in 0..1023"),
])
def test_a_priority_or_cpu_that_cannot_be_is_a_command_line_error(options, words, capsys):
    """SCHED_FIFO has priorities 1..99 and CPUs count from 0: these were carried to the
    system call, which refused them after the start (sim-bridge then ran without them)."""
    from uvd.commands.sim_bridge import main
    with pytest.raises(SystemExit) as exit_:
        main(options)
    assert exit_.value.code == 2 and words in capsys.readouterr().err


def test_a_truth_log_that_cannot_be_written_ends_and_the_vehicle_goes_on(tmp_path):
    """A truth log on a full disk (/dev/full: every write fails, ENOSPC): sim-bridge says so
    once and simulates on. The failed write used to end the plant's task, so the
    instruments fell silent and a daemon over it fired its staleness failsafes (session 25:
    ``uvd demo --record`` on a 2 MB tmpfs)."""
    from pathlib import Path
    proc = BridgeProcess(write_local_config(tmp_path), duration_s=30.0,
                         truth_log=Path("/dev/full")).start(timeout_s=90.0)
    try:
        time.sleep(1.5)  # the log is written every 100 plant steps (1 s at 100 Hz)
        first = proc.call("stats")["counters"]["plant_steps"]
        time.sleep(1.0)
        steps = proc.call("stats")["counters"]["plant_steps"] - first
        assert steps >= 50, steps  # 100 at 100 Hz; a stopped plant takes none
        told = proc.stderr_tail()
        assert told.count("truth log /dev/full: [Errno 28] No space left on device; the "
                          "simulation goes on without it") == 1, told
    finally:
        proc.stop(timeout_s=5.0)
        proc.kill()


def test_a_plant_that_stops_ends_sim_bridge_naming_it(tmp_path):
    """An error inside the plant's task (here an instrument encoder made to raise at the
    50th step — every real cause found so far is mended, so one is provoked) ends the run
    with the error named (``PlantStopped``), at once: before (session 26) the task ended
    unseen and sim-bridge answered its control channel on, its instruments silent for
    good."""
    import asyncio

    from sim_bridge.bridge import PlantStopped, SimBridge
    from uvd.commands.sim_bridge import bridge_config
    from uvd.runtime.config import load_config

    bridge = SimBridge(bridge_config(load_config(write_local_config(tmp_path))))
    step = bridge.emulators.step
    calls = []

    def failing_step(t_ns):
        calls.append(t_ns)
        if len(calls) == 50:
            raise ValueError("an encoder's bug")
        step(t_ns)

    bridge.emulators.step = failing_step
    t0 = time.monotonic()
    with pytest.raises(PlantStopped, match=r"stopped at plant step 49: ValueError: an "
                                           r"encoder's bug"):
        asyncio.run(asyncio.wait_for(bridge.run(duration_s=30.0), 60.0))
    assert time.monotonic() - t0 < 10.0  # not the run's 30 s
