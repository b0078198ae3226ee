"""The emulated drive's two timers (sim_bridge/amplifiers/node.py): when a late tick finds both
the command timeout and the consumed (daemon's) heartbeat run out, the one that ran out first
faults the drive — as on a drive whose timers run on their own, whatever the emulator thread's
lateness on a loaded machine (the fresh clone's test_bus_off_detected_and_recovered once saw
``daemon_heartbeat_lost`` where the 200 ms command timeout had run out first)."""

from __future__ import annotations

import uuid
from pathlib import Path

import can
import canopen
import pytest

from drivers.can import cia402
from sim_bridge.amplifiers.node import EmulatedAmplifier

EDS = Path(__file__).resolve().parents[1] / "drivers" / "can" / "amplifier.eds"
MS = 1_000_000


@pytest.fixture
def drive():
    net = canopen.Network(can.Bus(interface="virtual", channel=f"timers-{uuid.uuid4().hex}"))
    amp = EmulatedAmplifier(net, 3, EDS, index=0, thrust_per_permille_n=0.1, clock=lambda: 0)
    yield amp
    net.bus.shutdown()


def _both_run_out(amp, timeout_ms: int, consumer_ms: int, late_tick_ms: int) -> int:
    t0 = 1_000 * MS
    amp.state = cia402.OPERATION_ENABLED
    amp.command_timeout_ms = timeout_ms
    amp.consumer = (1, consumer_ms)
    amp.consumer_seen_ns = t0
    amp.last_rpdo_ns = t0
    amp.tick(t0 + late_tick_ms * MS)  # one late tick: both have run out
    assert amp.state == cia402.FAULT
    return amp.error_code


def test_the_command_timeout_that_ran_out_first_faults_the_drive(drive):
    assert _both_run_out(drive, 200, 300, 600) == cia402.FAULT_CODES["command_timeout"]
    assert drive.last_timeout_ms == 600.0


def test_the_heartbeat_that_ran_out_first_faults_the_drive(drive):
    assert _both_run_out(drive, 200, 100, 600) == cia402.FAULT_CODES["daemon_heartbeat_lost"]
