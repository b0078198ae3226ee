"""The [can] configuration: defaults, and errors that name the key."""

from __future__ import annotations

import pytest

from drivers.can.config import DEFAULT_UDP_GROUP, CanConfig
from uvd.errors import ConfigError


def test_defaults_are_a_valid_configuration():
    cfg = CanConfig.from_mapping(None)
    assert cfg.bus.interface == "socketcan" and cfg.amplifiers.node_ids == (1, 2, 3, 4, 5, 6)
    assert cfg.amplifiers.command_timeout_ms == 200 and cfg.bus.send_timeout_s == 0.0
    assert cfg.amplifiers.eds.is_file() and cfg.depth.eds.is_file()
    assert cfg.log.path is None


def test_a_full_table():
    cfg = CanConfig.from_mapping({
        "interface": "udp_multicast", "channel": DEFAULT_UDP_GROUP, "port": 40000,
        "amplifiers": {"node_ids": [11, 12, 13, 14, 15, 16], "mode": "pt",
                       "thrust_per_permille_n": [0.3] * 6},
        "depth": {"enabled": True, "node_id": 40},
        "log": {"path": "/tmp/x.blf", "max_bytes": 1000}})
    assert cfg.amplifiers.mode == "pt" and cfg.depth.node_id == 40
    assert cfg.log.path.suffix == ".blf"


@pytest.mark.parametrize("table,key", [
    ({"bitrate": 12}, "[can] bitrate"),
    ({"interface": ""}, "[can] interface"),
    ({"send_timeout_s": 1.0}, "[can] send_timeout_s"),
    ({"bogus": 1}, "[can]: unknown key(s) ['bogus']"),
    ({"interface": "udp_multicast", "channel": "239.74.163.2"}, "[can] channel"),
    ({"interface": "udp_multicast", "channel": "ff15::1"}, "[can] channel"),
    ({"interface": "udp_multicast", "channel": "not-an-ip"}, "[can] channel"),
    ({"amplifiers": {"node_ids": [1, 1, 2, 3, 4, 5]}}, "[can.amplifiers] node_ids"),
    ({"amplifiers": {"node_ids": [0, 2]}}, "[can.amplifiers] node_ids"),
    ({"amplifiers": {"mode": "csv"}}, "[can.amplifiers] mode"),
    ({"amplifiers": {"command_timeout_ms": 5}}, "[can.amplifiers] command_timeout_ms"),
    ({"amplifiers": {"master_node_id": 3}}, "[can.amplifiers] master_node_id"),
    ({"amplifiers": {"thrust_per_permille_n": [1.0]}}, "[can.amplifiers] thrust_per_permille_n"),
    ({"amplifiers": {"heartbeat_period_ms": 0}}, "[can.amplifiers] node_consumer_ms"),
    ({"amplifiers": {"wat": 0}}, "[can.amplifiers]: unknown key(s) ['wat']"),
    ({"depth": {"enabled": True, "node_id": 3}}, "[can.depth] node_id"),
    ({"depth": {"density_kg_m3": -1.0}}, "[can.depth] density_kg_m3"),
    ({"log": {"path": "/tmp/x.txt"}}, "[can.log] path"),
    ({"log": {"max_bytes": -1}}, "[can.log] max_bytes"),
    ({"amplifiers": [1, 2]}, "[can.amplifiers]: expected a table"),
])
def test_errors_name_the_key(table, key):
    with pytest.raises(ConfigError) as exc:
        CanConfig.from_mapping(table)
    assert key in str(exc.value)
    assert isinstance(exc.value, ValueError)


def test_a_network_group_is_allowed_only_deliberately():
    cfg = CanConfig.from_mapping({"interface": "udp_multicast", "channel": "239.74.163.2",
                                  "loopback_only": False})
    assert not cfg.bus.loopback_only
