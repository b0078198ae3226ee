"""``uvd demo --fault thruster:I:ETA@T``: a weak thruster in the hardware-in-the-loop demo,
detected by uvd-fdc over Zenoh and accommodated by the daemon.

T seconds after arming, sim-bridge's fault injection (the ``health`` command of its control
channel, the same as ``sim-bridge --at S '{"op": "health", …}'``) leaves thruster I with ETA of
its thrust; the amplifier still reports the speed it is told, so only the vehicle's motion shows
it. The demo runs, beside the daemon, ``uvd-fdc`` (started at arming: its baseline is the
armed run before the fault, ``warmup_s`` + ``baseline_s`` < T) and ``uvd watch``, both over
the daemon's Zenoh (a free port). The daemon runs online AID from the vehicle file's
parameters (what uvd-fdc watches) and ``[faults.fdc]`` with ``accept = "confirm"``
(docs/zenoh.md): uvd-fdc's sample is acted on only when the daemon's own thrust residual
confirms it. The demo times, on the one monotonic clock of this machine:

- **fault**: when sim-bridge weakened the thruster (its ``scheduled_ns``);
- **detection**: when uvd-fdc's sample ``uvd/<vehicle>/fault/thruster`` arrived;
- **reallocation**: the cycle that applied it (the ``FaultReport`` command's event ``t_ns``).

With ``--false-alarm`` the demo also puts, 5 s before the fault, a sample naming a healthy
thruster (the next one) at η 0.5 — what a false alarm of uvd-fdc would publish: the daemon's own
evidence contradicts it, and it is logged, counted and not acted on.

Ten seconds after the reallocation the thruster is repaired (sim-bridge ``health`` 1) and the
operator clears its η over MAVLink (COMMAND_LONG 31010, docs/mavlink.md); ``uvd watch``'s
lines of both events are printed.
"""

from __future__ import annotations

import contextlib
import json
import re
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uvd.zenoh_callbacks import SessionCallbacks

__all__ = ["FaultSpec", "FaultRun", "config_changes"]

_NUMBER = r"(\d+(?:\.\d*)?|\.\d+)"  # 0.5, 30, 30., .5 (not 1.2.3: the spec is named instead)
_SPEC = re.compile(rf"thruster:(\d+):{_NUMBER}@{_NUMBER}$")
#: after the reallocation, the thruster is repaired and its η cleared this much later (s)
CLEAR_AFTER_S = 10.0


@dataclass(frozen=True)
class FaultSpec:
    """``thruster:I:ETA@T``: thruster I (1-based) at efficiency ETA ∈ [0, 1), T s after
    arming."""

    thruster: int
    eta: float
    at_s: float

    @classmethod
    def parse(cls, text: str) -> FaultSpec:
        m = _SPEC.match(text.strip())
        if m is None:
            raise ValueError(f"--fault {text!r}: expected thruster:I:ETA@T (e.g. "
                             "thruster:4:0.5@30)")
        spec = cls(int(m.group(1)), float(m.group(2)), float(m.group(3)))
        if not 0.0 <= spec.eta < 1.0:
            raise ValueError(f"--fault {text!r}: ETA {spec.eta:g} is not in [0, 1)")
        if spec.at_s < 15.0:
            raise ValueError(f"--fault {text!r}: T {spec.at_s:g} s leaves uvd-fdc no baseline "
                             "(at least 15 s after arming)")
        return spec

    def fdc_args(self) -> list[str]:
        """uvd-fdc's baseline in the armed run before the fault: 3 s warm-up, then until 5 s
        before it, in residual segments of a thirteenth of that (it needs ten)."""
        baseline = self.at_s - 8.0
        return ["--warmup-s", "3", "--baseline-s", f"{baseline:g}",
                "--segment-s", f"{baseline / 13.0:.3g}"]


def config_changes(spec: FaultSpec, run_dir: Path, vehicle, accept: str = "confirm"
                   ) -> dict[str, Any]:
    """The daemon's configuration for a fault run: Zenoh and MAVLink on free loopback ports,
    online AID from the vehicle file's parameters, estimates every second, ``[faults.fdc]``."""
    from uvd.errors import ExperimentError
    from uvd.io.params import save_params
    from uvd.netports import free_port
    if not 1 <= spec.thruster <= vehicle.n_thrusters:  # the command line says it, no traceback
        raise ExperimentError(f"--fault: thruster {spec.thruster} is not one of "
                              f"1…{vehicle.n_thrusters} of {vehicle.name}")
    params = run_dir / "vehicle-params.toml"
    save_params(vehicle.params, params, title=f"{vehicle.name}: AID's start in uvd demo --fault")
    return {"telemetry": {"zenoh": {"enabled": True, "mode": "peer", "config_file": "",
                                    "listen": [f"tcp/127.0.0.1:{free_port()}"]}},
            "mavlink": {"enabled": True, "listen": f"127.0.0.1:{free_port('udp')}"},
            "estimation": {"aid": True, "initial_params": str(params),
                           "publish_every_s": 1.0},
            "faults": {"fdc": {"enabled": True, "accept": accept}}}


class FaultRun:
    """The fault, uvd-fdc, ``uvd watch`` and the timing of one demo run (module docstring)."""

    def __init__(self, spec: FaultSpec, cfg, run_dir: Path, progress,
                 false_alarm: bool = False) -> None:
        self.spec = spec
        self.n_thrusters = len(cfg.can.amplifiers.node_ids)
        self._false_at: float | None = None
        self.false_alarm = false_alarm
        self.key = cfg.telemetry.zenoh.key or Path(cfg.vehicle.name).stem
        self.endpoint = cfg.telemetry.zenoh.listen[0]
        self.mavlink = cfg.mavlink.listen
        self.run_dir = run_dir
        self.progress = progress
        self.procs: list[subprocess.Popen] = []
        self.fault_ns: int | None = None
        self.detected: dict[str, Any] | None = None
        self.reallocated: dict[str, Any] | None = None
        self.cleared: dict[str, Any] | None = None
        self.refused: list[str] = []
        self.awaited: list[str] = []  # samples the daemon kept to decide at a later segment
        self._lock = threading.Lock()
        self._session = None
        self._callbacks = SessionCallbacks()
        self._clear_at: float | None = None

    # -- start --

    def start(self, bridge, armed_at: float) -> None:
        """Schedule the fault T s after arming; start uvd-fdc, ``uvd watch`` and the demo's
        own subscriber."""
        import zenoh

        from uvd.fdc.client import client_config
        at = max(0.0, self.spec.at_s - (time.monotonic() - armed_at))
        ans = bridge.call("health", node=self.spec.thruster, value=self.spec.eta, at_s=at)
        if not ans.get("ok"):
            raise RuntimeError(f"sim-bridge refused the fault: {ans}")
        self.fault_ns = int(ans["scheduled_ns"])
        if self.false_alarm:
            self._false_at = time.monotonic() + max(0.0, at - 5.0)
        self._session = zenoh.open(client_config([self.endpoint]))
        self._session.declare_subscriber(f"uvd/{self.key}/fault/**",
                                         self._callbacks(self._on_fault))
        self._session.declare_subscriber(f"uvd/{self.key}/event", self._callbacks(self._on_event))
        bound = f"{self.spec.at_s + 600:g}"
        for name, argv in (
                ("fdc", ["-m", "uvd.fdc.client", "--connect", self.endpoint, "--vehicle",
                         self.key, "--seconds", bound, *self.spec.fdc_args()]),
                ("watch", ["-m", "uvd", "watch", "--connect", self.endpoint, "--vehicle",
                           self.key, "--seconds", bound])):
            log = (self.run_dir / f"{name}.log").open("w")
            self.procs.append(subprocess.Popen([sys.executable, *argv], stdout=log,
                                               stderr=subprocess.STDOUT,
                                               stdin=subprocess.DEVNULL))
        self.progress(f"  thruster {self.spec.thruster} to eta {self.spec.eta:g} in {at:.1f} s "
                      f"(sim-bridge); uvd-fdc ({' '.join(self.spec.fdc_args())}) and uvd watch "
                      f"on {self.endpoint}; MAVLink on udp {self.mavlink} (uvd eta "
                      f"{self.spec.thruster} clear --to {self.mavlink})")

    def _on_fault(self, sample) -> None:
        with self._lock:
            if self.detected is None and self.fault_ns is not None \
                    and time.monotonic_ns() >= self.fault_ns:
                with contextlib.suppress(ValueError):
                    self.detected = {"arrived_ns": time.monotonic_ns(),
                                     "sample": json.loads(sample.payload.to_bytes())}

    def _on_event(self, sample) -> None:
        try:
            m = json.loads(sample.payload.to_bytes())
        except ValueError:
            return
        r = m.get("record") or {}
        if m.get("kind") == "failsafe" and r.get("trigger") == "fdc":
            # a sample that awaited the daemon's residual, decided at a later segment
            acted, awaited = r.get("kind") == "accommodated", False
        elif m.get("kind") == "command":
            acted = bool(r.get("ok")) and "→" in str(r.get("reason"))  # through SetThrusterEta
            awaited = bool(r.get("ok")) and "awaiting the daemon's residual" in str(
                r.get("reason"))
        else:
            return
        with self._lock:
            if r.get("command") == "FaultReport" or m.get("kind") == "failsafe":
                if awaited:
                    self.awaited.append(m["text"])
                elif acted and self.reallocated is None:
                    self.reallocated = {"t_ns": int(r["t_ns"]), "text": m["text"]}
                    self._clear_at = time.monotonic() + CLEAR_AFTER_S
                elif not acted:
                    self.refused.append(m["text"])
            elif r.get("command") == "SetThrusterEta" and self.reallocated is not None:
                self.cleared = {"t_ns": int(r["t_ns"]), "text": m["text"]}

    # -- while it runs --

    def poll(self, bridge) -> None:
        """The false alarm when due; once the reallocation is CLEAR_AFTER_S old: repair the
        thruster and clear its η as the operator would (MAVLink)."""
        if self._false_at is not None and time.monotonic() >= self._false_at:
            self._false_at = None
            healthy = self.spec.thruster % self.n_thrusters + 1
            now = time.monotonic_ns()
            self._session.put(f"uvd/{self.key}/fault/thruster", json.dumps({
                "vehicle": self.key, "kind": "thruster", "t_ns": now,
                "channel": f"thruster{healthy}", "magnitude": 20.0, "relative_change": -0.5,
                "confidence": 2.0, "explanation": {"coef": [0.5],
                                                   "since_t_ns": now - 10_000_000_000}}))
            self.progress(f"  put a false alarm: thruster {healthy} at eta 0.5")
        if self._clear_at is None or time.monotonic() < self._clear_at:
            return
        self._clear_at = None
        bridge.call("health", node=self.spec.thruster, value=1.0)
        _clear_over_mavlink(self.mavlink, self.spec.thruster)

    # -- end --

    def finish(self) -> dict[str, Any]:
        """Stop the helpers; the figures (times in s on the monotonic clock)."""
        for p in self.procs:
            if p.poll() is None:
                p.terminate()
        for p in self.procs:
            try:
                p.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=5.0)
        if self._session is not None:
            self._callbacks.close(self._session)  # and their threads ended
        s = self.spec
        out: dict[str, Any] = {"thruster": s.thruster, "eta": s.eta, "at_s": s.at_s,
                               "fdc_args": s.fdc_args(), "detected": self.detected,
                               "reallocated": self.reallocated, "cleared": self.cleared,
                               "refused": self.refused, "awaited": self.awaited}
        f = self.fault_ns
        if f is not None and self.detected is not None:
            out["fault_to_detection_s"] = (self.detected["arrived_ns"] - f) * 1e-9
        if f is not None and self.reallocated is not None:
            out["fault_to_reallocation_s"] = (self.reallocated["t_ns"] - f) * 1e-9
            if self.detected is not None:
                out["detection_to_reallocation_s"] = (self.reallocated["t_ns"]
                                                      - self.detected["arrived_ns"]) * 1e-9
        watch = self.run_dir / "watch.log"
        out["watch_events"] = [ln for ln in watch.read_text().splitlines()
                               if "event: FaultReport" in ln or "event: SetThrusterEta" in ln
                               or ": fdc → " in ln] if watch.is_file() else []
        return out


def _clear_over_mavlink(listen: str, thruster: int) -> None:
    """COMMAND_LONG 31010 (thruster, η 1) from a ground station (docs/mavlink.md)."""
    import os
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil
    host, _, port = listen.rpartition(":")
    conn = mavutil.mavlink_connection(f"udpout:{host}:{port}", source_system=255,
                                      dialect="ardupilotmega")
    try:  # no HEARTBEAT: one would start the daemon's watch of the ground station's
        conn.mav.command_long_send(1, 1, 31010, 0, float(thruster), 1.0, 0, 0, 0, 0, 0)
        conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=2.0)
    finally:
        conn.close()


def report(f: dict[str, Any], progress) -> None:
    """The fault's lines of the demo's report."""
    progress(f"  fault: thruster {f['thruster']} at eta {f['eta']:g}, {f['at_s']:g} s after "
             "arming (sim-bridge)")
    d, stopped = f.get("fault_to_detection_s"), f.get("interrupted_after_s")
    if d is None and stopped is not None and stopped < f["at_s"]:
        progress(f"    not put: Ctrl-C {stopped:.1f} s after arming, before the fault's "
                 f"{f['at_s']:g} s")
        return
    progress("    fault → detection (uvd-fdc's sample)  " + (
        f"{d:6.1f} s" if d is not None else "not detected" if stopped is None else
        f"not detected in the {stopped - f['at_s']:.1f} s before the Ctrl-C"))
    r = f.get("detection_to_reallocation_s")
    if r is not None:
        progress(f"    detection → reallocation (the daemon) {r:6.3f} s")
    t = f.get("fault_to_reallocation_s")
    progress("    fault → reallocation                  " + (f"{t:6.1f} s" if t is not None
                                                           else "no reallocation"))
    if f.get("daemon_counts"):
        progress(f"    the daemon's fault samples: {f['daemon_counts']}")
    for text in f.get("awaited") or ():
        progress(f"    awaited the daemon's residual: {text}")
    for text in f.get("refused") or ():
        progress(f"    not acted on: {text}")
    for line in f.get("watch_events") or ():
        progress(f"    uvd watch: {line.strip()}")
    if f.get("reallocated") is not None:
        progress(f"    event: {f['reallocated']['text']}")
