"""Random and malformed MAVLink datagrams, and a bounded sender: the fuzz of the MAVLink link
(tests/test_mavlink.py, ``uvd bench loop --mavlink-fuzz N``)."""

from __future__ import annotations

import json
import random
import socket
import subprocess
import sys
import threading
import time

__all__ = ["fuzz_datagrams", "FuzzSender", "fuzz_process", "wait_ready", "start_fuzz",
           "receiver_process"]


def fuzz_datagrams(n: int, seed: int = 21) -> list[bytes]:
    """``n`` datagrams, six kinds in turn: random bytes; a valid packet (ARM, PARAM_SET far out
    of range, MANUAL_CONTROL at full scale, SET_MODE 99, HEARTBEAT) truncated; with one bit
    flipped; with a wrong CRC; a valid header before a random payload; 2 kB of noise behind a
    MAVLink 2 start byte."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink
    rng = random.Random(seed)
    enc = mavlink.MAVLink(None, 255, 190)
    enc.WIRE_PROTOCOL_VERSION = "2.0"
    good = [m.pack(enc) for m in (
        enc.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
        enc.param_set_encode(1, 1, b"CTL_KP_1", 1e9, 9),
        enc.manual_control_encode(1, 1000, 1000, 1000, 1000, 0),
        enc.set_mode_encode(1, 1, 99), enc.heartbeat_encode(6, 8, 0, 0, 0))]

    def noise(k: int) -> bytes:
        return rng.randbytes(k)

    out = []
    for i in range(n):
        g = bytearray(rng.choice(good))
        kind = i % 6
        if kind == 0:
            d = noise(rng.randint(0, 300))
        elif kind == 1:
            d = bytes(g[:rng.randint(0, len(g) - 1)])
        elif kind == 2:
            g[rng.randrange(len(g))] ^= 1 << rng.randrange(8)
            d = bytes(g)
        elif kind == 3:
            g[-1] ^= 0xFF
            d = bytes(g)
        elif kind == 4:
            d = bytes(g[:10]) + noise(rng.randint(0, 255))
        else:
            d = b"\xfd" + noise(2000)
        out.append(d)
    return out


class FuzzSender:
    """Send datagrams to ``(host, port)`` from a thread, spread evenly over the ``windows``
    (``(start, end)`` in ``time.monotonic`` seconds, a clock every process of the machine
    shares), nothing outside them."""

    def __init__(self, datagrams: list[bytes], host: str, port: int,
                 windows: list[tuple[float, float]]) -> None:
        self.datagrams, self.addr, self.windows = datagrams, (host, port), windows
        self.sent = 0
        self._thread = threading.Thread(target=self._run, name="mavlink-fuzz", daemon=True)

    def _due(self, i: int) -> float:
        """When datagram ``i`` goes: at its share of the windows' summed length."""
        total = sum(b - a for a, b in self.windows)
        at = total * i / len(self.datagrams)
        for a, b in self.windows:
            if at < b - a:
                return a + at
            at -= b - a
        return self.windows[-1][1]

    def _run(self) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            for i, d in enumerate(self.datagrams):
                wait = self._due(i) - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                sock.sendto(d, self.addr)
                self.sent += 1
        finally:
            sock.close()

    def start(self) -> FuzzSender:
        self._thread.start()
        return self

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)


def fuzz_process(port: int, n: int, host: str = "127.0.0.1") -> subprocess.Popen:
    """A second process that builds ``n`` fuzz datagrams for ``host:port`` (a sender thread in
    the measured process would compete with its loop for the interpreter lock). It prints
    ``ready`` once they are built; :func:`start_fuzz` then gives it the windows to send them
    in (:class:`FuzzSender`), so no datagram goes late, outside its windows, while it is still
    building."""
    return subprocess.Popen([sys.executable, "-m", "uvd.bench.mavlink_fuzz", host, str(port),
                             str(n)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)


def wait_ready(proc: subprocess.Popen, timeout_s: float = 60.0) -> None:
    """Wait for :func:`fuzz_process`'s ``ready`` line (its datagrams built); raises
    RuntimeError naming what came instead, or the timeout."""
    got: list[str] = []
    reader = threading.Thread(target=lambda: got.append(proc.stdout.readline()), daemon=True)
    reader.start()
    reader.join(timeout_s)
    if not got or got[0].strip() != "ready":
        proc.kill()
        raise RuntimeError(f"MAVLink fuzz sender not ready within {timeout_s:g} s "
                           f"(said {got[0].strip()!r})" if got else
                           f"MAVLink fuzz sender not ready within {timeout_s:g} s")


def start_fuzz(proc: subprocess.Popen, windows: list[tuple[float, float]]) -> None:
    """Give a ready :func:`fuzz_process` its windows (``time.monotonic`` seconds, a clock every
    process of the machine shares); it sends and prints how many it sent, then ends."""
    proc.stdin.write(json.dumps(windows) + "\n")
    proc.stdin.close()


def receiver_process() -> tuple[subprocess.Popen, int]:
    """The control of ``uvd bench loop --fuzz-control``: a process with no daemon behind it
    that binds a loopback UDP port and judges every datagram as the link's receiver does
    (:func:`uvd.links.mavlink.receiver.decode_datagram`), so the same kernel and parser work
    happens on the machine with nothing of the daemon on its path. Returns it and its port;
    it ends on SIGTERM, printing how many datagrams it judged."""
    proc = subprocess.Popen([sys.executable, "-m", "uvd.bench.mavlink_fuzz", "receive"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline().split()
    if not line or not line[-1].isdigit():
        proc.kill()
        raise RuntimeError(f"fuzz control receiver did not start (said {line!r})")
    return proc, int(line[-1])


def _receive() -> None:
    import signal

    from uvd.links.mavlink.receiver import decode_datagram, new_parser
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.2)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    print("port", sock.getsockname()[1], flush=True)
    rx, judged = new_parser(), 0
    while not stop.is_set():
        try:
            data = sock.recv(65536)
        except TimeoutError:
            continue
        decode_datagram(rx, data)
        judged += 1
    print(judged, flush=True)


if __name__ == "__main__" and sys.argv[1:2] == ["receive"]:
    _receive()
elif __name__ == "__main__":
    h, p, k = sys.argv[1:4]
    grams = fuzz_datagrams(int(k))
    print("ready", flush=True)
    w = json.loads(sys.stdin.readline())
    s = FuzzSender(grams, h, int(p), [tuple(x) for x in w]).start()
    s.join()
    print(s.sent, flush=True)
