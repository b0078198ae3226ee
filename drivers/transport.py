"""Async framed readers: one byte source → decoded, time-stamped frames, surviving unplugs.

:class:`FrameReader` is the part every transport shares: a resynchronising
:class:`~drivers.framing.StreamDecoder`, per-source :class:`~drivers.counters.Counters`, a
bounded queue of :class:`~drivers.framing.Stamped` frames, and a reconnect loop with
exponential back-off. A subclass only says how to open its byte source
(:mod:`drivers.serial_transport`, :mod:`drivers.net_transport`).

Bytes are decoded in the event loop's read callback, so a frame is delivered as soon as its
last byte arrives; every frame is stamped with the monotonic receive time of that chunk (ns,
from the injected ``clock``). Failures never raise into the caller: the reader records
``last_error``, counts the reconnect and tries again; :meth:`FrameReader.get` raises
:class:`~uvd.errors.SensorTimeout` only when the caller asked to wait and nothing came.

Typical use::

    async with SerialFrameReader("/dev/ttyUSB0", Pd0Codec(), baudrate=115200) as dvl:
        stamped = await dvl.get(timeout=1.0)      # or: for s in dvl.drain(): …
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Callable

from drivers.counters import Counters
from drivers.framing import FrameCodec, Stamped, StreamDecoder
from uvd.errors import SensorTimeout, TransportError


class _Protocol(asyncio.Protocol, asyncio.DatagramProtocol):
    """Forwards transport callbacks to its :class:`FrameReader`."""

    def __init__(self, owner: FrameReader):
        self.owner = owner

    def connection_made(self, transport):
        self.owner._transport = transport

    def data_received(self, data: bytes):
        self.owner._on_bytes(data)

    def datagram_received(self, data: bytes, addr):
        self.owner._on_bytes(data)

    def error_received(self, exc):
        self.owner.last_error = f"{self.owner.name}: {exc}"

    def connection_lost(self, exc):
        self.owner._on_lost(exc)


class FrameReader:
    """Base class of the framed readers.

    Parameters
    ----------
    codec : FrameCodec
        The wire format (``Pd0Codec()``, ``StdbinCodec()``, …).
    name : str
        Source name used in messages and counters (``"dvl"``).
    clock : callable
        Monotonic clock in ns (injected; ``time.monotonic_ns`` by default).
    queue_size : int
        Frames kept for the consumer; when full the oldest is dropped and counted.
    reconnect_min_s, reconnect_max_s : float
        Back-off between attempts to (re)open, doubling from min to max.
    max_buffer : int, optional
        Byte cap of the decoder's buffer.
    """

    where = "?"

    def __init__(self, codec: FrameCodec, *, name: str | None = None,
                 clock: Callable[[], int] = time.monotonic_ns, queue_size: int = 256,
                 reconnect_min_s: float = 0.05, reconnect_max_s: float = 2.0,
                 max_buffer: int | None = None, counters: Counters | None = None):
        if not (0 < reconnect_min_s <= reconnect_max_s):
            raise ValueError("need 0 < reconnect_min_s <= reconnect_max_s")
        self.codec = codec
        self.name = name or codec.name
        self.clock = clock
        self.counters = counters if counters is not None else Counters()
        self.decoder = StreamDecoder(codec, max_buffer=max_buffer, counters=self.counters,
                                     keep_raw=True)
        self.reconnect_min_s = reconnect_min_s
        self.reconnect_max_s = reconnect_max_s
        self.last_error: str = ""
        self.connected = False
        self._queue: deque[Stamped] = deque(maxlen=queue_size)
        self._waiter: asyncio.Future | None = None
        self._transport = None
        self._lost: asyncio.Event | None = None
        self._task: asyncio.Task | None = None
        self._closed = False
        self._opened_once = False
        #: ``tap(name, t_ns, data)`` sees every chunk of bytes as it arrives, stamped as the
        #: frames it completes (a black-box recorder); must be cheap and must not raise
        self.tap: Callable[[str, int, bytes], None] | None = None

    # ---- to implement ------------------------------------------------------------------------
    async def _open(self, protocol: _Protocol):
        """Open the byte source with ``protocol`` as its asyncio protocol; return the
        asyncio transport. On failure raise with the reason only: :meth:`run` prefixes the
        reader's name and where it reads from."""
        raise NotImplementedError

    # ---- callbacks (event loop) -------------------------------------------------------------
    def _on_bytes(self, data: bytes) -> None:
        t_ns = self.clock()
        if self.tap is not None:
            self.tap(self.name, t_ns, data)
        frames = self.decoder.feed(data)
        if not frames:
            return
        q = self._queue
        for msg, raw in frames:
            if len(q) == q.maxlen:
                self.counters.queue_drops += 1
            q.append(Stamped(t_ns, msg, raw))
        w = self._waiter
        if w is not None and not w.done():
            w.set_result(None)

    def _on_lost(self, exc) -> None:
        self.connected = False
        self._transport = None
        if exc is not None:
            self.last_error = f"{self.name}: connection to {self.where} lost: {exc}"
        if self._lost is not None:
            self._lost.set()

    # ---- lifecycle ---------------------------------------------------------------------------
    async def run(self) -> None:
        """Open, read until lost, re-open with back-off; returns only when closed.

        Cancelling the task closes the source (structured use: a TaskGroup may own it).
        """
        delay = self.reconnect_min_s
        self._lost = asyncio.Event()
        try:
            while not self._closed:
                self._lost.clear()
                try:
                    transport = await self._open(_Protocol(self))
                except asyncio.CancelledError:
                    raise
                except Exception as exc:  # noqa: BLE001 - an open failure is a status
                    self.last_error = f"{self.name}: cannot open {self.where}: {exc}"
                    await asyncio.sleep(delay)
                    delay = min(2.0 * delay, self.reconnect_max_s)
                    continue
                self._transport = transport
                if self._opened_once:
                    self.counters.reconnects += 1
                self._opened_once = True
                self.connected = True
                delay = self.reconnect_min_s
                await self._lost.wait()
                self.decoder.reset()  # a partial frame cannot continue on a new connection
                if not self._closed:
                    await asyncio.sleep(delay)
        finally:
            tr = self._transport
            if tr is not None:
                tr.close()
            self.connected = False

    def start(self) -> asyncio.Task:
        """Start :meth:`run` as a task of the running loop (idempotent)."""
        if self._task is None or self._task.done():
            self._closed = False
            self._task = asyncio.get_running_loop().create_task(self.run(),
                                                                name=f"reader-{self.name}")
        return self._task

    async def close(self) -> None:
        """Stop reading and close the source (waits up to 2 s for the reader task)."""
        self._closed = True
        tr = self._transport
        if tr is not None:
            tr.close()
        task = self._task
        if task is not None and not task.done():
            task.cancel()
            await asyncio.wait({task}, timeout=2.0)
        self.connected = False

    @property
    def source_open(self) -> bool:
        """The byte source is open (a graceful :meth:`close` may still be finishing)."""
        return self._transport is not None

    def force_close(self) -> None:
        """Close the port under the transport if a graceful close never completed (a serial
        port's exclusive lock is released); never raises."""
        tr = self._transport
        ser = getattr(tr, "serial", None) if tr is not None else None
        if ser is not None:
            try:
                ser.close()
            except OSError:
                pass

    async def __aenter__(self) -> FrameReader:
        self.start()
        return self

    async def __aexit__(self, *exc) -> None:
        await self.close()

    async def wait_connected(self, timeout: float) -> None:
        """Wait until the source is open; raises TransportError after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while not self.connected:
            if time.monotonic() > deadline:
                raise TransportError(f"{self.last_error} (not open after {timeout} s)"
                                     if self.last_error else
                                     f"{self.name}: {self.where} not open after {timeout} s")
            await asyncio.sleep(0.005)

    # ---- consumer API --------------------------------------------------------------------------
    def drain(self) -> list[Stamped]:
        """Every frame received since the previous call (oldest first), without waiting."""
        out = list(self._queue)
        self._queue.clear()
        return out

    async def get(self, timeout: float | None = None) -> Stamped:
        """The next frame; raises :class:`SensorTimeout` if none arrives within ``timeout``."""
        while not self._queue:
            loop = asyncio.get_running_loop()
            self._waiter = loop.create_future()
            try:
                await asyncio.wait_for(self._waiter, timeout)
            except TimeoutError as exc:
                raise SensorTimeout(f"{self.name}: no {self.codec.name} frame from "
                                    f"{self.where} within {timeout} s"
                                    + (f" ({self.last_error})" if self.last_error else "")) \
                    from exc
            finally:
                self._waiter = None
        return self._queue.popleft()

    def write(self, data: bytes) -> bool:
        """Send bytes (e.g. a Digiquartz command); False if not connected."""
        tr = self._transport
        if tr is None or not self.connected:
            return False
        try:
            tr.write(data)
        except Exception as exc:  # noqa: BLE001 - a failed write is a status
            self.last_error = f"{self.name}: write failed: {exc}"
            return False
        return True
