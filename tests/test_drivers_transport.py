"""Framed readers over real pseudo-terminals and loopback sockets."""

from __future__ import annotations

import asyncio
import errno
import os
import socket
import tty

import numpy as np
import pytest
import serial

from drivers import digiquartz, pd0, phins_stdbin
from drivers.counters import Counters
from drivers.framing import StreamDecoder
from drivers.net_transport import TcpFrameReader, UdpFrameReader
from drivers.serial_transport import SerialFrameReader
from uvd.errors import SensorTimeout, TransportError, UvdError

pytestmark = pytest.mark.timeout(30)


def _pty():
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


def _stdbin(k: int) -> bytes:
    return phins_stdbin.encode_frame(phins_stdbin.from_state(
        (0.01 * k, 0.02, 0.3), np.array([0.0, 0.0, 0.1]), counter=k))


def test_serial_reader_resyncs_after_garbage_and_split_frames():
    master, slave, path = _pty()
    frames = [_stdbin(k) for k in range(6)]
    garbage = b"\x00IX\x07garbage IX" + bytes(range(40))

    async def go():
        async with SerialFrameReader(path, phins_stdbin.StdbinCodec(), name="ins") as r:
            await r.wait_connected(3.0)
            os.write(master, frames[0] + garbage + frames[1])
            got = [await r.get(2.0), await r.get(2.0)]
            blob = frames[2] + frames[3][:17]  # a frame split over two writes
            os.write(master, blob)
            await asyncio.sleep(0.05)
            os.write(master, frames[3][17:] + b"\xff" * 9 + frames[4])
            got += [await r.get(2.0), await r.get(2.0), await r.get(2.0)]
            return got, r.counters

    try:
        got, c = asyncio.run(go())
    finally:
        os.close(master)
        os.close(slave)
    assert [s.frame.counter for s in got] == [0, 1, 2, 3, 4]
    assert [s.raw for s in got] == frames[:5]
    stamps = [s.t_ns for s in got]
    assert stamps == sorted(stamps) and stamps[0] > 0
    assert c.frames == 5 and c.resyncs == 2 and c.bytes_dropped == len(garbage) + 9
    assert c.bytes_in == sum(len(f) for f in frames[:5]) + len(garbage) + 9


def test_serial_port_is_opened_exclusively():
    master, slave, path = _pty()

    async def go():
        async with SerialFrameReader(path, pd0.Pd0Codec(), name="dvl") as first:
            await first.wait_connected(3.0)
            second = SerialFrameReader(path, pd0.Pd0Codec(), name="dvl2",
                                       reconnect_min_s=0.02, reconnect_max_s=0.05)
            second.start()
            with pytest.raises(TransportError, match="not open") as info:
                await second.wait_connected(0.3)
            err = second.last_error
            await second.close()
            return err, str(info.value)

    try:
        err, raised = asyncio.run(go())
    finally:
        os.close(master)
        os.close(slave)
    assert "lock" in err.lower() and "Errno 11" in err
    assert "another process holds it (fuser -v on the port names it" in err  # what to do
    # what, where and why, each said once (pyserial repeats the port around the OS error)
    assert raised.startswith(f"dvl2: cannot open {path}: ") and raised.count(path) == 1


def test_a_port_this_user_may_not_open_says_how_to_be_let_in():
    # root opens any device, so the refusal is raised here as pyserial raises it (the
    # operating system's error chained beneath its own, which names the port again)
    from drivers.serial_transport import why_not_open
    try:
        try:
            raise PermissionError(errno.EACCES, "Permission denied", "/dev/ttyUSB0")
        except OSError as os_error:
            raise serial.SerialException(
                os_error.errno, f"could not open port /dev/ttyUSB0: {os_error}") from None
    except serial.SerialException as exc:
        said = why_not_open(exc, "/dev/ttyUSB0")
    assert said.startswith("[Errno 13] Permission denied — this user may not open it (ls -l "
                           "on the port shows its group: add the daemon's user to it, often "
                           "dialout"), said


def test_a_device_not_there_names_the_adapters_that_are(tmp_path):
    # a by-id name of an adapter unplugged (or renamed by another firmware): the adapters
    # udev names are listed, or that there is none
    from drivers.serial_transport import why_not_open
    port = "/dev/serial/by-id/usb-FTDI_PHINS-if00-port0"
    try:
        serial.Serial(port)
    except serial.SerialException as exc:
        err = exc
    by_id = tmp_path / "by-id"
    by_id.mkdir()
    assert why_not_open(err, port, by_id).endswith(
        f"No such file or directory — unplugged, or another name? {by_id} holds none: no USB "
        "serial adapter is plugged in")
    (by_id / "usb-FTDI_FT232R_A12-if00-port0").touch()
    assert why_not_open(err, port, by_id).endswith(
        f"{by_id} holds {by_id}/usb-FTDI_FT232R_A12-if00-port0")
    assert "unplugged" not in why_not_open(err, "/tmp/uvd-sim/ins", by_id)  # a pty's placeholder


def test_missing_port_reports_and_get_times_out():
    async def go():
        r = SerialFrameReader("/nonexistent/uvd-tty", pd0.Pd0Codec(), name="dvl",
                              reconnect_min_s=0.01, reconnect_max_s=0.02)
        async with r:
            with pytest.raises(SensorTimeout) as info:
                await r.get(timeout=0.2)
            return info.value, r.last_error

    exc, last = asyncio.run(go())
    assert isinstance(exc, TimeoutError) and isinstance(exc, UvdError)
    assert "/nonexistent/uvd-tty" in str(exc) and "dvl" in str(exc)
    assert last == "dvl: cannot open /nonexistent/uvd-tty: [Errno 2] No such file or directory"


def test_queue_drops_oldest_when_consumer_is_slow():
    master, slave, path = _pty()
    line = digiquartz.encode_line(digiquartz.pressure_line(14.7))

    async def go():
        async with SerialFrameReader(path, digiquartz.DigiquartzCodec(), name="depth",
                                     queue_size=4) as r:
            await r.wait_connected(3.0)
            os.write(master, line * 10)
            for _ in range(100):
                if r.counters.frames == 10:
                    break
                await asyncio.sleep(0.01)
            return r.drain(), r.counters

    try:
        kept, c = asyncio.run(go())
    finally:
        os.close(master)
        os.close(slave)
    assert len(kept) == 4 and c.frames == 10 and c.queue_drops == 6


def test_host_commands_reach_the_device():
    master, slave, path = _pty()

    async def go():
        async with SerialFrameReader(path, digiquartz.DigiquartzCodec(), name="depth") as r:
            await r.wait_connected(3.0)
            assert r.write(digiquartz.command("P4"))
            await asyncio.sleep(0.05)
            return os.read(master, 100)

    try:
        sent = asyncio.run(go())
    finally:
        os.close(master)
        os.close(slave)
    assert sent == b"*0100P4\r\n"


def test_udp_reader_decodes_stdbin_datagrams():
    async def go():
        async with UdpFrameReader("127.0.0.1", 0, phins_stdbin.StdbinCodec(), name="ins") as r:
            await r.wait_connected(3.0)
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
                for k in range(3):
                    tx.sendto(_stdbin(k), ("127.0.0.1", r.bound_port))
                tx.sendto(b"not a frame", ("127.0.0.1", r.bound_port))
                tx.sendto(_stdbin(3), ("127.0.0.1", r.bound_port))
            return [await r.get(2.0) for _ in range(4)], r.counters

    got, c = asyncio.run(go())
    assert [s.frame.counter for s in got] == [0, 1, 2, 3]
    assert c.bytes_dropped == len(b"not a frame")


def test_tcp_reader_reconnects_when_the_server_drops():
    async def go():
        conns = []

        async def serve(reader, writer):
            conns.append(writer)
            writer.write(_stdbin(len(conns)))
            await writer.drain()
            if len(conns) == 1:
                writer.write(_stdbin(99)[:30])  # half a frame, then the link drops
                await writer.drain()
                writer.close()

        server = await asyncio.start_server(serve, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        async with server:
            async with TcpFrameReader("127.0.0.1", port, phins_stdbin.StdbinCodec(),
                                      name="ins", reconnect_min_s=0.02) as r:
                first = await r.get(3.0)
                second = await r.get(3.0)
                for w in conns:
                    w.close()
                return first, second, r.counters

    first, second, c = asyncio.run(go())
    assert (first.frame.counter, second.frame.counter) == (1, 2)
    assert c.reconnects >= 1
    assert c.bytes_dropped == 30  # the partial frame was discarded on reconnect


def test_decoder_buffer_is_capped():
    counters = Counters()
    dec = StreamDecoder(pd0.Pd0Codec(max_frame=1024), max_buffer=4096, counters=counters)
    # a plausible PD0 header that promises 1000 bytes, then never-ending bytes without sync
    head = b"\x7f\x7f" + (998).to_bytes(2, "little") + b"\x00\x01\x08\x00"
    assert dec.feed(head) == []
    for _ in range(50):
        dec.feed(b"\x00" * 997)
        assert dec.buffered <= 4096
    assert counters.bytes_dropped > 0 and counters.bad_checksums + counters.bad_frames >= 1
