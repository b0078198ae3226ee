"""The ``uvd`` command line.

Every sub-command lives in its own module under :mod:`uvd.commands` and exposes
``register(subparsers)``; modules are discovered, so adding a command never edits this file.
A registered handler returns an exit code (0 on success).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import pkgutil
import signal
import sys
import threading

from uvd import __version__
from uvd.blas import single_threaded_blas
from uvd.errors import UvdError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="uvd",
        description="Hardware-in-the-loop control daemon for fully actuated underwater vehicles.",
    )
    parser.add_argument("--version", action="version", version=f"uvd {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    import uvd.commands as commands

    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"uvd.commands.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    return parser


#: the signals that stop a command as Ctrl-C does (a terminal closed, ``kill``, ``timeout``)
UNWIND_SIGNALS = (signal.SIGTERM, signal.SIGHUP)


class Stopped(KeyboardInterrupt):
    """SIGTERM or SIGHUP in a command: raised in the main thread, it unwinds as Ctrl-C does,
    so every ``finally`` runs — the processes a command started (the demo's daemon and
    sim-bridge, a campaign's Dask workers) are stopped, not left behind."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _stop(signum: int, _frame) -> None:
    for s in UNWIND_SIGNALS:  # a second signal while unwinding ends the process at once
        signal.signal(s, signal.SIG_DFL)
    raise Stopped(signum)


@contextlib.contextmanager
def unwinding_signals():
    """Within: :data:`UNWIND_SIGNALS` raise :class:`Stopped` (main thread only; the handlers
    before are put back after). A command that handles its own signals (``uvd run``: SIGHUP
    reloads) sets ``own_signals`` and runs without."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = {s: signal.getsignal(s) for s in UNWIND_SIGNALS}
    for s in UNWIND_SIGNALS:
        signal.signal(s, _stop)
    try:
        yield
    finally:
        for s, h in before.items():
            signal.signal(s, signal.SIG_DFL if h is None else h)


def main(argv: list[str] | None = None) -> int:
    single_threaded_blas()  # before any command module imports numpy
    parser = build_parser()
    args = parser.parse_args(argv)
    handler = getattr(args, "handler", None)
    if handler is None:
        parser.print_help()
        return 2
    try:
        if getattr(args, "own_signals", False):
            return int(handler(args) or 0)
        with unwinding_signals():
            return int(handler(args) or 0)
    except UvdError as exc:
        print(f"uvd {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a full disk, an unwritable file: said, not a traceback
        print(f"uvd {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        return _interrupted(args.command, exc)
    except MemoryError as exc:  # `uvd experiment --hours 1e9` asked numpy for 15 PiB
        print(f"uvd {args.command}: error: out of memory ({exc or 'no detail'}): a shorter "
              "run, or a machine with more memory", file=sys.stderr)
        return 1
    except RuntimeError as exc:
        # Ctrl-C (or Stopped) raised in a lock's wait — a queue's get with a timeout, Dask's
        # as_completed — can leave the lock released once too often (CPython's Condition.wait
        # re-acquires it in a finally the interrupt cuts short), and its `with` then raises
        # "release unlocked lock" from the interrupt: the command was interrupted all the same
        if isinstance(exc.__context__, KeyboardInterrupt):
            return _interrupted(args.command, exc.__context__)
        raise


def _interrupted(command: str, exc: KeyboardInterrupt) -> int:
    """The end of a command interrupted by Ctrl-C (130) or stopped by a signal, cleaned up."""
    if not isinstance(exc, Stopped):
        print(f"uvd {command}: interrupted", file=sys.stderr)
        return 130
    # now end as the signal's default would, so that the parent (a shell, systemd, timeout)
    # sees the process stopped by it
    print(f"uvd {command}: stopped by {signal.Signals(exc.signum).name}", file=sys.stderr)
    sys.stdout.flush()
    sys.stderr.flush()
    signal.signal(exc.signum, signal.SIG_DFL)
    os.kill(os.getpid(), exc.signum)
    return 128 + exc.signum


if __name__ == "__main__":
    sys.exit(main())
