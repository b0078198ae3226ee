"""``uvd-fdc``: the reference fault-detection client (docs/zenoh.md). It uses only the wire
contract — the Zenoh key space and the JSON payloads — never the daemon's classes."""
