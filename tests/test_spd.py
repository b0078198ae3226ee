"""uvd.model.spd: the Cholesky test agrees with the eigenvalues, and a non-finite matrix is
refused, never raised on (it runs in the control cycle)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uvd.model.spd import cholesky, min_max_eig


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 6),
       shift=st.floats(-5.0, 5.0))
def test_cholesky_is_the_positive_definiteness_test_and_factorises(seed, n, shift):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, n))
    A = 0.5 * (X + X.T) + rng.uniform(-2.0, 4.0) * np.eye(n)
    lam = np.linalg.eigvalsh(A - shift * np.eye(n))
    if abs(lam[0]) < 1e-9:  # too close to the boundary to say
        return
    L = np.zeros((n, n))
    ok = cholesky(A, shift, n, L)
    assert ok == (lam[0] > 0)
    if ok:
        np.testing.assert_allclose(L @ L.T, A - shift * np.eye(n), atol=1e-10)
        lo, hi = min_max_eig(A)
        assert lo == pytest.approx(lam[0] + shift) and hi == pytest.approx(lam[-1] + shift)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_non_finite_entry_anywhere_in_the_lower_triangle_is_refused(bad):
    n = 6
    for i in range(n):
        for j in range(i + 1):
            A = 100.0 * np.eye(n)
            A[i, j] = A[j, i] = bad
            assert not cholesky(A, 0.0, n, np.zeros((n, n))), (i, j)
            lo, hi = min_max_eig(A)
            assert math.isnan(lo) and math.isnan(hi)
