"""Replay of a black-box recording (docs/recording.md), both ways, in one place.

* :mod:`uvd.runtime.replay.lockstep` — ``uvd replay RUN.mcap --lockstep``: the recorded raw
  bytes through the same decoders and the same update on the recorded clock; every amplifier
  command compared with the recorded one (bit-identical, or the first mismatch). The third way
  of running the one cycle (docs/architecture.md).
* :mod:`uvd.runtime.replay.realtime` — ``uvd replay RUN.mcap --realtime``: the recorded input
  played on the wire (pseudo-terminals, a CAN bus) with its original timing for a daemon under
  test, and its commands compared on the wire. Not a fourth way of running: the daemon under
  test runs the daemon way; this module uses only the recording's channels and the wire.

Both read recordings through :mod:`uvd.telemetry.recording`; :mod:`uvd.commands.replay` is the
command line over them.
"""
