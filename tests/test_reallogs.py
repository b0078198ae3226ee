"""Other systems' recordings: the log-format registry, log profiles, log → runs, thrust curves,
the published-model conversion and ``uvd identify`` / ``uvd xval`` with ``--profile``.

Real files: ``../shared/data/bluerov-exjobb`` (no licence: never copied into the repo; tests
skip naming the folder when it is absent) and ``tests/data/ardusub`` (MIT, in the repository).
"""

from __future__ import annotations

import itertools
import math
import re
import struct
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_DATA, shared_recordings
from driver_strategies import DATA
from hypothesis import given, settings
from hypothesis import strategies as hs

from uvd.errors import ConfigError, LogReadError, ParameterError
from uvd.io.logprofile import builtin_profiles, load_profile, profile_from_mapping
from uvd.io.logrun import (
    SignalStats,
    attitude_to_ned_frd,
    clean_signal,
    enu_to_ned,
    flu_to_frd,
    runs_from_log,
)
from uvd.io.logs import count_messages, detect_format, log_formats, open_log
from uvd.io.vehicle import load_curve, load_vehicle
from uvd.model.thrusters import ThrustCurve

REPO = Path(__file__).resolve().parents[1]
#: no licence: outside the repository (../shared/data), its tests skip naming the folder
EXJOBB = SHARED_DATA / "bluerov-exjobb"
#: MIT: copied into the repository (tests/data/ardusub, NOTICE beside it)
ARDUSUB = DATA / "ardusub"


def _need(folder: Path) -> Path:
    """``folder`` if present; a recording of the repository that is missing fails, one
    outside it skips naming its folder (conftest.shared_recordings)."""
    if folder.is_dir():
        return folder
    if DATA in folder.parents:
        pytest.fail(f"recordings {folder} missing: they belong to the repository (tests/data)")
    return shared_recordings(folder.name)


def _readme_table() -> dict[str, str]:
    """bag name → its README row (for the durations and thruster use)."""
    text = (_need(EXJOBB) / "README.md").read_text()
    return {m.group(1): m.group(0) for m in re.finditer(r"^\| `([^`]+\.bag)` \|.*$", text,
                                                        re.M)}


BAGS = sorted(p.name for p in EXJOBB.glob("*.bag")) if EXJOBB.is_dir() else []


# ---------------------------------------------------------------------------------------------
# every file read with the counts its own library reports
# ---------------------------------------------------------------------------------------------
@pytest.mark.skipif(not BAGS, reason=f"recordings bluerov-exjobb/ not found at {EXJOBB}")
@pytest.mark.parametrize("name", BAGS)
def test_bag_counts_match_rosbags(name):
    """Per topic, uvd reads (and decodes) exactly the messages rosbags' own index counts."""
    from rosbags.rosbag1 import Reader

    path = EXJOBB / name
    with Reader(path) as r:
        own = Counter()
        for c in r.connections:
            own[c.topic] += c.msgcount
    ours = count_messages(path)
    assert ours == own
    # the README's facts: its topics, and the thrusters' rate of the April/May files
    row = _readme_table()[name]
    assert name in row
    thr = [k for k in ours if k.lstrip("/") == "rovio/thrusters"]
    assert len(thr) == 1
    dur = float(row.split("|")[3])
    t = np.array([t for _tp, t, _m in open_log(path, topics=thr)]) * 1e-9
    assert t[-1] - t[0] <= dur + 0.5  # within the README's duration
    rate = (t.size - 1) / (t[-1] - t[0])  # README: April ≈ 4.8 Hz (one per step), May ≈ 97 Hz
    assert (4.0 < rate < 6.0) if "-04-" in name else (80 < rate < 110)


def test_bag_counts_match_readme_examples():
    """The README's example first messages of yaw_1 come out of uvd's reader as printed."""
    path = _need(EXJOBB) / "yaw_1_2016-04-18-13-44-26.bag"
    first = {}
    for topic, _t, msg in open_log(path):
        first.setdefault(topic.lstrip("/"), msg)
        if len(first) == 5:
            break
    assert list(first["rovio/thrusters"].data) == [1500, 1500, 1220, 1780, 1500, 1500]
    assert first["rovio/imu/data"].data[0] == pytest.approx(3292878)
    assert first["rovio/water_pressure/data"].data == pytest.approx(19347.76, abs=0.01)
    assert first["sensor_fusion/states"].data[9] == pytest.approx(1.982, abs=1e-3)


def _pymavlink_counts(path: Path) -> Counter:
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path))
    c = Counter()
    while (m := conn.recv_match()) is not None:
        c[m.get_type()] += 1
    return c


@pytest.mark.parametrize("name,total,facts", [
    ("small.tlog", 35916, {"ATTITUDE": 5245, "AHRS2": 5245, "SERVO_OUTPUT_RAW": 528,
                           "SCALED_PRESSURE2": 635, "LOCAL_POSITION_NED": 792,
                           "MANUAL_CONTROL": 1450, "HEARTBEAT": 1056}),
    ("small.BIN", 7510, {"IMU": 594, "BARO": 474, "ATT": 237, "RATE": 237, "RCOU": 237,
                         "CTUN": 237, "XKF1": 237, "PARM": 876, "FMT": 152}),
])
def test_ardusub_counts(name, total, facts):
    """Both ArduSub logs: uvd's counts = pymavlink's own = the README's."""
    path = _need(ARDUSUB) / name
    ours = count_messages(path)
    assert ours == _pymavlink_counts(path)
    assert sum(ours.values()) == total
    for k, v in facts.items():
        assert ours[k] == v


@pytest.mark.parametrize("name,profile", [("small.tlog", "ardusub-tlog"),
                                          ("small.BIN", "ardusub-bin")])
def test_ardusub_profiles_read(name, profile):
    """The built-in ArduSub profiles find every signal of the real logs, in plausible units."""
    from uvd.io.logrun import read_signals

    sig = read_signals(_need(ARDUSUB) / name, load_profile(profile))
    t, att = sig["attitude"]
    assert att.shape[1] == 3 and t.size > 100
    _t, pwm = sig["thrusters"]
    assert pwm.shape[1] == 8
    assert 1000 < np.median(pwm[:, 0]) < 2000
    _t, dep = sig["depth"]
    if profile == "ardusub-tlog":
        assert 900 < np.median(dep) < 1200  # hPa
    else:
        assert 9e4 < np.median(dep) < 1.2e5  # Pa


# ---------------------------------------------------------------------------------------------
# named errors: missing topic, wrong unit, truncated or corrupted file; nothing hangs
# ---------------------------------------------------------------------------------------------
def _small_bag() -> Path:
    return _need(EXJOBB) / "all_4_2016-04-18-15-06-06.bag"


@pytest.mark.timeout(60)
def test_missing_topic_named():
    prof = load_profile("bluerov-exjobb-may")  # no leading slash: wrong for an April file
    with pytest.raises(LogReadError, match=r"all_4.*topic (sensor_fusion/states|rovio/\S+): "
                                           r"no messages"):
        runs_from_log(_small_bag(), prof, load_vehicle("bluerov-exjobb"))


@pytest.mark.timeout(60)
def test_wrong_unit_named():
    doc = _profile_doc("bluerov-exjobb-april")
    doc["signals"]["thrusters"]["unit"] = "normalised"  # they are PWM µs
    prof = profile_from_mapping(doc, where="test")
    with pytest.raises(LogReadError, match=r"all_4.*topic /rovio/thrusters: signal thrusters "
                                           r"says unit normalised.*wrong unit"):
        runs_from_log(_small_bag(), prof, load_vehicle("bluerov-exjobb"))
    doc = _profile_doc("bluerov-exjobb-april")
    doc["signals"]["attitude"]["unit"] = "rad"
    doc["signals"]["attitude"]["index"] = [9, 9, 9]  # depth in m is no angle … mostly
    doc["signals"]["angular_rate"]["unit"] = "rad/s"
    doc["signals"]["depth"]["unit"] = "m"
    doc["signals"]["depth"]["field"] = "data"
    # a pressure in Pa read as an angular rate in rad/s: far out of any gyro's range
    doc["signals"]["angular_rate"] = {"topic": "/rovio/water_pressure/data", "fields":
                                      ["data", "data", "data"], "unit": "rad/s", "frame": "frd"}
    prof = profile_from_mapping(doc, where="test")
    with pytest.raises(LogReadError, match=r"topic /rovio/water_pressure/data: signal "
                                           r"angular_rate says unit rad/s.*wrong unit"):
        runs_from_log(_small_bag(), prof, load_vehicle("bluerov-exjobb"))


def _profile_doc(name: str) -> dict:
    import tomllib
    from importlib import resources

    with (resources.files("uvd") / "logprofiles" / f"{name}.toml").open("rb") as fh:
        return tomllib.load(fh)


def _by_record(path: Path) -> list[tuple[str, int]]:
    """(topic, t_ns) of a bag read record by record, in file order."""
    from uvd.io.logs import _read_ros1_by_record
    return [(topic, t) for topic, t, _ in _read_ros1_by_record(path, None, "test")]


@pytest.mark.timeout(60)
def test_a_bag_read_record_by_record_is_the_bag_rosbags_reads():
    """Every message of the real bag, decoded alike (rosbags' type system from the bag's own
    definitions), each topic in the same order as rosbags gives it by its index."""
    from uvd.io.logs import _read_ros1_by_record
    bag = _small_bag()
    indexed = list(open_log(bag))
    by_record = list(_read_ros1_by_record(bag, None, "test"))
    assert len(by_record) == len(indexed) == 5071
    for topic in {t for t, _, _ in indexed}:
        a = [(t_ns, repr(m)) for t, t_ns, m in indexed if t == topic]
        assert a == [(t_ns, repr(m)) for t, t_ns, m in by_record if t == topic], topic


@pytest.mark.timeout(60)
@pytest.mark.parametrize("cut, n", [(0.5, 2806), (0.97, 5071)])  # 0.97: inside the index
def test_a_bag_cut_short_is_read_up_to_the_cut(tmp_path, cut, n, caplog):
    """A bag cut short has lost its index (at its end): rosbags refuses it ("Bag index looks
    damaged"); it was an error naming ROS 1's `rosbag reindex FILE`, which a lab without
    ROS 1 cannot run. It is read record by record up to the cut, and said so."""
    data = _small_bag().read_bytes()
    bad = tmp_path / "truncated.bag"
    bad.write_bytes(data[:int(len(data) * cut)])
    got = [(topic, t) for topic, t, _ in open_log(bad)]
    assert len(got) == n and got == _by_record(_small_bag())[:n]
    assert "Bag index looks damaged" in caplog.text and "as `rosbag reindex` would" in caplog.text
    assert "B record by record; the last" in caplog.text


@pytest.mark.timeout(60)
@pytest.mark.parametrize("compression", ["BZ2", "LZ4"])
def test_a_compressed_bag_cut_short_reads_its_whole_chunks(tmp_path, compression, caplog):
    """A bag written by rosbags' writer in chunks of about 2 kB, compressed, then cut in its
    fourth chunk: the three whole chunks are read, the cut one is skipped and named."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS1_NOETIC)
    Float64 = store.types["std_msgs/msg/Float64"]
    path = tmp_path / "z.bag"
    w = Writer(path)
    w.set_compression(getattr(Writer.CompressionFormat, compression))
    w.chunk_threshold = 2000
    with w:
        conn = w.add_connection("/depth", Float64.__msgtype__, typestore=store)
        for k in range(600):
            w.write(conn, 10**9 + k * 10**7, store.serialize_ros1(Float64(data=0.5 * k),
                                                                  Float64.__msgtype__))
    data = path.read_bytes()
    chunks = [m.start() for m in re.finditer(rb"compression=", data)]
    assert len(chunks) > 4
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[:chunks[3] + 40])  # inside the fourth chunk
    got = [(t, m.data) for _topic, t, m in open_log(cut)]
    whole = [(t, m.data) for _topic, t, m in open_log(path)]
    assert 0 < len(got) < len(whole) and got == whole[:len(got)]
    assert f"(first: a {compression.lower()} chunk at byte " in caplog.text and "cut short" \
        in caplog.text


@pytest.mark.timeout(60)
def test_a_recording_never_closed_is_read(tmp_path, caplog):
    """What `rosbag record` leaves when the vehicle's power goes (NAME.bag.active): no index
    (index_pos 0), the chunk's size never written (0), the file ending inside a record."""
    d = bytearray(_small_bag().read_bytes())
    i = d.index(b"index_pos=")
    d[i + 10:i + 18] = bytes(8)
    (hlen,) = struct.unpack_from("<I", d, 13)  # the bag header record, after the magic line
    chunk = 13 + 8 + hlen + struct.unpack_from("<I", d, 13 + 4 + hlen)[0]
    (chlen,) = struct.unpack_from("<I", d, chunk)
    assert b"op=\x05" in d[chunk + 4:chunk + 4 + chlen]  # the one chunk
    (size,) = struct.unpack_from("<I", d, chunk + 4 + chlen)
    d[chunk + 4 + chlen:chunk + 8 + chlen] = bytes(4)
    active = tmp_path / "run.bag.active"
    active.write_bytes(bytes(d[:chunk + 8 + chlen + size - 1000]))
    assert detect_format(active) == "ros1"
    got = [(topic, t) for topic, t, _ in open_log(active)]
    assert len(got) == 5062 and got == _by_record(_small_bag())[:5062]  # 9 cut off
    assert "a recording never closed (.active)" in caplog.text


@pytest.mark.timeout(60)
def test_a_damaged_bag_costs_its_damaged_records(tmp_path, caplog):
    """A damaged record stops rosbags half way (an assert, a header that does not read, a
    message that does not decode: 34 of 60 single-bit flips of this bag refused it whole);
    the rest is read record by record, a damaged record skipped to the next one that reads
    and named. Over 60 single-bit flips none is refused, none loses more than one message."""
    data = bytearray(_small_bag().read_bytes())
    one = bytearray(data)
    at = one.index(b"op=\x02", len(one) // 2)  # a message's header, its kind damaged
    one[at + 3] ^= 0x10
    bad = tmp_path / "one.bag"
    bad.write_bytes(bytes(one))
    whole = _by_record(_small_bag())
    got = [(topic, t) for topic, t, _ in open_log(bad)]
    assert len(got) == len(whole) - 1 and set(got) < set(whole)
    assert "rosbags stopped after " in caplog.text
    assert "skipped 1 stretch(es) that do not read (first: " in caplog.text
    rng = np.random.default_rng(3)
    for i in rng.integers(4096, len(data) - 4096, 200):
        data[i] ^= 0xFF
    bad = tmp_path / "corrupted.bag"
    bad.write_bytes(bytes(data))
    caplog.clear()
    assert 4900 <= sum(count_messages(bad).values()) < len(whole)  # 4960 of 5071
    assert "stretch(es) that do not read" in caplog.text and "that do not decode skipped" in \
        caplog.text
    (tmp_path / "garbage.bag").write_bytes(b"not a bag at all" * 100)
    with pytest.raises(LogReadError, match=r"garbage\.bag"):
        count_messages(tmp_path / "garbage.bag")


@pytest.mark.timeout(60)
@pytest.mark.parametrize("name,profile", [("small.tlog", "ardusub-tlog"),
                                          ("small.BIN", "ardusub-bin")])
def test_truncated_and_corrupted_ardusub(tmp_path, name, profile):
    """A cut .tlog/.BIN reads to where it was cut (pymavlink's robust parsing; no hang); with a
    profile topic missing from what is left the error names file and topic."""
    data = (_need(ARDUSUB) / name).read_bytes()
    cut = tmp_path / f"cut{Path(name).suffix}"
    cut.write_bytes(data[:len(data) // 50])
    counts = count_messages(cut)
    assert 0 < sum(counts.values()) < sum(count_messages(ARDUSUB / name).values())
    junk = tmp_path / f"junk{Path(name).suffix}"
    junk.write_bytes(bytes(np.random.default_rng(1).integers(0, 256, 20000, dtype=np.uint8)))
    with pytest.raises(LogReadError, match=r"junk\.(tlog|BIN).*topic"):
        runs_from_log(junk, load_profile(profile), load_vehicle("bluerov-exjobb"))


def test_unknown_format_and_missing_file(tmp_path):
    with pytest.raises(LogReadError, match=r"x\.csv.*unknown log format"):
        detect_format(tmp_path / "x.csv")
    with pytest.raises(LogReadError, match=r"nope\.bag: no such file"):
        open_log(tmp_path / "nope.bag")
    assert {"ros1", "ros2", "mcap", "tlog", "dataflash", "uvd-telemetry"} <= set(log_formats())


def test_mcap_json_messages(tmp_path):
    """uvd's own MCAP (JSON messages) through the registry: its writer, our reader."""
    from mcap.writer import Writer

    path = tmp_path / "rec.mcap"
    with path.open("wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema("uvd.cycle", "jsonschema", b"{}")
        cid = w.register_channel("/uvd/cycle", "json", sid)
        for k in range(5):
            w.add_message(cid, log_time=k * 10**8, publish_time=k * 10**8,
                          data=b'{"type": "cycle", "k": %d}' % k)
        w.finish()
    got = list(open_log(path))
    assert [t for _tp, t, _m in got] == [k * 10**8 for k in range(5)]
    assert [m.k for _tp, _t, m in got] == list(range(5))
    assert count_messages(path) == Counter({"/uvd/cycle": 5})


# ---------------------------------------------------------------------------------------------
# profiles
# ---------------------------------------------------------------------------------------------
def test_builtin_profiles_valid():
    names = builtin_profiles()
    assert {"bluerov-exjobb-april", "bluerov-exjobb-may", "ardusub-tlog",
            "ardusub-bin"} <= set(names)
    for n in names:
        p = load_profile(n)
        assert p.name == n
    assert load_profile("bluerov-exjobb-april").signals["thrusters"].topic == "/rovio/thrusters"
    assert load_profile("bluerov-exjobb-may").signals["thrusters"].topic == "rovio/thrusters"


def _fields_instead(signal: dict, fields) -> None:
    """A profile's signal given by ``fields`` instead of its ``field`` and ``index``."""
    signal.pop("field")
    signal.pop("index", None)
    signal["fields"] = fields


@pytest.mark.parametrize("edit,match", [
    (lambda d: d.pop("signals"), r"missing \[signals\]"),
    # found by probing (session 21): said "missing [signals]"
    (lambda d: d.update(signals=5), r"\[signals\] must be a table, got int 5"),
    (lambda d: d.update(signals=[1]), r"\[signals\] must be a table, got list \[1\]"),
    (lambda d: d.update(bogus=1), r"unknown key\(s\) \['bogus'\]"),
    (lambda d: d["signals"].pop("thrusters"), r"identification needs \['thrusters'\]"),
    (lambda d: d["signals"]["angular_rate"].update(unit="rpm"),
     r"\[signals.angular_rate\]: unit 'rpm' is not one of"),
    (lambda d: d["signals"]["attitude"].update(frame="xyz"),
     r"\[signals.attitude\]: frame 'xyz'"),
    (lambda d: d["signals"]["attitude"].update(index=[0, 1]),
     r"attitude needs 3 component\(s\)"),
    (lambda d: d.update(resample="cubic"), r"resample must be 'hold' or 'interpolate'"),
    (lambda d: d.update(format="csv"), r"format 'csv' is not one of"),
    (lambda d: d["signals"]["depth"].pop("topic"), r"\[signals.depth\]: missing key 'topic'"),
    # found by fuzzing the built-in profiles: each raised a bare TypeError or ValueError
    (lambda d: _fields_instead(d["signals"]["angular_rate"], -1.0),
     r"\[signals.angular_rate\]: fields must be a list of field names"),
    (lambda d: d["signals"]["depth"].update(density_kg_m3="frd"),
     r"\[signals.depth\]: density_kg_m3 must be a finite number, got 'frd'"),
    (lambda d: d["signals"]["depth"].update(reference_pa=[1, 2]),
     r"reference_pa must be a finite number"),
    (lambda d: d["signals"]["depth"].update(scale=float("nan")), r"scale must be a finite"),
    (lambda d: d["signals"]["thrusters"].update(topic=["a"]),
     r"\[signals.thrusters\]: topic must be a string"),
    (lambda d: d.update(format=["ros1"]), r"format \['ros1'\] is not one of"),
    (lambda d: d.update(vehicle=7), r"vehicle must be a vehicle's name or file, got 7"),
    # found by fuzzing (session 19): each was taken as a number or a name without a word
    (lambda d: d.update(rate_hz=True), r"rate_hz must be a finite number, got True"),
    (lambda d: d.update(rate_hz="50"), r"rate_hz must be a finite number, got '50'"),
    (lambda d: d.update(rate_hz=20000), r"rate_hz must be in \(0, 10000\], got 20000"),
    (lambda d: d.update(max_gap_s=float("inf")), r"max_gap_s must be a finite number, got inf"),
    (lambda d: d.update(max_gap_s=0), r"max_gap_s must be > 0, got 0"),
    (lambda d: d["signals"]["depth"].update(density_kg_m3=-1000.0),
     r"\[signals.depth\]: density_kg_m3 must be > 0, got -1000.0"),
    (lambda d: d["signals"]["depth"].update(gravity_m_s2=0.0),
     r"\[signals.depth\]: gravity_m_s2 must be > 0, got 0.0"),
    (lambda d: d["signals"]["attitude"].update(index=[True, 1, 2]),
     r"\[signals.attitude\]: index must be a list of integers >= 0"),
    (lambda d: d.update(name=5), r"name must be a string, got 5"),
    (lambda d: d.update(time=5), r"time must be a string, got 5"),
])
def test_profile_errors_named(edit, match):
    doc = _profile_doc("bluerov-exjobb-april")
    edit(doc)
    with pytest.raises(ConfigError, match=r"myprofile: .*" + match):
        profile_from_mapping(doc, where="myprofile")


def test_unknown_profile():
    with pytest.raises(ConfigError, match="unknown log profile 'nope'"):
        load_profile("nope")


# ---------------------------------------------------------------------------------------------
# cleaning, one clock, frames
# ---------------------------------------------------------------------------------------------
def test_clean_signal_counts():
    t = np.array([0, 10, 20, 20, 15, 30, 40, 90, 100]) * 10**7  # ns
    x = np.arange(9.0)[:, None]
    x[6, 0] = np.nan
    st = SignalStats(topic="t")
    tc, xc = clean_signal(t, x, st, max_gap_s=0.3)
    assert (st.messages, st.non_finite, st.duplicates, st.out_of_order) == (9, 1, 1, 1)
    assert list(tc) == [0, 10**8, 2 * 10**8, 3 * 10**8, 9 * 10**8, 10**9]
    assert list(xc[:, 0]) == [0, 1, 2, 5, 7, 8]
    assert st.gaps == 1 and st.kept == 6


@settings(max_examples=300, deadline=None)
@given(hs.lists(hs.integers(0, 12), max_size=11))
def test_in_time_order_keeps_the_earliest_longest_increasing_run(stamps):
    """Against every subset: the kept samples are the first (in index order) of the largest
    subsets whose stamps strictly increase."""
    from uvd.io.logrun import _in_time_order

    t = np.array(stamps, dtype=np.int64)
    keep = _in_time_order(t)
    kept = [i for i in range(t.size) if keep[i]]
    best = []
    for n in range(t.size, 0, -1):
        best = next((list(c) for c in itertools.combinations(range(t.size), n)
                     if all(t[a] < t[b] for a, b in itertools.pairwise(c))), [])
        if best:
            break
    assert kept == best
    if np.all(np.diff(t) >= 0):   # never back: the first sample of each stamp
        assert kept == [i for i in range(t.size) if i == 0 or t[i] != t[i - 1]]


def _att_offsets(path: Path) -> list[int]:
    """Where each ATT message of a dataflash log starts (its TimeUS at +3, uint64 µs)."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path))
    out = []
    while (m := conn.recv_match(type="ATT", blocking=False)) is not None:
        out.append(conn.offset - m.fmt.len)
    conn.close()
    return out


def test_a_corrupted_time_stamp_costs_its_own_sample(tmp_path):
    """The real ArduSub log with two ATT time stamps corrupted as an SD card can: one to
    2^64 − 1 µs (beyond int64 ns: was an OverflowError traceback) is dropped as "without a
    time"; one 11.6 days ahead is dropped as out of order — and only it: the rule "older than
    the newest seen" had dropped every ATT sample after it (here 150 of 237; in a copy with 200
    bytes flipped at random, 55 grid samples kept against the file's 236, ATT at ~0.1 Hz)."""
    src = _need(ARDUSUB) / "small.BIN"
    prof, vehicle = load_profile("ardusub-bin"), load_vehicle("bluerov2-heavy")
    _runs, before = runs_from_log(src, prof, vehicle)
    data = bytearray(src.read_bytes())
    at = _att_offsets(src)
    assert len(at) == before.signals["attitude"].messages
    data[at[50] + 3:at[50] + 11] = struct.pack("<Q", 2**64 - 1)
    (t,) = struct.unpack("<Q", data[at[86] + 3:at[86] + 11])
    data[at[86] + 3:at[86] + 11] = struct.pack("<Q", t + 10**12)
    bad = tmp_path / "corrupted.BIN"
    bad.write_bytes(bytes(data))
    _runs, after = runs_from_log(bad, prof, vehicle)
    a, b = before.signals["attitude"], after.signals["attitude"]
    assert (a.bad_time, a.out_of_order, a.duplicates) == (0, 0, 0)
    assert (b.messages, b.bad_time, b.out_of_order, b.duplicates) == (a.messages, 1, 1, 0)
    assert b.kept == a.kept - 2 and b.gaps == a.gaps
    assert "1 without a time, 0 non-finite, 1 out of order" in after.text()
    for name in ("angular_rate", "depth", "thrusters"):   # the other signals untouched
        assert after.signals[name].as_dict() == before.signals[name].as_dict()


def test_a_damaged_message_type_costs_nothing_after_it(tmp_path):
    """The real ArduSub log with one message's type byte damaged into a type no FMT declares
    (an XKF5 at byte 187506, 0x50 → 0x10): asked for by type, pymavlink's dataflash reader
    went by its index, which ends there — 673 of the 1542 ATT, IMU, BARO and RCOU messages
    after it were lost, silently. Read in turn, every one of them is read."""
    src = _need(ARDUSUB) / "small.BIN"
    prof, vehicle = load_profile("ardusub-bin"), load_vehicle("bluerov2-heavy")
    _runs, before = runs_from_log(src, prof, vehicle)
    data = bytearray(src.read_bytes())
    assert data[187506:187509] == b"\xa3\x95\x50"  # a message's head: 0xA3 0x95, type XKF5
    data[187508] = 0x10
    bad = tmp_path / "damaged-type.BIN"
    bad.write_bytes(bytes(data))
    _runs, after = runs_from_log(bad, prof, vehicle)
    for name in ("attitude", "angular_rate", "depth", "thrusters"):
        assert after.signals[name].as_dict() == before.signals[name].as_dict(), name
    assert after.signals["attitude"].messages == 237

    def by_type(path: Path) -> int:  # the damage is the kind that cut the index short
        from pymavlink import mavutil
        conn = mavutil.mavlink_connection(str(path))
        n = sum(1 for _ in iter(lambda: conn.recv_match(type="ATT", blocking=False), None))
        conn.close()
        return n
    assert by_type(src) == 237 and by_type(bad) < 200


def test_onto_grid_never_invents():
    from uvd.io.logrun import _onto_grid

    t = np.array([0, 100, 200, 900, 1000], dtype=np.int64)
    x = np.array([[0.0], [1.0], [2.0], [9.0], [10.0]])
    grid = np.arange(0, 1001, 50, dtype=np.int64)
    h, ok_h = _onto_grid(t, x, grid, "hold", 300)
    assert h[grid == 150][0, 0] == 1.0 and h[grid == 500][0, 0] == 2.0
    assert not ok_h[grid == 550][0] and ok_h[grid == 500][0]
    i, ok_i = _onto_grid(t, x, grid, "interpolate", 300)
    assert i[grid == 150][0, 0] == pytest.approx(1.5)
    assert not ok_i[grid == 300][0]  # between 200 and 900: a 700 ns gap > 300
    assert ok_i[grid == 950][0] and i[grid == 950][0, 0] == pytest.approx(9.5)


def test_frame_flips():
    assert np.allclose(flu_to_frd([1.0, 2.0, 3.0]), [1.0, -2.0, -3.0])
    assert np.allclose(enu_to_ned([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    # a vehicle heading north, level: ENU yaw = +90° (x to north), FLU body
    R = attitude_to_ned_frd(np.array([[0.0, 0.0, math.pi / 2]]), "enu")[0]
    assert np.allclose(R, np.eye(3), atol=1e-12)
    # heading east in ENU (yaw 0) is yaw +90° in NED
    R = attitude_to_ned_frd(np.array([[0.0, 0.0, 0.0]]), "enu")[0]
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0]) and np.allclose(R @ [0, 0, 1], [0, 0, 1])
    # a body rolled to starboard in FRD/NED: its y axis points down-ish
    R = attitude_to_ned_frd(np.array([[0.3, 0.0, 0.0]]), "ned")[0]
    assert (R @ [0, 1, 0])[2] == pytest.approx(math.sin(0.3))


# ---------------------------------------------------------------------------------------------
# thrust curves and the vehicle
# ---------------------------------------------------------------------------------------------
def test_t200_curve():
    c = load_curve("t200")
    assert c.unit == "pwm_us" and "Aili" in c.source
    f = c.thrust(np.array([1100, 1480, 1500, 1520, 1521, 1580, 1900, 2000, 1000]))
    assert f[0] == pytest.approx(-40.0788) and f[6] == pytest.approx(49.9531)
    assert f[1] == f[2] == f[3] == 0.0  # dead band |u| ≤ 0.05
    assert f[4] > 0 and f[5] == pytest.approx(4.0923)
    assert f[7] == f[6] and f[8] == f[0]  # the ESC clamps
    assert c.thrust(1740) == pytest.approx(24.7324)
    assert c.thrust(1265) == pytest.approx(0.5 * (-21.351 - 19.528))  # interpolated
    assert abs(c.max_reverse_n) < c.max_forward_n  # forward and reverse differ


def test_thrust_curve_validation():
    with pytest.raises(ParameterError, match="increase strictly"):
        ThrustCurve(command=(0.0, 0.0), thrust_n=(0.0, 1.0))
    with pytest.raises(ParameterError, match="must not decrease"):
        ThrustCurve(command=(0.0, 1.0), thrust_n=(1.0, 0.0))
    for bad in ({"neutral": float("nan")}, {"dead_band": float("inf")}):  # taken silently before
        with pytest.raises(ParameterError, match="neutral and dead_band must be finite"):
            ThrustCurve(command=(0.0, 1.0), thrust_n=(0.0, 1.0), **bad)


def test_exjobb_vehicle_thrust_matrix():
    """The thesis's thrust matrix (eq:actuatorGeometry) with l_z6 = 0.11 m."""
    B = load_vehicle("bluerov-exjobb").B
    lx1, ly, lx5, lz6 = 0.19, 0.11, 0.17, 0.11
    T = np.array([[0, 0, 1, 1, 0, 0], [0, 0, 0, 0, 0, -1], [-1, -1, 0, 0, -1, 0],
                  [ly, -ly, 0, 0, 0, lz6], [lx1, lx1, 0, 0, -lx5, 0], [0, 0, ly, -ly, 0, 0]])
    assert np.allclose(B, T)


def test_vehicle_unknown_curve(tmp_path):
    src = (REPO / "uvd" / "vehicles" / "bluerov-exjobb.toml").read_text()
    bad = tmp_path / "v.toml"
    bad.write_text(src.replace('curve = "t200"', 'curve = "t9000"'))
    with pytest.raises(ConfigError, match=r"v\.toml: thrusters\[0\]: unknown thrust curve "
                                          r"'t9000'"):
        load_vehicle(bad)
    # a curve is a name, never a path: not a file of another folder of the package (a vehicle
    # was read as a curve), nor one too long for the file system (OSError until session 30)
    for name in ("../jhu-rov", "t" * 300):
        bad.write_text(src.replace('curve = "t200"', f'curve = "{name}"'))
        with pytest.raises(ConfigError, match=r"unknown thrust curve .* built-in curves \['t200'"):
            load_vehicle(bad)
    for name in ("curves/t200", "x" * 300 + ".toml"):  # nor is a vehicle's name
        with pytest.raises(ConfigError, match="unknown vehicle|File name too long"):
            load_vehicle(name)


# ---------------------------------------------------------------------------------------------
# the published model in θ_UV: conversion, units, signs
# ---------------------------------------------------------------------------------------------
def test_rot_from_lumped_equals_the_published_equations():
    """(2.40) with rot_from_lumped's θ_UVR and D_L gives the thesis's ṗ, q̇, ṙ exactly."""
    from uvd.estimation.xval import rot_from_lumped
    from uvd.model.dynamics import rot_accel

    A, B, C = 0.8337, 0.7987, 1.1250
    Kp, Kpp, Mq, Mqq, Nr, Nrr, zB = -0.8842, -0.6682, -0.8547, -0.3354, -1.0280, -1.0249, -0.042
    W = 6.621 * 9.82
    rot, DL = rot_from_lumped(A, B, C, Kp, Kpp, Mq, Mqq, Nr, Nrr, zB, W)
    assert rot.b[2] == pytest.approx(2.7307, abs=1e-3) and rot.b[2] > 0  # restoring
    rng = np.random.default_rng(0)
    from uvd.io.logrun import _euler_R
    for _ in range(20):
        phi, th, psi = rng.uniform(-1, 1, 3)
        p, q, r = rng.uniform(-2, 2, 3)
        tau = rng.uniform(-3, 3, 3)
        R = _euler_R(np.array([phi]), np.array([th]), np.array([psi]))[0]
        w = np.array([p, q, r])
        ours = rot_accel(rot, w, R, tau + DL @ w)
        thesis = np.array([
            (tau[0] + W * zB * math.cos(th) * math.sin(phi) + (Kp + Kpp * abs(p)) * p
             + (B - C) * q * r) / A,
            (tau[1] + W * zB * math.sin(th) + (Mq + Mqq * abs(q)) * q - (A - C) * p * r) / B,
            (tau[2] + (Nr + Nrr * abs(r)) * r + (A - B) * p * q) / C])
        assert np.allclose(ours, thesis, atol=1e-12)


def test_published_params_file_roundtrip(tmp_path):
    from uvd.estimation.realdata import rot_of
    from uvd.experiments.real_vehicles import published_toml
    from uvd.io.params import linear_damping_from_toml, params_from_toml

    text, rot, DL = published_toml("published-final", load_vehicle("bluerov-exjobb").params)
    f = tmp_path / "pub.toml"
    f.write_text(text)
    back = rot_of(params_from_toml(f))
    assert np.allclose(back.I, rot.I) and np.allclose(back.C, rot.C)
    assert np.allclose(back.b, rot.b)
    assert np.allclose(linear_damping_from_toml(f), DL)
    f.write_text(text.replace("rotational = [-0.8842", "rotational = [0.8842"))
    with pytest.raises(ParameterError, match="dissipative"):
        linear_damping_from_toml(f)


# ---------------------------------------------------------------------------------------------
# the commands on real data
# ---------------------------------------------------------------------------------------------
@pytest.mark.timeout(240)
def test_identify_and_xval_on_real_bags(tmp_path, capsys):
    """ls-consistent from all_3: inertia positive, drag dissipative, b₃ restoring; the
    translational DOFs refused with the reason; xval on all_4 prints finite MAE."""
    import json

    from uvd.cli import main

    _need(EXJOBB)
    out = tmp_path / "p.toml"
    rc = main(["identify", "--log", str(EXJOBB / "all_3_2016-04-18-15-04-50.bag"),
               "--profile", "bluerov-exjobb-april", "--method", "ls-consistent",
               "--out", str(out), "--json", str(tmp_path / "s.json"), "--quiet"])
    assert rc == 0
    text = capsys.readouterr().out
    assert re.search(r"REFUSED surge, sway, heave: no linear-velocity sensor", text)
    s = json.loads((tmp_path / "s.json").read_text())
    assert s["physical"] == {"inertia_positive": True, "drag_dissipative": True,
                             "restoring_b3_positive": True}
    assert set(s["refused"]) == {"surge", "sway", "heave"}
    assert s["reports"][0]["signals"]["thrusters"]["messages"] == 57
    assert "[refused]" in out.read_text()
    rc = main(["xval", "--params", str(out), "--log",
               str(EXJOBB / "all_4_2016-04-18-15-06-06.bag"), "--profile",
               "bluerov-exjobb-april", "--json", str(tmp_path / "x.json")])
    assert rc == 0
    x = json.loads((tmp_path / "x.json").read_text())
    assert all(math.isfinite(v) for v in x["runs"][0]["mae"].values())


def test_identify_with_linear_damping_on_real_bags(tmp_path, capsys):
    """--linear-damping: the file carries a dissipative [linear_damping] that xval reads and
    says it simulates; with AID (the thesis's model has no such term) it is refused by name."""
    import json

    from uvd.cli import main
    from uvd.io.params import linear_damping_from_toml

    _need(EXJOBB)
    out = tmp_path / "p.toml"
    rc = main(["identify", "--log", str(EXJOBB / "all_2_2016-04-18-14-56-58.bag"),
               str(EXJOBB / "all_3_2016-04-18-15-04-50.bag"), "--profile",
               "bluerov-exjobb-april", "--method", "ls-consistent", "--linear-damping",
               "--out", str(out), "--json", str(tmp_path / "s.json"), "--quiet"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "linear damping K_p, M_q, N_r" in text
    d = np.diag(linear_damping_from_toml(out))
    s = json.loads((tmp_path / "s.json").read_text())
    assert s["linear_damping"] == pytest.approx(d.tolist()) and np.all(d < 0)
    assert s["physical"]["drag_dissipative"] and s["model"] == "rot-lin"
    rc = main(["xval", "--params", str(out), "--log",
               str(EXJOBB / "all_4_2016-04-18-15-06-06.bag"), "--profile",
               "bluerov-exjobb-april"])
    assert rc == 0 and "with its linear damping" in capsys.readouterr().out
    rc = main(["identify", "--log", str(EXJOBB / "all_3_2016-04-18-15-04-50.bag"), "--profile",
               "bluerov-exjobb-april", "--method", "aid", "--linear-damping", "--out",
               str(tmp_path / "a.toml"), "--quiet"])
    assert rc == 2 and not (tmp_path / "a.toml").exists()
    assert "--linear-damping: only with --profile" in capsys.readouterr().err


def test_identify_refuses_without_vehicle(tmp_path, capsys):
    from uvd.cli import main

    _need(ARDUSUB)
    rc = main(["identify", "--log", str(ARDUSUB / "small.BIN"), "--profile", "ardusub-bin",
               "--method", "ls", "--out", str(tmp_path / "p.toml")])
    assert rc == 2
    assert "profile 'ardusub-bin' names no vehicle" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------
# AID scaled to the vehicle
# ---------------------------------------------------------------------------------------------
def test_aid_scaling_is_identity_on_the_jhu_rov_and_scales_the_bluerov2_per_dof():
    from uvd.estimation.aid import (
        INITP_6DOF,
        AID3Gains,
        AID6Gains,
        scaled_aid_gains,
        scaled_initp,
    )

    jhu_p = load_vehicle("jhu-rov").params
    jhu = np.diag(jhu_p.M)
    assert scaled_aid_gains(jhu) == AID6Gains()
    g3 = scaled_aid_gains(jhu, rotational=True)
    assert np.allclose([g3.a, g3.gamma1, g3.gamma2, g3.gamma3], [10, 5000, 10000, 1000])
    assert g3.dof_scale == (1.0, 1.0, 1.0)
    assert np.allclose(scaled_initp(jhu_p).theta, INITP_6DOF.theta)
    blue_p = load_vehicle("bluerov2-heavy").params
    blue = np.diag(blue_p.M)
    g = scaled_aid_gains(blue)
    assert (g.a, g.gamma1, g.gamma2, g.gamma3, g.gamma4) == (10.0, 5000.0, 20000.0, 2000.0,
                                                             2000.0)
    assert np.allclose(g.dof_scale, blue / jhu)  # each DOF's own mass ratio
    gf = scaled_aid_gains(blue, factors=(10.0, 3.0))
    assert np.allclose(gf.dof_scale, blue / jhu * [10, 10, 10, 3, 3, 3])
    p = scaled_initp(blue_p)
    assert np.allclose(np.diag(p.M), 100 * blue / jhu)
    d = [blue_p.D[i][i, i] / jhu_p.D[i][i, i] for i in range(6)]
    assert all(np.allclose(np.diag(p.D[i]), -100 * np.array(d)) for i in range(6))
    assert p.b[2] == pytest.approx(100 * 1.31 / 300) and p.g == 0.0
    p.validate(where="scaled INITP")
    custom = scaled_aid_gains(blue, base=AID6Gains(5.0, 1.0, 2.0, 3.0, 4.0))
    assert custom.a == 5.0 and custom.gamma3 == 3.0 and custom.dof_scale == g.dof_scale
    with pytest.raises(ValueError, match="positive"):
        scaled_aid_gains(np.array([1.0, 1, 1, 1, 1, 0]))
    with pytest.raises(ValueError, match="factors"):
        scaled_aid_gains(blue, factors=(1.0, -1.0))
    with pytest.raises(ValueError, match="dof_scale"):
        AID6Gains(dof_scale=(1.0,) * 5)
    assert AID3Gains() == scaled_aid_gains(jhu, rotational=True, base=AID3Gains())


def test_runtime_aid_starts_scaled_unless_switched_off():
    import tomllib

    from uvd.estimation.aid import INITP_6DOF, JHU_MASSES, AID6Gains, scaled_initp
    from uvd.runtime.build import aid_theta0
    from uvd.runtime.config import parse_config

    src = REPO / "config" / "sim-bluerov2.toml"
    doc = tomllib.loads(src.read_text())
    doc.setdefault("estimation", {})["aid"] = True
    cfg = parse_config(doc, source=src)
    v = cfg.load_vehicle()
    assert np.allclose(aid_theta0(cfg, v), scaled_initp(v.params).theta)
    g = cfg.estimation.aid_params(v).gains
    assert g.gamma1 == 5000.0 and np.allclose(g.dof_scale, np.diag(v.params.M) / JHU_MASSES)
    doc["estimation"]["gain_factors"] = [10, 3]
    g = parse_config(doc, source=src).estimation.aid_params(v).gains
    assert np.allclose(g.dof_scale, np.diag(v.params.M) / JHU_MASSES * [10, 10, 10, 3, 3, 3])
    doc["estimation"]["scale_to_vehicle"] = False
    cfg = parse_config(doc, source=src)
    assert aid_theta0(cfg, v) is None  # INITP
    assert cfg.estimation.aid_params(v).gains == AID6Gains()
    assert INITP_6DOF.M[0, 0] == 100.0


@pytest.mark.parametrize("storage", ["SQLITE3", "MCAP"])
def test_ros2_bag_and_cdr_mcap(tmp_path, storage):
    """A ROS 2 bag written by rosbags (sqlite3 or MCAP storage) reads through the registry, as
    a bag folder and, for MCAP, as the bare .mcap file (CDR decoded from its own schema)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    F = ts.types["std_msgs/msg/Float64MultiArray"]
    L = ts.types["std_msgs/msg/MultiArrayLayout"]
    bag = tmp_path / "bag"
    with Writer(bag, version=8, storage_plugin=getattr(StoragePlugin, storage)) as w:
        c = w.add_connection("/x", F.__msgtype__, typestore=ts)
        for k in range(10):
            msg = F(layout=L(dim=[], data_offset=0), data=np.array([k, 1.0, 2.0]))
            w.write(c, k * 10**8, ts.serialize_cdr(msg, F.__msgtype__))
    assert detect_format(bag) == "ros2"
    assert count_messages(bag) == Counter({"/x": 10})
    got = [(t, list(m.data)) for _tp, t, m in open_log(bag)]
    assert got[3] == (3 * 10**8, [3.0, 1.0, 2.0])
    if storage == "MCAP":
        f = next(bag.glob("*.mcap"))
        assert [(t, list(m.data)) for _tp, t, m in open_log(f)] == got


@pytest.mark.timeout(240)
def test_identify_ardusub_bin_end_to_end(tmp_path, capsys):
    """The idle ArduSub dataflash log through ardusub-bin and the BlueROV2 vehicle file: BARO
    instance 1 only (match), the translation refused, and the warning that the constraint, not
    the data, set the estimate (a log with PWM 1492-1508 excites nothing)."""
    from uvd.cli import main

    _need(ARDUSUB)
    rc = main(["identify", "--log", str(ARDUSUB / "small.BIN"), "--profile", "ardusub-bin",
               "--vehicle", "bluerov2-heavy", "--method", "ls-consistent", "--quiet",
               "--out", str(tmp_path / "p.toml")])
    assert rc == 0
    out = capsys.readouterr().out
    assert re.search(r"depth\s+BARO\s+237 msgs.* 0 duplicates", out)
    assert "REFUSED surge, sway, heave" in out
    assert "WARNING: the fit rests on its consistency bound for I" in out


def test_profile_match_validated():
    doc = _profile_doc("ardusub-bin")
    assert load_profile("ardusub-bin").signals["depth"].match == (("I", 1),)
    doc["signals"]["depth"]["match"] = [1]
    with pytest.raises(ConfigError, match=r"\[signals.depth\]: match must be a table"):
        profile_from_mapping(doc, where="p")


def test_aid_demo_series_reads_the_estimates_of_a_recorded_run(tmp_path):
    """The AID figure of docs/real-vehicles.md reads a `uvd demo --record` folder: the run's
    configuration (its vehicle's truth, AID settings) and the "estimate" records of its
    telemetry, in time order; a run without AID is a named error."""
    import json
    import shutil

    from uvd.estimation.aid import aid6_init, aid_diagnostics, scaled_initp
    from uvd.experiments.real_vehicles import aid_demo_series
    from uvd.jsonio import to_jsonable
    from uvd.telemetry.records import estimate_record

    run = tmp_path / "run"
    run.mkdir()
    cfg = (REPO / "config" / "sim-bluerov2.toml").read_text()
    (run / "uvd.toml").write_text(cfg + "\n[estimation]\naid = true\ngain_factors = [10, 3]\n")
    truth = load_vehicle("bluerov2-heavy").params
    st0 = aid6_init(scaled_initp(truth))
    st1 = aid6_init(truth)
    lines = [json.dumps({"type": "cycle", "t_ns": 1}),
             json.dumps(to_jsonable(estimate_record(2_000_000_000, "aid6", aid_diagnostics(st0)))),
             json.dumps(to_jsonable(estimate_record(3_500_000_000, "aid6", aid_diagnostics(st1))))]
    (run / "telemetry.jsonl").write_text("\n".join(lines) + "\n")
    s = aid_demo_series(run)
    assert s["t"] == [0.0, 1.5]
    assert np.allclose(s["M_diag"][0], np.diag(scaled_initp(truth).M))
    assert np.allclose(s["M_diag"][1], s["M_diag_truth"]) and s["g_b"][1][3] == 1.31
    assert s["settings"]["gain_factors"] == [10.0, 3.0] and not s["frozen"]
    shutil.copy(run / "uvd.toml", tmp_path / "uvd.toml")
    (tmp_path / "telemetry.jsonl").write_text(lines[0] + "\n")
    with pytest.raises(ValueError, match="no AID estimate records"):
        aid_demo_series(tmp_path)


@pytest.mark.parametrize("stamp", ['"12:00"', "null", "[1]", "true", "NaN", "Infinity", "1e400"])
def test_a_telemetry_record_whose_time_is_not_one_costs_its_own_sample(tmp_path, stamp):
    # found by probing (session 21): uvd's own JSON-lines telemetry read through a profile
    # took int() of t_ns: a ValueError, TypeError or OverflowError traceback from identify
    f = tmp_path / "telemetry.jsonl"
    lines = [f'{{"type": "cycle", "t_ns": {k * 100_000_000}, "x": {k}.0}}' for k in range(10)]
    lines[4] = lines[4].replace('"t_ns": 400000000', f'"t_ns": {stamp}')
    f.write_text("\n".join(lines) + "\n")
    assert [t for _topic, t, _m in open_log(f, "uvd-telemetry")] == \
        [k * 100_000_000 for k in range(10) if k != 4][:4] + [None] + \
        [k * 100_000_000 for k in range(5, 10)]


@pytest.mark.parametrize("head, what", [
    ("thrusters = 5", "thrusters must be an array of tables ([[thrusters]]), got int 5"),
    ('thrusters = ["a", "b", "c", "d", "e", "f"]', "thrusters[0] must be a table, got str 'a'"),
    ("thrusters = {a = 1}", "thrusters must be an array of tables ([[thrusters]]), got dict "
                            "{'a': 1}"),
    ("thruster_defaults = 5", "[thruster_defaults] must be a table, got int 5"),
    ("thrust_curves = 5", "[thrust_curves] must be a table, got int 5"),
    ("thrust_curves = {t200 = [1]}", "[thrust_curves.t200] must be a table, got list [1]"),
])
def test_vehicle_tables_that_are_not_tables_are_named(tmp_path, capsys, head, what):
    # found by probing (session 21): tracebacks ('int' object is not iterable, 'int' object
    # has no attribute 'items') or a text or a table taken letter by letter, key by key as
    # "thrusters[0]: unknown key(s) ['a']"
    from uvd.cli import main
    src = (REPO / "uvd" / "vehicles" / "bluerov-exjobb.toml").read_text()
    key = head.split(" = ")[0]
    src = re.sub(rf"(?ms)^\[+{key}\]+\n.*?(?=^\[|\Z)", "", src)  # the file's own goes
    assert f"[{key}]" not in src
    bad = tmp_path / "v.toml"
    bad.write_text(head + "\n" + src)
    with pytest.raises(ConfigError) as e:
        load_vehicle(bad)
    assert str(e.value) == f"{bad}: {what}"
    assert main(["identify", "--log", str(tmp_path / "x.bag"), "--profile",
                 "bluerov-exjobb-april", "--vehicle", str(bad), "--method", "ls",
                 "--out", str(tmp_path / "o.toml")]) == 2
    assert capsys.readouterr().err == f"uvd identify: error: {e.value}\n"
