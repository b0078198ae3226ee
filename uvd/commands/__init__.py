"""Sub-commands of ``uvd``: one module each, exposing ``register(subparsers)``."""

from __future__ import annotations

import sys


def checked_config(path, command: str, not_done: str):
    """The validated configuration at ``path`` (None: the embedded default), or None after
    telling, on stderr, ``uvd COMMAND: invalid configuration, NOT_DONE:`` and every wrong key
    (the command then exits 2, before anything starts)."""
    from uvd.runtime.config import ConfigValidationError, load_config
    try:
        return load_config(path)
    except ConfigValidationError as exc:
        print(f"uvd {command}: invalid configuration, {not_done}:\n{exc}", file=sys.stderr)
        return None
