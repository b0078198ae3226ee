"""Two streams of one vehicle merged in the order of their time stamps, not of their arrival.

uvd-fdc reads a vehicle's estimates and its state on two Zenoh keys. What the detector decides
depends on which of the two it saw first — the residual's baseline is learned from the state
samples up to the moment the estimates end the baseline, and a CUSUM alarm waits a fixed span
of sample time for the residual to name the fault — so feeding samples as they arrive made the
verdict depend on how the machine scheduled the two subscribers (a loaded machine delivered
the estimates of the fault ahead of the state samples that explain it, and the alarm kept the
kind of its channel: ``buoyancy``). :class:`Aligned` holds each stream's samples and releases
them in the order of their ``t_ns`` (ties: the estimate first, as the daemon publishes an
estimate computed from the cycle whose state follows it), a sample only once the other stream
has reached its time stamp. So any interleaving of the two arrivals, and any lateness of
one behind the other, gives the detector the same sequence.

A stream that stops must not hold the other for ever (an estimator that stopped, a daemon
that publishes no state). Once a stream has been heard, it stops holding the other when it is
more than ``lag_s`` of *sample time* behind it; a stream never heard stops holding the other
after ``quiet_s`` of the receiver's clock (monotonic seconds passed in: nothing here reads a
clock). Not the receiver's clock for a stream that was heard: a receiver starved of the CPU
for seconds (measured: a client at nice 5 beside two busy processes, samples 6.4 s late) wakes
with both streams' samples queued, and whichever subscription it serves first would find the
other "quiet" — 249 state samples were released out of order that way. A sample that arrives
after samples later than it were released is late; it is passed on if the detector can take
it out of order (an estimate), else counted and dropped (a state sample: the residual
integrates in time order). Each stream's own samples are expected in order (Zenoh keeps a
publisher's order on one key).
"""

from __future__ import annotations

import math
from collections import deque

__all__ = ["Aligned", "STREAMS"]

#: the streams, in the order that breaks a tie of time stamps
STREAMS = ("estimate", "state")


class Aligned:
    """The merge of a vehicle's ``estimate`` and ``state`` samples by ``t_ns``.

    Parameters
    ----------
    now : the receiver's monotonic clock (s) at creation: a stream not yet heard holds the
        other for ``quiet_s`` after it.
    quiet_s : a stream never heard holds the other this long (receiver's clock, s).
    lag_s : a stream more than this far behind the other in sample time no longer holds it
        (s of ``t_ns``).
    max_held : at most this many samples held per stream; beyond it the oldest is released
        whatever the other stream's time (a bound on memory, counted in ``forced``).
    """

    def __init__(self, now: float, quiet_s: float = 5.0, lag_s: float = 120.0,
                 max_held: int = 200_000) -> None:
        self.quiet_s = float(quiet_s)
        self.lag_ns = float(lag_s) * 1e9
        self.born = float(now)
        self.max_held = int(max_held)
        self.held: dict[str, deque] = {s: deque() for s in STREAMS}
        self.newest: dict[str, int] = {s: -math.inf for s in STREAMS}  # newest t_ns received
        self.released_t = -math.inf  # t_ns of the last sample released
        self.late = {s: 0 for s in STREAMS}
        self.forced = 0
        self.paused = False  # nothing released (the receiver still waits for what it needs)

    def push(self, stream: str, t_ns: int, item, now: float) -> list[tuple[str, object]]:
        """Take one sample (``item``, stamped ``t_ns``) of ``stream``, received at ``now``;
        returns the samples now released, in order, as (stream, item); a tie of time
        stamps goes to the stream first in :data:`STREAMS`."""
        if stream not in self.held:
            raise ValueError(f"stream must be one of {STREAMS}, got {stream!r}")
        out: list[tuple[str, object]] = []
        self.newest[stream] = max(self.newest[stream], t_ns)
        if t_ns < self.released_t:
            self.late[stream] += 1
            if stream == "estimate":
                out.append((stream, item))  # the detector takes an estimate out of order
            return out + self.pop(now)
        self.held[stream].append((t_ns, item))
        return out + self.pop(now)

    def pop(self, now: float) -> list[tuple[str, object]]:
        """The samples that may be released at ``now`` (call it now and then: a stream never
        heard stops holding the other only as time passes)."""
        out: list[tuple[str, object]] = []
        while not self.paused:
            heads = [(q[0][0], i, s) for i, (s, q) in enumerate(self.held.items()) if q]
            if not heads:
                return out
            t_ns, _, stream = min(heads)
            other = STREAMS[1 - STREAMS.index(stream)]
            reached = self.newest[other] >= t_ns  # its later samples come after this one
            if self.newest[other] == -math.inf:  # never heard
                quiet = now - self.born > self.quiet_s
            else:  # heard: judged in sample time, not by when this receiver ran
                quiet = self.newest[stream] - self.newest[other] > self.lag_ns
            full = len(self.held[stream]) > self.max_held
            if not (reached or quiet or full):
                return out
            if full and not (reached or quiet):
                self.forced += 1
            _, item = self.held[stream].popleft()
            self.released_t = t_ns
            out.append((stream, item))
        return out
