"""Argument types of the command line's numbers and outputs, checked by argparse before
anything starts (exit 2, the option named: ``uvd demo: error: argument --duration: '-1' is not
a positive finite number``) — not a traceback, a hang or a run that ends at once, nor minutes of
work whose result then cannot be written.

* Numbers: a duration, a count or a rate that is negative, zero where it must not be, NaN or
  infinite is refused.
* Outputs (a result file, a folder of figures or recordings): one rule for every command — a
  missing folder is made when the result is written, and a path that cannot be made is refused
  now: a folder where the file belongs, a file where a folder belongs (itself or one of its
  parents), or a folder that is not writable.
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
from pathlib import Path


def _float(text: str, ok, what: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(x) and ok(x)):
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}")
    return x


def _int(text: str, ok, what: str) -> int:
    try:
        x = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not ok(x):
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}")
    return x


def positive_float(text: str) -> float:
    """A finite number > 0 (a duration, a rate, a timeout)."""
    return _float(text, lambda x: x > 0.0, "a positive finite number")


def simulated_hours(text: str) -> float:
    """A simulated duration in hours, at least a second (1/3600 h): shorter ones run no
    control cycle, and most experiments ended in an IndexError on their empty logs
    (``uvd experiment two-step --hours 1e-9``, session 33)."""
    return _float(text, lambda x: x * 3600.0 >= 1.0, "a number of hours of at least a second "
                                                      "(1/3600 = 0.000278)")


def positive_float_upto(hi: float):
    """The type of a finite number in (0, ``hi``] (a duration with a ceiling the command's
    memory or waiting sets)."""
    def parse(text: str) -> float:
        return _float(text, lambda x: 0.0 < x <= hi, f"a positive number up to {hi:g}")
    return parse


def nonnegative_float(text: str) -> float:
    """A finite number ≥ 0 (0 often meaning "none" or "for ever", as each option says)."""
    return _float(text, lambda x: x >= 0.0, "a finite number >= 0")


def float_in(lo: float, hi: float):
    """The type of a finite number in ``lo..hi`` (a period with a sensible ceiling)."""
    def parse(text: str) -> float:
        return _float(text, lambda x: lo <= x <= hi, f"a number in {lo:g}..{hi:g}")
    return parse


def positive_int(text: str) -> int:
    """An integer ≥ 1 (a count of runs, cycles or repeats)."""
    return _int(text, lambda x: x >= 1, "an integer >= 1")


def machine_cores() -> int:
    """The machine's cores (those this process may run on)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def workers_count(text: str) -> int:
    """A number of local worker processes for CPU-bound runs: 1 up to the machine's cores
    (more only share them; `uvd campaign --workers 1000` on 2 cores started 1000 processes
    and was still starting them two minutes later, session 33)."""
    cores = machine_cores()
    return _int(text, lambda x: 1 <= x <= cores,
                f"an integer in 1..{cores} (this machine's cores; for more, a cluster's "
                "scheduler)")


def nonnegative_int(text: str) -> int:
    """An integer ≥ 0."""
    return _int(text, lambda x: x >= 0, "an integer >= 0")


def int_in(lo: int, hi: int):
    """The type of an integer in ``lo..hi`` (an identifier of a fixed width: a MAVLink system
    id is 1..255)."""
    def parse(text: str) -> int:
        return _int(text, lambda x: lo <= x <= hi, f"an integer in {lo}..{hi}")
    return parse


#: a CPU's number: Linux's CPU sets hold 1024 (a larger one overflowed the system call's
#: C long: sim-bridge --cpu 99999999999999999999 ended in a traceback, session 25)
cpu_number = int_in(0, 1023)


def _cannot_make_folder(folder: Path) -> str | None:
    """Why files cannot be made in ``folder`` (made first where missing), or None if they can:
    its nearest existing ancestor must be a writable folder."""
    p = folder
    while not p.exists() and p.parent != p:
        p = p.parent
    if not p.is_dir():
        return f"{p} is a file, not a folder"
    if not os.access(p, os.W_OK | os.X_OK):
        return f"{p} is not writable"
    # root passes access() nearly everywhere — /proc, sysfs, a read-only bind mount — and the
    # command then failed at its first write, exit 1 with the OS's words: so make something
    try:
        probe = tempfile.mkdtemp(prefix=".uvd-probe-", dir=p)
    except OSError as exc:
        return f"nothing can be made in {p} ({exc.strerror})"
    os.rmdir(probe)
    return None


def output_file(text: str) -> Path:
    """A file a command writes its result to (its missing folders made when it does)."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a folder, not a file")
    why = _cannot_make_folder(path.parent)
    if why:
        raise argparse.ArgumentTypeError(f"{text!r} cannot be written: {why}")
    return path


def output_folder(text: str) -> Path:
    """A folder a command writes its files into (made, with its parents, when it does)."""
    path = Path(text)
    why = _cannot_make_folder(path)
    if why:
        raise argparse.ArgumentTypeError(f"{text!r} cannot be made a folder: {why}")
    return path
