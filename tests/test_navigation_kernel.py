"""The compiled navigation step against the Python formula it replaced (tests/nav_reference.py),
bit for bit, on random sample sequences that reach every rule: missing, invalid and non-finite
samples, rates derived from attitude, lost bottom lock, too few beams, a rotated DVL with a
lever arm, the INS carried to the cycle's time or not, stamps after the cycle and time going
backwards."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.samples import DepthSample, DvlSample, InsSample
from tests import nav_reference as ref
from uvd.estimation import navigation as nav
from uvd.geometry import euler_to_R

MS = 1_000_000
_STATE_FIELDS = ("t_ns", "valid", "ins_valid", "dvl_valid", "depth_valid", "ins_age_s",
                 "dvl_age_s", "depth_age_s", "rates_degraded", "bottom_lock")
_MEM_FIELDS = ("t_ns", "north_m", "east_m", "depth_m", "R", "omega", "nu", "v_world_prev",
               "ins_t_ns", "dvl_t_ns", "depth_t_ns", "rates_degraded", "bottom_lock",
               "att_prev_R", "att_prev_t_ns", "dvl_raw", "omega_dot")


def _same(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        return a.shape == b.shape and np.array_equal(a, b, equal_nan=True)
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    return type(a) is type(b) and a == b


def _configs():
    yield "identity", dict()
    yield "mounted", dict(dvl_mount_R=euler_to_R(0.02, -0.01, math.pi / 4),
                          dvl_lever_arm_m=np.array([0.4, -0.1, 0.3]))
    yield "lever-arm", dict(dvl_lever_arm_m=np.array([0.0, 0.0, 0.5]))
    yield "not-carried", dict(propagate_ins=False, ins_timeout_s=0.25, min_good_beams=4)


def _sample(rng, t, kind):
    """One random sample of ``kind`` stamped near ``t`` (None, invalid or non-finite at times)."""
    u = rng.random()
    if u < 0.25:
        return None
    stamp = t - int(rng.integers(0, 120)) * MS if rng.random() < 0.9 else t + 5 * MS
    bad = rng.random() < 0.08
    if kind == "ins":
        ang = rng.normal(0.0, 0.4, 3)
        if bad:
            ang[rng.integers(3)] = np.nan
        w = rng.normal(0.0, 0.3, 3)
        if rng.random() < 0.2:
            w = np.full(3, np.nan)  # no rates: derived from attitude
        elif rng.random() < 0.1:
            w = (float(w[0]), float(w[1]), float(w[2]))  # not an array
        return InsSample(stamp, float(ang[0]), float(ang[1]), float(ang[2]), w,
                         rates_valid=bool(rng.random() < 0.8), valid=bool(rng.random() < 0.95))
    if kind == "dvl":
        vb = rng.normal(0.0, 0.5, 3)
        if bad:
            vb[rng.integers(3)] = np.inf
        return DvlSample(stamp, vb, bottom_lock=bool(rng.random() < 0.85),
                         good_beams=int(rng.integers(2, 5)))
    d = float(rng.normal(5.0, 1.0)) if not bad else float("nan")
    return DepthSample(stamp, d, valid=bool(rng.random() < 0.95))


@pytest.mark.parametrize("name,kw", list(_configs()), ids=[c[0] for c in _configs()])
def test_compiled_step_equals_the_python_formula_bit_for_bit(name, kw):
    cfg = nav.NavConfig(**kw)
    rcfg = ref.NavConfig(**kw)
    rng = np.random.default_rng(sum(map(ord, name)))
    for _ in range(40):  # sequences
        north, east = rng.normal(0.0, 10.0, 2)
        mem, rmem = nav.nav_init(cfg, north, east), ref.nav_init(rcfg, north, east)
        t = int(rng.integers(0, 10**12))
        for k in range(60):  # cycles
            t += int(rng.integers(40, 160)) * MS if rng.random() > 0.03 else -50 * MS
            if rng.random() < 0.02:
                fix = rng.normal(0.0, 5.0, 2)
                mem = nav.nav_set_position(mem, *fix)
                rmem = ref.nav_set_position(rmem, *fix)
            samples = [_sample(rng, t, kind) for kind in ("ins", "dvl", "depth")]
            s, mem = nav.nav_step(cfg, mem, t, *samples)
            rs, rmem = ref.nav_step(rcfg, rmem, t, *samples)
            where = f"{name}, cycle {k}"
            assert np.array_equal(s.H, rs.H, equal_nan=True), where
            assert np.array_equal(s.v, rs.v, equal_nan=True), where
            for f in _STATE_FIELDS:
                assert _same(getattr(s, f), getattr(rs, f)), (where, f)
            for f in _MEM_FIELDS:
                assert _same(getattr(mem, f), getattr(rmem, f)), (where, f)


def test_the_step_does_not_change_the_memory_it_was_given():
    cfg = nav.NavConfig(dvl_lever_arm_m=np.array([0.1, 0.0, 0.2]))
    mem = nav.nav_init(cfg, 1.0, 2.0)
    ins = InsSample(0, 0.1, 0.2, 0.3, np.array([0.01, 0.02, 0.03]))
    _, mem1 = nav.nav_step(cfg, mem, 0, ins, DvlSample(0, np.ones(3), True),
                           DepthSample(0, 3.0))
    f, i = mem1.f.copy(), mem1.i.copy()
    nav.nav_step(cfg, mem1, 100 * MS, None, DvlSample(50 * MS, np.ones(3), True), None)
    assert np.array_equal(mem1.f, f) and np.array_equal(mem1.i, i)
