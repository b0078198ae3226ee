"""One BLAS thread for the processes that run a real-time loop (``uvd``, ``sim-bridge``).

The BLAS thread pool would add worker threads next to the control loop, which spin for a while
after each call, and our matrices (at most 241 × 241) gain nothing from them: measured on the
AMBC + 6-DOF AID cycle, compute p50/p99 are the same with one thread. Must run before numpy is
imported (the command-line entry points call it first); a value the user exported wins.
"""

from __future__ import annotations

import os

VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def single_threaded_blas() -> None:
    """Ask numpy's BLAS for one thread unless the environment already says otherwise."""
    for var in VARIABLES:
        os.environ.setdefault(var, "1")
