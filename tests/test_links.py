"""The daemon's faces come from one registry (uvd.links.LINKS) that the App iterates: each face
the configuration enables is built once, named, and fed by the hub in the registry's order;
a face left off is neither built nor imported."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

from uvd.links import LINKS, LinkContext
from uvd.links.jsonl import JsonLinesSink
from uvd.links.mavlink.link import MavlinkLink
from uvd.links.mcap import McapRecorder
from uvd.links.params_file import ParamsFileSink
from uvd.runtime.app import App
from uvd.runtime.commands import CommandQueue
from uvd.runtime.config import load_config
from uvd.telemetry.sink import TelemetryHub

ROOT = Path(__file__).resolve().parents[1]


def config(tmp_path, **on):
    """sim.toml with each face on or off as ``on`` says (all off by default)."""
    cfg = load_config(ROOT / "config" / "sim.toml")
    tel = cfg.telemetry
    return replace(
        cfg,
        recording=replace(cfg.recording, enabled=on.get("mcap", False), dir=str(tmp_path / "r")),
        telemetry=replace(tel, jsonl=replace(tel.jsonl, enabled=on.get("jsonl", False),
                                             path=str(tmp_path / "t.jsonl"), every_n_cycles=3),
                          zenoh=replace(tel.zenoh, enabled=on.get("zenoh", False))),
        mavlink=replace(cfg.mavlink, enabled=on.get("mavlink", False), listen="127.0.0.1:0",
                        params_file=""),
        estimation=replace(cfg.estimation, aid=on.get("params_file", False),
                           save_path=str(tmp_path / "theta.toml")))


def test_the_registry_names_every_face_once():
    assert list(LINKS) == ["mcap", "jsonl", "zenoh", "mavlink", "params_file"]


def test_the_app_builds_the_enabled_faces_in_the_registry_order(tmp_path):
    extra = JsonLinesSink(tmp_path / "extra.jsonl", name="extra")
    app = App(config(tmp_path, mcap=True, jsonl=True, mavlink=True, params_file=True),
              lambda t, dt: None, sinks=[extra], realtime=False)
    assert list(app.links) == ["mcap", "jsonl", "mavlink", "params_file"]
    assert isinstance(app.links["mcap"], McapRecorder)
    assert isinstance(app.links["jsonl"], JsonLinesSink)
    assert isinstance(app.links["mavlink"], MavlinkLink)
    assert isinstance(app.links["params_file"], ParamsFileSink)
    # the test's own sink first, then the faces; each face once
    assert app.hub.sinks == [extra, *app.links.values()]
    lanes = {lane.sink.name: lane for lane in app.hub._lanes}
    assert lanes["jsonl"].every_n == 3                  # [telemetry.jsonl] every_n_cycles
    assert lanes["params-file"].types == {"estimate"}   # only the estimates
    # the link reads the configuration in force, not the one it was built with
    app.config = replace(app.config, control=replace(app.config.control, kp=(1.0,) * 6))
    assert app.links["mavlink"].config() is app.config


def test_a_face_left_off_is_not_built(tmp_path):
    app = App(config(tmp_path), lambda t, dt: None, realtime=False)
    assert app.links == {} and app.hub.sinks == []
    ctx = LinkContext(config(tmp_path), TelemetryHub(), CommandQueue(), lambda: None)
    assert all(make(ctx) is None for make in LINKS.values())
    # the estimate file needs the online estimator it keeps (AID), not only a path
    ctx = LinkContext(config(tmp_path, params_file=True), TelemetryHub(), CommandQueue(),
                      lambda: None)
    assert LINKS["params_file"](ctx) is not None


def test_a_daemon_without_zenoh_or_mavlink_loads_neither():
    code = ("import sys, tempfile\n"
            "from pathlib import Path\n"
            "sys.path.insert(0, sys.argv[1])\n"
            "from test_links import config\n"
            "from uvd.runtime.app import App\n"
            "App(config(Path(tempfile.mkdtemp()), jsonl=True), lambda t, dt: None,"
            " realtime=False)\n"
            "print(sorted(m for m in ('zenoh', 'pymavlink') if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code, str(ROOT / "tests")], capture_output=True,
                         text=True, timeout=60, check=True, cwd=ROOT)
    assert out.stdout.split() == ["[]"]
