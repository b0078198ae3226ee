"""Telemetry fed off the control loop (never on its critical path).

:class:`~uvd.telemetry.sink.TelemetryHub` takes one record per cycle from the loop through
bounded, non-blocking queues (drop-oldest-and-count) and pumps them to every
:class:`~uvd.telemetry.sink.TelemetrySink`: the JSON-lines file of
:mod:`uvd.telemetry.jsonl` and the parameters file of :mod:`uvd.telemetry.params_file` now;
Zenoh, MAVLink and the black-box recorder later.
"""

from uvd.telemetry.jsonl import JsonLinesSink
from uvd.telemetry.params_file import ParamsFileSink
from uvd.telemetry.sink import BoundedQueue, SinkStats, TelemetryHub, TelemetrySink

__all__ = ["BoundedQueue", "JsonLinesSink", "ParamsFileSink", "SinkStats", "TelemetryHub",
           "TelemetrySink"]
