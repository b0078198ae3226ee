"""The black-box recorder and lockstep replay, against a real run of the daemon over sim-bridge.

One HIL run with the recorder on (an operator mode change, an INS dropout that fires and
clears a failsafe) is read back record by record (MCAP's own record readers), every message
validated against its JSON Schema, and replayed through the one cycle: the commands must come
out bit-identical. A corrupted copy must show its first mismatch; other gains, other tracking;
cut, foreign and incomplete files clear messages; a damaged record costs only itself. A
writer killed with SIGKILL leaves a file readable up to at most one second before the kill.
"""

from __future__ import annotations

import asyncio
import base64
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from itertools import pairwise
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from tests.hil_daemon import reusing_bridge, run_scenario, running_bridge
from uvd.cli import main
from uvd.runtime import commands as cmd
from uvd.runtime.config import load_config
from uvd.runtime.replay.lockstep import replay_lockstep
from uvd.telemetry.recording import CHANNELS, RecordingError, load_run, read_messages, schema
from uvd.telemetry.report import write_report

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def shared_bridge(tmp_path_factory):
    """One sim-bridge for the module's daemons, each test's own configuration on it."""
    with running_bridge(tmp_path_factory.mktemp("bridge")) as b:
        yield b


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, shared_bridge):
    """(recording file, config path, daemon) of a short recorded HIL run."""
    run_dir = tmp_path_factory.mktemp("rec")
    changes = {"recording": {"enabled": True, "dir": str(run_dir / "rec"),
                             "flush_interval_s": 0.1},
               "failsafe": {"amplifier_fault": "reallocate"}}
    with reusing_bridge(shared_bridge, run_dir, changes) as (cfg_path, proc):
        cfg = load_config(cfg_path)

        async def scenario(d):
            res = await asyncio.wrap_future(d.app.commands.put(cmd.SetMode("pdc",
                                                                           source="test")))
            assert res.ok
            await asyncio.sleep(1.0)
            ans = await asyncio.to_thread(proc.call, "sensor", name="ins", mode="silence",
                                          seconds=0.5)
            assert ans.get("ok"), ans
            await asyncio.sleep(2.0)
            res = await asyncio.wrap_future(d.app.commands.put(cmd.SetMode("auto")))
            assert res.ok
            await asyncio.sleep(1.0)
            # a thruster dead and restored by the operator: a reallocation to replay
            for eta in (0.0, 1.0):
                res = await asyncio.wrap_future(d.app.commands.put(cmd.SetThrusterEta(4, eta)))
                assert res.ok, res
                await asyncio.sleep(1.0)
            # … and an aft amplifier's own fault: the cycle's amplifier source reallocates
            ans = await asyncio.to_thread(proc.call, "fault", node=1, name="overcurrent",
                                          persistent=True)
            assert ans.get("ok"), ans
            await asyncio.sleep(1.5)

        d, cycles = run_scenario(cfg, scenario)
    files = sorted((run_dir / "rec").glob("*.mcap"))
    assert len(files) == 1, files
    return files[0], cfg_path, d, cycles


def test_every_message_fits_its_schema_and_every_channel_is_there(recorded):
    path, _, d, cycles = recorded
    counts = Counter()
    validators = {t: jsonschema.Draft202012Validator(schema(s)) for t, (s, _) in
                  CHANNELS.items()}
    for topic, log_time, msg in read_messages(path):
        counts[topic] += 1
        errors = list(validators[topic].iter_errors(msg))
        assert not errors, (topic, log_time, errors[0].message)
    print(dict(counts))
    for topic in ("/uvd/start", "/uvd/cycle", "/uvd/pose", "/uvd/lifecycle", "/uvd/command",
                  "/uvd/failsafe", "/uvd/raw/serial", "/uvd/raw/can"):
        assert counts[topic] > 0, topic
    assert counts["/uvd/cycle"] == counts["/uvd/pose"] == len(cycles)
    sources = Counter(m["source"] for _, _, m in read_messages(path, ["/uvd/raw/serial"]))
    assert set(sources) == {"ins", "dvl", "depth"}
    assert d.recorder.raw_dropped == 0

    # what `mcap info` shows, from MCAP's own indexed reader: the summary a clean stop writes
    from mcap.reader import make_reader
    with path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    topics = {c.id: c.topic for c in summary.channels.values()}
    assert {summary.schemas[c.schema_id].name for c in summary.channels.values()} == \
        {s for s, _ in CHANNELS.values()}
    assert {topics[i]: n for i, n in summary.statistics.channel_message_counts.items()} == \
        dict(counts)


def test_lockstep_replay_is_bit_identical(recorded, tmp_path):
    path, _, _, cycles = recorded
    out = tmp_path / "replay.json"
    assert main(["replay", str(path), "--lockstep", "--json", str(out), "--quiet"]) == 0
    rep = json.loads(out.read_text())
    print({k: rep[k] for k in ("cycles", "commands_compared", "mismatches", "missing_samples",
                               "operator_commands")})
    assert rep["cycles"] == len(cycles) and rep["commands_compared"] == len(cycles) > 40
    assert rep["mismatches"] == 0 and rep["first_mismatch"] is None
    # arm, two modes, a thruster dead and restored
    assert rep["missing_samples"] == 0 and rep["operator_commands"] >= 5
    modes = {r["mode"] for r in cycles}
    assert {"pdc-fallback", "zero", "control"} <= modes  # the replay went through them all
    # … and through the reallocation: thruster 4 at exactly zero while controlling
    assert any(r["mode"] == "control" and r["thrust"][3] == 0.0 for r in cycles), cycles[-1]
    # η is a recorded input of every cycle, compared by the replay: the operator's thruster 4,
    # then the amplifier source's thruster 1 (no failsafe: the vehicle flew on)
    etas = [r["inputs"]["thruster_eta"] for r in cycles]
    assert any(e is not None and e.tolist() == [1, 1, 1, 0, 1, 1] for e in etas)
    amp = [r for r, e in zip(cycles, etas, strict=True)
           if e is not None and e.tolist() == [0, 1, 1, 1, 1, 1]]
    assert len(amp) > 5 and all(r["mode"] == "control" and r["thrust"][0] == 0.0 for r in amp)


def test_a_replay_on_other_blas_kernels_names_both_and_the_size_of_the_difference(
        recorded, tmp_path):
    """OpenBLAS (numpy's and scipy's wheels) picks its kernels from the CPU when it loads, and
    two kernels can round a product differently: a daemon's recording replayed on a machine
    with other kernels (SkylakeX against Haswell, measured) reported every command a mismatch
    by ~1e-14 N and nothing more. The start record names the kernels; a replay that differs on
    other kernels says so, with the largest difference and the command that replays bit for
    bit. Another machine is stood in for by OPENBLAS_CORETYPE (the replay in a subprocess)."""
    import platform

    from mcap.reader import make_reader  # the file's start record read as any MCAP client
    path = recorded[0]
    with path.open("rb") as fh:
        start = next(json.loads(msg.data) for _, _, msg in
                     make_reader(fh).iter_messages(topics=["/uvd/start"]))
    assert isinstance(start["blas"], dict) and all(isinstance(v, str)
                                                   for v in start["blas"].values())
    if platform.machine() != "x86_64" or not start["blas"]:
        pytest.skip(f"OpenBLAS kernel names of x86_64 wanted; here {platform.machine()}, "
                    f"kernels {start['blas']}")
    other = "Nehalem" if set(start["blas"].values()) != {"Nehalem"} else "Sandybridge"
    out = tmp_path / "replay.json"
    proc = subprocess.run([sys.executable, "-m", "uvd", "replay", str(path), "--lockstep",
                           "--quiet", "--json", str(out)], capture_output=True, text=True,
                          timeout=240, env={**os.environ, "OPENBLAS_CORETYPE": other})
    rep = json.loads(out.read_text())
    assert rep["blas"]["recorded"] == start["blas"]
    assert set(rep["blas"]["replayed"].values()) == {other}, rep["blas"]
    print(rep["mismatches"], rep["largest_difference_n"], proc.stdout[-400:])
    if rep["mismatches"]:   # (on this project's machine: SkylakeX against Nehalem, it does)
        assert proc.returncode == 1
        assert 0.0 < rep["largest_difference_n"] < 1e-6     # last bits, not a changed law
        assert (f"the recording was made with BLAS kernels "
                f"{', '.join(sorted(set(start['blas'].values())))}, this replay runs "
                f"{other}: they round differently") in proc.stdout
    else:                   # these kernels happen to round this run's products alike
        assert proc.returncode == 0 and "bit-identical" in proc.stdout


@pytest.mark.parametrize("recorded_blas, other", [
    ({"libscipy_openblas64_": "SkylakeX"}, True),
    ({"libscipy_openblas64_": "Haswell"}, False),       # this replay's own
    (None, False), ({}, False),                          # an older recording: nothing known
    ("SkylakeX", False), ({"lib": ["SkylakeX"]}, False),  # malformed: not a hint, no traceback
])
def test_other_kernels_are_told_only_from_a_start_record_that_names_them(recorded_blas, other):
    from uvd.runtime.replay.lockstep import ReplayReport
    rep = ReplayReport(recording="x.mcap", blas={"recorded": recorded_blas,
                                                 "replayed": {"libscipy_openblas64_": "Haswell"}})
    assert rep.other_arithmetic() is other


def test_a_recorded_eta_the_replay_does_not_reach_is_a_mismatch(recorded, tmp_path):
    path, _, _, _ = recorded
    bad = tmp_path / "eta.mcap"
    edited = []

    def edit(k, topic, msg):
        eta = (msg.get("inputs") or {}).get("thruster_eta") if topic == "/uvd/cycle" else None
        if eta is not None and not edited:
            msg["inputs"]["thruster_eta"] = [0.5 if x == 0 else x for x in eta]
            edited.append(msg["t_ns"])
        return msg
    _rewrite(path, bad, edit)
    rep = replay_lockstep(bad)
    assert edited and rep.mismatches == 1, rep.first_mismatch
    assert rep.first_mismatch["field"] == "thruster_eta"
    assert rep.first_mismatch["t_ns"] == edited[0]


def _keep_report_summaries(monkeypatch) -> list[dict]:
    """The summaries :func:`write_report` returns from now on (``uvd report`` calls it), so
    that one drawing of a report serves both the command's and the summary's checks."""
    import uvd.telemetry.report as report
    summaries: list[dict] = []
    real = report.write_report

    def keep(*args, **kwargs):
        summaries.append(real(*args, **kwargs))
        return summaries[-1]
    monkeypatch.setattr(report, "write_report", keep)
    return summaries


def _rewrite(src: Path, dst: Path, edit, schema_names: dict[str, str] | None = None,
             stray_channel: int | None = None) -> None:
    """Copy a recording message by message through MCAP's writer, ``edit``-ing each (None:
    left out; bytes: written as they are); ``schema_names`` renames channels' schemas,
    ``stray_channel`` adds a message on a channel id never declared, before the 20th cycle."""
    from mcap.writer import CompressionType, Writer
    with dst.open("wb") as fh:
        w = Writer(fh, use_chunking=False, compression=CompressionType.NONE)
        w.start()
        ids = {}
        for topic, (sname, _) in CHANNELS.items():
            sname = (schema_names or {}).get(topic, sname)
            sid = w.register_schema(sname, "jsonschema", json.dumps(schema(
                CHANNELS[topic][0])).encode())
            ids[topic] = w.register_channel(topic, "json", sid)
        n_cycle = 0
        for k, (topic, t, msg) in enumerate(read_messages(src)):
            if topic == "/uvd/cycle":
                n_cycle += 1
                if n_cycle == 20 and stray_channel is not None:
                    w.add_message(stray_channel, t, b"{}", t, k)
            msg = edit(k, topic, msg)
            if msg is not None:
                data = msg if isinstance(msg, bytes) else json.dumps(msg).encode()
                w.add_message(ids[topic], t, data, t, k)
        w.finish()


def test_a_run_in_several_files_replays_whole_from_its_first(recorded, tmp_path, capsys):
    """Found by probing (session 33): past ``rotate_mb`` / ``rotate_s`` the recorder starts
    a new file, and a replay of the first file covered that file alone (49 of a run's 208
    cycles), saying nothing of the rest; a later file replayed from a fresh state, "MISMATCH:
    51 of 51". Here the recording is cut as the recorder cuts it (the start record repeated
    atop each file), beside another run's files in the same folder."""
    path, _, _, cycles = recorded
    n = len(list(read_messages(path)))
    cuts = [0, n // 3, 2 * n // 3, n]
    runs = tmp_path / "runs"
    runs.mkdir()
    names = [runs / f"uvd-20261130T06390{k}-{k:03d}.mcap" for k in range(3)]
    for k, name in enumerate(names):
        _rewrite(path, name, lambda i, topic, msg, k=k: msg if topic == "/uvd/start"
                 or cuts[k] <= i < cuts[k + 1] else None)
    for k in range(2):  # another run, started later: its own start record
        _rewrite(path, runs / f"uvd-20261130T07000{k}-{k:03d}.mcap",
                 lambda i, topic, msg: {**msg, "t_ns": msg["t_ns"] + 1}
                 if topic == "/uvd/start" else msg)
    out = tmp_path / "replay.json"
    assert main(["replay", str(names[0]), "--lockstep", "--json", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert rep["files"] == [str(x) for x in names] and rep["stopped"] is None
    assert rep["cycles"] == rep["commands_compared"] == len(cycles) and rep["mismatches"] == 0
    assert f"uvd replay {names[0]} (3 files of the run): {len(cycles)} cycles" in \
        capsys.readouterr().out
    assert main(["replay", str(names[1]), "--lockstep"]) == 2
    assert f"{names[1]} is file 001 of its run: a replay starts from the run's first file " \
           f"(the cycle's state before this one is not recorded), {names[0]}" in \
           capsys.readouterr().err
    # uvd identify and uvd xval read the same run (they asked for another system's profile)
    whole, alone = load_run(path), load_run(names[0])
    assert len(alone) == len(whole) > 20 and np.array_equal(alone.u, whole.u)
    assert 0 < len(load_run(names[2])) < len(whole)  # a later file alone, as the report
    names[1].unlink()  # a file of the run lost: the replay covers what comes before it
    assert "file 001 of the run is not in" in load_run(names[0]).stretch_note()
    assert main(["replay", str(names[0]), "--lockstep", "--json", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert rep["files"] == [str(names[0])] and 0 < rep["cycles"] < len(cycles)
    assert rep["stopped"].startswith(f"file 001 of the run is not in {runs}: the run is read "
                                     "up to it (1 later file(s) not read)"), rep["stopped"]
    # uvd report draws the run as the replay reads it
    summary = write_report(names[0], tmp_path / "rep")
    assert summary["files"] == [str(names[0])] and summary["cycles"] == rep["cycles"]
    assert summary["missing_file"].startswith("file 001 of the run is not in")
    names[1] = runs / "uvd-20261130T063901-001.mcap"
    _rewrite(path, names[1], lambda i, topic, msg: msg if topic == "/uvd/start"
             or cuts[1] <= i < cuts[2] else None)
    summary = write_report(names[0], tmp_path / "rep")
    assert summary["files"] == [str(x) for x in names] and "missing_file" not in summary
    assert summary["cycles"] == len(cycles)
    assert write_report(names[2], tmp_path / "rep")["files"] == [str(names[2])]  # alone
    # the run's folder given for the recording (uvd demo --record DIR): the files to give,
    # not "cannot open: [Errno 21] Is a directory" (report, replay) nor "not a readable run
    # log (.npz)" (identify, xval)
    firsts = ", ".join(str(runs / f"uvd-20261130T0{t}-000.mcap") for t in ("63900", "70000"))
    for args in (["report", str(runs), "--out", str(tmp_path / "rep")],
                 ["replay", str(runs), "--lockstep"],
                 ["identify", "--log", str(runs), "--method", "ls", "--out",
                  str(tmp_path / "p.toml")]):
        assert main(args) == 2
        err = capsys.readouterr().err
        assert f"{runs}: a folder, not a recording: give a run's first file in it, {firsts}" \
            in err and "Traceback" not in err, (args, err)


def test_a_corrupted_frame_shows_as_the_first_mismatch(recorded, tmp_path):
    path, _, _, cycles = recorded
    armed_at = next(r["t_ns"] for r in cycles if r["state"] == "ARMED")
    # an INS frame a cycle used (the INS may send more frames than there are cycles: a frame
    # superseded before the next cycle is lost to nobody)
    used = {r["ins_rx_ns"] for r in cycles if r.get("ins_rx_ns") is not None}
    hit = {}

    def corrupt(k, topic, msg):
        if topic == "/uvd/raw/serial" and msg["source"] == "ins" and not hit \
                and msg["t_ns"] > armed_at + 500_000_000 and msg["t_ns"] in used:
            data = bytearray(base64.b64decode(msg["data"]))
            data[len(data) // 2] ^= 0xFF  # the frame's checksum fails: the INS sample is lost
            msg = {**msg, "data": base64.b64encode(bytes(data)).decode()}
            hit["t_ns"] = msg["t_ns"]
        return msg

    bad = tmp_path / "corrupted.mcap"
    _rewrite(path, bad, corrupt)
    rep = replay_lockstep(bad)
    assert hit and rep.missing_samples >= 1 and rep.mismatches >= 1
    m = rep.first_mismatch
    assert m["t_ns"] >= hit["t_ns"] and m["field"].startswith("thrust[")
    assert m["recorded"] != m["replayed"]


def test_other_gains_replay_and_compare_tracking(recorded, tmp_path):
    path, cfg_path, _, _ = recorded
    text = Path(cfg_path).read_text().replace("kp = 300.0", "kp = 600.0")
    assert "kp = 600.0" in text
    other = tmp_path / "other.toml"
    other.write_text(text)
    rep = replay_lockstep(path, config=other)
    assert not rep.same_config and rep.commands_compared == 0 and rep.cycles > 40
    rec, rpl = rep.tracking["recorded"], rep.tracking["replayed"]
    assert rec["cycles"] == rpl["cycles"] > 0
    assert rec["thrust_rms_n"] != rpl["thrust_rms_n"]


def test_cut_foreign_and_incomplete_files(recorded, tmp_path, capsys, monkeypatch):
    path, _, _, cycles = recorded
    data = path.read_bytes()
    # a file cut anywhere (a crash) replays with 0 mismatches: every cycle's samples lie in
    # the bytes before its record (one fixed cut at 2/3 missed 1 in 66 cycles now and then,
    # when the cut fell between a cycle's record and its raw bytes, written after it)
    seen, late = set(), []
    for topic, _, msg in read_messages(path, ["/uvd/raw/serial", "/uvd/cycle"]):
        if topic == "/uvd/raw/serial":
            seen.add((msg["source"], msg["t_ns"]))
            continue
        late += [(src, msg[f"{src}_rx_ns"]) for src in ("ins", "dvl", "depth")
                 if msg.get(f"{src}_rx_ns") is not None
                 and (src, msg[f"{src}_rx_ns"]) not in seen]
    assert late == [], f"{len(late)} samples recorded after the cycle that used them"
    cut = tmp_path / "cut.mcap"
    for percent in range(5, 100, 5):
        cut.write_bytes(data[: len(data) * percent // 100])
        n_cut = sum(1 for _ in read_messages(cut, ["/uvd/cycle"]))
        assert n_cut < len(cycles)
        if n_cut == 0:
            continue
        rep = replay_lockstep(cut)
        assert (rep.cycles, rep.mismatches, rep.missing_samples) == (n_cut, 0, 0), \
            (percent, rep.first_mismatch)
    # another system's MCAP (a ROS 2 bag's, CDR messages): the report says whose topics
    # they are and what reads them, not only "no cycle records"
    from mcap.writer import Writer
    ros2 = tmp_path / "ros2.mcap"
    with ros2.open("wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema("sensor_msgs/msg/Imu", "ros2msg", b"")
        for topic in ("/rovio/imu/data", "/rovio/thrusters", "/sensor_fusion/states"):
            w.add_message(w.register_channel(topic, "cdr", sid), log_time=1, publish_time=1,
                          data=b"\x00\x01\x00\x00")
        w.finish()
    with pytest.raises(RecordingError, match=re.escape(
            "no cycle records (/uvd/cycle): nothing to report; its topics are another system's "
            "(/rovio/imu/data, /rovio/thrusters, …): uvd identify --profile reads such a "
            "recording")):
        write_report(ros2, tmp_path / "ros2-report")
    foreign = tmp_path / "foreign.mcap"
    foreign.write_text("not a recording\n")
    with pytest.raises(RecordingError, match="foreign.mcap: not an MCAP file"):
        replay_lockstep(foreign)
    head = tmp_path / "head.mcap"
    head.write_bytes(data[:600])  # magic and a header, no start record
    with pytest.raises(RecordingError, match="no start record"):
        replay_lockstep(head)
    assert main(["replay", str(foreign), "--lockstep", "--quiet"]) == 2
    same = lambda k, topic, msg: msg  # noqa: E731
    other = tmp_path / "other-schema.mcap"
    _rewrite(path, other, same, schema_names={"/uvd/cycle": "uvd.cycle.v9"})
    with pytest.raises(RecordingError, match="other-schema.mcap: channel /uvd/cycle has schema "
                                             "'uvd.cycle.v9'"):
        replay_lockstep(other)
    # a message on a channel never declared (a damaged channel id): replay covers the 19
    # cycles before it (it refused the whole file)
    stray = tmp_path / "stray.mcap"
    _rewrite(path, stray, same, stray_channel=99)
    with pytest.raises(RecordingError, match="stray.mcap: message on unknown channel 99 at "
                                             "byte [0-9]+"):
        list(read_messages(stray))
    rep = replay_lockstep(stray)
    assert (rep.cycles, rep.mismatches) == (19, 0) and rep.stopped.startswith(
        "message on unknown channel 99 at byte "), rep.stopped
    # no cycle a reader can use (every one without its thrust): both refuse, by name
    no_thrust = tmp_path / "no-thrust.mcap"
    _rewrite(path, no_thrust, lambda k, topic, msg: {key: v for key, v in msg.items()
                                                     if key != "thrust"}
             if topic == "/uvd/cycle" else msg)
    with pytest.raises(RecordingError, match="no-thrust.mcap: no cycle records \\(/uvd/cycle\\) "
                                             "before a /uvd/cycle record at [0-9]+ ns is "
                                             "malformed \\(thrust is not a row of finite "
                                             "numbers\\)"):
        replay_lockstep(no_thrust)
    with pytest.raises(RecordingError, match="no-thrust.mcap: no cycle records \\(/uvd/cycle\\) "
                                             "\\([0-9]+ malformed, first: /uvd/cycle record at "
                                             "[0-9]+ ns: thrust is not a row of finite numbers\\)"):
        write_report(no_thrust, tmp_path / "report")
    assert main(["report", str(no_thrust), "--out", str(tmp_path / "report"), "--quiet"]) == 2
    # a message that is not JSON (a damaged byte): replay, which needs every input, covers
    # the 20 cycles before it; the report skips and counts it and draws the rest (both
    # refused the whole file)
    garbled = tmp_path / "garbled.mcap"
    n_cycle = iter(range(10**6))
    _rewrite(path, garbled, lambda k, topic, msg: json.dumps(msg).encode()[:-5]
             if topic == "/uvd/cycle" and next(n_cycle) == 20 else msg)
    rep = replay_lockstep(garbled)
    assert (rep.cycles, rep.mismatches) == (20, 0), rep.first_mismatch
    assert rep.stopped.startswith("message on /uvd/cycle at ") and \
        rep.stopped.endswith(" the replay covers the 20 cycles recorded before it"), rep.stopped
    n_recorded = sum(1 for _ in read_messages(path, ["/uvd/cycle"]))
    capsys.readouterr()
    summaries = _keep_report_summaries(monkeypatch)
    assert main(["report", str(garbled), "--out", str(tmp_path / "report-garbled"),
                 "--quiet"]) == 0
    (summary,) = summaries
    assert (summary["cycles"], summary["unreadable_messages"]) == (n_recorded - 1, 1)
    assert summary["first_unreadable"].startswith("message on /uvd/cycle at ")
    assert "uvd report: 1 unreadable message(s) skipped (first: message on /uvd/cycle" in \
        capsys.readouterr().err


@pytest.mark.parametrize("edit, why", [
    # a fuzzed byte that shortened one cycle's position: a numpy traceback once, then the
    # whole file refused by name
    (lambda msg: {**msg, "p": msg["p"][:2]}, "p is not 3 numbers"),
    # found by replacing one field of one record with other JSON: both printed a traceback
    (lambda msg: {**msg, "inputs": 7}, "inputs 7 is not an object"),
    (lambda msg: {**msg, "t_ns": str(msg["t_ns"])}, "t_ns '[0-9]+' is not a 64-bit integer"),
    (lambda msg: [msg["t_ns"]], "a JSON list, not an object"),
])
def test_a_malformed_cycle_record_is_skipped_by_the_report_and_ends_the_replay(
        recorded, tmp_path, capsys, monkeypatch, edit, why):
    """A cycle record that is valid JSON but not what uvd.cycle.v1 promises: the report
    skips and counts it and draws the rest (it refused the whole file, or printed a
    traceback); the replay, which needs every cycle, covers the 20 before it, bit for bit."""
    path, _, _, _ = recorded
    bad = tmp_path / "malformed.mcap"
    n_cycle = iter(range(10**6))
    _rewrite(path, bad, lambda k, topic, msg: edit(msg)
             if topic == "/uvd/cycle" and next(n_cycle) == 20 else msg)
    rep = replay_lockstep(bad)
    assert (rep.cycles, rep.mismatches) == (20, 0), rep.first_mismatch
    assert re.fullmatch(f"a /uvd/cycle record at .* ns is malformed \\({why}\\): the replay "
                        "covers the 20 cycles recorded before it", rep.stopped), rep.stopped
    n_recorded = sum(1 for _ in read_messages(path, ["/uvd/cycle"]))
    capsys.readouterr()
    # one report, drawn by the command, whose summary write_report returned is kept
    summaries = _keep_report_summaries(monkeypatch)
    assert main(["report", str(bad), "--out", str(tmp_path / "report"), "--quiet"]) == 0
    (summary,) = summaries
    assert (summary["cycles"], summary["malformed_records"]) == (n_recorded - 1, 1)
    assert re.fullmatch(f"/uvd/cycle record at [0-9]+ ns: {why}", summary["first_malformed"])
    assert re.search(f"uvd report: 1 malformed record\\(s\\) skipped \\(first: /uvd/cycle "
                     f"record at [0-9]+ ns: {why}\\)", capsys.readouterr().err)


def test_a_cycle_with_another_number_of_thrusters_is_skipped_by_the_report(recorded, tmp_path):
    """One cycle whose thrust has 5 values where the run's others have 6 (each row a valid
    record alone): the report counts it malformed, by the run's own count, and draws the rest
    (numpy could not stack the rows: a ValueError refused the whole file)."""
    path, _, _, _ = recorded
    n_cycle = iter(range(10**6))
    short = tmp_path / "five-thrusts.mcap"
    _rewrite(path, short, lambda i, topic, msg: {**msg, "thrust": msg["thrust"][:5]}
             if topic == "/uvd/cycle" and next(n_cycle) == 20 else msg)
    summary = write_report(short, tmp_path / "report")
    assert summary["malformed_records"] == 1
    assert re.fullmatch("/uvd/cycle record at [0-9]+ ns: 5 thrusts( and 6 propeller speeds)? "
                        "where the run's others have 6", summary["first_malformed"])


def test_estimates_the_report_does_not_draw_are_not_called_malformed(recorded, tmp_path):
    """An estimate whose θ̂ has another length (another estimator's) is valid and left out of
    the figure, as before; one whose θ̂ is not a row of numbers is counted malformed."""
    path, _, _, _ = recorded
    n_estimate = iter(range(10**6))
    theta = {0: [1.0] * 9, 1: "x"}  # the first estimate's θ̂, the second's

    def edit(i, topic, msg):
        if topic != "/uvd/estimate":
            return msg
        k = next(n_estimate)
        return {**msg, "theta": theta[k]} if k in theta else msg
    edited = tmp_path / "estimates.mcap"
    _rewrite(path, edited, edit)
    drawable = sum(1 for _, _, m in read_messages(path, ["/uvd/estimate"])
                   if m.get("theta") is not None and len(m["theta"]) in (16, 241))
    summary = write_report(edited, tmp_path / "report")
    assert summary["malformed_records"] == 1
    assert re.fullmatch("/uvd/estimate record at [0-9]+ ns: theta is not a row of numbers",
                        summary["first_malformed"])
    assert summary["estimates"] == drawable - 2 > 0


def test_an_armed_cycle_without_a_valid_position_is_drawn(recorded, tmp_path):
    """An armed cycle whose position is null (NaN, as the daemon writes a navigation state
    that is not valid; the schema allows it) and whose reference is too: drawn with the rest,
    nothing skipped (the report refused the whole file: an object array's TypeError)."""
    path, _, _, cycles = recorded
    k = next(i for i, r in enumerate(cycles) if r["state"] == "ARMED" and r["p_ref"] is not None)
    n_cycle = iter(range(10**6))
    nan_p = tmp_path / "nan-p.mcap"
    _rewrite(path, nan_p, lambda i, topic, msg: {**msg, "p": [None] * 3, "p_ref": [None] * 3}
             if topic == "/uvd/cycle" and next(n_cycle) == k else msg)
    summary = write_report(nan_p, tmp_path / "report")
    assert summary["cycles"] == sum(1 for _ in read_messages(path, ["/uvd/cycle"]))
    assert "malformed_records" not in summary and "tracking.png" in summary["figures"]


def test_malformed_inputs_and_commands_end_the_replay_there(recorded, tmp_path):
    """What a replay reads beyond the cycle record's own fields: its inputs (an amplifier
    status that is not an object: an AttributeError's traceback) and the operator's commands
    (arguments that are not an object: a TypeError's) — the replay ends at the first."""
    path, _, _, cycles = recorded
    bad = tmp_path / "bad-actuators.mcap"
    n_cycle = iter(range(10**6))
    _rewrite(path, bad, lambda k, topic, msg: {**msg, "inputs": {**msg["inputs"],
                                                                 "actuators": 7}}
             if topic == "/uvd/cycle" and next(n_cycle) == 20 else msg)
    rep = replay_lockstep(bad)
    assert (rep.cycles, rep.mismatches) == (20, 0), rep.first_mismatch
    assert rep.stopped.startswith(f"cycle 20 (t = {cycles[20]['t_ns']} ns): its inputs are "
                                  "malformed (AttributeError: ") and rep.stopped.endswith(
        ": the replay covers the 20 cycles recorded before it"), rep.stopped
    every = list(read_messages(path))
    k = next(i for i, (topic, _, _) in enumerate(every)
             if topic == "/uvd/command" and i > len(every) // 2)
    bad = tmp_path / "bad-command.mcap"
    _rewrite(path, bad, lambda i, topic, msg: {**msg, "args": 5} if i == k else msg)
    n_before = sum(1 for topic, _, _ in every[:k] if topic == "/uvd/cycle")
    rep = replay_lockstep(bad)
    assert (rep.cycles, rep.mismatches) == (n_before, 0), rep.first_mismatch
    assert rep.stopped == (f"a /uvd/command record at {every[k][2]['t_ns']} ns is malformed "
                           f"({every[k][2]['command']}: args 5 are not an object): the "
                           f"replay covers the {n_before} cycles recorded before it")


def test_a_raw_message_that_is_not_base64_ends_the_replay_there(recorded, tmp_path):
    """Valid JSON whose bytes are not base64 (a damaged character: found by flipping bits of
    a demo's recording) refused the whole replay; it ends there, as any damage does."""
    path, _, _, _ = recorded
    every = list(read_messages(path))
    k = next(i for i, (topic, _, _) in enumerate(every)
             if topic == "/uvd/raw/serial" and i > len(every) // 2)
    bad = tmp_path / "not-base64.mcap"
    _rewrite(path, bad, lambda i, topic, msg: {**msg, "data": "!" + msg["data"][1:]}
             if i == k else msg)
    n_before = sum(1 for topic, _, _ in every[:k] if topic == "/uvd/cycle")
    rep = replay_lockstep(bad)
    assert (rep.cycles, rep.mismatches) == (n_before, 0), rep.first_mismatch
    assert rep.stopped == (f"a /uvd/raw/serial message at {every[k][2]['t_ns']} ns is malformed "
                           "(Error: Only base64 data is allowed): the replay covers the "
                           f"{n_before} cycles recorded before it")


def _record_offsets(data: bytes) -> list[tuple[int, int]]:
    """(offset, opcode) of each record of an MCAP file's data section, walked by the format's
    own framing (an opcode byte, a uint64 length), up to DataEnd."""
    import struct
    out, pos = [], 8
    while pos < len(data):
        op, length = struct.unpack_from("<BQ", data, pos)
        if op == 0x0F:
            break
        out.append((pos, op))
        pos += 9 + length
    return out


@pytest.mark.parametrize("damage, why", [
    # a length that runs past the end: read as a cut, it silently lost the rest of the run
    # (3662 of 4439 messages in one probe)
    (lambda b, at: b.__setitem__(slice(at + 1, at + 9), (2**40).to_bytes(8, "little")),
     "its length, 1099511627776 B, runs past the end of the file"),
    # an opcode MCAP has not: its record is skipped, unseen
    (lambda b, at: b.__setitem__(at, 0x85), "no MCAP record has opcode 0x85"),
])
def test_a_damaged_record_costs_only_itself(recorded, tmp_path, damage, why):
    """A record's header damaged in the middle of a file (found by flipping single bytes of
    a demo's recording: 9 of 300 made report and replay refuse the whole file, 5 lost most
    of it silently): every other message is read, the damage is named with its byte; replay
    covers the cycles before it, bit for bit."""
    path, _, _, _ = recorded
    data = path.read_bytes()
    messages = [(at, op) for at, op in _record_offsets(data) if op == 0x05]
    i, (at, _) = len(messages) // 2, messages[len(messages) // 2]
    b = bytearray(data)
    damage(b, at)
    bad = tmp_path / "damaged.mcap"
    bad.write_bytes(bytes(b))
    every = list(read_messages(path))
    notes: list[str] = []
    assert list(read_messages(bad, unreadable=notes)) == every[:i] + every[i + 1:]
    assert notes == [f"damaged MCAP record at byte {at} ({why}): "
                     f"{messages[i + 1][0] - at} bytes skipped to the next record"]
    with pytest.raises(RecordingError, match=f"damaged.mcap: damaged MCAP record at byte {at}"):
        list(read_messages(bad))
    n_before = sum(1 for topic, _, _ in every[:i] if topic == "/uvd/cycle")
    rep = replay_lockstep(bad)
    assert (rep.cycles, rep.mismatches) == (n_before, 0), rep.first_mismatch
    assert rep.stopped == f"{notes[0]}: the replay covers the {n_before} cycles recorded " \
                          "before it"
    summary = write_report(bad, tmp_path / "report")
    n_cycles = sum(1 for topic, _, _ in every if topic == "/uvd/cycle")
    assert summary["cycles"] == n_cycles - (every[i][0] == "/uvd/cycle")
    assert summary["unreadable_messages"] == 1 and summary["first_unreadable"] == notes[0]


def test_sigkill_of_the_daemon_leaves_a_file_report_reads_to_within_a_second(
        tmp_path, shared_bridge):
    """``uvd run`` (a real daemon process over sim-bridge, recording) killed with SIGKILL
    mid-run: ``uvd report`` reads its file up to at most one second before the kill."""
    changes = {"recording": {"enabled": True, "dir": str(tmp_path / "rec")}}
    with reusing_bridge(shared_bridge, tmp_path, changes) as (cfg_path, _):
        proc = subprocess.Popen([sys.executable, "-m", "uvd", "run", "--config", str(cfg_path),
                                 "--arm", "--duration", "60"], stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, cwd=Path(__file__).parents[1])
        try:
            deadline = time.monotonic() + 60.0
            while not list((tmp_path / "rec").glob("*.mcap")) or \
                    sum(1 for _ in read_messages(next((tmp_path / "rec").glob("*.mcap")),
                                                 ["/uvd/cycle"])) < 30:
                assert proc.poll() is None and time.monotonic() < deadline
                time.sleep(0.5)
            t_kill = time.monotonic_ns()  # the daemon stamps on this same clock
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
    (f,) = (tmp_path / "rec").glob("*.mcap")
    assert main(["report", str(f), "--out", str(tmp_path / "report"), "--quiet"]) == 0
    last = max(t for _, t, _ in read_messages(f, ["/uvd/cycle"]))
    lost_s = (t_kill - last) * 1e-9
    print(f"SIGKILL: uvd report reads the file up to {lost_s * 1e3:.0f} ms before the kill")
    assert 0.0 <= lost_s <= 1.0


def _check_report(out: Path, names: set[str]) -> None:
    """``out/index.html`` references every PNG, and each is a valid PNG of sensible size."""
    import struct
    html = (out / "index.html").read_text()
    pngs = sorted(out.glob("*.png"))
    assert {p.name for p in pngs} == names
    for p in pngs:
        data = p.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n", p  # a PNG
        w, h = struct.unpack(">II", data[16:24])  # IHDR
        assert 400 <= w <= 3000 and 200 <= h <= 3000 and len(data) > 5_000, (p, w, h)
        assert f'src="{p.name}"' in html


def test_report_writes_valid_pngs_the_html_references(recorded, tmp_path):
    path, _, _, _ = recorded
    out = tmp_path / "report"
    assert main(["report", str(path), "--out", str(out), "--quiet"]) == 0
    # estimates.png: AID is off, but the adaptive controller's θ̂ of the "auto" stretch is
    # recorded (estimate/<controller>, issue 19)
    _check_report(out, {"tracking.png", "mne.png", "thrust.png", "failsafe.png",
                        "lateness.png", "estimates.png"})
    assert main(["report", str(tmp_path / "none.mcap"), "--out", str(out), "--quiet"]) == 2


@pytest.mark.untimed
def test_a_two_step_experiment_records_the_daemons_channels_and_reports(tmp_path):
    """``uvd experiment two-step --record``: the same format (every message fits its schema),
    and ``uvd report`` draws it, the controller's θ̂ included, and cross-validates a parameter
    set on it (``--params``: the vehicle file's, Figs. 4.5–4.7)."""
    rec = tmp_path / "rec"
    assert main(["experiment", "two-step", "--hours", "0.01", "--record", str(rec),
                 "--json", str(tmp_path / "out.json")]) == 0
    (path,) = json.loads((tmp_path / "out.json").read_text())["recordings"]
    validators = {t: jsonschema.Draft202012Validator(schema(s)) for t, (s, _) in
                  CHANNELS.items()}
    counts = Counter()
    for topic, _, msg in read_messages(path):
        counts[topic] += 1
        errors = list(validators[topic].iter_errors(msg))
        assert not errors, (topic, errors[0].message)
    assert counts["/uvd/cycle"] == counts["/uvd/pose"] == 360 and counts["/uvd/estimate"] > 30
    out = tmp_path / "report"
    vehicle = Path(__file__).parents[1] / "uvd" / "vehicles" / "jhu-rov.toml"
    assert main(["report", path, "--out", str(out), "--params", str(vehicle), "--quiet"]) == 0
    xval = {f"xval-{s}.png" for s in ("roll_deg", "pitch_deg", "u_mps", "v_mps", "w_mps",
                                      "p_degps", "q_degps", "r_degps")}
    _check_report(out, {"tracking.png", "mne.png", "thrust.png", "estimates.png",
                        "failsafe.png", "lateness.png"} | xval)
    # a lockstep replay needs a daemon's bytes: said as such (it was the recorded
    # configuration's missing sensor ports, named by a temporary file)
    with pytest.raises(RecordingError, match="no raw instrument channels.*uvd experiment "
                                             "--record.*needs a daemon's recording"):
        replay_lockstep(path)


def test_a_stalled_disk_drops_counts_and_never_delays_the_loop(tmp_path):
    """The worker's writes hang for 2 s (a stalled disk) while a 100 Hz 'loop' publishes:
    publishing and the taps stay instant, memory stays bounded, every record is either in
    the file or counted as dropped, and the file reads back whole after the stall."""
    from uvd.links.mcap import McapRecorder
    from uvd.telemetry.sink import TelemetryHub

    stall = threading.Event()
    rec = McapRecorder(tmp_path, flush_interval_s=0.05, max_pending_mb=0.02, raw_queue_size=64)
    write_bytes = rec._write_bytes

    def stalled(path, data, close):
        stall.wait(10.0)
        write_bytes(path, data, close)

    rec._write_bytes = stalled
    hub = TelemetryHub([rec], queue_size=64, flush_interval_s=0.01)
    n = 300

    async def main():
        task = asyncio.create_task(hub.run())
        worst, peak = 0.0, 0
        for k in range(n):
            t = time.monotonic_ns()
            t0 = time.perf_counter()
            hub.publish({"type": "failsafe", "t_ns": t, "kind": "fired", "trigger": "test",
                         "action": "warn", "reason": f"record {k} " + "x" * 100}, always=True)
            rec.tap_serial("ins", t, b"\x00" * 64)
            worst = max(worst, time.perf_counter() - t0)
            peak = max(peak, rec._buf.pending if rec._buf is not None else 0)
            if k == 200:
                stall.set()  # the disk comes back after 2 s
            await asyncio.sleep(0.01)
        await hub.aclose(timeout_s=5.0)
        await task
        return worst, peak

    worst, peak = asyncio.run(asyncio.wait_for(main(), 30.0))
    st = hub.stats()["mcap"]
    written = sum(1 for _ in read_messages(rec.files[0], ["/uvd/failsafe", "/uvd/sink"]))
    print(f"publish + tap worst {worst * 1e6:.0f} µs; pending peak {peak} B; written "
          f"{written}, dropped by the recorder {rec.stalled_dropped}, by the hub queue "
          f"{st['dropped']}, raw frames dropped {rec.raw_dropped}")
    assert worst < 0.01  # a wait for the disk would be seconds
    assert rec.stalled_dropped > 0 and rec.raw_dropped > 0
    assert written + rec.stalled_dropped + st["dropped"] == st["published"]
    assert st["published"] > n  # the stall told: a "sink" record (and its end, if in time)
    assert written > 100 and peak < 0.02e6 + 64 * 400  # the bound plus one batch


#: the black box and the JSON lines through the hub, as in the daemon, while no file may grow
#: (RLIMIT_FSIZE 1 byte: each write fails in the kernel, EFBIG, as on a full disk) from the
#: 100th record to the 400th
_FULL_DISK = """
import asyncio, json, resource, signal, sys
from pathlib import Path
from uvd.links.jsonl import JsonLinesSink
from uvd.links.mcap import McapRecorder
from uvd.telemetry.recording import read_messages
from uvd.telemetry.sink import TelemetryHub

signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # past the limit a write fails, no signal
out = Path(sys.argv[1])


async def main():
    rec = McapRecorder(out / "rec", flush_interval_s=0.02)
    hub = TelemetryHub([rec, JsonLinesSink(out / "t.jsonl")], queue_size=4096,
                       flush_interval_s=0.01)
    task = asyncio.create_task(hub.run())
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    for k in range(600):
        if k == 100:
            resource.setrlimit(resource.RLIMIT_FSIZE, (1, hard))
        if k == 400:
            resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        hub.publish({"type": "failsafe", "t_ns": 10**9 + k, "kind": "fired", "trigger": "t",
                     "action": "warn", "reason": f"record {k}"}, always=True)
        await asyncio.sleep(0.002)
    for _ in range(250):  # on disk while running (what a crash would leave), up to 5 s
        on_disk = (sum(1 for _ in read_messages(rec.files[0], ["/uvd/failsafe"])),
                   sum(b'"failsafe"' in x for x in (out / "t.jsonl").read_bytes().splitlines()))
        if on_disk == (600, 600):
            break
        await asyncio.sleep(0.02)
    await hub.aclose(timeout_s=5.0)
    await task
    print(json.dumps({k: v.get("sink") for k, v in hub.stats().items()}))
    print(json.dumps(on_disk))

asyncio.run(main())
"""


def test_a_full_disk_is_told_and_the_files_go_on_whole_when_it_has_room(tmp_path):
    """Writes that fail in the kernel for 300 records' time: each file is cut back to its
    last whole write, told in the log once (and when writing resumes), and the bytes wait;
    when the disk takes them again, both files hold all 600 records in order, nothing lost.
    Before (session 25) nothing was told, and after the spell nothing more reached either file
    until the close — the black box's flush task had ended at the first failed write, the
    lines waited in a 64 kB buffer: a crash then would have lost them all."""
    r = subprocess.run([sys.executable, "-c", _FULL_DISK, str(tmp_path)], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr[-3000:]
    stats, on_disk = (json.loads(x) for x in r.stdout.splitlines()[-2:])
    assert on_disk == [600, 600]  # written while running, not only at the close
    (mcap,) = sorted((tmp_path / "rec").glob("*.mcap"))
    for path in (mcap, tmp_path / "t.jsonl"):
        told = [line for line in r.stderr.splitlines() if str(path) in line]
        assert len(told) == 2, r.stderr[-3000:]  # the spell's first failure, and its end
        assert "recording: cannot write" in told[0] and "File too large" in told[0]
        assert "written again after" in told[1]
    for name in ("mcap", "jsonl"):
        assert stats[name]["write_errors"] >= 2 and stats[name]["lost_bytes"] == 0, stats
    want = [f"record {k}" for k in range(600)]
    assert [m["reason"] for _, _, m in read_messages(mcap, ["/uvd/failsafe"])] == want
    lines = [json.loads(line) for line in (tmp_path / "t.jsonl").read_text().splitlines()]
    assert [r["reason"] for r in lines if r["type"] == "failsafe"] == want
    told = {(r["sink"], r["ok"]) for r in lines if r["type"] == "sink"}
    assert {("mcap", False), ("jsonl", False)} <= told, told  # the operator told of both


def test_failures_by_turns_are_told_by_spells_not_by_writes():
    """A disk that fills and empties by turns (each write fails, the next succeeds): the
    first ten spells are told (start and end), then every 100th failure only — 1000 flips
    are 10 + 10 + 10 lines, not 2000; one long spell is its start, every 100th and its end."""
    from uvd.spells import FailureSpells
    s = FailureSpells(every=100)
    lines = 0
    for _ in range(1000):
        lines += s.failed()
        lines += s.recovered()
    assert (lines, s.total, s.spells) == (10 + 10 + 10, 1000, 1000)
    s = FailureSpells(every=100)
    told = [s.failed() for _ in range(250)]
    assert [k for k, t in enumerate(told) if t] == [0, 99, 199] and s.recovered()
    assert not s.recovered()  # no spell to end


@pytest.mark.parametrize("how", ["time", "size"])
def test_files_rotate_by_time_or_size_each_with_the_start_record(tmp_path, how):
    """Through the hub, as in the daemon: a new file past ``rotate_s`` of record time or
    ``rotate_mb``; each begins with the start record, none loses a message, and each is a
    complete MCAP file (summary included)."""
    from mcap.reader import make_reader

    from uvd.links.mcap import McapRecorder
    from uvd.telemetry.sink import TelemetryHub

    rotate = {"rotate_s": 0.5} if how == "time" else {"rotate_mb": 0.004}
    rec = McapRecorder(tmp_path, flush_interval_s=0.05, **rotate)
    hub = TelemetryHub([rec], flush_interval_s=0.01)
    n = 100

    async def main():
        task = asyncio.create_task(hub.run())
        await asyncio.sleep(0.05)  # opened: the first file's time starts
        t0 = time.monotonic_ns()
        hub.publish({"type": "start", "t_ns": t0, "version": "test", "config_toml": "# x\n"},
                    always=True)
        for k in range(n):  # 20 ms of record time apart: 2 s
            hub.publish({"type": "failsafe", "t_ns": t0 + (k + 1) * 20_000_000, "kind": "fired",
                         "trigger": "test", "action": "warn", "reason": "x" * 100},
                        always=True)
            if k % 10 == 0:
                await asyncio.sleep(0.02)
        await hub.aclose(timeout_s=5.0)
        await task

    asyncio.run(asyncio.wait_for(main(), 30.0))
    files = sorted(tmp_path.glob("*.mcap"))
    assert files == rec.files and len(files) >= 3, files
    got = 0
    for f in files:
        msgs = list(read_messages(f))
        assert msgs[0][0] == "/uvd/start"
        got += sum(1 for topic, _, _ in msgs if topic == "/uvd/failsafe")
        with f.open("rb") as fh:
            assert make_reader(fh).get_summary() is not None
    assert got == n


def _statustexts(station, until_text: str, timeout_s: float) -> list[tuple[int, str]]:
    """The station's STATUSTEXTs (severity, whole text: chunks of one id joined) up to the
    first whose text starts with ``until_text`` (AssertionError after ``timeout_s``)."""
    texts: list[tuple[int, str]] = []
    chunks: dict[int, list[str]] = {}
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        m = station.conn.recv_match(type="STATUSTEXT", blocking=True, timeout=0.1)
        if m is None:
            continue
        if m.id == 0:
            texts.append((m.severity, m.text))
        else:  # chunks of 50 characters; the last is shorter (or its text ends in NUL)
            chunks.setdefault(m.id, []).append(m.text)
            if len(m.text) < 50:
                texts.append((m.severity, "".join(chunks.pop(m.id))))
        if texts and texts[-1][1].startswith(until_text):
            return texts
    raise AssertionError(f"no STATUSTEXT {until_text!r} within {timeout_s} s: {texts}")


def _logging_bits(station) -> tuple[bool, bool, bool]:
    """The next SYS_STATUS's MAV_SYS_STATUS_LOGGING bit: (present, enabled, healthy)."""
    from tests.mavlink_gcs import mav
    return station.sensor_bits(mav.MAV_SYS_STATUS_LOGGING)


def _late_station_logging_bits(port: int) -> tuple[bool, bool, bool]:
    """A station that comes now: the first SYS_STATUS's logging bit it gets."""
    from tests.mavlink_gcs import Station
    s = Station(port)
    try:
        s.heartbeat(timeout=10.0)
        return _logging_bits(s)
    finally:
        s.close()


def test_the_operator_is_told_when_the_black_box_cannot_write_and_when_it_can_again(
        tmp_path, shared_bridge):
    """A real ``uvd run`` over sim-bridge, recording, with a ground station on MAVLink: its
    files may not grow (``prlimit`` RLIMIT_FSIZE 1 byte on the daemon's pid, EFBIG in the
    kernel as a full disk fails) and then may again. The station is told both (STATUSTEXT,
    WARNING then NOTICE), the black box holds both ``/uvd/sink`` records and every cycle of
    the spell, the daemon flies on and ends cleanly. Before (session 26) the operator was told
    nothing: only the daemon's log said so. A second station that connects after the WARNING
    learns it from SYS_STATUS: logging present and enabled, not healthy; healthy again after
    the NOTICE (before session 27 SYS_STATUS had no logging bit)."""
    import resource

    from tests.mavlink_gcs import Station
    from uvd.telemetry.sink import TELL_HOLD_S

    # the link on a port the kernel picks, which its log line names
    # (a disk with little room told as such, min_free_mb, is another test's)
    changes = {"recording": {"enabled": True, "dir": str(tmp_path / "rec"), "min_free_mb": 0},
               "mavlink": {"enabled": True, "listen": "127.0.0.1:0",
                           "params_file": str(tmp_path / "params.toml"),
                           "signing_timestamp_file": str(tmp_path / "signing.ts")}}
    log_lines: list[str] = []
    with reusing_bridge(shared_bridge, tmp_path, changes) as (cfg_path, _):
        proc = subprocess.Popen([sys.executable, "-m", "uvd", "run", "--config", str(cfg_path),
                                 "--duration", "120"], stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True,
                                cwd=Path(__file__).parents[1])
        reader = threading.Thread(target=lambda: log_lines.extend(proc.stderr), daemon=True)
        reader.start()
        deadline = time.monotonic() + 60.0
        while not (bound := [ln for ln in log_lines if "MAVLink link on udp" in ln]):
            assert proc.poll() is None and time.monotonic() < deadline, "".join(log_lines)
            time.sleep(0.05)
        port = int(re.search(r"MAVLink link on udp [\d.]+:(\d+)", bound[0]).group(1))
        station = Station(port)
        try:
            station.heartbeat(timeout=60.0)
            logging_before = _logging_bits(station)
            soft, hard = resource.prlimit(proc.pid, resource.RLIMIT_FSIZE)
            time.sleep(1.0)  # a second of cycles on disk before
            resource.prlimit(proc.pid, resource.RLIMIT_FSIZE, (1, hard))
            t_full = time.monotonic()
            told = _statustexts(station, "telemetry sink mcap cannot write", 10.0)
            failing = told[-1]
            logging_late = _late_station_logging_bits(port)  # comes after the telling
            time.sleep(1.0)  # two seconds of cycles that wait for the disk, with the above
            resource.prlimit(proc.pid, resource.RLIMIT_FSIZE, (soft, hard))
            told = _statustexts(station, "telemetry sink mcap writes again", TELL_HOLD_S + 10)
            again = told[-1]
            logging_again = _logging_bits(station)  # sent after the NOTICE
            assert proc.poll() is None, "the daemon ended"
        finally:
            station.close()
            proc.terminate()
            code = proc.wait(timeout=20)
            reader.join(5.0)
    print(f"told {time.monotonic() - t_full:.1f} s after the limit: {failing}; {again}")
    assert code == 0, "".join(log_lines)[-3000:]
    assert failing[0] == 4 and "File too large" in failing[1]  # MAV_SEVERITY_WARNING
    assert again[0] == 5 and "records dropped" in again[1]  # MAV_SEVERITY_NOTICE
    assert logging_before == (True, True, True), logging_before
    assert logging_late == (True, True, False), logging_late  # present, enabled, unhealthy
    assert logging_again == (True, True, True), logging_again
    assert "Traceback" not in "".join(log_lines)
    (f,) = (tmp_path / "rec").glob("*.mcap")
    sinks = [m for _, _, m in read_messages(f, ["/uvd/sink"])]
    assert [(m["sink"], m["ok"]) for m in sinks] == [("mcap", False), ("mcap", True)]
    assert sinks[1]["records_dropped"] == 0 and sinks[1]["bytes_given_up"] == 0, sinks
    for m in sinks:
        jsonschema.validate(m, schema("uvd.sink.v1"))
    t = [t_ns for _, t_ns, _ in read_messages(f, ["/uvd/cycle"])]
    spell = [a for a in t if sinks[0]["t_ns"] <= a <= sinks[1]["t_ns"]]
    assert len(spell) > 20 and max(b - a for a, b in pairwise(t)) < 0.5e9  # none lost
    summary = write_report(f, tmp_path / "report")  # a reader of the black box is told too
    assert summary["sinks_told"] == [m["text"] for m in sinks]
    from mcap.reader import make_reader  # and any MCAP reader: its channel and schema
    with open(f, "rb") as fh:
        got = [(sch.name, ch.message_encoding, json.loads(msg.data)["ok"]) for sch, ch, msg in
               make_reader(fh).iter_messages(topics=["/uvd/sink"])]
    assert got == [("uvd.sink.v1", "json", False), ("uvd.sink.v1", "json", True)]


def test_the_free_room_of_the_recordings_disk_is_measured_and_named_below_the_bound(tmp_path):
    """``low_space()`` after real writes (the lockstep path: the caller's thread writes):
    below ``min_free_mb`` it names the disk's free megabytes and the folder (this machine's
    disk has less than 1e12 MB free); above it (1 kB), and with the bound off, None."""
    import shutil

    from uvd.links.mcap import McapRecorder
    recs = {mb: McapRecorder(tmp_path / f"rec-{mb:g}", min_free_mb=mb) for mb in (1e12, 1e-3,
                                                                                  0.0)}
    for rec in recs.values():
        rec.open_now(1)
        rec.write_now([{"type": "failsafe", "t_ns": 2, "kind": "fired", "trigger": "test",
                        "action": "warn", "reason": "x" * 1000}])
        rec.close_now()
    low = recs[1e12].low_space()
    free_mb = shutil.disk_usage(tmp_path).free / 1e6
    assert low is not None and low.startswith(f"{recs[1e12].free_bytes / 1e6:.0f} MB free on "
                                              f"{tmp_path / 'rec-1e+12'} (below [recording] "
                                              "min_free_mb 1e+12)"), low
    assert abs(recs[1e12].free_bytes / 1e6 - free_mb) < 100.0  # what statvfs says
    assert recs[1e-3].low_space() is None and recs[0.0].low_space() is None
    assert recs[0.0].free_bytes is None  # not even measured


def test_a_disk_with_little_room_is_told_once_and_the_vehicle_flies_on(tmp_path, shared_bridge):
    """A real daemon over sim-bridge recording to a disk with less free than ``[recording]
    min_free_mb`` (1e9 MB: more than any disk here has): the operator is told once — a
    ``"sink"`` record ``recording-disk`` ("recording disk low: N MB free on DIR (below
    [recording] min_free_mb 1e+09)"), which the black box keeps too — while the recording
    itself stays healthy (SYS_STATUS's logging bit) and the vehicle stays armed. Before
    (session 27) nothing was told until writes failed."""
    from tests.hil_daemon import ListSink, link_port, run_scenario, station_link

    changes = {"recording": {"enabled": True, "dir": str(tmp_path / "rec"), "min_free_mb": 1e9},
               **station_link(tmp_path)}
    sink = ListSink()
    out: dict = {}
    with reusing_bridge(shared_bridge, tmp_path, changes) as (cfg_path, _):
        async def scenario(d):
            end = time.monotonic() + 20.0
            while not [r for r in sink.records if r.get("type") == "sink"] \
                    and time.monotonic() < end:
                await asyncio.sleep(0.05)

            out["logging_healthy"] = (await asyncio.to_thread(
                _late_station_logging_bits, link_port(d)))[2]
            out["syncs"] = d.app.hub.stats()["mcap"]["sink"]["syncs"]
            out["state"] = d.supervisor.state.value

        run_scenario(load_config(cfg_path), scenario, sink=sink, timeout_s=90.0)
    told = [r for r in sink.records if r.get("type") == "sink"]
    assert len(told) == 1 and (told[0]["sink"], told[0]["ok"]) == ("recording-disk", False)
    text = told[0]["text"]
    assert re.fullmatch(r"recording disk low: \d+ MB free on \S+rec \(below \[recording\] "
                        r"min_free_mb 1e\+09\)(; about [\d.]+ h of recording left at \d+ MB/h)?",
                        text), text
    jsonschema.validate(told[0], schema("uvd.sink.v1"))
    # the black box forced to the disk every [recording] sync_interval_s (1 s) it ran
    assert out.pop("syncs") >= 2, out
    assert out == {"logging_healthy": True, "state": "ARMED"}, out
    (f,) = (tmp_path / "rec").glob("*.mcap")
    assert [m["text"] for _, _, m in read_messages(f, ["/uvd/sink"])] == [text]


def test_the_data_is_forced_to_the_disk_at_the_sync_interval_and_at_the_end(tmp_path,
                                                                           monkeypatch):
    """``AppendFile`` with ``sync_interval_s`` 0.05: over ~0.5 s of writes every 10 ms the data
    is forced to the disk (``fdatasync``, on this machine's real file system) once per
    interval, not per write; with 0, only when the file ends. What a power cut of the
    machine loses is then bounded by the interval, not by the kernel's writeback (~30 s).
    Each new file's folder is forced once, at its first sync, so that its name survives too
    (the folder syncs watched as the real ``os.fsync`` runs)."""
    import stat

    from uvd.telemetry.appendfile import AppendFile

    folders: list[int] = []
    real_fsync = os.fsync

    def fsync(fd):
        if stat.S_ISDIR(os.fstat(fd).st_mode):
            folders.append(fd)
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)

    timed, plain = AppendFile(1 << 20, sync_interval_s=0.05), AppendFile(1 << 20)
    t0 = time.monotonic()
    worst = 0.0
    for _ in range(50):
        for f, name in ((timed, "timed.bin"), (plain, "plain.bin")):
            w0 = time.perf_counter()
            assert f.write(tmp_path / name, b"x" * 4096)
            if f is timed:
                worst = max(worst, time.perf_counter() - w0)
        time.sleep(0.01)
    span = time.monotonic() - t0
    print(f"{timed.syncs} syncs in {span:.2f} s of writes; slowest write with its sync "
          f"{worst * 1e3:.2f} ms")
    assert span / 0.05 * 0.5 <= timed.syncs <= span / 0.05 + 1, (timed.syncs, span)
    assert plain.syncs == 0 and len(folders) == 1  # the timed file's, at its first sync
    plain.write(tmp_path / "plain.bin", b"", close=True)
    assert plain.syncs == 1 and plain.stats()["syncs"] == 1 and len(folders) == 2
    assert (tmp_path / "timed.bin").stat().st_size == 50 * 4096


def test_estimates_of_several_estimators_are_drawn_one_figure_each():
    """AID's 241 parameters beside an adaptive controller's 16 (``uvd demo --fault``'s run:
    AMBC and ``[estimation] aid``) ended the report in numpy's "inhomogeneous shape"; records
    that name no estimator are told apart by their length."""
    from uvd.estimation.aid import INITP_6DOF
    from uvd.io.figures import _pyplot
    from uvd.telemetry.report import _estimates_figures
    plt = _pyplot()
    theta = list(map(float, INITP_6DOF.theta))
    est = [{"t_ns": k, "theta": theta} for k in range(3)] + \
        [{"t_ns": k, "theta": [1.0] * 16} for k in range(3)]
    named = [{**e, "estimator": "aid6", "source": "estimator"} for e in est[:3]] + \
        [{**e, "estimator": "two-step-ambc", "source": "controller"} for e in est[3:]]
    for records, files in ((est, ["estimates-estimate-241.png", "estimates-estimate-16.png"]),
                           (named, ["estimates-aid6.png", "estimates-two-step-ambc.png"]),
                           (named[:3], ["estimates.png"])):
        saved: list[str] = []

        def save(fig, name: str, caption: str, saved=saved) -> None:
            plt.close(fig)
            saved.append(name)
        _estimates_figures(plt, save, records, 0)
        assert saved == files
