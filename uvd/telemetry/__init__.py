"""Telemetry fed off the control loop (never on its critical path).

:class:`~uvd.telemetry.sink.TelemetryHub` takes one record per cycle from the loop through
bounded, non-blocking queues (drop-oldest-and-count) and pumps them to every
:class:`~uvd.telemetry.sink.TelemetrySink`; the sinks — the daemon's faces: JSON lines, Zenoh,
MAVLink, the black box, the parameters file — are in :mod:`uvd.links`. Here: the hub and the
sink base, the record types (:mod:`uvd.telemetry.records`), the black box's channel contract
and reader (:mod:`uvd.telemetry.recording`) and the JSON Schemas (``schemas/``).
"""

from uvd.telemetry.sink import BoundedQueue, SinkStats, TelemetryHub, TelemetrySink

__all__ = ["BoundedQueue", "SinkStats", "TelemetryHub", "TelemetrySink"]
