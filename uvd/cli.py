"""The ``uvd`` command line.

Every sub-command lives in its own module under :mod:`uvd.commands` and exposes
``register(subparsers)``; modules are discovered, so adding a command never edits this file.
A registered handler returns an exit code (0 on success).
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

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


def main(argv: list[str] | None = None) -> int:
    single_threaded_blas()  # before any command module imports numpy
    parser = build_parser()
    args = parser.parse_args(argv)
    handler = getattr(args, "handler", None)
    if handler is None:
        parser.print_help()
        return 2
    try:
        return int(handler(args) or 0)
    except UvdError as exc:
        print(f"uvd {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"uvd {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
