"""The MAVLink ground-station link (docs/mavlink.md): :mod:`~uvd.links.mavlink.link` (a sink
of the hub and the commands it queues), :mod:`~uvd.links.mavlink.receiver` (the process that
reads its UDP socket), :mod:`~uvd.links.mavlink.params` (the parameters it exposes, kept in
``[mavlink] params_file``), :mod:`~uvd.links.mavlink.signing` (MAVLink 2 message signing)."""
