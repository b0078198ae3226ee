"""``uvd-fdc``: watch one vehicle or a fleet over Zenoh and report faults.

Subscribes to ``uvd/*/estimate/**`` and ``uvd/*/state`` (the key space of docs/zenoh.md; JSON
payloads of schemas ``uvd.zestimate.v1`` and ``uvd.state.v1``), asks each vehicle's
``uvd/<vehicle>/params?what=configuration`` for its thruster matrix, runs one
:class:`~uvd.fdc.detector.VehicleDetector` per vehicle and estimator (the state stream and the
thruster matrix let it name a weak thruster), prints each detection and publishes it on
``uvd/<vehicle>/fault/<kind>`` (``uvd.fault.v1``: kind, t_ns, channel, magnitude in σ,
relative change, confidence, the residual's explanation). Vehicles are followed by
their liveliness token ``uvd/<vehicle>/alive``: one that goes away is forgotten, and one that
comes back starts a new baseline (it may have been repaired, or restarted with other
parameters). So does one whose thruster effectiveness η changed (its ``uvd/<vehicle>/event``:
the operator's ``SetThrusterEta``, a fault sample acted on, the amplifier's own fault
accommodated): the vehicle is another from then on — a fault accommodated, or a thruster
repaired and cleared — and a later fault is found against it (before session 34 a vehicle
that had alarmed once was held faulty until its daemon restarted: no second fault was ever
reported); an event setting the η this client saw set last changes nothing. Nothing of the
daemon is imported: only the wire contract.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import signal
import sys
import threading
import time
from collections import deque

from uvd.cliargs import output_file
from uvd.fdc.align import STREAMS, Aligned
from uvd.fdc.detector import CusumSettings, VehicleDetector, thruster_matrix
from uvd.zenoh_callbacks import SessionCallbacks
from uvd.zenoh_names import endpoint_problem, vehicle_key_problem

#: state samples of a vehicle kept until its first estimate (10 minutes at 100 Hz)
EARLY_STATES = 60_000


class LinkStats:
    """Per key: samples received, samples lost (gaps in ``seq``, which the daemon raises by
    one a sample per key), samples dropped as malformed, and end-to-end latencies (receipt −
    ``wall_time``, seconds)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.received: dict[str, int] = {}
        self.lost: dict[str, int] = {}
        self.last_seq: dict[str, int] = {}
        self.dropped: dict[str, int] = {}
        self._dropped_for: dict[tuple[str, str], int] = {}
        self.latency_s: list[float] = []

    def drop(self, key: str, why: str, detail: str = "") -> str | None:
        """Count a sample of ``key`` dropped as malformed for ``why``; the line that tells it
        (``detail`` of this one), at the first and every 1000th of the key for that reason:
        a flood of malformed samples is not a line each (None: not told)."""
        with self._lock:
            self.dropped[key] = self.dropped.get(key, 0) + 1
            n = self._dropped_for[key, why] = self._dropped_for.get((key, why), 0) + 1
        if n == 1 or n % 1000 == 0:
            return f"{key}: {why}{detail}; dropped" + ("" if n == 1 else f" ({n} so far)")
        return None

    def take(self, key: str, payload: dict) -> None:
        now = time.time()
        with self._lock:
            self.received[key] = self.received.get(key, 0) + 1
            seq, last = payload.get("seq"), self.last_seq.get(key)
            if isinstance(seq, int):
                if last is not None and seq > last + 1:
                    self.lost[key] = self.lost.get(key, 0) + seq - last - 1
                self.last_seq[key] = seq
            if isinstance(payload.get("wall_time"), (int, float)):
                self.latency_s.append(now - payload["wall_time"])

    def summary(self) -> dict:
        with self._lock:
            lat = sorted(self.latency_s)
            ms = {"n": len(lat), "p50": None, "p99": None, "max": None}
            if lat:
                ms.update(p50=lat[len(lat) // 2] * 1e3,
                          p99=lat[min(len(lat) - 1, int(0.99 * len(lat)))] * 1e3,
                          max=lat[-1] * 1e3)
            return {"received": dict(self.received), "lost": dict(self.lost),
                    "dropped": dict(self.dropped), "last_seq": dict(self.last_seq),
                    "latency_ms": ms}


def endpoint(text: str) -> str:
    """``--connect``: a Zenoh endpoint (:func:`uvd.zenoh_names.endpoint_problem`)."""
    why = endpoint_problem(text)
    if why:
        raise argparse.ArgumentTypeError(f"{text!r} {why}")
    return text


def vehicle_pattern(text: str) -> str:
    """``--vehicle``: one vehicle's key, or ``*`` for every vehicle."""
    why = None if text == "*" else vehicle_key_problem(text)
    if why:
        raise argparse.ArgumentTypeError(f"{text!r} {why}; or * for every vehicle")
    return text


def zenoh_message(exc: BaseException) -> str:
    """A ``zenoh.ZError``'s text without the Rust source locations it ends its lines with."""
    return re.sub(r"\s+at /\S+\.rs:\d+\.?", "", str(exc)).strip()


def add_connection_arguments(p: argparse.ArgumentParser) -> None:
    """``--connect`` and ``--zenoh-config`` of a client (:func:`client_config`)."""
    p.add_argument("--connect", action="append", type=endpoint, default=[], metavar="ENDPOINT",
                   help="a daemon's (or router's) endpoint (repeatable; default "
                        "tcp/127.0.0.1:7447)")
    p.add_argument("--zenoh-config", metavar="FILE",
                   help="a Zenoh JSON5 configuration (client mode through a router, "
                        "user/password, TLS: config/zenoh/fdc.json5, docs/zenoh.md)")


def client_config(connect: list[str], config_file: str | None = None):
    """The ``zenoh.Config`` of a client of the key space: ``config_file`` (JSON5) when given,
    else a peer with multicast scouting off; ``connect`` endpoints (default, without a file,
    ``tcp/127.0.0.1:7447``: the demo's daemon) replace the file's.

    Raises ValueError naming ``--zenoh-config``: a file that is missing or not Zenoh's JSON5."""
    import zenoh
    if config_file:
        try:
            conf = zenoh.Config.from_file(str(config_file))
        except zenoh.ZError as exc:
            raise ValueError(f"--zenoh-config {config_file}: {zenoh_message(exc)}") from exc
    else:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        connect = connect or ["tcp/127.0.0.1:7447"]
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return conf


#: seconds after which a client that has reached no router or peer says so
REACH_S = 3.0


def reached_through(connect: list[str], config_file: str | None = None) -> str:
    """What a client connects through, in words: its endpoints, its file, or the default."""
    return ", ".join(connect) or config_file or "tcp/127.0.0.1:7447"


class ReachNote:
    """The note a client prints once, :data:`REACH_S` after it opened, when its session has
    reached no router or peer (a wrong endpoint, no daemon yet: a peer's session opens anyway
    and waits in silence), or, watching one ``vehicle``, when no liveliness token of that
    name is up where it reached (a misspelt name: the vehicles that are up are named). The
    client goes on trying either way."""

    def __init__(self, session, via: str, who: str, vehicle: str = "*") -> None:
        self.session, self.via, self.who, self.vehicle = session, via, who, vehicle
        self._t0 = time.monotonic()
        self._due: float | None = self._t0 + REACH_S

    def due(self, ending: bool = False) -> str | None:
        """The note, the first time it is asked for after REACH_S if nothing was reached;
        None before, after, or when something was. ``ending``: the client's last look (its
        ``--seconds`` are over): the note then comes whenever it is, without "still trying"
        (it said so as it stopped, or nothing at all for a run shorter than REACH_S)."""
        if self._due is None or (not ending and time.monotonic() < self._due):
            return None
        self._due = None
        info = self.session.info
        waited = time.monotonic() - self._t0 if ending else REACH_S
        waited_s = f"{waited:.0f}" if waited >= 1.0 else f"{waited:.1f}"  # a 0.5 s run: "0.5"
        trying = "" if ending else "; still trying"
        if list(info.routers_zid()) or list(info.peers_zid()):
            up = self._vehicles_up()
            if "*" in self.vehicle or up is None or self.vehicle in up:
                return None
            return (f"{self.who}: no vehicle {self.vehicle!r} through {self.via} in "
                    f"{waited_s} s; " + (f"up there: {', '.join(up)} (--vehicle NAME, or * "
                                         "for every vehicle)" if up else
                                         "no uvd vehicle is up there") + trying)
        return (f"{self.who}: nothing reached through {self.via} in {waited_s} s (is the "
                "daemon running, its [telemetry.zenoh] listen that endpoint?)" + trying)

    def _vehicles_up(self) -> list[str] | None:
        """The vehicles whose liveliness token ``uvd/<vehicle>/alive`` answers (within a
        second), None when the query fails."""
        try:
            replies = self.session.liveliness().get("uvd/*/alive", timeout=1.0)
            return sorted({str(r.ok.key_expr).split("/")[1] for r in replies
                           if r.ok is not None})
        except Exception:  # noqa: BLE001 - a note is not worth failing the client over
            return None


def open_client(connect: list[str], config_file: str | None = None):
    """``zenoh.open`` of :func:`client_config`. Raises ValueError in words where zenoh raises
    its ZError: the configuration file, or a router that cannot be reached (client mode)."""
    import zenoh
    conf = client_config(connect, config_file)
    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        raise ValueError(f"cannot open the Zenoh session: {zenoh_message(exc)}") from exc


class FleetWatch:
    """What one session watches: per (vehicle, estimator) a :class:`VehicleDetector` and the
    :class:`~uvd.fdc.align.Aligned` that merges its two streams by time stamp (the verdict must
    not depend on how the two subscriptions' samples interleave or how late they arrive), per
    vehicle its thruster matrix. Zenoh's callback threads call :meth:`on_estimate`,
    :meth:`on_state` and :meth:`on_alive`; the main thread calls :meth:`tick` (it asks new
    vehicles for their thruster matrix and releases what the aligners hold as time passes).
    One lock guards the state; detections are printed and put on
    ``uvd/<vehicle>/fault/<kind>`` outside it."""

    def __init__(self, session, settings: CusumSettings, stats: bool) -> None:
        import zenoh
        self.session, self.settings, self.stats = session, settings, stats
        self._put = zenoh.SampleKind.PUT
        self._fault_encoding = zenoh.Encoding("application/json;schema=uvd.fault.v1")
        self.lock = threading.Lock()
        self.link = LinkStats()
        self.detectors: dict[tuple[str, str], VehicleDetector] = {}
        self.aligned: dict[tuple[str, str], Aligned] = {}
        self.thrusters: dict[str, object] = {}  # vehicle → its thruster matrix B (None: unknown)
        self.asked: set[str] = set()  # vehicles asked for B (again when they come back)
        self.settled: set[str] = set()  # vehicles whose question for B is answered
        #: vehicle → thruster → the η its events last set it to (:meth:`on_event`)
        self.etas: dict[str, dict[int, float]] = {}
        self.early: dict[str, deque] = {}  # vehicle → state samples before its first estimate

    def say(self, text: str) -> None:
        with self.lock:
            print(text, flush=True)

    def tell(self, line: str | None) -> None:
        if line is not None:
            self.say(line)

    # ------------------------------------------------------------------ Zenoh's threads

    def on_estimate(self, sample) -> None:
        parts = str(sample.key_expr).split("/")
        if len(parts) != 4:
            return
        vehicle, estimator = parts[1], parts[3]
        payload = self._json_object(sample)
        if payload is None:
            return
        if self.stats:
            self.link.take(str(sample.key_expr), payload)
        if payload.get("source") == "controller":
            return  # an adaptive controller's θ̂ moves by design (AMBC's step 1 → 2)
        t_ns = self._stamp(sample, payload)
        if t_ns is None:
            return
        now = time.monotonic()
        with self.lock:
            al = self.aligned.get((vehicle, estimator))
            if al is None:
                self.detectors[vehicle, estimator] = VehicleDetector(
                    vehicle, self.settings, B=self.thrusters.setdefault(vehicle, None))
                al = self.aligned[vehicle, estimator] = Aligned(now)
                al.paused = vehicle not in self.settled  # the detector starts with its B
                for t_state, item in self.early.pop(vehicle, ()):
                    al.push("state", t_state, item, now)
            found = self._feed(vehicle, estimator,
                               al.push("estimate", t_ns, (str(sample.key_expr), payload), now))
        self._report(vehicle, found)

    def on_state(self, sample) -> None:
        payload = self._json_object(sample)
        if payload is None:
            return
        if self.stats:
            self.link.take(str(sample.key_expr), payload)
        t_ns = self._stamp(sample, payload)
        if t_ns is None:
            return
        vehicle, key = str(sample.key_expr).split("/")[1], str(sample.key_expr)
        now, found = time.monotonic(), []
        with self.lock:
            mine = [(e, al) for (v, e), al in self.aligned.items() if v == vehicle]
            if not mine:  # no estimate yet: kept for the detectors to come
                self.early.setdefault(vehicle, deque(maxlen=EARLY_STATES)).append(
                    (t_ns, (key, payload)))
            for estimator, al in mine:
                found += self._feed(vehicle, estimator,
                                    al.push("state", t_ns, (key, payload), now))
        self._report(vehicle, found)

    def on_event(self, sample) -> None:
        """An event of the vehicle's (``uvd.event.v1``) that changed its thruster
        effectiveness: its detectors start a new baseline (the module docstring). One that
        sets a thruster to the η this client saw it set to last changes nothing (an operator
        clearing a thruster twice: each new baseline costs ``warmup_s + baseline_s``)."""
        payload = self._json_object(sample)
        what = None if payload is None else eta_set(payload)
        if what is None:
            return
        vehicle = str(sample.key_expr).split("/")[1]
        with self.lock:
            seen = self.etas.setdefault(vehicle, {})
            if what is True:  # a thruster set to an η not read here: none is known now
                seen.clear()
            elif seen.get(what[0]) == what[1]:
                return
            else:
                seen[what[0]] = what[1]
            for key in [k for k in self.detectors if k[0] == vehicle]:
                del self.detectors[key], self.aligned[key]
            self.early.pop(vehicle, None)
        self.say(f"{vehicle}: thruster effectiveness changed ({payload.get('text')}): a new "
                 "baseline")

    def on_alive(self, sample) -> None:
        vehicle = str(sample.key_expr).split("/")[1]
        if sample.kind == self._put:
            self.say(f"{vehicle}: up")
            return
        with self.lock:
            for key in [k for k in self.detectors if k[0] == vehicle]:
                del self.detectors[key], self.aligned[key]
            self.thrusters.pop(vehicle, None)
            self.etas.pop(vehicle, None)
            self.asked.discard(vehicle)
            self.settled.discard(vehicle)
            self.early.pop(vehicle, None)
        self.say(f"{vehicle}: gone (its baseline is forgotten)")

    # ------------------------------------------------------------------ the main thread

    def tick(self) -> None:
        """Ask each new vehicle for its thruster matrix; release what the aligners hold (a
        stream gone quiet stops holding the other)."""
        with self.lock:
            unknown = [v for v, B in self.thrusters.items() if B is None and v not in self.asked]
        for vehicle in unknown:
            self.asked.add(vehicle)
            self._ask_thrusters(vehicle)
        self._release()

    def closing_lines(self, late: dict[str, int], forced: int) -> list[str]:
        """What the client says as it ends: malformed samples dropped, samples late (``late``
        and ``forced`` of :meth:`lateness`)."""
        lines = []
        if self.link.dropped:
            lines.append(f"uvd-fdc: dropped {sum(self.link.dropped.values())} malformed samples "
                         f"({', '.join(f'{k} {n}' for k, n in sorted(self.link.dropped.items()))})")
        if any(late.values()) or forced:
            lines.append(f"uvd-fdc: samples late behind the other stream: {late} (late state "
                         f"samples dropped); released unaligned (too many held): {forced}")
        return lines

    def lateness(self) -> tuple[dict[str, int], int]:
        """Samples late per stream and those released unaligned, over every aligner."""
        late = {s: sum(al.late[s] for al in self.aligned.values()) for s in STREAMS}
        return late, sum(al.forced for al in self.aligned.values())

    # ------------------------------------------------------------------ inside

    def _feed(self, vehicle: str, estimator: str, released) -> list:
        """Give the detector of (vehicle, estimator) the samples its aligner released (lock
        held); a malformed one is counted and dropped."""
        det, found = self.detectors[vehicle, estimator], []
        for stream, (key, payload) in released:
            try:
                found += det.update(payload) if stream == "estimate" else \
                    det.update_state(payload)
            except (KeyError, TypeError, ValueError) as exc:
                line = self.link.drop(key, f"malformed {stream}", f" ({exc})")
                if line is not None:
                    print(line, flush=True)  # the lock is held: not say()
        return found

    def _release(self, vehicle: str | None = None) -> None:
        """What the aligners (of ``vehicle``; None: all) release as time passes."""
        now, found = time.monotonic(), {}
        with self.lock:
            for (v, e), al in self.aligned.items():
                if vehicle is None or v == vehicle:
                    found.setdefault(v, []).extend(self._feed(v, e, al.pop(now)))
        for v, f in found.items():
            self._report(v, f)

    def _report(self, vehicle: str, found) -> None:
        for d in found:
            rel = "n/a" if d.relative_change is None else f"{d.relative_change:+.1%}"
            self.say(f"FAULT {vehicle}: {d.kind} ({d.channel} {rel}, "
                     f"{d.magnitude:+.1f} σ, confidence {d.confidence:.1f})")
            self.session.put(f"uvd/{vehicle}/fault/{d.kind}", json.dumps(d.as_dict()),
                             encoding=self._fault_encoding)

    def _ask_thrusters(self, vehicle: str) -> None:
        """The vehicle's thruster matrix from its ``params`` queryable."""
        for reply in self.session.get(f"uvd/{vehicle}/params?what=configuration", timeout=2.0):
            try:
                conf = json.loads(reply.ok.payload.to_bytes())["configuration"]
                B = thruster_matrix(conf["thruster_matrix"])
            except (AttributeError, KeyError, TypeError, ValueError) as exc:
                self.say(f"uvd/{vehicle}/params: no usable thruster matrix ({exc!r}); faults "
                         "are reported with the kind of the estimates' channel")
                break
            with self.lock:
                self.thrusters[vehicle] = B
                for (v, _), det in self.detectors.items():
                    if v == vehicle:
                        det.set_thrusters(B)
            break
        self._settle(vehicle)

    def _settle(self, vehicle: str) -> None:
        """The question of ``vehicle``'s B is answered (B, or none usable, or no reply): its
        samples flow to the detectors."""
        with self.lock:
            self.settled.add(vehicle)
            for (v, _), al in self.aligned.items():
                if v == vehicle:
                    al.paused = False
        self._release(vehicle)

    def _json_object(self, sample) -> dict | None:
        try:
            payload = json.loads(sample.payload.to_bytes())
        except ValueError as exc:
            self.tell(self.link.drop(str(sample.key_expr), "not JSON", f" ({exc})"))
            return None
        if not isinstance(payload, dict):
            self.tell(self.link.drop(str(sample.key_expr), "not a JSON object"))
            return None
        return payload

    def _stamp(self, sample, payload: dict) -> int | None:
        """The sample's ``t_ns`` (an integer), else counted and dropped."""
        t_ns = payload.get("t_ns")
        if isinstance(t_ns, int) and not isinstance(t_ns, bool):
            return t_ns
        self.tell(self.link.drop(str(sample.key_expr), "no integer t_ns", f" ({t_ns!r:.40})"))
        return None


def eta_set(event: dict) -> tuple[int, float] | None | bool:
    """What a vehicle's event (``uvd.event.v1``: kind, text, record) set a thruster's
    effectiveness η to: (thruster, η) of the operator's ``SetThrusterEta`` done, from its
    recorded arguments; True for an η set that is always a change — a ``FaultReport`` acted
    on (its reason goes on "→ thruster …"), a failsafe ``accommodated`` event (a thruster
    newly set by the amplifier's fault or a sample confirmed after it waited) — or a
    ``SetThrusterEta`` whose arguments do not read; None for any other event. Only recorded
    fields are read, never the words of a reason for numbers."""
    r = event.get("record")
    if not isinstance(r, dict):
        return None
    if event.get("kind") == "failsafe":
        return True if r.get("kind") == "accommodated" else None
    if event.get("kind") != "command" or r.get("ok") is not True:
        return None
    if r.get("command") == "SetThrusterEta":
        args = r.get("args") if isinstance(r.get("args"), dict) else {}
        try:
            return int(args["thruster"]), float(args["eta"])
        except (KeyError, TypeError, ValueError):
            return True
    if r.get("command") == "FaultReport" and "→ thruster" in str(r.get("reason")):
        return True
    return None


def _arguments(argv: list[str] | None) -> tuple[argparse.Namespace, CusumSettings]:
    """The command line and the detector's settings it gives; exit 2 naming what is wrong."""
    p = argparse.ArgumentParser(prog="uvd-fdc", description=__doc__.split("\n\n")[0])
    add_connection_arguments(p)
    p.add_argument("--vehicle", type=vehicle_pattern, default="*",
                   help="vehicle key or * (default: every vehicle)")
    p.add_argument("--seconds", type=float, default=0.0, help="stop after this long (0: never)")
    p.add_argument("--stats", type=output_file, metavar="FILE",
                   help="write, at the end, per key the samples received, those lost (gaps "
                        "in seq) and the end-to-end latency (receipt − the payload's "
                        "wall_time: same machine only)")
    p.add_argument("--warmup-s", type=float, default=CusumSettings.warmup_s)
    p.add_argument("--baseline-s", type=float, default=CusumSettings.baseline_s)
    p.add_argument("--reference-lag-s", type=float, default=CusumSettings.reference_lag_s,
                   help="deviations are taken from the median of the baseline_s of estimates "
                        "that ended this long ago (it follows AID's slow drift, not a fault)")
    p.add_argument("--segment-s", type=float, default=CusumSettings.segment_s,
                   help="length of the commanded vs realised wrench residual's segments (the "
                        "baseline needs 10 of them to name a thruster)")
    p.add_argument("--threshold", type=float, default=CusumSettings.h,
                   help="CUSUM h (a log-likelihood ratio: about one false alarm in e^h "
                        "estimates)")
    args = p.parse_args(argv)
    if not (math.isfinite(args.seconds) and args.seconds >= 0.0):
        p.error(f"argument --seconds: {args.seconds!r} is not a finite number >= 0")
    try:  # a NaN threshold, a negative window…: one line naming it, exit 2, before Zenoh
        settings = CusumSettings(warmup_s=args.warmup_s, baseline_s=args.baseline_s,
                                 reference_lag_s=args.reference_lag_s,
                                 h=args.threshold, segment_s=args.segment_s)
    except ValueError as exc:
        text = str(exc)
        for name, option in (("warmup_s", "--warmup-s"), ("baseline_s", "--baseline-s"),
                             ("reference_lag_s", "--reference-lag-s"), ("h", "--threshold"),
                             ("segment_s", "--segment-s")):
            text = text.replace(f"CusumSettings.{name} ", f"argument {option} ")
        p.error(text)
    return args, settings


def main(argv: list[str] | None = None) -> int:
    args, settings = _arguments(argv)
    from uvd.fdc.residual import warm
    warm()  # the residual's kernels before any sample waits on them

    try:
        session = open_client(args.connect, args.zenoh_config)
    except ValueError as exc:
        print(f"uvd-fdc: error: {exc}", file=sys.stderr)
        return 2
    watch = FleetWatch(session, settings, stats=bool(args.stats))
    callbacks = SessionCallbacks()
    try:
        session.declare_subscriber(f"uvd/{args.vehicle}/estimate/*",
                                   callbacks(watch.on_estimate))
        session.declare_subscriber(f"uvd/{args.vehicle}/state", callbacks(watch.on_state))
        session.declare_subscriber(f"uvd/{args.vehicle}/event", callbacks(watch.on_event))
        session.liveliness().declare_subscriber(f"uvd/{args.vehicle}/alive",
                                                callbacks(watch.on_alive), history=True)
        watch.say(f"uvd-fdc: watching uvd/{args.vehicle}/estimate/* and state (baseline after "
                  f"{settings.warmup_s:g} s over {settings.baseline_s:g} s; "
                  f"h {settings.h:g})")
        # SIGTERM (systemd, a parent) and SIGINT (Ctrl-C; also when started in the background,
        # where a shell would have it ignored) end it cleanly: counts written
        stop = threading.Event()
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: stop.set())
        deadline = time.monotonic() + args.seconds if args.seconds > 0 else math.inf
        reach = ReachNote(session, reached_through(args.connect, args.zenoh_config), "uvd-fdc",
                          args.vehicle)
        while not stop.wait(min(0.2, max(0.0, deadline - time.monotonic()))):
            if time.monotonic() >= deadline:
                watch.tell(reach.due(ending=True))
                break
            watch.tell(reach.due())
            watch.tick()
    finally:
        callbacks.close(session, warn=watch.say, who="uvd-fdc")  # their threads ended
        late, forced = watch.lateness()
        for line in watch.closing_lines(late, forced):
            watch.say(line)
        if args.stats:
            args.stats.parent.mkdir(parents=True, exist_ok=True)
            with open(args.stats, "w") as f:
                json.dump({**watch.link.summary(), "late": late, "forced": forced}, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
