"""Network framed readers: PHINS STDBIN (or any codec) over UDP and TCP.

A PHINS sends its output repeaters on Ethernet as UDP datagrams (one frame each) or on a TCP
server port. Both readers feed the same resynchronising decoder as the serial one, so a frame
split across datagrams or segments, or garbage on the wire, is handled the same way.
See :class:`drivers.transport.FrameReader` for the consumer API.
"""

from __future__ import annotations

import asyncio

from drivers.framing import FrameCodec
from drivers.transport import FrameReader, _Protocol
from uvd.errors import TransportError


class UdpFrameReader(FrameReader):
    """Listen on ``(host, port)`` for datagrams carrying frames.

    ``port=0`` binds an ephemeral port; the bound one is in :attr:`bound_port` once open.
    """

    def __init__(self, host: str, port: int, codec: FrameCodec, **kwargs):
        super().__init__(codec, **kwargs)
        self.host = host
        self.port = int(port)
        self.where = f"udp://{host}:{port}"
        self.bound_port: int | None = None

    async def _open(self, protocol: _Protocol):
        loop = asyncio.get_running_loop()
        try:
            transport, _ = await loop.create_datagram_endpoint(
                lambda: protocol, local_addr=(self.host, self.port))
        except OSError as exc:
            raise TransportError(f"bind failed: {exc}") from exc
        self.bound_port = transport.get_extra_info("sockname")[1]
        self.where = f"udp://{self.host}:{self.bound_port}"
        return transport


class TcpFrameReader(FrameReader):
    """Connect to a TCP server (the PHINS) at ``(host, port)``; reconnects when it drops."""

    def __init__(self, host: str, port: int, codec: FrameCodec, *,
                 connect_timeout_s: float = 2.0, **kwargs):
        super().__init__(codec, **kwargs)
        self.host = host
        self.port = int(port)
        self.where = f"tcp://{host}:{port}"
        self.connect_timeout_s = connect_timeout_s

    async def _open(self, protocol: _Protocol):
        loop = asyncio.get_running_loop()
        try:
            transport, _ = await asyncio.wait_for(
                loop.create_connection(lambda: protocol, self.host, self.port),
                self.connect_timeout_s)
        except (TimeoutError, OSError) as exc:
            what = f"no answer within {self.connect_timeout_s} s" \
                if isinstance(exc, TimeoutError) else str(exc)
            raise TransportError(f"connect failed: {what}") from exc
        return transport
