"""The serial (or network) instruments of ``[sensors]``: a framed reader, a frame → sample
converter and a :class:`~uvd.runtime.mailbox.Mailbox` each — the read side of the daemon's
sensors. Reader tasks only decode and convert; the cycle takes the newest sample.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Any

from uvd.runtime.config import Config
from uvd.runtime.mailbox import Mailbox

__all__ = ["SerialSensor", "Instruments", "make_sensors"]

log = logging.getLogger("uvd.daemon")


class SerialSensor:
    """One instrument: a framed reader, a frame → sample converter, a mailbox.

    The reader decodes in the event loop's read callback; :meth:`run` converts each frame
    (a few µs) and puts the sample in the mailbox. Nothing else happens on this path.

    Parameters
    ----------
    name : str
        ``ins``, ``dvl`` or ``depth``.
    reader : drivers.transport.FrameReader
    convert : callable
        ``convert(stamped) -> sample or None``.
    box : Mailbox
    on_connect : callable, optional
        ``on_connect(reader)`` after the port opened (the Digiquartz gets ``P4``).
    connect_timeout_s : float
        :meth:`start` waits this long for the port to open.

    Attributes
    ----------
    on_sample : callable or None
        Called with no argument after each sample is put (the INS's wakes the
        sensor-synchronous loop, :meth:`uvd.runtime.loop.FixedRateLoop.wake`).
    """

    def __init__(self, name: str, reader, convert: Callable[[Any], Any], box: Mailbox, *,
                 on_connect: Callable[[Any], None] | None = None,
                 connect_timeout_s: float = 5.0) -> None:
        self.name = name
        self.reader = reader
        self.convert = convert
        self.box = box
        self.on_connect = on_connect
        self.connect_timeout_s = connect_timeout_s
        self.samples = 0
        self.rejected = 0
        self.on_sample: Callable[[], None] | None = None

    async def start(self) -> None:
        self.reader.start()
        try:
            await self.reader.wait_connected(self.connect_timeout_s)
        except asyncio.CancelledError:  # the App's start timeout: say which port it was
            log.error("%s: %s did not open%s", self.name, self.reader.where,
                      f" ({self.reader.last_error})" if self.reader.last_error else "")
            raise
        if self.on_connect is not None:
            self.on_connect(self.reader)

    async def run(self) -> None:
        was_connected = True
        while True:
            st = await self.reader.get()
            if not was_connected and self.on_connect is not None:
                self.on_connect(self.reader)
            was_connected = self.reader.connected
            try:
                sample = self.convert(st)
            except Exception as exc:  # noqa: BLE001 - a bad frame is dropped and counted
                self.rejected += 1
                log.warning("%s: frame not converted: %s: %s", self.name, type(exc).__name__,
                            exc)
                continue
            if sample is not None:
                self.samples += 1
                self.box.put(sample)
                if self.on_sample is not None:
                    self.on_sample()

    async def stop(self, timeout_s: float = 0.3) -> None:
        await self.reader.close()
        # pyserial-asyncio-fast closes the port in a background task (flush and close in the
        # default executor); wait for it, bounded, so the exclusive lock is released before
        # the App shuts its executor down
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while self.reader.source_open and loop.time() < deadline:
            await asyncio.sleep(0.005)

    def close_now(self) -> None:
        """Close the port if it is still open (a stop the App had no time left for)."""
        if self.reader.connected or self.reader.source_open:
            self.reader.force_close()

    def stats(self) -> dict[str, Any]:
        return {"samples": self.samples, "rejected": self.rejected,
                "connected": bool(self.reader.connected),
                "last_error": self.reader.last_error or "",
                "counters": self.reader.counters.as_dict()
                if hasattr(self.reader.counters, "as_dict") else {},
                "mailbox": self.box.stats()}


class Instruments:
    """The instruments' part of the cycle's inputs (a hardware interface,
    :mod:`uvd.runtime.interfaces`): the newest INS, DVL and depth samples, from the mailboxes
    the readers (serial, network, the CAN depth sensor) fill.

    ``sync`` (``[loop] trigger = "ins"``): the sensor-synchronous cycle acts on the state as
    of its INS frame — a DVL or depth frame received after that frame waits for the next
    cycle (docs/runtime.md), so which cycle gets a frame follows the receive stamps, not the
    order in which the event loop happened to serve the readers (counted: ``dvl_deferred``,
    ``depth_deferred``).
    """

    def __init__(self, sync: bool = False) -> None:
        self.ins_box: Mailbox = Mailbox("ins")
        self.dvl_box: Mailbox = Mailbox("dvl")
        self.depth_box: Mailbox = Mailbox("depth")
        self.sync = sync
        self.counters = {"dvl_deferred": 0, "depth_deferred": 0}

    def read(self, t_ns: int, armed: bool, parts) -> None:
        ins = self.ins_box.take()
        if ins is not None and self.sync:
            dvl, depth = self.dvl_box.take_until(ins.t_ns), self.depth_box.take_until(ins.t_ns)
            self.counters["dvl_deferred"] += dvl is None and self.dvl_box.peek() is not None
            self.counters["depth_deferred"] += depth is None and \
                self.depth_box.peek() is not None
        else:
            dvl, depth = self.dvl_box.take(), self.depth_box.take()
        parts.ins, parts.dvl, parts.depth = ins, dvl, depth


def _open_reader(port: str, codec, baud: int, name: str):
    from urllib.parse import urlsplit
    if port.startswith(("udp://", "tcp://")):
        from drivers.net_transport import TcpFrameReader, UdpFrameReader
        u = urlsplit(port)
        kind = UdpFrameReader if u.scheme == "udp" else TcpFrameReader
        return kind(u.hostname, u.port, codec, name=name)
    from drivers.serial_transport import SerialFrameReader
    return SerialFrameReader(port, codec, baudrate=baud, name=name)


def decoders(cfg: Config) -> dict[str, tuple[Any, Callable[[Any], Any]]]:
    """Per instrument of ``[sensors]`` (``ins``, ``dvl``, and ``depth`` when read from a serial
    port): its wire codec and its converter ``convert(stamped frame) -> sample or None`` —
    the one decoding path the daemon's readers and a replay of recorded bytes share. Each
    call makes fresh converters (the PHINS ASCII assembler keeps state between sentences)."""
    from drivers import digiquartz, pd0, phins_ascii, phins_stdbin
    s = cfg.sensors
    out: dict[str, tuple[Any, Callable[[Any], Any]]] = {}
    if s.ins.format == "phins-stdbin":
        out["ins"] = (phins_stdbin.StdbinCodec(),
                      lambda st: phins_stdbin.to_ins_sample(st.frame, st.t_ns))
    else:
        asm = phins_ascii.AsciiInsAssembler()
        out["ins"] = (phins_ascii.PhinsAsciiCodec(), lambda st: asm.push(st.t_ns, st.frame))
    out["dvl"] = (pd0.Pd0Codec(), lambda st: pd0.to_dvl_sample(st.frame, st.t_ns))
    if s.depth.source == "serial" and s.depth.port is not None:
        conv = s.depth.conversion
        out["depth"] = (digiquartz.DigiquartzCodec(), lambda st: conv.to_sample(st.frame, st.t_ns))
    return out


def make_sensors(cfg: Config, ins_box: Mailbox, dvl_box: Mailbox, depth_box: Mailbox
                 ) -> list[SerialSensor]:
    """The serial (or network) instruments of ``[sensors]``."""
    from drivers import digiquartz
    s = cfg.sensors
    boxes = {"ins": ins_box, "dvl": dvl_box, "depth": depth_box}
    ports = {"ins": s.ins, "dvl": s.dvl, "depth": s.depth}
    out = []
    for name, (codec, convert) in decoders(cfg).items():
        port = ports[name]
        on_connect = None
        if name == "depth":
            def on_connect(reader) -> None:
                reader.write(digiquartz.command("P4"))  # continuous pressure output
        out.append(SerialSensor(name, _open_reader(port.port, codec, port.baud, name), convert,
                                boxes[name], on_connect=on_connect))
    return out
