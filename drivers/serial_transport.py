"""Serial framed reader over pyserial + pyserial-asyncio-fast (PHINS, DVL, Digiquartz ports).

The port is opened **exclusively** (pyserial's ``exclusive=True``: an advisory ``flock`` that
a second uvd or a stray terminal cannot take), non-blocking, and read in the event loop's
callback. An unplugged USB adapter or a closed pseudo-terminal shows up as a read error; the
reader closes the port, discards the partial frame, counts the reconnect and re-opens the same
path with back-off (a udev symlink such as ``/dev/serial/by-id/…`` makes the path stable).
Input that queued in the driver before the port was opened is discarded (stale stamps).
See :class:`drivers.transport.FrameReader` for the consumer API.
"""

from __future__ import annotations

import asyncio
import errno
from pathlib import Path

import serial
import serial_asyncio_fast

from drivers.framing import FrameCodec
from drivers.transport import FrameReader, _Protocol
from uvd.errors import TransportError

#: where udev names each USB serial adapter plugged in by its vendor, model and serial number
BY_ID = Path("/dev/serial/by-id")


def why_not_open(exc: BaseException, port: str, by_id: Path = BY_ID) -> str:
    """Why ``port`` did not open, saying the port once (the reader's message names it):
    pyserial repeats it around the operating system's error, which it chains as context; and
    what to do where the operator can (a device not there: the adapters that are, in
    ``by_id``; one another process holds; one this user may not open)."""
    text = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
    ctx = exc.__context__
    if isinstance(ctx, OSError) and ctx.strerror:
        text = text.replace(str(ctx), f"[Errno {ctx.errno}] {ctx.strerror}")
    text = text.replace(f"could not open port {port}: ", "").replace(f"port {port}", "the port")
    code = getattr(exc, "errno", None)
    if code in (errno.EAGAIN, errno.EBUSY):
        text += (" — another process holds it (fuser -v on the port names it: a second uvd, "
                 "a terminal program, ModemManager probing a USB adapter?)")
    elif code == errno.ENOENT and port.startswith("/dev/"):
        try:
            present = sorted(str(p) for p in by_id.iterdir())
        except OSError:
            present = []
        text += (f" — unplugged, or another name? {by_id} holds " + (
            ", ".join(present[:6]) + (", …" if len(present) > 6 else "") if present
            else "none: no USB serial adapter is plugged in"))
    elif code == errno.EACCES:
        text += (" — this user may not open it (ls -l on the port shows its group: add the "
                 "daemon's user to it, often dialout, or give the port one with a udev rule)")
    return text


class SerialFrameReader(FrameReader):
    """Framed reader of one serial port.

    Parameters
    ----------
    port : str
        Device path (``/dev/ttyUSB0``, a pty slave, a by-id symlink) or a pyserial URL.
    codec : FrameCodec
    baudrate : int
        Line speed (8N1).
    exclusive : bool
        Lock the port against other openers (default True).
    **kwargs
        Passed to :class:`~drivers.transport.FrameReader` (name, clock, back-off, …).
    """

    def __init__(self, port: str, codec: FrameCodec, baudrate: int = 115200, *,
                 exclusive: bool = True, **kwargs):
        super().__init__(codec, **kwargs)
        self.port = str(port)
        self.where = self.port
        self.baudrate = int(baudrate)
        self.exclusive = exclusive

    async def _open(self, protocol: _Protocol):
        loop = asyncio.get_running_loop()
        try:
            transport, _ = await serial_asyncio_fast.create_serial_connection(
                loop, lambda: protocol, self.port, baudrate=self.baudrate,
                exclusive=self.exclusive)
            # bytes that waited in the driver while nobody listened are stale: their receive
            # stamps would be wrong. Flushed before the first read callback runs.
            transport.serial.reset_input_buffer()
            return transport
        except (serial.SerialException, OSError, ValueError) as exc:
            raise TransportError(why_not_open(exc, self.port)) from exc
