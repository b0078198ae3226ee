"""The [can] configuration: defaults, conversion into the driver's dataclasses, and errors that
name the key (declared in uvd/runtime/config.py with the rest of the schema)."""

from __future__ import annotations

from pathlib import Path

import pytest

from drivers.can.config import DEFAULT_UDP_GROUP, AmplifierConfig, CanBusConfig, CanConfig
from uvd.runtime import schema
from uvd.runtime.config import CanSection


def build(table):
    return schema.build(CanSection, table, prefix="can")


def test_defaults_are_a_valid_configuration():
    sec, errors = build({})
    assert errors == []
    cfg = sec.convert()
    assert isinstance(cfg, CanConfig) and isinstance(cfg.bus, CanBusConfig)
    assert isinstance(cfg.amplifiers, AmplifierConfig)
    assert cfg == CanConfig()  # the driver's defaults are the configuration's defaults
    assert cfg.bus.interface == "socketcan" and cfg.amplifiers.node_ids == (1, 2, 3, 4, 5, 6)
    assert cfg.amplifiers.command_timeout_ms == 300 and cfg.bus.send_timeout_s == 0.0
    assert cfg.amplifiers.eds.is_file() and cfg.depth.eds.is_file()
    assert cfg.log.path is None


def test_a_full_table():
    sec, errors = build({
        "interface": "udp_multicast", "channel": DEFAULT_UDP_GROUP, "port": 40000,
        "reopen_backoff_s": [1, 4], "options": {"x": 1},
        "amplifiers": {"node_ids": [11, 12, 13, 14, 15, 16], "mode": "pt",
                       "thrust_per_permille_n": [0.3] * 6, "eds": "~/amp.eds"},
        "depth": {"enabled": True, "node_id": 40},
        "log": {"path": "/tmp/x.blf", "max_bytes": 1000}})
    assert errors == []
    cfg = sec.convert()
    assert cfg.amplifiers.mode == "pt" and cfg.depth.node_id == 40
    assert cfg.amplifiers.node_ids == (11, 12, 13, 14, 15, 16)
    assert cfg.amplifiers.eds == Path("~/amp.eds").expanduser()
    assert cfg.amplifiers.thrust_per_permille_n == (0.3,) * 6
    assert cfg.bus.reopen_backoff_s == (1.0, 4.0) and cfg.bus.options == {"x": 1}
    assert cfg.bus.port == 40000 and cfg.bus.is_udp_multicast
    assert cfg.log.path == Path("/tmp/x.blf") and cfg.log.max_bytes == 1000


@pytest.mark.parametrize("table,key,words", [
    ({"bitrate": 12}, "can.bitrate", "out of range"),
    ({"interface": ""}, "can.interface", "not a python-can interface"),
    ({"send_timeout_s": 1.0}, "can.send_timeout_s", "out of range"),
    ({"bogus": 1}, "can.bogus", "unknown key"),
    ({"reopen_backoff_s": [5.0, 1.0]}, "can.reopen_backoff_s", "above largest"),
    ({"interface": "udp_multicast", "channel": "239.74.163.2"}, "can.channel",
     "could leave this machine"),
    ({"interface": "udp_multicast", "channel": "ff15::1"}, "can.channel",
     "could leave this machine"),
    ({"interface": "udp_multicast", "channel": "not-an-ip"}, "can.channel",
     "needs a multicast IP group"),
    ({"interface": "udp_multicast", "channel": "10.0.0.1"}, "can.channel",
     "not a multicast group"),
    ({"amplifiers": {"node_ids": [1, 1, 2, 3, 4, 5]}}, "can.amplifiers.node_ids", "distinct"),
    ({"amplifiers": {"node_ids": [0, 2]}}, "can.amplifiers.node_ids[0]", "out of range"),
    ({"amplifiers": {"node_ids": []}}, "can.amplifiers.node_ids", "at least one"),
    ({"amplifiers": {"mode": "csv"}}, "can.amplifiers.mode", "not one of"),
    ({"amplifiers": {"command_timeout_ms": 5}}, "can.amplifiers.command_timeout_ms",
     "out of range"),
    ({"amplifiers": {"master_node_id": 3}}, "can.amplifiers.master_node_id",
     "an amplifier's node id"),
    ({"amplifiers": {"thrust_per_permille_n": [1.0]}}, "can.amplifiers.thrust_per_permille_n",
     "1 values for 6 node ids"),
    ({"amplifiers": {"thrust_per_permille_n": [float("inf")] * 6}},
     "can.amplifiers.thrust_per_permille_n[0]", "expected a finite number, got inf"),
    ({"amplifiers": {"heartbeat_period_ms": 0}}, "can.amplifiers.node_consumer_ms",
     "does not produce"),
    ({"amplifiers": {"node_consumer_ms": 100}}, "can.amplifiers.node_consumer_ms",
     "must be longer than heartbeat_period_ms"),
    ({"amplifiers": {"wat": 0}}, "can.amplifiers.wat", "unknown key"),
    ({"depth": {"enabled": True, "node_id": 3}}, "can.depth.node_id", "already used"),
    ({"depth": {"density_kg_m3": -1.0}}, "can.depth.density_kg_m3", "out of range"),
    ({"depth": {"gravity_m_s2": float("inf")}}, "can.depth.gravity_m_s2",
     "expected a finite number, got inf"),
    ({"log": {"path": "/tmp/x.txt"}}, "can.log.path", "must end in one of .log, .asc, .blf"),
    ({"log": {"max_bytes": -1}}, "can.log.max_bytes", "out of range"),
    ({"amplifiers": [1, 2]}, "can.amplifiers", "expected a table"),
])
def test_errors_name_the_key(table, key, words):
    sec, errors = build(table)
    assert sec is None
    errs = dict(errors)
    assert key in errs, errors
    assert words in errs[key]


def test_a_network_group_is_allowed_only_deliberately():
    sec, errors = build({"interface": "udp_multicast", "channel": "239.74.163.2",
                         "loopback_only": False})
    assert errors == [] and not sec.convert().bus.loopback_only
