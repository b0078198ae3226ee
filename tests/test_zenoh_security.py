"""Zenoh through a router with TLS, user/password authentication and access control: the
documented examples (config/zenoh/router.json5, vehicle.json5, fdc.json5; docs/zenoh.md)
loaded as they are, with only the endpoint and the test-time certificate and password paths
put in. No zenohd here (neither PyPI's wheel nor Debian ships one): the router is a Zenoh
session opened in router mode — the same library, so the same TLS, authentication and ACL.

The vehicle side is the daemon's own Zenoh sink built from a uvd configuration whose
``[telemetry.zenoh] config_file`` names the vehicle's JSON5; the fault-detection side is a
plain Zenoh session that knows nothing of the daemon.
"""

from __future__ import annotations

import asyncio
import json
import shutil
import subprocess
import time
from pathlib import Path

import pytest
import zenoh

from sim_bridge.bridge import write_local_config
from uvd.netports import free_port
from uvd.runtime.config import load_config
from uvd.zenoh_callbacks import SessionCallbacks

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None,
                                reason="openssl makes the test's certificates")

EXAMPLES = Path(__file__).parents[1] / "config" / "zenoh"


def _certificates(d: Path) -> None:
    """A CA, the router's certificate for localhost signed by it, and an unrelated CA."""
    def ssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True,
                       timeout=60)
    ssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out",
        "ca.pem", "-days", "1", "-subj", "/CN=uvd-test-ca")
    ssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "router.key", "-out", "router.csr",
        "-subj", "/CN=localhost")
    (d / "san.cnf").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    ssl("x509", "-req", "-in", "router.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
        "-CAcreateserial", "-out", "router.pem", "-days", "1", "-extfile", "san.cnf")
    ssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "other.key", "-out",
        "other-ca.pem", "-days", "1", "-subj", "/CN=some-other-ca")


def _example(name: str, d: Path, endpoint: str, **paths: str) -> zenoh.Config:
    """An example file as it is, with the test's endpoint and files put in."""
    conf = zenoh.Config.from_file(str(EXAMPLES / f"{name}.json5"))
    key = "listen/endpoints" if name == "router" else "connect/endpoints"
    conf.insert_json5(key, json.dumps([endpoint]))
    for path, file in paths.items():
        conf.insert_json5(path, json.dumps(str(d / file)))
    return conf


def _client(name: str, d: Path, endpoint: str, password: str,
            ca: str = "ca.pem") -> zenoh.Config:
    conf = _example(name, d, endpoint, **{"transport/link/tls/root_ca_certificate": ca})
    conf.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    return conf


def _wait(pred, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not pred() and time.monotonic() < deadline:
        time.sleep(0.05)
    return pred()


def fleet(d: Path, changes: dict | None = None):
    """The router of router.json5 on a free port (users ``rov`` and ``fdc``, passwords
    ``rov-secret`` and ``fdc-secret``) and the vehicle's uvd configuration naming its Zenoh
    file (key ``rov7``), read as the daemon reads it, with ``changes``: (router, endpoint,
    configuration)."""
    _certificates(d)
    (d / "users.txt").write_text("rov:rov-secret\nfdc:fdc-secret\n")
    endpoint = f"tls/localhost:{free_port()}"
    router = zenoh.open(_example("router", d, endpoint, **{
        "transport/link/tls/listen_certificate": "router.pem",
        "transport/link/tls/listen_private_key": "router.key",
        "transport/auth/usrpwd/dictionary_file": "users.txt"}))
    (d / "vehicle.json5").write_text(str(_client("vehicle", d, endpoint, "rov-secret")))
    cfg = load_config(write_local_config(d, changes={"telemetry": {"zenoh": {
        "enabled": True, "key": "rov7", "config_file": "vehicle.json5"}}, **(changes or {})}))
    return router, endpoint, cfg


def test_router_tls_auth_and_acl_let_fdc_read_and_refuse_its_control_puts(tmp_path):
    router, endpoint, cfg = fleet(tmp_path)
    from uvd.links.zenoh import zenoh_sink
    from uvd.telemetry.sink import TelemetryHub
    sink = zenoh_sink(cfg, TelemetryHub())
    commands, faults, seen = [], [], []
    try:
        async def vehicle_up() -> None:
            await sink.open()
        asyncio.run(vehicle_up())
        # the vehicle listens on a control key (as a daemon taking commands would)
        listener = zenoh.open(_client("vehicle", tmp_path, endpoint, "rov-secret"))
        listener_callbacks, fdc_callbacks = SessionCallbacks(), SessionCallbacks()
        listener.declare_subscriber("uvd/rov7/command/**", listener_callbacks(
            lambda s: commands.append(s.payload.to_bytes())))
        listener.declare_subscriber("uvd/rov7/fault/**", listener_callbacks(
            lambda s: faults.append(s.payload.to_bytes())))
        fdc = zenoh.open(_client("fdc", tmp_path, endpoint, "fdc-secret"))
        fdc.declare_subscriber("uvd/**", fdc_callbacks(lambda s: seen.append(str(s.key_expr))))
        time.sleep(0.5)  # the declarations travel through the router

        async def publish() -> None:  # the daemon's sink, as the hub feeds it
            await sink.write([{"type": "start", "t_ns": time.monotonic_ns(),
                               "version": "test"}])
        asyncio.run(publish())
        assert _wait(lambda: "uvd/rov7/event" in seen), seen  # it reads uvd/**
        replies = list(fdc.get("uvd/rov7/params?what=configuration", timeout=2.0))
        assert len(replies) == 1 and replies[0].ok is not None  # and queries params
        alive = [str(r.ok.key_expr) for r in fdc.liveliness().get("uvd/*/alive", timeout=2.0)
                 if r.ok is not None]
        assert alive == ["uvd/rov7/alive"]

        fdc.put("uvd/rov7/command/arm", b"arm")  # refused by the router's ACL
        fdc.put("uvd/rov7/fault/entanglement", b"{}")  # allowed: its own detections
        assert _wait(lambda: faults), "the allowed fault put never arrived"
        time.sleep(0.5)
        assert commands == []
        listener.put("uvd/rov7/command/arm", b"from the vehicle")  # the key itself works
        assert _wait(lambda: commands == [b"from the vehicle"]), commands

        # no connection with a wrong password, nor to a router the client's CA did not sign
        with pytest.raises(zenoh.ZError):
            zenoh.open(_client("fdc", tmp_path, endpoint, "wrong"))
        with pytest.raises(zenoh.ZError):
            zenoh.open(_client("fdc", tmp_path, endpoint, "fdc-secret", ca="other-ca.pem"))
        running = fdc_callbacks.close(fdc), listener_callbacks.close(listener)
        assert running == (0, 0)  # both sessions' callback threads ended
    finally:
        async def vehicle_down() -> None:
            await sink.aclose()
        asyncio.run(vehicle_down())
        router.close()
