"""``uvd demo``'s listeners: a second demo (or a daemon, or another program) holding the
configured Zenoh or MAVLink port moves this run's to a free one, said; free ones stay where
``uvd watch`` and MAVProxy look by default. Before, the second demo ran without both links
("sink zenoh did not open … Address already in use; its records are dropped")."""

from __future__ import annotations

import socket

from uvd.commands.demo import _listener_moves, _local_config
from uvd.netports import free_port, port_taken


def test_taken_listeners_move_and_free_ones_stay(tmp_path):
    zport, mport = free_port("tcp"), free_port("udp")
    changes = {"telemetry": {"zenoh": {"listen": [f"tcp/127.0.0.1:{zport}"]}},
               "mavlink": {"listen": f"127.0.0.1:{mport}"}}
    _, cfg, said = _local_config(tmp_path / "free", None, changes)
    assert said == [] and cfg.telemetry.zenoh.listen == (f"tcp/127.0.0.1:{zport}",)

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as z, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as m:
        z.bind(("127.0.0.1", zport))
        z.listen()
        m.bind(("127.0.0.1", mport))
        assert port_taken("tcp", "127.0.0.1", zport) and port_taken("udp", "127.0.0.1", mport)
        _, cfg, said = _local_config(tmp_path / "taken", None, changes)
        (zep,), mav = cfg.telemetry.zenoh.listen, cfg.mavlink.listen
        assert zep.startswith("tcp/127.0.0.1:") and zep != f"tcp/127.0.0.1:{zport}"
        assert mav.startswith("127.0.0.1:") and mav != f"127.0.0.1:{mport}"
        assert not port_taken("tcp", "127.0.0.1", int(zep.rpartition(":")[2]))
        assert said == [
            f"  Zenoh: tcp/127.0.0.1:{zport} is taken (another daemon or demo?): this run "
            f"listens on {zep}",
            f"  MAVLink: udp 127.0.0.1:{mport} is taken (another daemon or demo?): this run "
            f"listens on udp {mav}"]
        # the other keys of the run's configuration are kept
        assert cfg.sensors.ins.port == str(tmp_path / "taken" / "ins")


def test_endpoints_it_does_not_read_are_left_alone(tmp_path):
    from sim_bridge.bridge import write_local_config
    from uvd.runtime.config import load_config
    path = write_local_config(tmp_path, changes={
        "telemetry": {"zenoh": {"listen": ["unixsock-stream//tmp/z.sock"]}},
        "mavlink": {"enabled": False}})
    assert _listener_moves(load_config(path)) == ({}, [])
