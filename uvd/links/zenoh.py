"""Live state, parameter estimates, health and events over Zenoh, for fault-detection clients.

A :class:`~uvd.telemetry.sink.TelemetrySink` of the hub (so it never touches the loop: the
hub's bounded drop-oldest queue stands between them). Key space (docs/zenoh.md):

==================================  ==========================================================
``uvd/<vehicle>/state``             pose, velocity, reference and tracking error, thrust
                                    (``uvd.state.v1``), at ``state_hz``
``uvd/<vehicle>/estimate/<name>``   each online estimate as the daemon publishes it
                                    (``uvd.zestimate.v1``): θ̂, the six masses and drags, g, b,
                                    λ_min(M̂), frozen flag and reason, steps, age
``uvd/<vehicle>/health``            lifecycle, failsafe action and triggers, source ages,
                                    amplifier faults, telemetry drops, the sinks last told
                                    failing (``uvd.health.v1``), at ``health_hz``
``uvd/<vehicle>/event``             failsafe transitions, lifecycle, commands, reloads, the
                                    start (``uvd.event.v1``)
``uvd/<vehicle>/params``            queryable: the configuration's vehicle and gains and the
                                    latest estimates (``uvd.params.v1``); ``?what=`` one of
                                    ``all`` (default), ``configuration``, ``estimates``
``uvd/<vehicle>/alive``             liveliness token while the daemon runs
``uvd/<vehicle>/fault/**``          subscribed (``[faults.fdc] enabled``): uvd-fdc's fault
                                    samples (``uvd.fault.v1``), each queued for the cycle as a
                                    :class:`~uvd.runtime.commands.FaultReport`
                                    (:mod:`uvd.runtime.fdc_source`)
==================================  ==========================================================

Every payload is JSON with its schema in the sample's encoding
(``application/json;schema=uvd.state.v1``) and carries ``seq`` (per key, +1 a sample: a gap
is a lost sample), ``t_ns`` (the daemon's monotonic clock) and ``wall_time``. Publishers use
congestion control DROP: a slow or absent subscriber never makes a put wait. The puts run in
the sink's worker thread, off the event loop.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from uvd.geometry import R_to_euler, wrap_angle
from uvd.jsonio import is_int64, to_jsonable
from uvd.telemetry._worker import DaemonWorker
from uvd.zenoh_callbacks import SessionCallbacks
from uvd.zenoh_names import vehicle_key_problem

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from uvd.runtime.config import Config
    from uvd.telemetry.sink import TelemetryHub

__all__ = ["ZenohSink", "zenoh_config", "zenoh_sink", "estimate_payload", "state_payload",
           "fault_report", "ENCODINGS", "QUERY_WHAT"]

#: key (relative to uvd/<vehicle>) → the schema named in its samples' encoding
ENCODINGS = {"state": "uvd.state.v1", "estimate": "uvd.zestimate.v1",
             "health": "uvd.health.v1", "event": "uvd.event.v1", "params": "uvd.params.v1"}
QUERY_WHAT = ("all", "configuration", "estimates")


def zenoh_config(*, mode: str = "peer", listen: Sequence[str] = (),
                 connect: Sequence[str] = (), multicast_scouting: bool = False,
                 config_file: str | None = None, extra: Mapping[str, Any] | None = None):
    """A ``zenoh.Config``: from ``config_file`` (JSON5) when given, else the keys given here
    (``extra`` maps further JSON5 paths to values, e.g. TLS or authentication settings)."""
    import zenoh
    if config_file:
        conf = zenoh.Config.from_file(str(config_file))
    else:
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(mode))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast_scouting)))
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    for path, value in (extra or {}).items():
        conf.insert_json5(path, json.dumps(value))
    return conf


def _rpy(R) -> list[float]:
    return list(R_to_euler(np.asarray(R, dtype=float).reshape(3, 3)))


def publication_period_ns(hz: float) -> int:
    """The period of a stream published at ``hz`` (``state_hz``, ``health_hz``); 0: off."""
    return int(1e9 / hz) if hz > 0 else 0


def next_publication_ns(t_ns: int, period_ns: int) -> int:
    """When a stream published at ``t_ns`` with ``period_ns`` (``state``, ``health``) is
    next due: a period on, less a tenth, so that a cycle a little early is not skipped."""
    return t_ns + period_ns - period_ns // 10


class ZenohSink:
    """Publish the hub's records under ``uvd/<vehicle>/…`` (module docstring).

    Parameters
    ----------
    vehicle : str
        The ``<vehicle>`` of the key space (a single key chunk: no ``/``, ``*``, ``?``…).
    config : zenoh.Config
        The session's configuration (:func:`zenoh_config`).
    state_hz, health_hz : float
        Publication rates of ``state`` and ``health`` (cycles in between are skipped).
    configuration : mapping
        What the ``params`` queryable reports of the configuration (vehicle, controller,
        gains, failsafe thresholds), as plain data.
    dropped : callable, optional
        ``dropped() -> int``: records the hub dropped so far (published in ``health``).
    faults : callable, optional
        ``faults(report)``: subscribe to ``uvd/<vehicle>/fault/**`` and hand each well-formed
        sample, as a :class:`~uvd.runtime.commands.FaultReport`, to it (the daemon's command
        queue's ``put``); a malformed one is counted (``faults_dropped``,
        ``faults_malformed``), told in the log at the first and every 1000th, and dropped,
        and so is one that arrives while :data:`FAULTS_WAITING_MAX` samples still wait for the
        cycle (``faults_flooded`` too): a flooding client never fills the command queue the
        operator's Disarm goes through.
    """

    name = "zenoh"

    def __init__(self, vehicle: str, config, *, state_hz: float = 20.0, health_hz: float = 2.0,
                 configuration: Mapping[str, Any] | None = None, dropped=None,
                 faults=None) -> None:
        why = vehicle_key_problem(vehicle)
        if why:
            raise ValueError(f"[telemetry.zenoh] vehicle: {vehicle!r} {why}")
        self.vehicle = vehicle
        self.prefix = f"uvd/{vehicle}"
        self.config = config
        self.state_period_ns = publication_period_ns(state_hz)
        self.health_period_ns = publication_period_ns(health_hz)
        self.configuration = dict(configuration or {})
        self.dropped = dropped
        self.failing_sinks: set[str] = set()  # as the "sink" records told (in health)
        self._worker = DaemonWorker("uvd-sink-zenoh")
        self._session = None
        self._pubs: dict[str, Any] = {}
        self._seq: dict[str, int] = {}
        self._next_state = 0
        self._next_health = 0
        self._estimates: dict[str, dict[str, Any]] = {}
        self._lock = threading.Lock()
        self._token = None
        self._queryable = None
        self._callbacks = SessionCallbacks()  # the queryable's and fault subscriber's threads
        self.published = 0
        self.query_errors = 0
        self.faults = faults
        self._fault_sub = None
        self.faults_received = 0
        self.faults_dropped = 0
        self.faults_flooded = 0
        self.faults_malformed = 0
        self._faults_waiting = 0
        self._faults_lock = threading.Lock()

    # -- session (worker thread) --

    def _open(self) -> None:
        import zenoh
        self._session = zenoh.open(self.config)
        self._token = self._session.liveliness().declare_token(f"{self.prefix}/alive")
        self._queryable = self._session.declare_queryable(f"{self.prefix}/params",
                                                          self._callbacks(self._on_query))
        if self.faults is not None:
            self._fault_sub = self._session.declare_subscriber(
                f"{self.prefix}/fault/**", self._callbacks(self._on_fault))

    def _on_fault(self, sample) -> None:
        """A fault sample (zenoh's thread): queued for the cycle, or counted and dropped."""
        key = str(sample.key_expr)
        with self._faults_lock:  # a place among the waiting samples, or dropped
            flooded = self._faults_waiting >= FAULTS_WAITING_MAX
            if flooded:
                self.faults_dropped += 1
                self.faults_flooded += 1
            else:
                self._faults_waiting += 1
        if flooded:  # told at the first and every 1000th: not a log line per sample
            if self.faults_flooded == 1 or self.faults_flooded % 1000 == 0:
                log.warning("%s: %d fault samples already wait for the cycle; dropped (%d "
                            "so far)", key, FAULTS_WAITING_MAX, self.faults_flooded)
            return
        try:
            report = fault_report(key, sample.payload.to_bytes())
        except ValueError as exc:
            n = self._fault_taken(dropped=True)
            if n == 1 or n % 1000 == 0:  # likewise told at the first and every 1000th
                log.warning("%s%s", exc, "" if n == 1 else f" ({n} malformed so far)")
            return
        self.faults_received += 1
        waiting = self.faults(report)
        if hasattr(waiting, "add_done_callback"):  # the cycle took it (or the queue refused it)
            waiting.add_done_callback(lambda _f: self._fault_taken())
        else:
            self._fault_taken()

    def _fault_taken(self, dropped: bool = False) -> int:
        """A waiting sample's place freed (zenoh's or the cycle's thread): taken by the cycle,
        or ``dropped`` as malformed (counted under the same lock as a flooded one); returns
        how many were malformed so far."""
        with self._faults_lock:
            self._faults_waiting -= 1
            self.faults_dropped += dropped
            self.faults_malformed += dropped
            return self.faults_malformed

    def _publisher(self, key: str, schema_name: str):
        import zenoh
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._session.declare_publisher(
                key, encoding=zenoh.Encoding(f"application/json;schema={schema_name}"),
                congestion_control=zenoh.CongestionControl.DROP)
            self._pubs[key] = pub
        return pub

    def _put_all(self, items: list[tuple[str, str, dict[str, Any]]]) -> None:
        for key, schema_name, payload in items:
            self._publisher(key, schema_name).put(
                json.dumps(payload, separators=(",", ":"), allow_nan=False))
            self.published += 1

    def _on_query(self, query) -> None:
        """The ``params`` queryable (zenoh's thread): the snapshot, or an error naming what
        was wrong with the selector."""
        import zenoh
        try:
            params = dict(query.parameters) if query.parameters is not None else {}
        except Exception:  # noqa: BLE001 - a selector zenoh hands us but we cannot read
            params = {"?": str(query.parameters)}
        unknown = sorted(set(params) - {"what"})
        what = params.get("what", "all") or "all"
        if unknown or what not in QUERY_WHAT:
            self.query_errors += 1
            why = (f"unknown selector parameter(s) {', '.join(unknown)} (known: what)"
                   if unknown else f"what={what!r} is not one of {', '.join(QUERY_WHAT)}")
            query.reply_err(json.dumps({"error": f"{self.prefix}/params: {why}"}),
                            encoding=zenoh.Encoding("application/json"))
            return
        with self._lock:
            estimates = dict(self._estimates)
        body = {"vehicle": self.vehicle, "t_ns": time.monotonic_ns(),
                "configuration": self.configuration if what in ("all", "configuration")
                else {}, "estimates": estimates if what in ("all", "estimates") else {}}
        query.reply(f"{self.prefix}/params", json.dumps(to_jsonable(body), allow_nan=False),
                    encoding=zenoh.Encoding(f"application/json;schema={ENCODINGS['params']}"))

    def _close(self) -> None:
        try:
            if self._token is not None:
                self._token.undeclare()
            if self._session is not None:
                self._callbacks.close(self._session, warn=log.warning)
        finally:
            self._session = None

    # -- the sink --

    async def open(self) -> None:
        await self._worker.submit(self._open)

    def _stamp(self, key: str, t_ns: int, body: dict[str, Any]) -> dict[str, Any]:
        seq = self._seq.get(key, 0)
        self._seq[key] = seq + 1
        return {"seq": seq, "t_ns": int(t_ns), "wall_time": time.time(),
                "vehicle": self.vehicle, **body}

    async def write(self, records: Sequence[Mapping[str, Any]]) -> None:
        items: list[tuple[str, str, dict[str, Any]]] = []
        for r in records:
            kind = r.get("type")
            t_ns = int(r.get("t_ns") or time.monotonic_ns())
            if kind == "cycle":
                if self.state_period_ns and t_ns >= self._next_state:
                    self._next_state = next_publication_ns(t_ns, self.state_period_ns)
                    key = f"{self.prefix}/state"
                    items.append((key, ENCODINGS["state"], self._stamp(key, t_ns,
                                                                       state_payload(r))))
                if self.health_period_ns and t_ns >= self._next_health:
                    self._next_health = next_publication_ns(t_ns, self.health_period_ns)
                    key = f"{self.prefix}/health"
                    items.append((key, ENCODINGS["health"], self._stamp(
                        key, t_ns, _health(r, self.dropped() if self.dropped else 0,
                                           self.failing_sinks))))
            elif kind == "estimate":
                body = estimate_payload(r)
                with self._lock:
                    self._estimates[body["estimator"]] = body
                key = f"{self.prefix}/estimate/{body['estimator']}"
                items.append((key, ENCODINGS["estimate"], self._stamp(key, t_ns, body)))
            elif kind in ("failsafe", "lifecycle", "command", "reload", "sink", "start"):
                if kind == "sink":
                    (self.failing_sinks.discard if r["ok"] else self.failing_sinks.add)(
                        r["sink"])
                key = f"{self.prefix}/event"
                items.append((key, ENCODINGS["event"], self._stamp(key, t_ns, _event(kind, r))))
        if items:
            await self._worker.submit(self._put_all, items)

    async def flush(self) -> None:
        return None

    async def aclose(self) -> None:
        try:
            await self._worker.submit(self._close)
        finally:
            self._worker.close()


# ----------------------------------------------------------------------------- payloads

def state_payload(r: Mapping[str, Any]) -> dict[str, Any]:
    """The body of a ``uvd/<vehicle>/state`` sample (``uvd.state.v1``, without ``seq``,
    ``vehicle`` and the stamps) of a ``"cycle"`` hub record."""
    R = np.asarray(r["R"], dtype=float)
    out = {"state": str(r["state"]), "mode": str(r["mode"]), "action": str(r["action"]),
           "nav_valid": bool(r["nav_valid"]), "p": r["p"], "R": R, "rpy": _rpy(R), "v": r["v"],
           "u": r["u"], "u_cmd": r["u_cmd"], "thrust": r["thrust"], "p_ref": None,
           "rpy_ref": None, "v_ref": None, "tracking_error": None}
    if r.get("p_ref") is not None:
        rpy, rpy_ref = out["rpy"], _rpy(r["R_ref"])
        out.update(p_ref=r["p_ref"], rpy_ref=rpy_ref, v_ref=r["v_ref"], tracking_error={
            "position_m": (np.asarray(r["p"], float) - np.asarray(r["p_ref"], float)),
            "attitude_rad": [wrap_angle(a - b) for a, b in zip(rpy, rpy_ref, strict=True)]})
    return to_jsonable(out)


def _health(r: Mapping[str, Any], dropped: int, failing_sinks=()) -> dict[str, Any]:
    ages = r.get("ages") or (None,) * 4
    inputs = r.get("inputs") or {}
    act = inputs.get("actuators") or {}
    return to_jsonable({
        "lifecycle": str(r["state"]), "action": str(r["action"]), "mode": str(r["mode"]),
        "operator_mode": str(r.get("operator_mode", "auto")),
        "triggers": list(r.get("triggers") or ()),
        "ages_s": dict(zip(("ins", "dvl", "depth", "feedback"), ages, strict=True)),
        "amplifier_faults": list(act.get("faults") or ()),
        "overrun_streak": inputs.get("overrun_streak"), "telemetry_dropped": int(dropped),
        "sinks_failing": sorted(failing_sinks)})


def estimate_payload(r: Mapping[str, Any]) -> dict[str, Any]:
    """The body of a ``uvd/<vehicle>/estimate/<name>`` sample (``uvd.zestimate.v1``, without
    ``seq``, ``vehicle`` and the stamps) of an ``"estimate"`` hub record."""
    theta = r.get("theta")
    masses = drags = b = g = None
    if theta is not None:
        th = np.asarray(theta, dtype=float)
        if th.shape == (241,):
            from uvd.model.params import UVParams
            p = UVParams.from_theta(th)
            masses = np.diag(p.M)
            drags = np.array([p.D[i][i, i] for i in range(6)])
            g, b = float(p.g), p.b
    return to_jsonable({"estimator": str(r["estimator"]), "theta": theta, "masses": masses,
                        "drags": drags, "g": g, "b": b, "m_min_eig": r.get("m_min_eig"),
                        "m_max_eig": r.get("m_max_eig"), "frozen": bool(r.get("frozen")),
                        "freeze_reason": str(r.get("freeze_reason") or ""),
                        "hold_reason": str(r.get("hold_reason") or ""),
                        "steps": r.get("steps"), "velocity_error": r.get("velocity_error"),
                        "age_s": r.get("age_s"),
                        "source": str(r.get("source") or "estimator")})


#: fault samples waiting for the cycle at most (the command queue holds 64; the cycle takes
#: every waiting command at its start): more are dropped and counted, so that a client that
#: floods ``uvd/<vehicle>/fault/**`` leaves the queue to the operator's commands
FAULTS_WAITING_MAX = 8

#: the longest ``channel`` a fault sample may name (uvd-fdc's are ``thruster12``, ``mass6``…):
#: what the daemon tells of a sample (event, STATUSTEXT) stays a line
CHANNEL_MAX = 64


def fault_report(key: str, payload: bytes):
    """The :class:`~uvd.runtime.commands.FaultReport` of a ``uvd.fault.v1`` sample on ``key``;
    ValueError naming the key and what is wrong otherwise: not JSON (nested too deep for the
    parser too), a field missing or of the wrong type, a ``kind`` outside the schema's enum,
    a ``channel`` longer than :data:`CHANNEL_MAX`, a clock beyond 64 bits, a confidence that
    is not finite or below the schema's minimum 1."""
    from uvd.runtime.commands import FaultReport
    from uvd.telemetry.recording import schema
    try:
        d = json.loads(payload)
    except (ValueError, RecursionError) as exc:
        raise ValueError(f"{key}: fault sample is not JSON ({exc}); dropped") from None
    if not isinstance(d, dict):
        raise ValueError(f"{key}: fault sample is not a JSON object; dropped")
    expl = d.get("explanation") if isinstance(d.get("explanation"), dict) else {}
    since = expl.get("since_t_ns")
    checks = (("kind", str, "a string"), ("channel", str, "a string"),
              ("t_ns", int, "an integer"), ("confidence", (int, float), "a number"))
    for name, typ, what in checks:
        if not isinstance(d.get(name), typ) or isinstance(d.get(name), bool):
            raise ValueError(f"{key}: fault sample's {name} is {d.get(name)!r} (uvd.fault.v1 "
                             f"wants {what}); dropped")
    kinds = schema("uvd.fault.v1")["properties"]["kind"]["enum"]
    if d["kind"] not in kinds:
        raise ValueError(f"{key}: fault sample's kind {d['kind'][:CHANNEL_MAX]!r} is not one of "
                         f"{', '.join(kinds)} (uvd.fault.v1); dropped")
    if len(d["channel"]) > CHANNEL_MAX:
        raise ValueError(f"{key}: fault sample's channel is {len(d['channel'])} characters "
                         f"(at most {CHANNEL_MAX}); dropped")
    rc = d.get("relative_change")
    if rc is not None and (isinstance(rc, bool) or not isinstance(rc, (int, float))):
        raise ValueError(f"{key}: fault sample's relative_change is {rc!r} (a number or "
                         "null); dropped")
    if since is not None and (isinstance(since, bool) or not isinstance(since, int)):
        raise ValueError(f"{key}: fault sample's explanation.since_t_ns is {since!r} (an "
                         "integer); dropped")
    # a clock in ns fits 64 bits, a confidence is finite (JSON's NaN and Infinity are not)
    for name, x in (("t_ns", d["t_ns"]), ("explanation.since_t_ns", since)):
        if x is not None and not is_int64(x):
            raise ValueError(f"{key}: fault sample's {name} {x} is beyond 64 bits; dropped")
    if not math.isfinite(d["confidence"]):
        raise ValueError(f"{key}: fault sample's confidence is {d['confidence']!r} (a finite "
                         "number); dropped")
    least = schema("uvd.fault.v1")["properties"]["confidence"]["minimum"]
    if d["confidence"] < least:  # the detector's sum over its threshold: below 1, no detection
        raise ValueError(f"{key}: fault sample's confidence {d['confidence']!r} is below "
                         f"{least:g} (uvd.fault.v1's minimum); dropped")
    return FaultReport(d["kind"], d["channel"], None if rc is None else float(rc),
                       int(d["t_ns"]), float(d["confidence"]), since)


def _event(kind: str, r: Mapping[str, Any]) -> dict[str, Any]:
    if kind == "failsafe":
        text = f"failsafe {r['kind']}: {r['trigger']} → {r['action']} ({r['reason']})"
    elif kind == "lifecycle":
        text = f"{r['from']} → {r['to']} ({r['event']}: {r['cause']})"
    elif kind == "command":
        text = f"{r['command']} from {r.get('source') or '?'}: " + (
            ("ok" + (f" — {r['reason']}" if r.get("reason") else "")) if r["ok"]
            else f"refused ({r['reason']})")  # an ok's reason: what it did (SetThrusterEta)
    elif kind == "reload":
        text = "reload: " + ("applied " + ", ".join(r.get("applied") or ()) if r.get("ok")
                             else f"refused ({r.get('error')})")
    elif kind == "sink":
        text = str(r["text"])
    else:
        text = f"started (uvd {r.get('version')})"
    rec = {k: v for k, v in r.items() if k != "config_toml"}
    return to_jsonable({"kind": kind, "text": text, "record": rec})


def zenoh_sink(config: Config, hub: TelemetryHub, vehicle: Any = None,
               commands: Any = None) -> ZenohSink:
    """The ``[telemetry.zenoh]`` sink of a configuration (docs/zenoh.md); ``vehicle``: the
    configured one when already loaded; ``commands``: the daemon's command queue, which
    uvd-fdc's fault samples go to when ``[faults.fdc]`` is enabled."""
    from uvd.runtime.schema import as_dict
    z = config.telemetry.zenoh
    base = Path(config.source).parent if config.source else Path.cwd()
    file = str(base / z.config_file) if z.config_file else None
    key = z.key or Path(config.vehicle.name).stem
    c = config.control
    configuration = {"vehicle": config.vehicle.name, "controller": c.controller,
                     "model": c.model, "kp": c.kp, "kd": c.kd, "eps": c.eps,
                     "reference": c.reference, "rate_hz": config.loop.rate_hz,
                     "failsafe": as_dict(config.failsafe),
                     # u = B f: what a client needs to tell a weak thruster (uvd-fdc)
                     "thruster_matrix": (vehicle or config.load_vehicle()).B.tolist()}
    return ZenohSink(key, zenoh_config(mode=z.mode, listen=z.listen, connect=z.connect,
                                       multicast_scouting=z.multicast_scouting,
                                       config_file=file),
                     state_hz=z.state_hz, health_hz=z.health_hz, configuration=configuration,
                     dropped=lambda: sum(s["dropped"] for s in hub.stats().values()),
                     faults=commands.put if commands is not None and config.faults.fdc.enabled
                     else None)
