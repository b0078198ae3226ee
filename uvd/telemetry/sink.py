"""Telemetry sinks and the hub that feeds them off the control loop.

The loop calls :meth:`TelemetryHub.publish` with a plain record (a dict of numbers, strings,
numpy arrays…) once per cycle. ``publish`` only appends to one bounded deque per sink —
O(number of sinks), no lock, no await, no I/O — and when a sink's queue is full the *oldest*
record is dropped and counted, so the loop never waits for a slow consumer and the freshest
data survives. A pump task per sink (owned by the application's TaskGroup through
:meth:`TelemetryHub.run`) drains its queue every ``flush_interval_s`` and hands batches to the
sink; a sink that fails is counted, logged (a spell's first failed batch and its end for the
first ten spells, every 1000th failed batch) and retried with the next batch, never
propagated. The operator is told when a sink starts failing — it did not open, its writes
fail, or its own ``trouble()`` names a failing or hung disk — and when it works again: a
``"sink"`` record to every sink (:meth:`TelemetryHub._tell`). So is a recording that is no
sink of the hub (the CAN log, :meth:`TelemetryHub.watch`).

Records must not be mutated after they are published (the core returns new arrays every cycle,
so this holds by construction).

A sink implements :class:`TelemetrySink`; the daemon's sinks — JSON lines, Zenoh, MAVLink,
the black-box recorder, the parameters file — are the faces of :mod:`uvd.links`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from uvd.spells import FailureSpells

__all__ = ["TelemetrySink", "BoundedQueue", "TelemetryHub", "SinkStats"]

log = logging.getLogger("uvd.telemetry")

#: after a sink's first failed batch, one in this many is logged
_LOG_EVERY = 1000

#: the operator is told of a sink's failing and working again at most once in this many
#: seconds a sink (the first change at once): a disk at the edge of full is not a flood
TELL_HOLD_S = 10.0


@runtime_checkable
class TelemetrySink(Protocol):
    """Where telemetry records go. Every method runs in the event loop, off the loop's cycle.

    ``write`` should not block the event loop for long: encode in small slices and hand file
    or network I/O to a thread (see :class:`~uvd.links.jsonl.JsonLinesSink`).
    """

    name: str

    async def open(self) -> None:
        """Acquire resources (file, session); called once before the first ``write``."""

    async def write(self, records: Sequence[Mapping[str, Any]]) -> None:
        """Take a batch of records (oldest first)."""

    async def flush(self) -> None:
        """Push buffered data out (called on shutdown before ``aclose``)."""

    async def aclose(self) -> None:
        """Release resources; the sink is not used afterwards."""


class BoundedQueue:
    """A non-blocking bounded FIFO: ``put`` never waits; when full the oldest is dropped.

    Safe to ``put`` from the loop's thread while the pump drains it in the same event loop.
    """

    __slots__ = ("_dq", "capacity", "published", "dropped")

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError("capacity must be >= 1")
        self.capacity = int(capacity)
        self._dq: deque = deque(maxlen=self.capacity)
        self.published = 0
        self.dropped = 0

    def put(self, item: Any) -> bool:
        """Append ``item``; returns False when an older item had to be dropped for it."""
        full = len(self._dq) == self.capacity
        if full:
            self.dropped += 1
        self._dq.append(item)
        self.published += 1
        return not full

    def drain(self, max_items: int | None = None) -> list:
        """Remove and return up to ``max_items`` items, oldest first."""
        dq = self._dq
        n = len(dq) if max_items is None else min(len(dq), max_items)
        return [dq.popleft() for _ in range(n)]

    def __len__(self) -> int:
        return len(self._dq)


@dataclass
class SinkStats:
    """Counters of one sink."""

    published: int = 0
    dropped: int = 0
    written: int = 0
    batches: int = 0
    errors: int = 0
    last_error: str | None = None
    queued: int = 0
    close_s: float | None = None

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


class _Telling:
    """What the operator was last told of one sink or watched recording."""

    def __init__(self) -> None:
        self.told: str | None = None  # the problem the operator was last told of (None: ok)
        self.told_at = -math.inf  # monotonic s
        self.failing_since = 0.0


@dataclass
class _Watched:
    """A recording the hub tells the operator about but does not feed (:meth:`watch`)."""

    name: str
    label: str
    trouble: Callable[[], str | None]
    counts: Callable[[], Mapping[str, int]] | None
    failing_as: str
    ok_as: str
    telling: _Telling


class _Lane:
    def __init__(self, sink: TelemetrySink, capacity: int, every_n: int = 1,
                 types: Iterable[str] | None = None) -> None:
        self.sink = sink
        self.every_n = max(1, int(every_n))
        self.types = None if types is None else frozenset(types)
        self.queue = BoundedQueue(capacity)
        self.stats = SinkStats()
        self.opened = False
        self.open_failed = False
        self.open_lock = asyncio.Lock()
        self.wake = asyncio.Event()
        self.lock = asyncio.Lock()  # one drain at a time keeps batches in order
        self.failing = FailureSpells(_LOG_EVERY)  # failed batches (a full disk, a lost peer)
        self.telling = _Telling()


class TelemetryHub:
    """Fan-out from the loop to every sink, each through its own bounded queue.

    Parameters
    ----------
    sinks : iterable of TelemetrySink
    queue_size : int
        Records buffered per sink.
    flush_interval_s : float
        How often the pumps drain their queues.
    batch : int
        Largest batch handed to a sink at once.
    every_n : int
        Default decimation: a sink takes one cycle record in N (events published with
        ``always=True`` are never decimated). Per sink with :meth:`add_sink` /
        :meth:`set_every_n`.
    tell_hold_s : float
        Least time between two changes told of one sink (failing, working again).
    """

    def __init__(self, sinks: Iterable[TelemetrySink] = (), *, queue_size: int = 1024,
                 flush_interval_s: float = 0.05, batch: int = 256, every_n: int = 1,
                 tell_hold_s: float = TELL_HOLD_S) -> None:
        self.tell_hold_s = float(tell_hold_s)
        self.queue_size = int(queue_size)
        self.flush_interval_s = float(flush_interval_s)
        self.batch = int(batch)
        self._count = 0
        self._lanes: list[_Lane] = [_Lane(s, self.queue_size, every_n) for s in sinks]
        self._watched: list[_Watched] = []
        self._closing = False
        self._settled = asyncio.Event()  # every sink opened or failed to (wait_open)

    def add_sink(self, sink: TelemetrySink, every_n: int = 1,
                 types: Iterable[str] | None = None) -> None:
        """Add a sink before :meth:`run` starts.

        It takes one cycle record in ``every_n``, and, when ``types`` is given, only records
        whose ``"type"`` is one of them (e.g. ``("estimate",)``).
        """
        self._lanes.append(_Lane(sink, self.queue_size, every_n, types))

    def watch(self, name: str, trouble: Callable[[], str | None],
              counts: Callable[[], Mapping[str, int]] | None = None, *,
              label: str | None = None, failing_as: str = "cannot write",
              ok_as: str = "writes again") -> None:
        """Tell the operator of what is no sink of the hub as of a sink (the CAN log, the
        recording's disk running low): ``trouble()`` — called from the event loop every
        ``flush_interval_s``, cheap, never blocking — names the problem (None: none);
        ``counts()`` gives its ``records_dropped``, ``write_errors`` and ``bytes_given_up``
        (None: it has none). The texts: "LABEL FAILING_AS: problem", "LABEL OK_AS after
        N s (counts)"; ``label`` by default "telemetry sink NAME". Before :meth:`run`
        starts."""
        self._watched.append(_Watched(name, label or f"telemetry sink {name}", trouble, counts,
                                      failing_as, ok_as, _Telling()))

    def set_every_n(self, name: str, every_n: int) -> None:
        """Change a sink's decimation at run time (reload)."""
        for lane in self._lanes:
            if lane.sink.name == name:
                lane.every_n = max(1, int(every_n))

    @property
    def sinks(self) -> list[TelemetrySink]:
        return [lane.sink for lane in self._lanes]

    def publish(self, record: Mapping[str, Any], *, always: bool = False) -> None:
        """From the loop: enqueue ``record`` for every sink. Never blocks, never raises.

        Cycle records are decimated per sink; ``always=True`` (failsafe events, lifecycle
        transitions) goes to every sink regardless.
        """
        if not always:
            self._count += 1
        n = self._count
        for lane in self._lanes:
            if lane.types is not None and record.get("type") not in lane.types:
                continue
            if always or lane.every_n == 1 or n % lane.every_n == 0:
                lane.queue.put(record)

    async def _ensure_open(self, lane: _Lane) -> bool:
        async with lane.open_lock:
            if not lane.opened and not lane.open_failed:
                try:
                    await lane.sink.open()
                    lane.opened = True
                except Exception as exc:  # a sink that cannot open is reported, others go on
                    lane.open_failed = True
                    lane.stats.errors += 1
                    lane.stats.last_error = f"open: {type(exc).__name__}: {exc}"
                    log.warning("telemetry: sink %s did not open (%s: %s); its records are "
                                "dropped", lane.sink.name, type(exc).__name__, exc)
                    self._tell(lane)
        if not self.opening():
            self._settled.set()
        return lane.opened

    def opening(self) -> list[str]:
        """The sinks still opening: neither open nor failed to."""
        return [lane.sink.name for lane in self._lanes if not (lane.opened or lane.open_failed)]

    async def wait_open(self, timeout_s: float) -> list[str]:
        """With :meth:`run` started: wait until every sink has opened or failed to, at most
        ``timeout_s``; returns :meth:`opening` (a sink that takes longer goes on opening, its
        records queued). The daemon declares itself ready after it, so a station that comes
        at once finds the MAVLink port bound."""
        if self.opening():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._settled.wait(), max(0.0, timeout_s))
        return self.opening()

    async def _pump(self, lane: _Lane) -> None:
        if not await self._ensure_open(lane):
            return
        while not self._closing:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(lane.wake.wait(), self.flush_interval_s)
            lane.wake.clear()
            await self._drain(lane)
            self._tell(lane)

    def _tell(self, lane: _Lane) -> None:
        """Tell the operator when ``lane``'s sink starts failing (it did not open, its writes
        fail, its disk fails or hangs: the sink's own ``trouble()``) and when it works again
        (:meth:`_tell_change`)."""
        if lane.open_failed or lane.failing.in_a_row:
            problem = lane.stats.last_error
        else:
            own = getattr(lane.sink, "trouble", None)
            problem = own() if callable(own) else None
        name = lane.sink.name

        def counts() -> dict[str, int]:
            st = self.stats()[name]
            own_stats = st.get("sink") or {}
            return {"records_dropped": int(st["dropped"])
                    + int(own_stats.get("stalled_dropped", 0)),
                    "write_errors": int(own_stats.get("write_errors", 0)) + lane.failing.total,
                    "bytes_given_up": int(own_stats.get("lost_bytes", 0))}
        self._tell_change(lane.telling, name, f"telemetry sink {name}", problem, counts,
                          "did not open" if lane.open_failed else "cannot write",
                          "writes again")

    def _tell_watched(self) -> None:
        for w in self._watched:
            try:
                problem = w.trouble()
            except Exception as exc:  # noqa: BLE001 - a broken watch is told, never raised
                problem = f"its state unknown: {type(exc).__name__}: {exc}"

            def counts(w: _Watched = w) -> dict[str, int] | None:
                if w.counts is None:
                    return None
                try:
                    return {k: int(v) for k, v in w.counts().items()}
                except Exception:  # noqa: BLE001 - unknown counts are none, never raised
                    return {}
            self._tell_change(w.telling, w.name, w.label, problem, counts, w.failing_as,
                              w.ok_as)

    def _tell_change(self, t: _Telling, name: str, label: str, problem: str | None,
                     counts: Callable[[], dict[str, int] | None], failing_as: str,
                     ok_as: str) -> None:
        """A ``"sink"`` record to every sink when ``problem`` (None: it works) changes what the
        operator was last told of ``name`` — on Zenoh an ``event``, over MAVLink a
        STATUSTEXT, in the black box ``/uvd/sink``. At most one change every ``tell_hold_s``
        a sink; what is told follows what is, so the last change is told when the hold
        ends."""
        now = time.monotonic()
        if problem and not t.failing_since:
            t.failing_since = now
        if (problem is None) == (t.told is None) or now - t.told_at < self.tell_hold_s:
            return
        got = counts()
        n = {k: int((got or {}).get(k, 0)) for k in ("records_dropped", "write_errors",
                                                     "bytes_given_up")}
        if problem:
            text = f"{label} {failing_as}: {problem}"
        else:
            text = f"{label} {ok_as} after {now - t.failing_since:.1f} s" + (
                "" if got is None else f" ({n['records_dropped']} records dropped, "
                                       f"{n['bytes_given_up']} bytes given up so far)")
            t.failing_since = 0.0
        t.told, t.told_at = problem, now
        self.publish({"type": "sink", "t_ns": time.monotonic_ns(), "sink": name,
                      "ok": problem is None, "problem": problem or "", "text": text, **n},
                     always=True)

    async def _watch(self) -> None:
        while not self._closing:
            self._tell_watched()
            await asyncio.sleep(self.flush_interval_s)

    async def _drain(self, lane: _Lane) -> None:
        async with lane.lock:
            await self._drain_locked(lane)

    async def _drain_locked(self, lane: _Lane) -> None:
        while len(lane.queue):
            batch = lane.queue.drain(self.batch)
            try:
                await lane.sink.write(batch)
                lane.stats.written += len(batch)
                lane.stats.batches += 1
            except Exception as exc:  # counted and told; the records of that batch are lost
                lane.stats.errors += 1
                lane.stats.last_error = f"write: {type(exc).__name__}: {exc}"
                lane.stats.dropped += len(batch)
                if lane.failing.failed():
                    log.warning("telemetry: sink %s cannot write (%s: %s); %d failed batches "
                                "in a row, %d records dropped so far", lane.sink.name,
                                type(exc).__name__, exc, lane.failing.in_a_row,
                                lane.stats.dropped)
                return
            if lane.failing.recovered():
                log.warning("telemetry: sink %s writes again (%d records dropped so far)",
                            lane.sink.name, lane.stats.dropped)

    async def run(self) -> None:
        """Pump every sink until :meth:`aclose` (run it as one task of the TaskGroup)."""
        if not self._lanes:
            return
        async with asyncio.TaskGroup() as tg:
            for lane in self._lanes:
                tg.create_task(self._pump(lane), name=f"telemetry:{lane.sink.name}")
            if self._watched:
                tg.create_task(self._watch(), name="telemetry:watched")

    async def aclose(self, timeout_s: float = 0.5) -> dict[str, dict[str, Any]]:
        """Stop the pumps, write what is queued, flush and close every sink.

        Each sink gets ``timeout_s`` for its final drain + flush + close; a sink that does not
        finish in time is abandoned (counted as an error). Returns :meth:`stats`.
        """
        self._closing = True
        for lane in self._lanes:
            lane.wake.set()

        async def finish(lane: _Lane) -> None:
            if await self._ensure_open(lane):
                # a failed write ends one drain (the pump retries later); at close, go on until
                # every record is written or counted as dropped — each drain takes >= 1 batch
                while len(lane.queue):
                    await self._drain(lane)
                await lane.sink.flush()
                await lane.sink.aclose()

        for lane in self._lanes:
            t0 = time.monotonic()
            try:
                await asyncio.wait_for(finish(lane), timeout_s)
            except TimeoutError:
                lane.stats.errors += 1
                lane.stats.last_error = f"close: not finished within {timeout_s:g} s"
            except Exception as exc:
                lane.stats.errors += 1
                lane.stats.last_error = f"close: {type(exc).__name__}: {exc}"
            lane.stats.close_s = time.monotonic() - t0
        return self.stats()

    def stats(self) -> dict[str, dict[str, Any]]:
        """Per-sink counters: published, dropped (queue full or failed write), written…, and
        under ``sink`` the sink's own (``stats()``: a file's failed writes, a link's counts)."""
        out = {}
        for lane in self._lanes:
            st = lane.stats
            st.published = lane.queue.published
            st.queued = len(lane.queue)
            d = st.as_dict()
            d["dropped"] = lane.queue.dropped + st.dropped
            own = getattr(lane.sink, "stats", None)
            if callable(own):
                d["sink"] = own()
            out[lane.sink.name] = d
        return out
