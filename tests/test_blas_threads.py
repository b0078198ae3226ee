"""The real-time processes (``uvd``, ``sim-bridge``) run numpy with one BLAS thread
(:mod:`uvd.blas`): their entry points set it before anything imports numpy."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from uvd.blas import VARIABLES

# call the entry point (it exits after --help), then load numpy and count this process' threads
PROBE = """
import os, sys
from {mod} import main
try:
    main(["--help"])
except SystemExit:
    pass
import numpy
numpy.ones((300, 300)) @ numpy.ones((300, 300))  # a BLAS call big enough to use a pool
print(",".join(os.environ.get(v, "") for v in {variables!r}),
      len(os.listdir(f"/proc/{{os.getpid()}}/task")))
"""


def _probe(mod: str, env: dict) -> tuple[list[str], int]:
    code = PROBE.format(mod=mod, variables=VARIABLES)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=60, check=True).stdout.strip().splitlines()[-1]
    values, n = out.split(" ")
    return values.split(","), int(n)


def _clean_env(**extra) -> dict:
    return {**{k: v for k, v in os.environ.items() if k not in VARIABLES}, **extra}


@pytest.mark.parametrize("mod", ["uvd.cli", "uvd.commands.sim_bridge"])
def test_entry_point_asks_for_one_blas_thread_before_numpy_loads(mod):
    values, n_threads = _probe(mod, _clean_env())
    assert values == ["1"] * len(VARIABLES)
    assert n_threads == 1  # the main thread only: no BLAS pool


def test_an_exported_value_wins():
    values, _ = _probe("uvd.cli", _clean_env(OPENBLAS_NUM_THREADS="2"))
    assert values[0] == "2"


def test_the_kernels_named_are_numpy_s_and_scipy_s_whatever_else_was_imported():
    """uvd.blas.kernels names the kernels of the BLAS uvd's arithmetic runs on; SCS (imported
    with cvxpy) brings its own OpenBLAS (Prescott here), which made the answer depend on the
    imports before it (a test failed in the suite's process and passed alone)."""
    code = ("import numpy, scipy.linalg; from uvd.blas import kernels; a = kernels(); "
            "import cvxpy, scs; b = kernels(); print(sorted(a), sorted(b), a == b)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True).stdout.split()
    assert out[-1] == "True", out
    import platform
    if platform.system() == "Linux":    # numpy's and scipy's wheels bundle OpenBLAS there
        assert "'libscipy_openblas64_'" in " ".join(out), out
