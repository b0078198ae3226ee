"""Fuzz: random and malformed CAN frames never raise out of the driver, and are counted."""

from __future__ import annotations

import time
import uuid

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.can import cia402
from drivers.can.amplifier import AmplifierGroup
from drivers.can.bus import CAN_ERR_PROT, CanBus, make_error_frame
from drivers.can.config import AmplifierConfig, CanBusConfig, DepthConfig
from drivers.can.depth import CanDepthSensor
from sim_bridge.amplifiers.harness import realtime_priority, run_cycles, start_rig
from uvd.io.vehicle import load_vehicle

VEHICLE = load_vehicle("jhu-rov")
NODES = (1, 2, 3, 4, 5, 6)
# every COB-ID the driver listens to, plus neighbours
KNOWN = sorted({base + n for n in (*NODES, 32) for base in (0x80, 0x180, 0x580, 0x700)}
               | {0x000, 0x080, 0x181 + 0x100, 0x7E5})
BUCKETS = ("rx_error_frames", "rx_remote", "rx_extended", "rx_fd", "rx_malformed", "rx_unknown")


@pytest.fixture(scope="module")
def driver():
    cfg = CanBusConfig(interface="virtual", channel=f"uvd-fuzz-{uuid.uuid4().hex[:8]}")
    bus = CanBus(cfg).open()
    group = AmplifierGroup(bus, AmplifierConfig(), VEHICLE.thrusters)
    depth = CanDepthSensor(bus, DepthConfig(enabled=True))
    yield bus, group, depth
    bus.close()


frames = st.one_of(
    st.builds(lambda cid, data: can.Message(arbitration_id=cid, data=data, is_extended_id=False),
              st.sampled_from(KNOWN), st.binary(max_size=8)),
    st.builds(lambda cid, data: can.Message(arbitration_id=cid, data=data, is_extended_id=False),
              st.integers(0, 0x7FF), st.binary(max_size=8)),
    st.builds(lambda cid, data: can.Message(arbitration_id=cid, data=data, is_extended_id=True),
              st.integers(0, 0x1FFFFFFF), st.binary(max_size=8)),
    st.builds(lambda cid, dlc: can.Message(arbitration_id=cid, is_remote_frame=True, dlc=dlc,
                                           is_extended_id=False),
              st.sampled_from(KNOWN), st.integers(0, 8)),
    st.builds(lambda cid, data: can.Message(arbitration_id=cid, data=data, is_error_frame=True),
              st.integers(0, 0x1FFFFFFF), st.binary(max_size=8)),
    st.builds(lambda cid, data: can.Message(arbitration_id=cid, data=data, is_fd=True,
                                            is_extended_id=False),
              st.sampled_from(KNOWN), st.binary(min_size=9, max_size=64)),
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(batch=st.lists(frames, min_size=1, max_size=30))
def test_random_frames_never_raise_and_every_frame_is_counted(driver, batch):
    bus, group, depth = driver
    before = bus.status().counters
    for msg in batch:
        bus._on_rx(msg)  # the dispatcher the notifier thread calls
    after = bus.status().counters
    assert after["rx_frames"] - before["rx_frames"] == len(batch)
    assert after["rx_callback_errors"] == 0
    dropped = sum(after[k] - before[k] for k in BUCKETS)
    wellformed = [m for m in batch if not (m.is_error_frame or m.is_remote_frame
                                           or m.is_extended_id or m.is_fd)]
    assert dropped >= len(batch) - len(wellformed)
    # the driver still answers, whatever it was fed
    fb = group.read()
    assert fb.omega_rad_s.shape == (6,) and np.isfinite(fb.omega_rad_s).all()
    assert group.write(np.full(6, 1.0)).cycle > 0
    assert depth.latest() is None or np.isfinite(depth.latest().pressure_pa)


def test_malformed_frames_are_dropped_before_decoding(driver):
    bus, group, _ = driver
    node = group.nodes[2]  # node 3
    with group._lock:
        sw_before = node.statusword
    base = dict(bus.malformed_by_id)
    for data in (b"", b"\x27", b"\x27\x02\x00", b"\x27\x02\x00\x00\x00\x00\x00\x00\x00"[:7]):
        bus._on_rx(can.Message(arbitration_id=0x183, data=data, is_extended_id=False))
    bus._on_rx(can.Message(arbitration_id=0x83, data=b"\x10\x23", is_extended_id=False))  # EMCY
    bus._on_rx(can.Message(arbitration_id=0x703, data=b"", is_extended_id=False))  # heartbeat
    assert bus.malformed_by_id[0x183] - base.get(0x183, 0) == 4
    assert bus.malformed_by_id[0x83] - base.get(0x83, 0) == 1
    assert bus.malformed_by_id[0x703] - base.get(0x703, 0) == 1
    assert node.statusword == sw_before  # nothing half-decoded reached the state
    good = cia402.statusword_for(cia402.FAULT).to_bytes(2, "little") + bytes(6)
    bus._on_rx(can.Message(arbitration_id=0x183, data=good, is_extended_id=False))
    assert group.read().nodes[2].state == cia402.FAULT


@pytest.mark.timeout(60)
def test_junk_on_a_live_bus_does_not_disturb_the_exchange():
    """A third node floods the bus with junk while the driver commands the emulators."""
    with realtime_priority():
        _junk_exchange()


def _junk_exchange():
    rig = start_rig("virtual", pressure_node=None)
    bus = CanBus(rig.bus_cfg).open()
    junk = can.Bus(interface="virtual", channel=rig.bus_cfg.channel)
    try:
        group = AmplifierGroup(bus, AmplifierConfig(), VEHICLE.thrusters)
        assert group.start().ok and group.wait_enabled(2.0)
        rng = np.random.default_rng(7)
        sent = {"n": 0}

        def spray(i, _st):
            for _ in range(5):
                kind = rng.integers(5)
                if kind == 0:
                    m = can.Message(arbitration_id=int(rng.choice([0x181, 0x182, 0x83])),
                                    data=rng.integers(0, 256, int(rng.integers(0, 5)),
                                                      dtype=np.uint8).tobytes(),
                                    is_extended_id=False)  # wrong DLC on known ids
                elif kind == 1:
                    m = can.Message(arbitration_id=int(rng.integers(0x600, 0x680)),
                                    data=bytes(8), is_extended_id=False)  # unknown to us
                elif kind == 2:
                    m = make_error_frame(CAN_ERR_PROT)
                elif kind == 3:
                    m = can.Message(arbitration_id=int(rng.integers(0, 0x1FFFFFFF)),
                                    data=b"\x01", is_extended_id=True)
                else:
                    m = can.Message(arbitration_id=0x183, is_remote_frame=True, dlc=8,
                                    is_extended_id=False)
                junk.send(m)
                sent["n"] += 1

        cmd = np.array([30.0, -30.0, 20.0, -20.0, 10.0, -10.0])
        c0 = bus.status().counters
        run_cycles(group, 150, cmd, on_cycle=spray)
        # the exchange as it stands at its last cycle: read before anything waits, since a
        # drive rightly times out 300 ms after its last command (command_timeout_ms), and
        # the wait for the junk's counts below (up to 2 s on a loaded machine) sends none
        fb = group.read()

        def junk_counted():
            c = bus.status().counters
            return sum(c[k] - c0[k] for k in BUCKETS)

        deadline = time.monotonic() + 2.0
        while junk_counted() < sent["n"] and time.monotonic() < deadline:
            time.sleep(0.01)
        assert junk_counted() == sent["n"], str(bus.status().counters)
        c = bus.status().counters
        assert c["rx_malformed"] > 0 and c["rx_error_frames"] > 0 and c["rx_extended"] > 0
        assert c["rx_remote"] > 0 and c["rx_unknown"] > 0 and c["rx_callback_errors"] == 0
        # 150 bus-error frames in 1.5 s: the bus is (rightly) error-passive; still working
        assert fb.faults.get(0) in (None, ("error_passive",))
        # a drive timed out: how long it went without a command, by its own clock (seen once
        # in a loaded fresh clone's run, not reproduced beside two busy loops)
        assert set(fb.faults) <= {0}, (fb.faults, {k: v["last_timeout_ms"] for k, v in
                                                    rig.call("stats")["nodes"].items()})
        np.testing.assert_array_equal(fb.torque_permille, np.rint(cmd / 0.3))
        syncs = group.counters["syncs_sent"]
        deadline = time.monotonic() + 1.0
        while set(group.stats()["tpdo_rx_by_node"].values()) != {syncs} \
                and time.monotonic() < deadline:
            time.sleep(0.01)
        assert group.stats()["tpdo_rx_by_node"] == dict.fromkeys(NODES, syncs)
    finally:
        junk.shutdown()
        bus.close()
        rig.close()


@pytest.mark.timeout(60)
def test_a_speed_no_propeller_turns_at_is_not_valid_feedback(caplog):
    """A third sender's TPDO1 for node 1 — OPERATION ENABLED, velocity 2³¹−1 counts, 2.1e6
    rad/s on a 250 rad/s thruster — after the drive's own answer to the SYNC. On a running
    daemon such frames reached the cycle for 41 cycles as valid feedback, the estimators'
    applied wrench k ω|ω| ~ 2e10 N, uncounted. Now that read's feedback is not valid (the
    cycle gets no speeds: its last command stands in), counted and logged by node."""
    import logging
    import struct

    from uvd.runtime.can_component import actuator_status
    rig = start_rig("virtual", pressure_node=None)
    bus = CanBus(rig.bus_cfg).open()
    junk = can.Bus(interface="virtual", channel=rig.bus_cfg.channel)
    spoof = can.Message(arbitration_id=0x181, is_extended_id=False,
                        data=struct.pack("<Hhi", 0x0627, 0, 2 ** 31 - 1))
    cmd = np.full(6, 30.0)

    def counts(group) -> dict[int, int]:
        return dict(group.stats()["tpdo_rx_by_node"])

    def answered(group, before: dict[int, int]) -> bool:
        """Every drive answered the SYNC (bounded): each answers on its own, so node 1's
        answer says nothing of the others' (a loaded machine heard node 1's before them)."""
        deadline = time.monotonic() + 1.0
        while not all(counts(group)[k] > n for k, n in before.items()) \
                and time.monotonic() < deadline:
            time.sleep(0.002)
        return all(counts(group)[k] > n for k, n in before.items())

    try:
        group = AmplifierGroup(bus, AmplifierConfig(), VEHICLE.thrusters)
        assert group.start().ok and group.wait_enabled(2.0)
        run_cycles(group, 20, cmd)
        n = counts(group)
        group.write(cmd)
        assert answered(group, n)
        fb = group.read()
        assert fb.valid.all() and group.counters["implausible_speed"] == 0, fb
        n = counts(group)
        group.write(cmd)
        assert answered(group, n)
        with caplog.at_level(logging.WARNING, logger="drivers.can.amplifier"):
            junk.send(spoof)
            deadline = time.monotonic() + 1.0
            while group.read().omega_rad_s[0] < 1e6 and time.monotonic() < deadline:
                time.sleep(0.002)
            fb = group.read()
        assert fb.omega_rad_s[0] == pytest.approx((2 ** 31 - 1) * 1e-3)
        assert fb.valid.tolist() == [False] + [True] * 5, fb.valid
        assert group.counters["implausible_speed"] >= 1
        assert actuator_status(fb, 1).omega_rad_s is None  # the cycle gets no speeds
        assert any("node 1 (aft-port) 2.147e+06 rad/s" in r.getMessage()
                   for r in caplog.records), [r.getMessage() for r in caplog.records]
        # the drive's next answer is plausible again
        n = counts(group)
        group.write(cmd)
        assert answered(group, n)
        assert group.read().valid.all()
    finally:
        junk.shutdown()
        bus.close()
        rig.close()
