"""``uvd zero-thrust`` (the unit's ExecStopPost): zero-target RPDOs with controlword "disable
voltage" to every configured amplifier on the configured bus, through the CAN driver."""

from __future__ import annotations

import struct
from collections import Counter
from pathlib import Path

import can
import pytest

from uvd.cli import main
from uvd.commands.zero_thrust import zero_amplifiers
from uvd.runtime.config import load_config

SENSORS = """
[sensors.ins]
port = "/dev/ttyUSB0"
[sensors.dvl]
port = "/dev/ttyUSB1"
[sensors.depth]
port = "/dev/ttyUSB2"
"""


def config(tmp_path: Path, channel: str, extra: str = "") -> Path:
    p = tmp_path / "uvd.toml"
    p.write_text(SENSORS + f'[can]\ninterface = "virtual"\nchannel = "{channel}"\n' + extra)
    return p


def received(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (m := bus.recv(0.05)) is not None:
        out.append(m)
    return out


def test_zero_rpdos_reach_every_amplifier(tmp_path):
    path = config(tmp_path, "zt-1", "[can.amplifiers]\nnode_ids = [11, 12, 13, 14, 15, 16]\n")
    rx = can.Bus(interface="virtual", channel="zt-1")
    try:
        res = zero_amplifiers(load_config(path), cycles=4, period_s=0.001)
        msgs = received(rx)
    finally:
        rx.shutdown()
    assert res["nodes"] == [11, 12, 13, 14, 15, 16] and res["send_failed_cycles"] == 0
    rpdos = [m for m in msgs if 0x200 < m.arbitration_id < 0x280]
    per_node = Counter(m.arbitration_id - 0x200 for m in rpdos)
    assert per_node == {n: 4 for n in range(11, 17)}
    for m in rpdos:   # RPDO1 of drivers/can/amplifier.eds: controlword 0x6040, target torque 0x6071
        controlword, target = struct.unpack_from("<Hh", bytes(m.data))
        assert target == 0 and controlword == 0x0000     # "disable voltage"
    assert sum(m.arbitration_id == 0x80 for m in msgs) == 4          # a SYNC per cycle
    nmt = [bytes(m.data) for m in msgs if m.arbitration_id == 0]
    assert sorted(nmt) == sorted(bytes([0x80, n]) for n in range(11, 17))  # pre-operational
    assert res["frames_sent"] >= 4 * 7


def test_command_line(tmp_path, capsys):
    path = config(tmp_path, "zt-2")
    rx = can.Bus(interface="virtual", channel="zt-2")
    try:
        assert main(["zero-thrust", "--config", str(path), "--cycles", "2",
                     "--period", "0"]) == 0
        assert len([m for m in received(rx) if 0x200 < m.arbitration_id < 0x280]) == 12
    finally:
        rx.shutdown()
    # what was sent, not a claim of the drives' state: nothing here answers
    out = capsys.readouterr().out
    assert "amplifiers disabled" not in out
    assert "with \"disable voltage\", then NMT pre-operational (sent; no answer" in out, out
    bad = tmp_path / "bad.toml"
    bad.write_text(SENSORS + "[control]\nkp = -1\n")
    assert main(["zero-thrust", "--config", str(bad)]) == 2
    assert "control.kp" in capsys.readouterr().err
    nobus = tmp_path / "nobus.toml"
    nobus.write_text(SENSORS + '[can]\ninterface = "socketcan"\nchannel = "uvdnosuch0"\n')
    assert main(["zero-thrust", "--config", str(nobus)]) == 2
    assert "uvdnosuch0" in capsys.readouterr().err


def test_options_out_of_range_are_refused_before_anything_is_sent(tmp_path, capsys):
    """--cycles 0 and -1 used to run one cycle, --period nan and -1 none, and --period 1e308
    ended in an OverflowError traceback after the first frames (a sleep of that long)."""
    path = config(tmp_path, "zt-3")
    rx = can.Bus(interface="virtual", channel="zt-3")
    try:
        for option, bad in (("--cycles", "0"), ("--cycles", "-1"), ("--cycles", "101"),
                            ("--period", "nan"), ("--period", "-1"), ("--period", "1e308")):
            with pytest.raises(SystemExit) as exit_:
                main(["zero-thrust", "--config", str(path), option, bad])
            assert exit_.value.code == 2
            assert f"argument {option}: '{bad}' is not" in capsys.readouterr().err
        assert received(rx) == []
    finally:
        rx.shutdown()
