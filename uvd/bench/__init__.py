"""Benchmarks (``uvd bench NAME``): they print figures, never assert them.

Each module in this package exposes ``BENCH``, a :class:`Bench`; the registry discovers them.
Figures are a flat or nested dict of numbers; medians and percentiles are quoted, not means.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import platform
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from uvd.blas import single_threaded_blas

single_threaded_blas()  # measure what `uvd` runs (one BLAS thread): before numpy is imported

import numpy as np  # noqa: E402

from uvd.errors import ExperimentError  # noqa: E402


@dataclass(frozen=True)
class Bench:
    name: str
    summary: str
    run: Callable[[argparse.Namespace], dict[str, Any]]
    add_arguments: Callable[[argparse.ArgumentParser], None] | None = None


def registry() -> dict[str, Bench]:
    found: dict[str, Bench] = {}
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_") or info.name in ("all", "page"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        bench = getattr(module, "BENCH", None)
        if bench is not None:
            found[bench.name] = bench
    return found


def get(name: str) -> Bench:
    reg = registry()
    if name not in reg:
        raise ExperimentError(f"unknown benchmark {name!r}; known: {', '.join(sorted(reg))}")
    return reg[name]


def default_args(bench: Bench) -> argparse.Namespace:
    """The arguments ``uvd bench NAME`` gets without options (what ``make bench`` runs)."""
    parser = argparse.ArgumentParser(prog=f"uvd bench {bench.name}")
    if bench.add_arguments:
        bench.add_arguments(parser)
    return parser.parse_args([])


def machine() -> dict[str, Any]:
    """The machine a benchmark runs on, recorded with its figures: Python, the processor's
    architecture, its CPUs and the BLAS kernels numpy picked for it (``SkylakeX``: an AVX-512
    CPU; ``Haswell``: AVX2), which tell machines of one architecture apart."""
    from uvd.blas import kernel_names
    return {"python": platform.python_version(), "processor": platform.machine(),
            "cpus": os.cpu_count(), "blas": kernel_names() or None}


def run(bench: Bench, args: argparse.Namespace) -> dict[str, Any]:
    """Run ``bench``; its figures with ``bench`` and ``machine`` added."""
    figures = bench.run(args)
    figures.setdefault("bench", bench.name)
    figures.setdefault("machine", machine())
    return figures


def stop_hil(daemon, bridge) -> None:
    """A hardware-in-the-loop benchmark's end, however it ends: the daemon process stopped
    (:func:`uvd.runtime.process.stop_daemon`) unless it has, then sim-bridge."""
    import contextlib
    import subprocess

    from uvd.runtime.process import stop_daemon
    if daemon is not None and daemon.poll() is None:
        with contextlib.suppress(subprocess.TimeoutExpired):
            stop_daemon(daemon)
    if bridge is not None:
        bridge.stop(timeout_s=5.0)
        bridge.kill()


def percentiles(samples_s, scale: float = 1e6) -> dict[str, float]:
    """Median, p90, p99, p99.9 and max of timing samples (seconds), scaled (µs by default)."""
    a = np.asarray(samples_s, dtype=float) * scale
    if a.size == 0:
        return {"n": 0}
    return {
        "n": int(a.size),
        "p50": float(np.percentile(a, 50)),
        "p90": float(np.percentile(a, 90)),
        "p99": float(np.percentile(a, 99)),
        "p999": float(np.percentile(a, 99.9)),
        "max": float(a.max()),
    }


def host_steal_s(cpus=None) -> float | None:
    """CPU time the hypervisor gave to others (``steal`` of /proc/stat, s): summed over all
    CPUs, or over ``cpus`` (CPU numbers) only; None where the kernel does not say.

    A virtual machine whose host is busy is paused now and then: every thread on the paused
    CPU stalls at once, whatever its priority. Benchmarks and the demo report it so such a
    stall can be told from one of ours. The counter ticks in 1/USER_HZ (10 ms) units.
    """
    want = None if cpus is None else {f"cpu{int(c)}" for c in cpus}
    try:
        total = 0
        with open("/proc/stat", encoding="ascii") as fh:
            for line in fh:
                if not line.startswith("cpu"):
                    break
                fields = line.split()
                if (want is None and fields[0] == "cpu") or (want and fields[0] in want):
                    total += int(fields[8])
        return total / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None
