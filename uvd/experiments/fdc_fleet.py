"""``uvd experiment fdc-fleet``: a fleet of lockstep vehicles publishing over Zenoh to one
``uvd-fdc`` process, on the simulated clock.

One vehicle per fault of :data:`uvd.experiments.fdc.FAULTS` (injected after 30 simulated
minutes) and one without a fault, each a :class:`~uvd.experiments.fdc.SimVehicle` whose
estimates (AID's and AMBC's, every 10 simulated seconds) and state (``STATE_HZ``) go through
the daemon's own Zenoh sink (:class:`~uvd.links.zenoh.ZenohSink`, key ``sim<i>``, its
own loopback port, its ``params`` queryable answering the thruster matrix), stamped with the
simulated clock — so an hour of a fleet passes in about a minute. A separate
``uvd-fdc`` process connects to every vehicle and learns, detects and publishes on
``uvd/<vehicle>/fault/<kind>`` exactly as it would for real vehicles; this experiment listens
to those fault samples (the documented key space, ``uvd.fault.v1``) and to the client's
counts (``--stats``: samples received, gaps in ``seq``).
"""

from __future__ import annotations

import asyncio
import json
import threading
import time

from uvd.errors import ExperimentError
from uvd.experiments import Experiment, ExperimentOptions
from uvd.experiments.fdc import FAULTS

#: state samples a simulated second (of the 10 Hz loop): enough for the residual's 10 s
#: segments (the detector names the faults alike from 2 to 10 Hz), a fifth of the load
STATE_HZ = 2.0


def run(opts: ExperimentOptions) -> dict:
    import zenoh

    from uvd.bench.zenoh import FdcProcess
    from uvd.experiments.fdc import SimVehicle
    from uvd.links.zenoh import ZenohSink, zenoh_config
    from uvd.netports import free_port
    from uvd.zenoh_callbacks import SessionCallbacks

    hours = 1.0 if opts.hours is None else opts.hours
    nominal_min = 30.0  # uvd-fdc's baseline is learned from 5 to 25 min
    if hours * 60.0 <= nominal_min:
        raise ExperimentError(f"fdc-fleet: --hours {hours:g} is too short: the faults come "
                              f"after {nominal_min:g} min (uvd-fdc learns its baseline over "
                              "the first 25)")
    faults = [*FAULTS, None]
    vehicles = [SimVehicle(f, nominal_min, opts.seed + i) for i, f in enumerate(faults)]
    names = [f"sim{i}" for i in range(len(vehicles))]
    endpoints = [f"tcp/127.0.0.1:{free_port()}" for _ in vehicles]
    sinks = [ZenohSink(name, zenoh_config(listen=[ep]), state_hz=STATE_HZ, health_hz=0.0,
                       configuration={"thruster_matrix": v.B.tolist()})
             for name, ep, v in zip(names, endpoints, vehicles, strict=True)]
    n_cycles = int(round(hours * 3600.0 * vehicles[0].rate))
    observer_ep = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh_config(listen=[observer_ep])
    found: dict[str, list[dict]] = {n: [] for n in names}
    lock = threading.Lock()

    def on_fault(sample) -> None:
        vehicle = str(sample.key_expr).split("/")[1]
        with lock:
            found.setdefault(vehicle, []).append(json.loads(sample.payload.to_bytes()))

    t0 = time.perf_counter()
    observer = zenoh.open(conf)
    callbacks = SessionCallbacks()
    try:
        observer.declare_subscriber("uvd/*/fault/*", callbacks(on_fault))
        fdc = None

        async def main() -> None:
            nonlocal fdc
            for s in sinks:
                await s.open()
            fdc = FdcProcess([observer_ep, *endpoints])
            await fdc.subscribed()
            await asyncio.sleep(2.0)  # its subscriptions reach every vehicle
            try:
                report = n_cycles // 4
                while any(v.next_k < n_cycles for v in vehicles):
                    for v, s in zip(vehicles, sinks, strict=True):
                        if v.next_k < n_cycles:
                            estimates = v.next_estimates()
                            await s.write([*v.cycles, *estimates])
                    k = vehicles[0].k
                    if report and k // report != (k - vehicles[0].every) // report:
                        opts.progress(f"  fdc-fleet: simulated {k / vehicles[0].rate / 60:.0f}"
                                      f" / {hours * 60:.0f} min of {len(vehicles)} vehicles "
                                      f"({time.perf_counter() - t0:.0f} s wall)")
                await asyncio.sleep(2.0)  # the last samples and faults arrive
            finally:
                for s in sinks:
                    await s.aclose()

        try:
            asyncio.run(main())
        finally:
            stats = fdc.finish() if fdc is not None else {}
    finally:
        callbacks.close(observer)
    published = {k: n for s in sinks for k, n in s._seq.items()}
    received = stats.get("received", {})
    runs = {}
    for name, v in zip(names, vehicles, strict=True):
        runs[name] = v.outcome(found.get(name, []))
    lost = sum(n - received.get(k, 0) for k, n in published.items())
    n_state = sum(n for k, n in published.items() if k.endswith("/state"))
    wall = time.perf_counter() - t0
    lines = [f"fdc-fleet: {len(vehicles)} lockstep vehicles × {hours:g} h → Zenoh → one uvd-fdc"
             f" process; samples published {sum(published.values())} (estimates "
             f"{sum(published.values()) - n_state}, state {n_state}), lost {lost}",
             f"{'vehicle':>8} {'fault':>12} {'detected':>9} {'kind':>13} {'right':>6} "
             f"{'latency':>9} {'alarms':>7}"]
    for name, r in runs.items():
        if r["fault"] is None:
            lines.append(f"{name:>8} {'none':>12} {'-':>9} {'-':>13} {'-':>6} {'-':>9} "
                         f"{r['false_alarms']:>7}")
            continue
        lat = "-" if r["latency_s"] is None else f"{r['latency_s']:.0f} s"
        lines.append(f"{name:>8} {r['fault']:>12} {str(r['detected']):>9} "
                     f"{str(r['kind']):>13} {str(r['right_kind']):>6} {lat:>9} "
                     f"{len(r['detections']):>7}")
    lines.append(f"wall {wall:.0f} s")
    return {"summary": "\n".join(lines), "runs": runs, "vehicles": len(vehicles),
            "hours": hours, "published": published, "received": received,
            "estimates_lost": lost, "gaps_in_seq": sum(stats.get("lost", {}).values()),
            "latency_ms": stats.get("latency_ms"), "wall_s": wall,
            "fdc_output": fdc.out.strip().splitlines()[-40:]}


EXPERIMENTS = [Experiment("fdc-fleet", "a fleet of lockstep vehicles (one per fault of issue "
                                       "19, one without) publishing over Zenoh to one uvd-fdc "
                                       "process, on the simulated clock", run)]
