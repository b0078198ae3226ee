"""``uvd bench can``: the CAN amplifier exchange, timed (figures only, never asserted).

* ``encode_send_us`` — one command cycle (encode and send six RPDOs + SYNC, heartbeat when
  due): :meth:`AmplifierGroup.write`, on an in-process ``virtual`` bus and on
  ``udp_multicast``;
* ``decode_six_tpdo_us`` — six TPDOs through the receive dispatcher, canopen's PDO decoding
  and the driver's callbacks;
* ``round_trip_ms`` — command → emulated feedback over ``udp_multicast``: from the start of a
  cycle's write to the arrival of the last of the six TPDOs answering its SYNC (the emulators
  in a second process);
* ``exchange`` — ``--duration`` s (60 by default) at ``--rate`` Hz (100) with the emulators in
  that second process: cycles, feedback frames lost, cycles whose feedback came late (after
  the next cycle had started), commands lost, period jitter;
* ``command_timeout`` — then the command stream stops: when each emulated amplifier zeroed its
  output (its own measurement) and when the driver saw each EMCY, after the last command;
* ``fault_detection`` — a fault injected on one node while cycling: cycles until the driver
  reports it by name.

By default the process asks for SCHED_FIFO priority (as a vehicle's daemon would run) and so
do the emulators; ``--no-realtime`` measures at normal priority. ``scheduling`` in the output
says which applied. Both freeze the garbage collector's view of their start-up objects
(``gc.freeze()``), as a real-time daemon should: a full collection of the ~60 000 objects the
libraries leave behind takes ~50 ms, five cycles.
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import time
import uuid

import numpy as np

from uvd.bench import Bench, percentiles
from uvd.cliargs import positive_float, positive_int


def _add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duration", type=positive_float, default=60.0,
                   help="seconds of the 100 Hz exchange over udp_multicast (default 60)")
    p.add_argument("--rate", type=positive_float, default=100.0,
                   help="cycle rate, Hz (default 100)")
    p.add_argument("--samples", type=positive_int, default=2000,
                   help="cycles for the in-process encode/decode timings (default 2000)")
    p.add_argument("--no-realtime", dest="realtime", action="store_false",
                   help="do not ask for SCHED_FIFO priority")


def _realtime(on: bool) -> str:
    if not on:
        return "other"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
        return "fifo/10"
    except (OSError, AttributeError):
        return "other (SCHED_FIFO not permitted)"


def _encode_decode(samples: int) -> dict:
    import can  # here, not at the top: the command line registers every bench

    from drivers.can import cia402
    from drivers.can.amplifier import AmplifierGroup
    from drivers.can.bus import CanBus
    from drivers.can.config import AmplifierConfig, CanBusConfig
    from uvd.io.vehicle import load_vehicle

    thrusters = load_vehicle("jhu-rov").thrusters
    cfg = CanBusConfig(interface="virtual", channel=f"bench-{uuid.uuid4().hex[:8]}")
    bus = CanBus(cfg).open()
    sink = can.Bus(interface="virtual", channel=cfg.channel)
    try:
        group = AmplifierGroup(bus, AmplifierConfig(), thrusters)
        cmd = np.linspace(-50, 50, 6)
        enc = []
        for i in range(samples):
            st = group.write(cmd * np.sin(i / 50))
            enc.append(st.duration_ns / 1e9)
            while sink.recv(0) is not None:
                pass
        sw = cia402.statusword_for(cia402.OPERATION_ENABLED).to_bytes(2, "little")
        tpdos = [can.Message(arbitration_id=0x180 + n, is_extended_id=False,
                             data=sw + (100 + n).to_bytes(2, "little", signed=True)
                             + (12345 * n).to_bytes(4, "little", signed=True))
                 for n in range(1, 7)]
        dec = []
        for _ in range(samples):
            t0 = time.perf_counter_ns()
            for m in tpdos:
                bus._on_rx(m)
            dec.append((time.perf_counter_ns() - t0) / 1e9)
        ok = group.read().torque_permille.tolist() == [101, 102, 103, 104, 105, 106]
    finally:
        sink.shutdown()
        bus.close()
    return {"encode_send_virtual_us": percentiles(enc), "decode_six_tpdo_us": percentiles(dec),
            "decode_check": ok}


# _exchange is long (~130 lines) because it owns a second process and a bus for its whole
# duration: set-up, the timed exchange and the teardown share one try/finally.
def _exchange(duration_s: float, rate_hz: float, realtime: bool) -> dict:
    from drivers.can.amplifier import AmplifierGroup
    from drivers.can.bus import CanBus
    from drivers.can.config import AmplifierConfig
    from sim_bridge.amplifiers.harness import start_rig
    from uvd.io.vehicle import load_vehicle

    vehicle = load_vehicle("jhu-rov")
    n = vehicle.n_thrusters
    rig = start_rig("udp_multicast", pressure_node=None, duration_s=duration_s + 120,
                    realtime=realtime)
    out: dict = {"emulators_realtime": bool(rig.handle.ready.get("realtime"))}
    bus = CanBus(rig.bus_cfg).open()
    try:
        group = AmplifierGroup(bus, AmplifierConfig(), vehicle.thrusters)
        t0 = time.monotonic()
        report = group.start()
        out["start_s"] = time.monotonic() - t0
        out["start_ok"] = report.ok
        t0 = time.monotonic()
        out["enabled"] = group.wait_enabled(2.0)
        out["enable_s"] = time.monotonic() - t0
        # what a real-time daemon does after start-up: the ~60k long-lived objects of the
        # libraries leave the collector's view, so that no full collection (~50 ms) stalls
        # a cycle
        gc.collect()
        gc.freeze()
        # -- the exchange --
        period = 1.0 / rate_hz
        cycles = int(duration_s * rate_hz)
        amp = 0.25 * vehicle.max_thrust_n
        phase = np.arange(n)
        write_s, rtt_s, periods, late = [], [], [], 0
        syncs0 = group.counters["syncs_sent"]
        rx0 = dict(group.stats()["tpdo_rx_by_node"])
        emu0 = rig.call("stats")["nodes"]
        prev_start = None
        pending = None  # (t_start_ns, tpdo counts before)
        t_next = time.monotonic()
        for k in range(cycles):
            if pending is not None:
                t_start, counts = pending
                if all(nd.tpdo_count > counts[i] for i, nd in enumerate(group.nodes)):
                    rtt_s.append((max(nd.tpdo_ns for nd in group.nodes) - t_start) / 1e9)
                else:
                    late += 1
            counts = [nd.tpdo_count for nd in group.nodes]
            st = group.write(amp * np.sin(2 * np.pi * 0.2 * k * period + phase))
            pending = (st.t_ns, counts)
            write_s.append(st.duration_ns / 1e9)
            if prev_start is not None:
                periods.append((st.t_ns - prev_start) / 1e9)
            prev_start = st.t_ns
            t_next += period
            delay = t_next - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        last_end = st.t_ns + st.duration_ns  # the command stream stops here
        # -- command timeout: wait for every EMCY 0x8250 --
        emcy_ns: dict[int, int] = {}
        deadline = time.monotonic() + 1.0
        while len(emcy_ns) < n and time.monotonic() < deadline:
            for nd in group.nodes:
                with group._lock:
                    t = nd.emcy_active.get(0x8250)
                if t is not None:
                    emcy_ns.setdefault(nd.node_id, t)
            time.sleep(0.0005)
        stats = group.stats()
        emu = rig.call("stats")
        syncs = group.counters["syncs_sent"] - syncs0
        rx = {k: v - rx0[k] for k, v in stats["tpdo_rx_by_node"].items()}
        emu_nodes = emu["nodes"]
        rpdo_rx = {k: v["rpdo_rx"] - emu0[k]["rpdo_rx"] for k, v in emu_nodes.items()}
        no_cmd = {k: v["rpdo_missed"] - emu0[k]["rpdo_missed"] for k, v in emu_nodes.items()}
        out["exchange"] = {
            "duration_s": duration_s, "rate_hz": rate_hz, "cycles": cycles,
            "syncs_sent": syncs,
            "feedback_frames_expected": syncs * n,
            "feedback_frames_lost": int(sum(syncs - v for v in rx.values())),
            "cycles_feedback_late": late,
            "commands_sent": cycles * n,
            "commands_lost": int(sum(cycles - v for v in rpdo_rx.values())),
            "emulator_syncs_without_command": int(sum(no_cmd.values())),
            "send_failed_cycles": stats["send_failed_cycles"],
            "driver_bus": {k: v for k, v in stats["bus"].items() if v},
            "emulator_bus": {k: v for k, v in emu.get("bus", {}).items() if v},
            "encode_send_udp_us": percentiles(write_s),
            "period_ms": percentiles(periods, 1e3),
        }
        out["round_trip_ms"] = percentiles(rtt_s, 1e3)
        out["emulator_sync_ms"] = emu.get("sync_ms", {})
        out["command_timeout"] = {
            "configured_ms": group.cfg.command_timeout_ms,
            "emulator_zeroed_after_ms": {k: v["last_timeout_ms"] for k, v in emu_nodes.items()},
            "emcy_seen_after_ms": {k: (t - last_end) / 1e6 for k, t in sorted(emcy_ns.items())},
            "outputs_zero": all(v["thrust_command_n"] == 0.0 for v in emu_nodes.values()),
        }
        # -- fault detection within one cycle --
        group.reset_faults()
        group.wait_enabled(2.0)
        seen = []
        for trial in range(5):
            for _ in range(5):
                group.write(np.full(n, 10.0))
                time.sleep(period)
            node = 1 + trial % n
            t_inj = time.monotonic_ns()
            rig.call("fault", node=node, name="overcurrent")
            for c in range(1, 50):
                group.write(np.full(n, 10.0))
                time.sleep(period)
                if "overcurrent" in group.read().faults.get(node, ()):
                    with group._lock:
                        t_emcy = group.nodes[node - 1].emcy_active.get(0x2310, 0)
                    # cycles: writes until the next read() named it (1 = within one cycle);
                    # emcy_ms: from the injection request (a pipe to the other process) to
                    # the EMCY's arrival at the driver
                    seen.append({"node": node, "cycles": c, "emcy_ms": (t_emcy - t_inj) / 1e6})
                    break
            group.reset_faults()
            group.wait_enabled(2.0)
        out["fault_detection"] = seen
        group.shutdown()
    finally:
        gc.unfreeze()
        bus.close()
        rig.close()
    return out


def run(args: argparse.Namespace) -> dict:
    sched = _realtime(getattr(args, "realtime", True))
    sys.setswitchinterval(0.0005)
    figures: dict = {"scheduling": sched}
    gc.collect()
    gc.freeze()
    try:
        figures.update(_encode_decode(int(getattr(args, "samples", 2000))))
    finally:
        gc.unfreeze()
    figures.update(_exchange(float(getattr(args, "duration", 60.0)),
                             float(getattr(args, "rate", 100.0)),
                             realtime=getattr(args, "realtime", True)))
    return figures


BENCH = Bench(name="can",
              summary="CAN amplifiers: encode/send and decode per cycle, command→feedback "
                      "round trip and a 100 Hz exchange over udp_multicast (second process)",
              run=run, add_arguments=_add_arguments)
