"""Telemetry fed off the control loop (never on its critical path).

:class:`~uvd.telemetry.sink.TelemetryHub` takes one record per cycle from the loop through
bounded, non-blocking queues (drop-oldest-and-count) and pumps them to every
:class:`~uvd.telemetry.sink.TelemetrySink`: the JSON-lines file of
:mod:`uvd.telemetry.jsonl` now; Zenoh, MAVLink and the black-box recorder later.
"""

from uvd.telemetry.jsonl import JsonLinesSink
from uvd.telemetry.sink import BoundedQueue, SinkStats, TelemetryHub, TelemetrySink

__all__ = ["BoundedQueue", "JsonLinesSink", "SinkStats", "TelemetryHub", "TelemetrySink"]
