"""The processes below a test's command, read from /proc: what it started, and whether any of
them outlived it."""

from __future__ import annotations

import time
from pathlib import Path


def _parents() -> dict[int, int]:
    """pid → parent pid of every process now."""
    out: dict[int, int] = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:  # "pid (comm) state ppid ...": comm may hold spaces, so split after its ')'
            out[int(d.name)] = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
    return out


def children(pid: int) -> list[int]:
    """The live processes whose parent is ``pid``."""
    return [c for c, parent in _parents().items() if parent == pid]


def descendants(pid: int) -> set[int]:
    """Every live process below ``pid``."""
    parents = _parents()
    found, todo = set(), [pid]
    while todo:
        parent = todo.pop()
        kids = [c for c, pp in parents.items() if pp == parent]
        found.update(kids)
        todo += kids
    return found


def alive(pid: int) -> bool:
    """Running (a zombie, ended but not yet reaped, is not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def assert_gone(pids, within_s: float = 10.0) -> None:
    """Every one of ``pids`` ends within ``within_s``."""
    t0 = time.monotonic()
    while any(alive(p) for p in pids) and time.monotonic() - t0 < within_s:
        time.sleep(0.1)
    assert not [p for p in pids if alive(p)], "left behind"
