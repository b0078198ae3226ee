"""uvd.geometry: Euler ⇄ R (App. A), η, and the one angle-wrap convention (−π, π] — and no
other wrap anywhere in the project."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from uvd.geometry import (
    TWO_PI,
    R_to_euler,
    eta_of,
    euler_of_rotations,
    euler_to_R,
    wrap_angle,
    wrap_angles,
)
from uvd.model.lie import R_euler, euler_R

ROOT = Path(__file__).resolve().parents[1]
angles = st.floats(-1e6, 1e6, allow_nan=False)
in_range = st.floats(-math.pi, math.pi)
# away from gimbal lock (|θ| = π/2), where only φ ∓ ψ is defined
pitches = st.floats(-1.5, 1.5)


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


@given(in_range, pitches, in_range)
def test_euler_to_R_is_Rz_Ry_Rx(roll, pitch, heading):
    """App. A: R = Rz(ψ) Ry(θ) Rx(φ), a rotation (RᵀR = I, det R = 1)."""
    R = euler_to_R(roll, pitch, heading)
    np.testing.assert_allclose(R, _rot(2, heading) @ _rot(1, pitch) @ _rot(0, roll), atol=1e-15)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
    assert abs(np.linalg.det(R) - 1.0) < 1e-14


@given(in_range, pitches, in_range)
def test_R_to_euler_inverts_euler_to_R(roll, pitch, heading):
    r, p, h = R_to_euler(euler_to_R(roll, pitch, heading))
    assert -math.pi < r <= math.pi and -math.pi < h <= math.pi
    assert abs(p - pitch) < 1e-9
    assert abs(wrap_angle(r - roll)) < 1e-9 and abs(wrap_angle(h - heading)) < 1e-9


@settings(deadline=None)  # the first example loads (or compiles) the numba versions
@given(st.lists(st.tuples(in_range, st.floats(-math.pi / 2, math.pi / 2), in_range),
                min_size=1, max_size=20))
@example([(0.0, 0.75, 0.0)])   # numpy's arcsin on AVX-512: 0.75, math.asin: 0.75 - 1 ulp
def test_the_compiled_and_vectorised_forms_are_the_same_functions(eulers):
    """The compiled forms (numba, which calls the C library as math does) are the same bit for
    bit. The vectorised one is numpy's arcsin and arctan2, whose SIMD loops (AVX-512 builds)
    round differently from the C library in about 8 % of arguments: the same angle within
    1 ulp (a roll or heading's difference wrapped, so that −π + 1 ulp against π is 1 ulp).
    It asserted bit-for-bit equality, which failed on every run on an AVX-512 machine."""
    Rs = np.array([euler_to_R(*e) for e in eulers])
    for e, R in zip(eulers, Rs, strict=True):
        assert np.array_equal(euler_R(*e), R)
        assert R_euler(R) == R_to_euler(R)
    got = euler_of_rotations(Rs)
    want = np.array([R_to_euler(R) for R in Rs])
    diff = got - want
    diff[:, 0::2] = wrap_angles(diff[:, 0::2])
    assert np.all(np.abs(diff) <= np.spacing(np.maximum(np.abs(got), np.abs(want)))), diff


def test_eta_of_a_pose():
    H = np.eye(4)
    H[:3, :3] = euler_to_R(0.1, -0.2, 3.0)
    H[:3, 3] = [1.0, -2.0, 3.5]
    np.testing.assert_allclose(eta_of(H), [1.0, -2.0, 3.5, 0.1, -0.2, 3.0], atol=1e-12)


def test_the_heading_of_a_negative_zero_is_plus_pi():
    """atan2(−0, −1) = −π: R_to_euler returns the convention's +π."""
    R = np.diag([-1.0, -1.0, 1.0])
    R[1, 0] = -0.0
    assert R_to_euler(R)[2] == math.pi
    assert euler_of_rotations(R[None])[0, 2] == math.pi


@given(angles)
def test_wrap_is_in_the_half_open_range_and_congruent(a):
    w = wrap_angle(a)
    assert -math.pi < w <= math.pi
    k = round((a - w) / TWO_PI)
    assert abs(a - w - k * TWO_PI) <= 1e-9 * max(1.0, abs(a))


@given(in_range)
def test_wrap_leaves_an_angle_in_range_unchanged_bit_for_bit(a):
    assert wrap_angle(a) == (math.pi if a == -math.pi else a)


@given(angles)
def test_wrap_is_idempotent(a):
    assert wrap_angle(wrap_angle(a)) == wrap_angle(a)


def test_wrap_at_the_ends():
    assert wrap_angle(math.pi) == math.pi
    assert wrap_angle(-math.pi) == math.pi
    assert wrap_angle(3 * math.pi) == math.pi
    assert wrap_angle(TWO_PI) == 0.0
    assert math.isnan(wrap_angle(math.inf)) and math.isnan(wrap_angle(math.nan))


@given(st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=30))
def test_wrap_angles_is_wrap_angle_of_every_entry(xs):
    got = wrap_angles(np.array(xs, dtype=float).reshape(-1))
    want = np.array([wrap_angle(x) for x in xs], dtype=float)
    np.testing.assert_array_equal(got, want)


# ------------------------------------------------------------- one convention everywhere
#: how a wrap is written when written again: modulo 2π, IEEE remainder, fmod, % with π
_WRAP_CALLS = {("math", "remainder"), ("math", "fmod"), ("np", "mod"), ("np", "remainder"),
               ("np", "fmod"), ("numpy", "mod"), ("numpy", "remainder")}


def _mentions_pi(node: ast.AST) -> bool:
    return any(isinstance(n, ast.Attribute) and n.attr in ("pi", "TWO_PI", "_TWO_PI")
               or isinstance(n, ast.Name) and n.id in ("pi", "TWO_PI", "_TWO_PI")
               for n in ast.walk(node))


def wraps_in(source: str) -> list[int]:
    """Lines of ``source`` that wrap an angle themselves (a modulo or remainder by 2π)."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mod) \
                and _mentions_pi(node.right):
            out.append(node.lineno)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                and isinstance(node.func.value, ast.Name) \
                and (node.func.value.id, node.func.attr) in _WRAP_CALLS \
                and len(node.args) == 2 and _mentions_pi(node.args[1]):
            out.append(node.lineno)
    return out


def test_the_scanner_sees_the_three_old_wraps():
    assert wraps_in("h = (h + math.pi) % (2 * math.pi) - math.pi\n") == [1]
    assert wraps_in("r = math.remainder(a, 2.0 * math.pi)\n") == [1]
    assert wraps_in("a = math.fmod(x + math.pi, _TWO_PI)\nb = np.pi - np.mod(np.pi - x, "
                    "_TWO_PI)\n") == [1, 2]
    assert wraps_in("d = math.degrees(h) % 360.0\nk = i % 2\n") == []


def test_one_wrap_convention_everywhere():
    """Only uvd/geometry.py wraps angles; every other module calls wrap_angle(s)."""
    found = {}
    for pkg in ("uvd", "drivers", "sim_bridge"):
        for path in sorted((ROOT / pkg).rglob("*.py")):
            if path == ROOT / "uvd" / "geometry.py":
                continue
            lines = wraps_in(path.read_text(encoding="utf-8"))
            if lines:
                found[str(path.relative_to(ROOT))] = lines
    assert not found, f"angle wraps outside uvd.geometry: {found}"


@pytest.mark.parametrize("name", ["euler_to_R", "R_to_euler", "eta_of", "wrap_pi",
                                  "wrap_pi_array", "euler_R"])
def test_one_definition_of_each(name):
    defs = [str(p.relative_to(ROOT)) for pkg in ("uvd", "drivers", "sim_bridge")
            for p in (ROOT / pkg).rglob("*.py")
            if any(isinstance(n, ast.FunctionDef) and n.name == name
                   for n in ast.walk(ast.parse(p.read_text(encoding="utf-8"))))]
    assert defs == ([] if name in ("wrap_pi", "wrap_pi_array", "euler_R")
                    else ["uvd/geometry.py"])
