"""The daemon against a live ``sim-bridge``: the set-up the HIL tests share.

``uvd run``'s :class:`~uvd.runtime.daemon.Daemon` runs in the test's process (its real drivers
on the bridge's pseudo-terminals and ``udp_multicast`` CAN bus, its real loop and App);
``sim-bridge`` runs as a second process, controlled through its JSON channel.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import time
from pathlib import Path

from sim_bridge.bridge import BridgeProcess, hil_scheduling, write_local_config
from uvd.runtime.daemon import Daemon
from uvd.runtime.lifecycle import State
from uvd.runtime.loop import drop_realtime


class ListSink:
    """A telemetry sink keeping every record in memory (as published: arrays stay arrays)."""

    name = "test"

    def __init__(self) -> None:
        self.records: list[dict] = []

    async def open(self) -> None:
        pass

    async def write(self, records) -> None:
        self.records.extend(records)

    async def flush(self) -> None:
        pass

    async def aclose(self) -> None:
        pass

    def cycles(self) -> list[dict]:
        return [r for r in self.records if r.get("type") == "cycle"]


@contextlib.contextmanager
def running_bridge(run_dir: Path, changes: dict | None = None, duration_s: float = 300.0):
    """``sim-bridge`` on a fresh local configuration (``changes`` merged in); yields
    ``(config path, BridgeProcess)`` and stops the bridge in every case."""
    # as the demo runs them: the devices at SCHED_FIFO 60, the daemon's loop at 50, not pinned
    # (several HIL set-ups may run at once) — the machine also runs other test suites, and a
    # 200 ms stall of either side would trip the drives' command timeout mid-test
    bridge_args, base = hil_scheduling()
    # no files, and no Zenoh on the demo's 7447 (a test that wants it names its own port)
    base["telemetry"] = {"jsonl": {"enabled": False}, "zenoh": {"enabled": False}}
    # nor MAVLink on the demo's 14551 (a test that wants it listens on port 0)
    base["mavlink"] = {"enabled": False}
    cfg_path = write_local_config(run_dir, changes={**base, **(changes or {})})
    proc = BridgeProcess(cfg_path, duration_s=duration_s, hold=True,
                         extra=bridge_args).start(timeout_s=90.0)
    try:
        yield cfg_path, proc
    finally:
        proc.stop(timeout_s=5.0)
        proc.kill()


def daemon_config(bridge_cfg: Path, run_dir: Path, changes: dict | None = None) -> Path:
    """A daemon configuration for a bridge already running (a module's shared one): the
    bridge's own (its instruments' ports, its CAN bus) with ``changes`` merged in, table by
    table, as :func:`running_bridge` merges them; written to ``run_dir/uvd.toml``."""
    from sim_bridge.bridge import merge_tables
    from uvd.io.toml import dump_toml, read_toml
    data = read_toml(bridge_cfg)
    merge_tables(data, changes or {})
    path = Path(run_dir) / "uvd.toml"
    path.write_text(dump_toml(data), encoding="utf-8")
    return path


@contextlib.contextmanager
def reusing_bridge(shared: tuple[Path, BridgeProcess], run_dir: Path,
                   changes: dict | None = None):
    """:func:`running_bridge`'s ``(config path, BridgeProcess)`` for a module's shared bridge
    (as tests/test_daemon_faults.py shares one): reset and placed as at its start, with a
    daemon configuration of the caller's own (:func:`daemon_config`)."""
    cfg_path, proc = shared
    assert proc.call("reset")["ok"] and proc.call("place", hold=True)["ok"]
    Path(run_dir).mkdir(parents=True, exist_ok=True)
    yield daemon_config(cfg_path, run_dir, changes), proc


def station_link(run_dir: Path) -> dict:
    """The configuration changes that put the daemon's MAVLink link on a loopback UDP port the
    kernel picks when it binds (port 0: no other test or process can take it between a pick
    and the bind — a picked port was once found taken under load), for a station of the
    test's own (no parameter file, no operator-loss failsafe, the signing time stamp in
    ``run_dir``). :func:`link_port` tells the port once the daemon runs."""
    return {"mavlink": {"enabled": True, "listen": "127.0.0.1:0", "params_file": "",
                        "operator_timeout_s": 0.0,
                        "signing_timestamp_file": str(run_dir / "signing.ts")}}


def link_port(daemon) -> int:
    """The UDP port a running daemon's MAVLink link is bound to."""
    return daemon.app.links["mavlink"].port


async def until(pred, timeout_s: float, what: str, task=None) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        if task is not None and task.done():
            raise AssertionError(f"the daemon stopped while waiting for {what}")
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.02)


def run_scenario(cfg, scenario, *, daemon_cls=Daemon, tracking_s: float = 1.0,
                 timeout_s: float = 60.0, sink: ListSink | None = None):
    """Start the daemon (auto-arm), let it track, run ``scenario(daemon)``, stop it.

    Returns the daemon and its cycle records (every record stays in ``sink``).
    """
    sink = sink if sink is not None else ListSink()
    out = {}

    async def main():
        d = daemon_cls(cfg, auto_arm=True, sinks=[sink])
        out["daemon"] = d
        task = asyncio.get_running_loop().create_task(d.run())
        try:
            await until(lambda: d.supervisor.armed, 30.0, "arming", task)
            await asyncio.sleep(tracking_s)
            assert d.supervisor.state is State.ARMED, d.supervisor.failsafe_events()
            await scenario(d)
        finally:
            d.stop("test done")
            out["code"] = await asyncio.wait_for(task, 10.0)

    affinity = os.sched_getaffinity(0)
    try:
        asyncio.run(asyncio.wait_for(main(), timeout_s))
    finally:  # the daemon made this thread real-time: back to normal for the next tests
        drop_realtime()
        os.sched_setaffinity(0, affinity)
    assert out["code"] == 0
    print("shutdown:", out["daemon"].app.shutdown_report.get("steps"),
          f"{out['daemon'].app.shutdown_report.get('duration_s', 0):.3f} s")
    return out["daemon"], sink.cycles()
