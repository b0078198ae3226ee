"""The device end of a serial line on a pseudo-terminal: :class:`PtyPort`.

What writes an instrument's bytes for a daemon that opens a serial port — the simulated
instruments of ``sim_bridge`` and the realtime replay of a recording
(:mod:`uvd.runtime.replay.realtime`): the daemon opens the symlink like a serial device.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tty
from pathlib import Path

__all__ = ["PtyPort"]


class PtyPort:
    """A pseudo-terminal whose slave side is reachable at ``link`` (a symlink).

    The emulator writes on the master side; the daemon opens ``link`` like a serial device.
    The emulator keeps the slave side open too, so the device exists while no reader is
    attached. Writes never block: a full pty buffer drops the frame (counted).
    """

    def __init__(self, link: str | Path):
        self.link = Path(link)
        self.master: int | None = None
        self._slave: int | None = None
        self.device = ""
        self.frames_written = 0
        self.frames_dropped = 0

    @property
    def is_open(self) -> bool:
        return self.master is not None

    def open(self) -> None:
        """Create the pty pair (raw mode) and point the symlink at its slave device."""
        if self.master is not None:
            return
        master, slave = os.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        os.set_blocking(master, False)
        self.master, self._slave = master, slave
        self.device = os.ttyname(slave)
        self.link.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.link.with_name(self.link.name + ".tmp")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        os.symlink(self.device, tmp)
        os.replace(tmp, self.link)  # atomic: a reader never sees a missing link mid-swap

    def close(self) -> None:
        """Close both sides and remove the symlink (a pulled cable)."""
        for fd in (self.master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.master = self._slave = None
        with contextlib.suppress(FileNotFoundError):
            if self.link.is_symlink() and os.readlink(self.link) == self.device:
                self.link.unlink()

    def write(self, data: bytes) -> bool:
        """Write one frame; False (and counted) if the port is closed or its buffer full."""
        if self.master is None:
            self.frames_dropped += 1
            return False
        try:
            n = os.write(self.master, data)
        except BlockingIOError:
            self.frames_dropped += 1
            return False
        except OSError as exc:
            if exc.errno in (errno.EIO, errno.EBADF):
                self.frames_dropped += 1
                return False
            raise
        if n < len(data):  # partial write: the rest would corrupt the next frame; give up
            self.frames_dropped += 1
            return False
        self.frames_written += 1
        return True

    def read(self) -> bytes:
        """Bytes the host wrote (commands), without blocking."""
        if self.master is None:
            return b""
        try:
            return os.read(self.master, 4096)
        except (BlockingIOError, OSError):
            return b""
