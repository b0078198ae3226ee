"""Lockstep experiments (``uvd experiment NAME``): plant and core on a simulated clock, no I/O.

Each module in this package exposes ``EXPERIMENTS``, a list of :class:`Experiment`; the
registry discovers them, so adding an experiment never edits a shared file.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from uvd.errors import ExperimentError


def _stderr_progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


@dataclass(frozen=True)
class ExperimentOptions:
    """Options common to every experiment.

    ``hours`` overrides the experiment's default simulated duration where it has one;
    ``progress`` receives short human-readable progress lines (stderr by default);
    ``record`` a folder for MCAP black-box files of the control runs (docs/recording.md);
    ``advance(done_s, total_s, label)`` is told the simulated time of a run as it goes
    (:class:`uvd.progress.Progress.update`).
    """

    seed: int = 0
    hours: float | None = None
    plots: Path | None = None
    record: Path | None = None
    advance: Callable[[float, float, str], None] | None = None
    progress: Callable[[str], None] = field(default=_stderr_progress)


@dataclass(frozen=True)
class Experiment:
    """A named lockstep experiment returning a JSON-serialisable dict of results."""

    name: str
    summary: str
    run: Callable[[ExperimentOptions], dict[str, Any]]


def registry() -> dict[str, Experiment]:
    """Every experiment of every module in this package, by name."""
    found: dict[str, Experiment] = {}
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        for exp in getattr(module, "EXPERIMENTS", ()):
            if exp.name in found:
                raise ExperimentError(f"experiment {exp.name!r} is defined twice")
            found[exp.name] = exp
    return found


def get(name: str) -> Experiment:
    reg = registry()
    if name not in reg:
        known = ", ".join(sorted(reg)) or "(none)"
        raise ExperimentError(f"unknown experiment {name!r}; known: {known}")
    return reg[name]
