"""The CAN bus: error frames, bus states, full queues, reopening, udp_multicast confinement."""

from __future__ import annotations

import errno
import json
import shutil
import subprocess
import sys
import textwrap
import time
import uuid

import can
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.can import bus as b
from drivers.can.amplifier import AmplifierGroup
from drivers.can.config import AmplifierConfig, CanBusConfig
from sim_bridge.amplifiers.harness import local_group
from uvd.errors import BusError, TransportError
from uvd.io.vehicle import load_vehicle
from uvd.netports import free_port

VEHICLE = load_vehicle("jhu-rov")


def vcfg(**kw) -> CanBusConfig:
    return CanBusConfig(interface="virtual", channel=f"uvd-{uuid.uuid4().hex[:10]}", **kw)


class FakeClock:
    def __init__(self):
        self.t = 1_000_000_000

    def __call__(self):
        return self.t

    def advance(self, s: float):
        self.t += int(s * 1e9)


# --- error frames ---------------------------------------------------------------------------

@pytest.mark.parametrize("frame,state,classes", [
    (b.make_error_frame(b.CAN_ERR_BUSOFF), b.BUS_OFF, ("bus_off",)),
    (b.make_error_frame(b.CAN_ERR_CRTL, b.CAN_ERR_CRTL_TX_PASSIVE), b.PASSIVE, ("controller",)),
    (b.make_error_frame(b.CAN_ERR_CRTL, b.CAN_ERR_CRTL_RX_WARNING), b.WARNING, ("controller",)),
    (b.make_error_frame(b.CAN_ERR_RESTARTED), b.ACTIVE, ("restarted",)),
    (b.make_error_frame(b.CAN_ERR_PROT, tx_errors=130, rx_errors=5), b.PASSIVE,
     ("protocol", "counters")),
    (b.make_error_frame(b.CAN_ERR_ACK, tx_errors=100), b.WARNING, ("no_ack", "counters")),
    (b.make_error_frame(b.CAN_ERR_PROT), None, ("protocol",)),
])
def test_error_frames_decode(frame, state, classes):
    info = b.decode_error_frame(frame)
    assert info.state == state and info.classes == classes


@given(cid=st.integers(0, 0x1FFFFFFF), data=st.binary(max_size=8))
def test_error_frame_decoding_never_raises(cid, data):
    msg = can.Message(arbitration_id=cid, data=data, is_error_frame=True)
    info = b.decode_error_frame(msg)
    assert info.state in (None, b.ACTIVE, b.WARNING, b.PASSIVE, b.BUS_OFF)


def test_monitor_bus_off_hold_off_probe_and_recovery():
    clock = FakeClock()
    m = b.BusMonitor(CanBusConfig(busoff_holdoff_s=0.2))
    m.on_error_frame(b.decode_error_frame(b.make_error_frame(b.CAN_ERR_BUSOFF)), clock())
    assert m.state == b.BUS_OFF and not m.allow_send(clock())
    clock.advance(0.19)
    assert not m.allow_send(clock())
    clock.advance(0.02)
    assert m.allow_send(clock())  # probe
    m.on_rx(clock())
    assert m.state == b.BUS_OFF  # a frame alone proves nothing: our probe must get out
    m.on_send_ok(clock())
    m.on_rx(clock())
    assert m.state == b.ACTIVE and m.busoff_count == 1


def test_monitor_bus_off_from_send_failures_alone():
    clock = FakeClock()
    m = b.BusMonitor(CanBusConfig(busoff_send_failures=4))
    for _ in range(3):
        m.on_send_failed(clock())
    assert m.state == b.ACTIVE
    m.on_send_failed(clock())
    assert m.state == b.BUS_OFF and "4 sends failed" in m.reason


def test_monitor_error_passive_from_a_burst_of_bus_errors_then_back():
    clock = FakeClock()
    m = b.BusMonitor(CanBusConfig(error_passive_frames=8))
    info = b.decode_error_frame(b.make_error_frame(b.CAN_ERR_PROT))
    for _ in range(7):
        m.on_error_frame(info, clock())
        clock.advance(0.01)
    assert m.state == b.ACTIVE
    m.on_error_frame(info, clock())
    assert m.state == b.PASSIVE
    clock.advance(0.5)
    m.tick(clock())
    assert m.state == b.PASSIVE
    clock.advance(0.6)
    m.tick(clock())
    assert m.state == b.ACTIVE


def test_monitor_trusts_interface_state_only_to_escalate():
    clock = FakeClock()
    m = b.BusMonitor(CanBusConfig())
    m.tick(clock(), b.BUS_OFF)
    assert m.state == b.BUS_OFF
    m.tick(clock(), b.ACTIVE)
    assert m.state == b.BUS_OFF


# --- opening --------------------------------------------------------------------------------

def test_unknown_interface_is_a_clear_error():
    with pytest.raises(b.BusOpenError) as exc:
        b.open_bus(CanBusConfig(interface="no_such_iface", channel="x"))
    assert "no_such_iface" in str(exc.value) and exc.value.__cause__ is not None
    assert isinstance(exc.value, BusError) and isinstance(exc.value, TransportError)
    assert isinstance(exc.value, OSError)


def test_a_socketcan_bus_that_cannot_open_says_what_to_do():
    # a kernel without SocketCAN (this machine's: EAFNOSUPPORT) or without the interface
    # (ENODEV): python-can's bare "[Errno 97] Address family not supported by protocol"
    # left the operator to guess
    with pytest.raises(b.BusOpenError) as exc:
        b.open_bus(CanBusConfig(interface="socketcan", channel="uvdnone9"))
    code = exc.value.__cause__.errno
    assert code in (errno.EAFNOSUPPORT, errno.ENODEV), exc.value
    said = str(exc.value)
    assert ("modprobe can_raw" in said if code == errno.EAFNOSUPPORT
            else "no network interface uvdnone9 (ip -details link show" in said), said
    # another interface's errors are python-can's own words
    assert b._socketcan_hint(CanBusConfig(interface="pcan", channel="x"),
                             OSError(errno.ENODEV, "x")) == ""
    assert "systemd's SystemCallFilter=" in b._socketcan_hint(
        CanBusConfig(interface="socketcan", channel="can1"), OSError(errno.EPERM, "no"))


def test_udp_multicast_is_opened_with_hop_limit_zero_and_drops_its_echo():
    cfg = CanBusConfig(interface="udp_multicast", channel=local_group(),
                       port=free_port("udp", "::1"))
    with b.CanBus(cfg) as ours:
        assert b.udp_hop_limit(ours.python_can_bus) == 0
        peer = can.Bus(interface="udp_multicast", channel=cfg.channel, port=cfg.port,
                       hop_limit=0)
        try:
            for i in range(20):
                assert ours.send(can.Message(arbitration_id=0x200 + i, data=[i],
                                             is_extended_id=False))
            got = [peer.recv(1.0) for _ in range(20)]
            assert [m.arbitration_id for m in got if m] == [0x200 + i for i in range(20)]
            peer.send(can.Message(arbitration_id=0x7E5, data=[1], is_extended_id=False))
            deadline = time.monotonic() + 2.0
            while ours.status().counters["rx_frames"] < 1 and time.monotonic() < deadline:
                time.sleep(0.01)
            c = ours.status().counters
            assert c["rx_echo"] == 20 and c["rx_frames"] == 1 and c["rx_unknown"] == 1
        finally:
            peer.shutdown()


# --- sending: never blocks, never queues, never repeats by itself ----------------------------

def test_full_queue_drops_frames_counts_them_and_raises_faults():
    cfg = vcfg(busoff_send_failures=10, busoff_holdoff_s=0.1)
    bus = b.CanBus(cfg).open()
    # a peer that never reads, with room for one frame: the virtual bus is then "full"
    stuck = can.Bus(interface="virtual", channel=cfg.channel, rx_queue_size=1)
    try:
        group = AmplifierGroup(bus, AmplifierConfig(max_failed_cycles=3), VEHICLE.thrusters)
        t0 = time.monotonic()
        statuses = [group.write(np.full(6, 10.0)) for _ in range(5)]
        assert time.monotonic() - t0 < 0.5  # no send waited for room
        assert statuses[0].sent == 1 and statuses[0].dropped == 6
        assert all(s.sent == 0 and s.dropped == 7 for s in statuses[1:])
        c = bus.status().counters
        # 10 full-queue failures in a row, then the bus is taken as bus-off and held
        assert c["tx_full"] == 10 and c["tx_busoff_held"] == 6 + 4 * 7 + 1 - 10
        assert bus.status().state == b.BUS_OFF
        assert group.read().faults[0] == ("bus_off", "send_failed")
        assert stuck.recv(0.0) is not None and stuck.recv(0.0) is None  # nothing queued
        stuck.shutdown()  # room again; after the hold-off the next cycle probes the bus
        time.sleep(0.12)
        assert group.write(np.zeros(6)).ok
        life = can.Bus(interface="virtual", channel=cfg.channel)  # a node speaks again
        life.send(can.Message(arbitration_id=0x701, data=[5], is_extended_id=False))
        life.shutdown()
        deadline = time.monotonic() + 1.0
        while bus.status().state != b.ACTIVE and time.monotonic() < deadline:
            time.sleep(0.01)
        assert group.write(np.zeros(6)).ok
        assert 0 not in group.read().faults
    finally:
        bus.close()


def test_nothing_is_ever_sent_periodically():
    cfg = vcfg()
    bus = b.CanBus(cfg).open()
    try:
        group = AmplifierGroup(bus, AmplifierConfig(), VEHICLE.thrusters)
        for _ in range(5):
            group.write(np.zeros(6))
        assert bus.python_can_bus._periodic_tasks == []
        task = bus.network.send_periodic(0x200, b"\x00", 0.01)
        task.update(b"\x01")
        task.stop()
        assert bus.status().counters["periodic_refused"] == 1
        assert bus.python_can_bus._periodic_tasks == []
    finally:
        bus.close()


def test_interface_failure_reopens_the_bus_with_backoff(monkeypatch):
    # a backoff long against a loaded machine's scheduling: two polls in a row must fall in it
    cfg = vcfg(reopen_after_s=0.05, reopen_backoff_s=(0.5, 1.0))
    bus = b.CanBus(cfg).open()
    peer = can.Bus(interface="virtual", channel=cfg.channel)
    try:
        msg = can.Message(arbitration_id=0x100, data=[1], is_extended_id=False)
        bus.python_can_bus.shutdown()  # the interface goes away under us
        assert not bus.send(msg)
        assert bus.status().counters["tx_failed"] == 1
        time.sleep(0.08)
        real_open = b.open_bus
        monkeypatch.setattr(b, "open_bus", lambda c: (_ for _ in ()).throw(
            b.BusOpenError("still down")))
        assert bus.poll().state == b.CLOSED  # attempt 1 failed
        assert bus.status().counters["reopen_failures"] == 1
        assert bus.poll().state == b.CLOSED  # backing off: no attempt yet
        assert bus.status().counters["reopen_failures"] == 1
        monkeypatch.setattr(b, "open_bus", real_open)
        time.sleep(0.55)
        assert bus.poll().state == b.ACTIVE
        assert bus.status().counters["reopens"] == 1
        assert bus.send(msg)
        assert peer.recv(1.0).arbitration_id == 0x100
    finally:
        peer.shutdown()
        bus.close()


def test_a_closed_bus_is_not_reopened():
    bus = b.CanBus(vcfg(reopen_after_s=0.01)).open()
    bus.close()
    time.sleep(0.02)
    assert bus.poll().state == b.CLOSED and bus.status().counters["reopens"] == 0


# --- confinement of udp_multicast to this machine -------------------------------------------

CONFINE = textwrap.dedent('''
    import json, socket, struct, subprocess, threading, time
    import can
    from drivers.can.bus import CanBus
    from drivers.can.config import CanBusConfig

    def sh(cmd):
        subprocess.run(cmd, shell=True, check=True, capture_output=True)

    sh("sysctl -qw net.ipv6.conf.all.accept_dad=0 net.ipv6.conf.default.accept_dad=0")
    sh("ip link set lo up && ip link add v0 type veth peer name v1")
    sh("ip link set v0 up && ip link set v1 up")
    sh("ip -6 addr add fd00:75::1/64 dev v0 nodad && ip -6 addr add fd00:75::2/64 dev v1 nodad")
    time.sleep(0.3)
    captured = []
    sniff = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(0x0003))
    sniff.settimeout(0.05)
    stop = threading.Event()
    def run():
        while not stop.is_set():
            try:
                data, addr = sniff.recvfrom(65535)
            except socket.timeout:
                continue
            if addr[0] != "lo":
                captured.append(data)
    threading.Thread(target=run, daemon=True).start()

    def udp_to(port):
        n = 0
        for p in captured:
            if len(p) >= 62 and p[12:14] == b"\\x86\\xdd" and p[20] == 17 \\
                    and struct.unpack("!H", p[56:58])[0] == port:
                n += 1
        return n

    def mentions(group):
        g = socket.inet_pton(socket.AF_INET6, group)
        return sum(1 for p in captured if g in p)

    out = {}
    tx = can.Bus(interface="udp_multicast", channel="ff15::7576:1", port=47001, hop_limit=1)
    for i in range(20):
        tx.send(can.Message(arbitration_id=0x100 + i, data=b"ctrl", is_extended_id=False))
    time.sleep(0.3)
    out["control_udp"] = udp_to(47001)
    tx.shutdown()
    cfg = CanBusConfig(interface="udp_multicast", channel="ff11::7576:1", port=47002)
    a = CanBus(cfg).open()
    r = CanBus(cfg).open()
    got = []
    r.network.subscribe(0x123, lambda *x: got.append(x))
    for i in range(20):
        a.send(can.Message(arbitration_id=0x123, data=bytes([i]), is_extended_id=False))
    time.sleep(0.3)
    out["uvd_received"] = len(got)
    out["uvd_udp"] = udp_to(47002)
    out["uvd_group_mentions"] = mentions("ff11::7576:1")
    a.close(); r.close(); stop.set()
    print(json.dumps(out))
''')


@pytest.mark.timeout(60)
def test_udp_multicast_datagrams_never_leave_the_machine(tmp_path):
    """In a private network namespace with a veth pair standing in for the machine's network
    interfaces: a site-scope group (the control) does appear on them; uvd's interface-local
    group, hop limit 0, is delivered locally and never appears on any interface but lo — not
    even as an MLD membership report."""
    unshare = shutil.which("unshare")
    if unshare is None or subprocess.run([unshare, "--net", "true"]).returncode != 0:
        pytest.skip("needs `unshare --net` (root) for a private network namespace")
    if subprocess.run([unshare, "--net", "ip", "link", "add", "v0", "type", "veth", "peer",
                       "name", "v1"], capture_output=True).returncode != 0:
        pytest.skip("no veth support in this kernel")
    script = tmp_path / "confine.py"
    script.write_text(CONFINE)
    res = subprocess.run([unshare, "--net", sys.executable, str(script)], capture_output=True,
                         text=True, timeout=50)
    assert res.returncode == 0, res.stderr[-2000:]
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["control_udp"] >= 20  # the sniffer sees what does leave
    assert out["uvd_received"] == 20  # uvd's frames are delivered locally
    assert out["uvd_udp"] == 0 and out["uvd_group_mentions"] == 0
