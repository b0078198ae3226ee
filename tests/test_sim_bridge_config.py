"""sim-bridge's own configuration, made from the daemon's file at the top layer: the bridge
answers where the daemon will look (ports, bus, nodes), for every shipped configuration."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from sim_bridge.config import BridgeConfig
from uvd.commands.sim_bridge import bridge_config
from uvd.runtime.config import load_config, shipped_configs


@pytest.mark.parametrize("name", shipped_configs())
def test_the_bridge_answers_where_the_daemon_looks(name):
    cfg = load_config(name)
    b = bridge_config(cfg)
    s = cfg.sensors
    assert b.serial_ports == {k: Path(p) for k, p in (
        ("ins", s.ins.port), ("dvl", s.dvl.port),
        ("depth", s.depth.port if s.depth.source == "serial" else None)) if p is not None}
    assert b.can == cfg.can  # the bus, the amplifiers' node ids and object dictionary
    assert b.vehicle.n_thrusters == len(cfg.can.amplifiers.node_ids)
    assert (b.trajectory, b.start_north_m, b.start_east_m) == (
        cfg.control.reference, cfg.navigation.initial_north_m, cfg.navigation.initial_east_m)
    assert b.ins_protocol == ("ascii" if s.ins.format == "phins-ascii" else "stdbin")
    assert b.depth == s.depth.conversion
    assert vars(b.instruments).items() >= vars(cfg.simulation.instruments).items()


def test_a_port_that_is_no_path_is_refused_by_name():
    b = bridge_config(load_config("sim"))
    with pytest.raises(ValueError, match=r"sensors.ins.port must be a path, not 'COM3'"):
        replace(b, serial_ports={"ins": "COM3"})
    with pytest.raises(ValueError, match="ins_protocol"):
        BridgeConfig(vehicle=b.vehicle, ins_protocol="nmea")
