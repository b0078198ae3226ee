"""Every face of the daemon: what leaves it and what enters it besides sensors and amplifiers.

Each face is a sink of the one :class:`~uvd.telemetry.sink.TelemetryHub` (bounded,
drop-oldest, counted; never on the loop's critical path), and a link that takes commands
queues them on the App's command queue for the next cycle:

* :mod:`uvd.links.mavlink` — the ground-station link (docs/mavlink.md): the link, its
  receiver process, the parameters it exposes, message signing;
* :mod:`uvd.links.zenoh` — state, estimates and health for fault-detection clients
  (docs/zenoh.md);
* :mod:`uvd.links.mcap` — the black-box recorder (docs/recording.md);
* :mod:`uvd.links.jsonl` — every record as a JSON line;
* :mod:`uvd.links.params_file` — the newest online estimate θ̂ kept as a parameters file.
"""
