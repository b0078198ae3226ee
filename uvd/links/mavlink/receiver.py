"""The MAVLink link's receiver: a process of its own that reads the link's UDP socket and
passes on only datagrams of whole, well-formed MAVLink packets (docs/mavlink.md).

Why a process. Judging a datagram is Python work (pymavlink's pure-Python parser checks the
CRC): ~0.1 ms each. In the daemon's process that work holds the interpreter lock, and a flood
of garbage (the fuzz of issue 21: 10 000 datagrams) then makes the control loop wait for the
lock at its wake-ups — measured with ``uvd bench loop --mavlink-fuzz 10000``: lateness p99
+27 % to +2183 % under normal scheduling with the parsing in a thread of the daemon. Here the
daemon's link thread only reads what this process forwards, so garbage costs the daemon
nothing but the kernel's share of a CPU; at ``SCHED_BATCH`` this process never preempts the
loop when a datagram wakes it, and takes nothing from a loop at SCHED_FIFO.

Wire between the two (an ``AF_UNIX`` ``SOCK_SEQPACKET`` pair, one message each, never
blocking: what the daemon does not take in time is dropped and counted):

* ``b"D" + json([host, port, ...]) + b"\\n" + datagram`` — a datagram that passed
  :func:`decode_datagram` (its sender's address as ``recvfrom`` gave it);
* ``b"C" + json({counter: increment})`` — this process's counters since its last report
  (``datagrams``, ``bad_datagrams``, ``recv_errors``, ``forward_dropped``,
  ``kernel_dropped``: datagrams the kernel dropped from the full receive buffer, as the next
  datagram to arrive reports them), at most every 0.25 s.

The daemon creates and binds the UDP socket (so the port is known at once and telemetry goes
out from it) and hands it over by file descriptor. This process runs at ``SCHED_BATCH``
(:func:`_leave_realtime`: a flood must not preempt the loop, and the link must not starve on
a busy machine), and ends
when the daemon shuts its end of the pair (after a last count report) or dies — not on
SIGINT: Ctrl-C in the terminal of ``uvd run`` reaches every process of its group, and the
daemon, stopping in order, still has telemetry to send and its receiver to end (before, the
receiver died at once and the daemon logged an error and started another during its
shutdown). Nor on SIGTERM or SIGHUP, which reach the group the same way (``timeout``,
``kill -- -PGID``, a closed terminal; before session 34 the same error at each such stop).
"""

from __future__ import annotations

import collections
import contextlib
import json
import os
import select
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from typing import Any

__all__ = ["framed", "decode_datagram", "spawn_receiver", "read_forwarded", "stop_receiver",
           "new_parser"]

_REPORT_S = 0.25


def framed(data: bytes) -> bool:
    """True when ``data`` is whole MAVLink packets back to back, judged by their headers'
    lengths alone (a station sends whole packets per datagram)."""
    i, n = 0, len(data)
    while i < n:
        if i + 3 > n:
            return False
        if data[i] == 0xFD:
            i += data[i + 1] + 12 + (13 if data[i + 2] & 0x01 else 0)
        elif data[i] == 0xFE:
            i += data[i + 1] + 8
        else:
            return False
    return i == n and n > 0


def new_parser(system_id: int = 1, component_id: int = 1) -> Any:
    """A pymavlink (ardupilotmega dialect) parser that reports garbage instead of raising."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink
    rx = mavlink.MAVLink(None, system_id, component_id, use_native=False)
    rx.robust_parsing = True
    return rx


def decode_datagram(rx: Any, data: bytes) -> list | None:
    """The messages of one datagram, or None when it is not wholly good MAVLink (framing,
    CRC, an unknown message): the parser starts afresh for each datagram."""
    if not framed(data):  # cheap: most garbage never reaches pymavlink's parser
        return None
    rx.buf, rx.buf_index, rx.expected_length = bytearray(), 0, 8  # HEADER_LEN_V1 + 2
    rx.have_prefix_error = False
    try:
        msgs = rx.parse_buffer(data) or []
    except Exception:  # noqa: BLE001 - whatever pymavlink raises on garbage
        return None
    # an unknown message id (a flipped bit of a known one, often) has no CRC seed to check
    if not msgs or any(m.get_type() == "BAD_DATA" or m.get_type().startswith("UNKNOWN_")
                       for m in msgs):
        return None
    return msgs


def spawn_receiver(sock: socket.socket, avoid_cpus: Sequence[int] = ()
                   ) -> tuple[subprocess.Popen, socket.socket]:
    """Start the receiver process on the bound UDP ``sock``, off ``avoid_cpus`` (the loop's,
    ``[loop] cpu_affinity``) when the machine has others; returns it and the daemon's end of
    the pair (non-blocking) to read with :func:`read_forwarded`."""
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "uvd.links.mavlink.receiver", str(sock.fileno()),
             str(theirs.fileno()), ",".join(str(int(c)) for c in avoid_cpus)],
            pass_fds=(sock.fileno(), theirs.fileno()), stdin=subprocess.DEVNULL)
    except BaseException:
        ours.close()
        raise
    finally:
        theirs.close()
    ours.setblocking(False)
    return proc, ours


def read_forwarded(pair: socket.socket, counters: collections.Counter,
                   limit: int = 64) -> list[tuple[bytes, tuple]]:
    """Up to ``limit`` forwarded datagrams ``(data, addr)`` waiting on ``pair``; counter
    reports are added to ``counters``. Raises EOFError when the receiver has gone."""
    out = []
    for _ in range(limit):
        try:
            msg = pair.recv(65536)
        except (BlockingIOError, InterruptedError):
            break
        if not msg:
            raise EOFError("the MAVLink receiver process ended")
        if msg[:1] == b"D":
            head, _, data = msg[1:].partition(b"\n")
            out.append((data, tuple(json.loads(head))))
        elif msg[:1] == b"C":
            counters.update(json.loads(msg[1:]))
    return out


def stop_receiver(proc: subprocess.Popen, pair: socket.socket, counters: collections.Counter,
                  timeout_s: float = 1.0) -> None:
    """End the receiver: it is told so (our end shut for writing), sends its last counts
    (added to ``counters``; datagrams still in flight are counted ``forward_dropped``) and
    exits; one that does not within ``timeout_s`` is killed. Never raises: a receiver that has
    not gone 5 s after its kill is counted (``receiver_not_reaped``) and left to the system.

    A machine busy with other work slows it (measured at ``SCHED_IDLE``, its earlier policy:
    a fresh clone's tests beside two CPU-bound processes, load ~4.5 on 2 cores — neither its
    exit within 1 s nor its exit after SIGKILL within 1 s, and the close raised
    ``TimeoutExpired``): it is given ``SCHED_OTHER`` first, so that it can finish."""
    with contextlib.suppress(OSError, AttributeError):  # gone already; no sched_* here
        os.sched_setscheduler(proc.pid, os.SCHED_OTHER, os.sched_param(0))
    deadline = time.monotonic() + timeout_s
    with contextlib.suppress(OSError, EOFError):  # EOFError: it has sent all and gone
        pair.shutdown(socket.SHUT_WR)
        while time.monotonic() < deadline:
            select.select([pair], [], [], max(0.0, deadline - time.monotonic()))
            if late := read_forwarded(pair, counters):
                counters["forward_dropped"] += len(late)
    pair.close()
    try:
        proc.wait(timeout=max(0.05, deadline - time.monotonic()))
    except subprocess.TimeoutExpired:
        proc.kill()
        try:
            proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            counters["receiver_not_reaped"] += 1


# ----------------------------------------------------------------------------- the process

def _leave_realtime(avoid_cpus: set[int]) -> None:
    """``SCHED_BATCH`` at normal weight, on every CPU but ``avoid_cpus`` (it may have
    inherited the loop's SCHED_FIFO and CPU set). A batch task never preempts a running one
    when a datagram wakes it, so a flood does not cut into the loop's cycles on a wake-up; a
    loop at SCHED_FIFO always comes first. At normal weight it gets its share of a machine
    busy with other work like any ordinary task, so the operator's heartbeats and commands
    get through. Measured before (fresh clones' tests beside two to four CPU-bound
    processes, load ~4 on 2 cores): at ``SCHED_IDLE`` (weight 3) the link was deaf — no
    station heard in 10 s, 419 of 10 000 datagrams judged; at nice 19 (weight 15) the
    receiver neither reported nor exited within 5 s beside a results re-run. Off the
    loop's CPUs it does not even cost the loop a context switch (when the loop has CPUs of
    its own)."""
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
    cpus = set(range(os.cpu_count() or 1))
    for want in (cpus - avoid_cpus, cpus):
        try:
            os.sched_setaffinity(0, want)
            return
        except (OSError, AttributeError, ValueError):
            continue


def serve(sock: socket.socket, pair: socket.socket) -> None:
    """Read ``sock``, forward the good datagrams on ``pair`` until ``pair`` closes."""
    rx = new_parser()
    counts: collections.Counter = collections.Counter()
    parent = os.getppid()
    next_report = time.monotonic() + _REPORT_S
    sock.setblocking(False)
    kernel_seen = 0  # the socket's drop count as last reported with a datagram
    with contextlib.suppress(OSError):
        sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
    while True:
        readable, _, _ = select.select([sock, pair], [], [], _REPORT_S)
        if pair in readable or os.getppid() != parent:  # the daemon ends us (or died)
            pair.send(b"C" + json.dumps(counts).encode())  # the last counts
            return
        for _ in range(256 if readable else 0):
            try:
                data, anc, _flags, addr = sock.recvmsg(4096, _ANC_SPACE)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                counts["recv_errors"] += 1
                break
            counts["datagrams"] += 1
            if anc and (total := kernel_drops(anc)) is not None and total != kernel_seen:
                counts["kernel_dropped"] += (total - kernel_seen) % 2**32
                kernel_seen = total
            if decode_datagram(rx, data) is None:
                counts["bad_datagrams"] += 1
                continue
            try:
                pair.send(b"D" + json.dumps(addr).encode() + b"\n" + data, socket.MSG_DONTWAIT)
            except BlockingIOError:
                counts["forward_dropped"] += 1
        now = time.monotonic()
        if counts and now >= next_report:
            next_report = now + _REPORT_S
            with contextlib.suppress(BlockingIOError):
                pair.send(b"C" + json.dumps(counts).encode(), socket.MSG_DONTWAIT)
                counts.clear()


#: Linux's per-socket drop count, delivered with each datagram (socket(7); not in Python's
#: ``socket`` module): the datagrams the kernel dropped because the receive buffer was full
SO_RXQ_OVFL = 40
_ANC_SPACE = socket.CMSG_SPACE(4)


def kernel_drops(ancillary) -> int | None:
    """The receive queue's cumulative drop count carried by one datagram's ancillary data
    (``SO_RXQ_OVFL``; the kernel adds it only once something was dropped)."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(data) >= 4:
            return int.from_bytes(data[:4], sys.byteorder)
    return None


def main(argv: list[str]) -> int:
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):  # the daemon's to end it
        signal.signal(sig, signal.SIG_IGN)  # (module docstring)
    _leave_realtime({int(c) for c in argv[2].split(",") if c} if len(argv) > 2 else set())
    sock = socket.socket(fileno=int(argv[0]))
    pair = socket.socket(fileno=int(argv[1]))
    try:
        serve(sock, pair)
    except (BrokenPipeError, ConnectionResetError):
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
