"""Argument types of the command line's numbers: a duration, a count or a rate that is
negative, zero where it must not be, NaN or infinite is an error argparse names by its option
(``uvd demo: error: argument --duration: '-1' is not a positive finite number``), exit 2,
before anything starts — not a traceback, a hang or a run that ends at once."""

from __future__ import annotations

import argparse
import math


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


def nonnegative_float(text: str) -> float:
    """A finite number ≥ 0 (0 often meaning "none" or "for ever", as each option says)."""
    return _float(text, lambda x: x >= 0.0, "a finite number >= 0")


def positive_int(text: str) -> int:
    """An integer ≥ 1 (a count of runs, cycles or repeats)."""
    return _int(text, lambda x: x >= 1, "an integer >= 1")


def nonnegative_int(text: str) -> int:
    """An integer ≥ 0."""
    return _int(text, lambda x: x >= 0, "an integer >= 0")
