"""Compiled tests on small symmetric matrices, shared by the controllers and the estimators.

Used in the control cycle, so neither raises. A matrix with a non-finite entry is refused
(``cholesky``) or reported as NaN (``min_max_eig``) instead. numba's eigendecompositions
raise ``LinAlgError`` on one.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def cholesky(A, shift, n, L):
    """L Lᵀ = A − shift·I for symmetric A (n × n; only its lower triangle is read), written
    into the lower triangle of ``L`` (n × n, zeros above the diagonal on entry).

    Returns True on success. Returns False (``L`` partly written) when A − shift·I is not
    positive definite or a pivot is not finite, which catches every NaN or ±inf in the lower
    triangle: a NaN or inf entry makes a later pivot NaN, −inf or +inf.
    """
    for j in range(n):
        d = A[j, j] - shift
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not (0.0 < d < math.inf):
            return False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            x = A[i, j]
            for k in range(j):
                x -= L[i, k] * L[j, k]
            L[i, j] = x / L[j, j]
    return True


@numba.njit(cache=True)
def min_max_eig(A):
    """(λ_min, λ_max) of symmetric A; (NaN, NaN) if A has a non-finite entry."""
    for i in range(A.shape[0]):
        for j in range(A.shape[1]):
            if not np.isfinite(A[i, j]):
                return math.nan, math.nan
    w = np.linalg.eigvalsh(A)
    return w[0], w[-1]
