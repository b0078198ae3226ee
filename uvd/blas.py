"""One BLAS thread for the processes that run a real-time loop (``uvd``, ``sim-bridge``).

The BLAS thread pool would add worker threads next to the control loop, which spin for a while
after each call, and our matrices (at most 241 × 241) gain nothing from them: measured on the
AMBC + 6-DOF AID cycle, compute p50/p99 are the same with one thread. Must run before numpy is
imported (the command-line entry points call it first); a value the user exported wins.
:func:`kernels` names the kernels the BLAS chose for this CPU (a recording's start record
carries them).
"""

from __future__ import annotations

import os
from pathlib import Path

VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def single_threaded_blas() -> None:
    """Ask numpy's BLAS for one thread unless the environment already says otherwise."""
    for var in VARIABLES:
        os.environ.setdefault(var, "1")


def kernel_names(table: dict[str, str] | None = None) -> str:
    """The kernels of a :func:`kernels` table as one name (``"SkylakeX"``; several joined by
    ", "; "" when none is known); without a table, this process's, numpy loaded first."""
    if table is None:
        import numpy  # noqa: F401  (loads numpy's BLAS, whose kernels are asked for)
        table = kernels()
    return ", ".join(sorted(set(table.values())))


def kernels() -> dict[str, str]:
    """numpy's and scipy's OpenBLAS loaded in this process, each with the kernel it chose for
    this CPU (``{"libscipy_openblas64_": "SkylakeX"}``); empty where that cannot be told (not
    Linux, another BLAS, a build without the query). Only theirs: they do uvd's arithmetic
    (numba's kernels call scipy's), while another package's own copy (SCS's, loaded with
    cvxpy) would make the answer depend on what was imported before.

    A library built with ``DYNAMIC_ARCH`` (numpy's and scipy's wheels) picks its kernels at load
    time from the CPU, unless ``OPENBLAS_CORETYPE`` names one, and two kernels may round a
    product differently in its last bit. A recording replayed, or a campaign run, with other
    kernels than it was made with can therefore differ in the last bits of every command:
    the recording's start record carries these names (docs/recording.md).
    """
    import ctypes

    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as fh:
            paths = sorted({line.split(None, 5)[5].strip() for line in fh
                            if len(line.split(None, 5)) == 6 and "openblas" in line.lower()})
        paths = [p for p in paths if Path(p).parent.name in ("numpy.libs", "scipy.libs")
                 or "scipy_openblas" in Path(p).name]
    except OSError:
        return {}
    out: dict[str, str] = {}
    for path in paths:
        try:
            lib = ctypes.CDLL(path, mode=ctypes.RTLD_LOCAL)
        except OSError:
            continue
        for symbol in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename",
                       "openblas_get_corename64_", "openblas_get_corename"):
            query = getattr(lib, symbol, None)
            if query is not None:
                query.restype = ctypes.c_char_p
                name = Path(path).name.split("-")[0].removesuffix(".so")
                out[name] = (query() or b"").decode("ascii", "replace").strip()
                break
    return out
