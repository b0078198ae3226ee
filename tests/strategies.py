"""Hypothesis strategies shared by the model tests."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from uvd.model.lie import exp_so3

finite = st.floats(min_value=-3.0, max_value=3.0, allow_nan=False, allow_infinity=False)


def vec(n: int, scale: float = 1.0):
    return st.lists(finite, min_size=n, max_size=n).map(lambda xs: scale * np.array(xs))


def rotation():
    return vec(3).map(exp_so3)


def rotvec_inside_pi():
    """q with ‖q‖ < π (strictly, away from the cut locus by 1e-6)."""
    return vec(3).map(lambda q: q if np.linalg.norm(q) < np.pi - 1e-6
                      else q * (np.pi - 1e-3) / np.linalg.norm(q) * 0.999)


def spd(n: int, floor: float = 0.5):
    return st.lists(finite, min_size=n * n, max_size=n * n).map(
        lambda xs: (lambda A: A @ A.T + floor * np.eye(n))(np.array(xs).reshape(n, n)))


def theta_uv():
    """Any θ ∈ R²⁴¹ (the regressor identity holds for every θ, physical or not)."""
    return st.lists(finite, min_size=241, max_size=241).map(lambda xs: 100.0 * np.array(xs))
