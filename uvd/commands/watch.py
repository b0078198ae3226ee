"""``uvd watch [--connect ENDPOINT] [--zenoh-config FILE] [--vehicle '*'] [--seconds S]``.

Watches vehicles over Zenoh (docs/zenoh.md) as any client would — through the documented key
space and JSON payloads only, nothing of the daemon's classes: one line a second per vehicle
(pose, mode, action, thrust), every event as it comes, the failsafe triggers active, the
amplifier faults and the telemetry sinks that fail as ``health`` says, when they change (so a
watcher that comes after the events is told what holds), and the vehicles coming and going
(liveliness). An unreadable sample is told at the first and every 1000th of its key
for each kind, as uvd-fdc tells them, and all are counted at the end.
"""

from __future__ import annotations

import json
import math
import sys
import threading
import time

from uvd.cliargs import nonnegative_float

#: the lists of a ``health`` sample printed when they change (a watcher that comes late is
#: told what holds: the events that said so went before it)
_HEALTH_LISTS = (("triggers", "failsafe triggers active"),
                 ("amplifier_faults", "amplifier faults"),
                 ("sinks_failing", "telemetry sinks failing"))


def register(sub) -> None:
    p = sub.add_parser("watch", help="watch running vehicles over Zenoh (docs/zenoh.md)",
                       description="Print the state, events and liveliness of uvd vehicles.")
    from uvd.fdc.client import add_connection_arguments, vehicle_pattern
    add_connection_arguments(p)
    p.add_argument("--vehicle", type=vehicle_pattern, default="*",
                   help="vehicle key, or * for all (default)")
    p.add_argument("--seconds", type=nonnegative_float, default=0.0,
                   help="stop after this long (default 0: until Ctrl-C, as uvd-fdc's)")
    p.set_defaults(handler=_run)


def _run(args) -> int:
    import zenoh

    from uvd.fdc.client import LinkStats, ReachNote, open_client, reached_through
    from uvd.zenoh_callbacks import SessionCallbacks
    lock = threading.Lock()
    last_line: dict[str, float] = {}
    unreadable = LinkStats()  # only its count of samples dropped

    def out(text: str | None) -> None:
        if text is not None:
            with lock:
                print(text, flush=True)

    def on_state(sample) -> None:
        try:
            m = json.loads(sample.payload.to_bytes())
            key = str(sample.key_expr).split("/")[1]
            now = time.monotonic()
            if now - last_line.get(key, 0.0) < 1.0:
                return
            last_line[key] = now
            p, rpy = m["p"], [math.degrees(a) for a in m["rpy"]]
            out(f"{key:>12} {m['state']:<8} {m['mode']:<12} {m['action']:<11} "
                f"n {p[0]:7.2f} e {p[1]:7.2f} d {p[2]:6.2f} m  roll {rpy[0]:6.1f} pitch "
                f"{rpy[1]:6.1f} heading {rpy[2]:7.1f} deg  |thrust| max "
                f"{max(abs(x) for x in m['thrust']):6.1f} N")
        except (ValueError, KeyError, TypeError) as exc:
            out(unreadable.drop(str(sample.key_expr), "unreadable state sample", f" ({exc})"))

    def on_event(sample) -> None:
        try:
            m = json.loads(sample.payload.to_bytes())
            out(f"{str(sample.key_expr).split('/')[1]:>12} event: {m['text']}")
        except (ValueError, KeyError, TypeError) as exc:
            out(unreadable.drop(str(sample.key_expr), "unreadable event", f" ({exc})"))

    #: each vehicle's health lists, as last printed (none before its first sample)
    told: dict[tuple[str, str], list[str]] = {}

    def on_health(sample) -> None:
        try:
            m = json.loads(sample.payload.to_bytes())
            key = str(sample.key_expr).split("/")[1]
            for field, what in _HEALTH_LISTS:
                now = m.get(field, [])
                if not (isinstance(now, list) and all(isinstance(x, str) for x in now)):
                    raise TypeError(f"{field} is not a list of names")
                if now != told.get((key, field), []):
                    out(f"{key:>12} {what}: {', '.join(now) or 'none'}")
                told[(key, field)] = now
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            out(unreadable.drop(str(sample.key_expr), "unreadable health sample", f" ({exc})"))

    def on_alive(sample) -> None:
        what = "up" if sample.kind == zenoh.SampleKind.PUT else "gone"
        out(f"{str(sample.key_expr).split('/')[1]:>12} {what}")

    try:
        session = open_client(args.connect, args.zenoh_config)
    except ValueError as exc:
        print(f"uvd watch: error: {exc}", file=sys.stderr)
        return 2
    callbacks = SessionCallbacks()
    try:
        v = args.vehicle
        session.declare_subscriber(f"uvd/{v}/state", callbacks(on_state))
        session.declare_subscriber(f"uvd/{v}/event", callbacks(on_event))
        session.declare_subscriber(f"uvd/{v}/health", callbacks(on_health))
        session.liveliness().declare_subscriber(f"uvd/{v}/alive", callbacks(on_alive),
                                                history=True)
        via = reached_through(args.connect, args.zenoh_config)
        out(f"watching uvd/{v}/… through {via} (Ctrl-C to stop)")
        deadline = time.monotonic() + args.seconds if args.seconds > 0 else math.inf
        reach = ReachNote(session, via, "uvd watch", v)  # say so, and go on trying
        while True:
            time.sleep(min(0.2, max(0.0, deadline - time.monotonic())))
            ending = time.monotonic() >= deadline
            if (note := reach.due(ending=ending)) is not None:
                print(note, file=sys.stderr, flush=True)
            if ending:
                break
    except KeyboardInterrupt:
        pass
    finally:
        callbacks.close(session)  # and their threads ended: none left at exit
    if dropped := unreadable.summary()["dropped"]:
        each = ", ".join(f"{k} {n}" for k, n in sorted(dropped.items()))
        print(f"uvd watch: dropped {sum(dropped.values())} unreadable samples ({each})",
              file=sys.stderr, flush=True)
    sys.stdout.flush()
    return 0
