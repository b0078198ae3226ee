"""Two-step AMBC (§5.2.6): step 1 adapts only g and b with M = D = 0 (model (5.37)); step 2
holds g and b at the step-1 values and adapts M and D from zero; the switch happens on the
controller's own clock; the reference blends from the quasi-static trajectory to RefTraj1."""

import numpy as np
import pytest

from uvd.control.ambc import gravity_index
from uvd.control.trajectory import quasi_static, reftraj1
from uvd.control.twostep import (
    two_step_init,
    two_step_params,
    two_step_reference,
    two_step_step,
)
from uvd.control.types import VehicleState
from uvd.model.lie import exp_se3


def _cycle(params, ctrl, ref, rng, dt=0.1):
    vs = VehicleState(ref.H @ exp_se3(0.05 * rng.normal(size=6)), ref.v + 0.05 * rng.normal(size=6))
    return two_step_step(vs, ref, params, ctrl, dt)


@pytest.mark.parametrize("model", ["decoupled", "full"])
def test_step1_adapts_only_g_b_then_step2_only_M_D(model):
    p = two_step_params(model, eps=1.0, kd1=100.0, kd2=1000.0, step1_duration_s=1.0)
    gi = gravity_index(model)
    assert np.all(p.step1.K[gi] > 0) and np.count_nonzero(p.step1.K) == 4
    assert np.all(p.step2.K[gi] == 0) and np.count_nonzero(p.step2.K) == p.step2.n - 4
    assert p.step1.kd == 100.0 and p.step2.kd == 1000.0
    rng = np.random.default_rng(0)
    ref = reftraj1().at(3.0)
    ctrl = two_step_init(p)
    for _ in range(10):  # 1 s of step 1
        _, ctrl = _cycle(p, ctrl, ref, rng)
        assert ctrl.phase == 1
    th = ctrl.ambc.theta
    mask = np.ones(th.size, bool)
    mask[gi] = False
    assert np.all(th[mask] == 0.0) and np.any(th[gi] != 0.0)
    gb = th[gi].copy()
    for _ in range(10):
        _, ctrl = _cycle(p, ctrl, ref, rng)
        assert ctrl.phase == 2
    np.testing.assert_array_equal(ctrl.gb_step1, gb)
    np.testing.assert_array_equal(ctrl.ambc.theta[gi], gb)  # held
    assert np.any(ctrl.ambc.theta[mask] != 0.0)              # M, D adapt
    assert ctrl.switched_at_s == pytest.approx(1.0)


def test_two_step_reference_is_quasi_static_then_reftraj1():
    ref = two_step_reference(step1_duration_s=100.0, blend_s=20.0)
    qs, r1 = quasi_static(), reftraj1()
    np.testing.assert_allclose(ref.dof(50.0)[0], qs.dof(50.0)[0])
    np.testing.assert_allclose(ref.dof(130.0)[0], r1.dof(30.0)[0])
    a, b = ref.dof(100.0 - 1e-6), ref.dof(100.0 + 1e-6)
    for k in range(3):
        np.testing.assert_allclose(a[k], b[k], atol=1e-4)


def test_theta0_shapes_are_checked():
    with pytest.raises(ValueError):
        two_step_params("decoupled", theta0=np.zeros(5))
