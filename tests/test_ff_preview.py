"""Feed-forward preview of the AMBC/MBC (uvd.control.ambc.ambc_step, CoreConfig.ff_preview_s)
and the actuation delay it is set to (uvd.control.allocation.actuation_delay_s): the derived
delay against a direct simulation of the hold + propeller-lag chain; δ = 0 changes nothing;
the increment is the reference regressor's; the update law is untouched; the core's wiring and
its zero thrust on a non-finite preview."""

import dataclasses
import math

import numpy as np
import pytest

from drivers.samples import DepthSample, DvlSample, InsSample
from uvd import core
from uvd.control.allocation import Allocator, actuation_delay_s, lag_compensate
from uvd.control.ambc import (
    MBCParams,
    MBCState,
    ambc_init,
    ambc_params,
    ambc_step,
    mbc_step,
    theta_of,
)
from uvd.control.trajectory import reftraj1
from uvd.control.types import VehicleState
from uvd.estimation.navigation import NavConfig
from uvd.io.vehicle import load_vehicle
from uvd.model.lie import exp_se3
from uvd.model.params import DECOUPLED_INDEX
from uvd.model.regressors import W_UV

VEH = load_vehicle("jhu-rov")
TAU = VEH.thrusters[0].time_constant_s
DT = 0.1


# ------------------------------------------------------------------------- the derived delay
def test_delay_formula_values_and_limits():
    assert actuation_delay_s(DT, 0.0, compensated=True) == 0.5 * DT
    assert actuation_delay_s(DT, 0.0, compensated=False) == 0.5 * DT
    assert actuation_delay_s(DT, TAU, compensated=False) == pytest.approx(0.5 * DT + TAU)
    d = actuation_delay_s(DT, TAU, compensated=True)
    assert d == pytest.approx(0.0944852, abs=1e-6)  # docs/experiments.md measured 94.5 ms
    assert actuation_delay_s(DT, 1e-6, compensated=True) == pytest.approx(0.5 * DT, abs=2e-6)
    assert actuation_delay_s(DT, 1e4, compensated=True) == pytest.approx(DT, abs=1e-6)
    for bad in ((0.0, TAU), (DT, -1.0), (math.nan, TAU), (DT, math.inf)):
        with pytest.raises(ValueError):
            actuation_delay_s(*bad, compensated=True)


def _chain_delay(tau: float, compensated: bool, w: float = 0.1, periods: int = 4,
                 sub: int = 200) -> float:
    """Delay of the thrust's fundamental behind the continuous desired thrust, simulated: the
    desired thrust sampled every DT, lag-compensated (or not) by the production
    :func:`lag_compensate` from the speed measured at the sample, held, and passed through the
    exact first-order speed lag τ ω̇ = ω* − ω on ``sub`` points per period; f = k ω|ω|."""
    k = 0.02
    alloc = Allocator(B=np.eye(1, 6).T, B_pinv=np.eye(1, 6), max_thrust_n=np.array([1e6]),
                      k_thrust=np.array([k]), time_constant_s=np.array([tau]))
    f0, a = 200.0, 10.0  # no reversal; small signal around f0
    n = int(round(periods * 2 * math.pi / w / DT))
    s = (np.arange(sub) + 0.5) * (DT / sub)  # midpoints: the average over the period
    omega = math.sqrt((f0 + a * math.sin(-w * 0.0)) / k)
    ts, fs = [], []
    for j in range(n):
        t = j * DT
        f_des = np.array([f0 + a * math.sin(w * t)])
        cmd = lag_compensate(alloc, f_des, np.array([omega]), DT)[0] if compensated else f_des
        w_set = math.copysign(math.sqrt(abs(cmd[0]) / k), cmd[0])
        decay = np.exp(-s / tau) if tau > 0 else np.zeros(sub)
        om = w_set + (omega - w_set) * decay
        ts.append(t + s)
        fs.append(k * om * np.abs(om))
        omega = w_set + (omega - w_set) * (math.exp(-DT / tau) if tau > 0 else 0.0)
    t = np.concatenate(ts)
    f = np.concatenate(fs)
    keep = t >= 2 * math.pi / w  # one period of start-up left out
    t, f = t[keep], f[keep]
    X = np.column_stack([np.ones_like(t), np.sin(w * t), np.cos(w * t)])
    c = np.linalg.lstsq(X, f, rcond=None)[0]
    phase = math.atan2(-c[2], c[1])  # f ≈ c0 + A sin(w t − phase)
    return phase / w


@pytest.mark.parametrize("tau,compensated", [(0.0, True), (TAU, True), (TAU, False),
                                             (0.05, True), (0.4, True)])
def test_derived_delay_matches_a_direct_simulation_of_hold_and_lag(tau, compensated):
    measured = _chain_delay(tau, compensated)
    assert measured == pytest.approx(actuation_delay_s(DT, tau, compensated=compensated),
                                     abs=0.1e-3)


# ------------------------------------------------------------------------------ the control law
def _case(seed=0, t=1234.5):
    rng = np.random.default_rng(seed)
    traj = reftraj1()
    ref = traj.at(t)
    H = ref.H @ exp_se3(rng.normal(size=6) * 0.02)
    v = ref.v + rng.normal(size=6) * 0.02
    truth = theta_of(VEH.params, "decoupled")
    theta = truth * (1 + 0.2 * rng.normal(size=16))
    return traj, ref, VehicleState(H=H, v=v), theta


def _params():
    return ambc_params("decoupled", kp=300.0, kd=1000.0, eps=2.0,
                       allocator=Allocator.from_vehicle(VEH))


def _w_d_theta(ref, theta):
    """W_MBC on the reference alone, from the kron-built regressor of (2.49)."""
    return W_UV(ref.v, ref.vdot, ref.H[:3, :3])[:, DECOUPLED_INDEX] @ theta


@pytest.mark.parametrize("seed", range(3))
def test_zero_preview_gives_exactly_the_old_output(seed):
    traj, ref, state, theta = _case(seed)
    p = _params()
    ctrl = ambc_init(p, theta)
    u0, c0 = ambc_step(state, ref, p, ctrl, DT)
    u1, c1 = ambc_step(state, dataclasses.replace(ref, preview=traj.at(1234.5)), p, ctrl, DT)
    np.testing.assert_array_equal(u1, u0)
    np.testing.assert_array_equal(c1.theta, c0.theta)
    np.testing.assert_array_equal(c1.last_f, c0.last_f)
    m = MBCParams(theta=theta)
    np.testing.assert_array_equal(
        mbc_step(state, dataclasses.replace(ref, preview=ref), m, MBCState(), DT)[0],
        mbc_step(state, ref, m, MBCState(), DT)[0])


@pytest.mark.parametrize("seed", range(3))
def test_preview_adds_the_reference_regressor_increment_and_keeps_the_update(seed):
    traj, ref, state, theta = _case(seed)
    delta = actuation_delay_s(DT, TAU, compensated=True)
    ahead = traj.at(1234.5 + delta)
    p = _params()
    ctrl = ambc_init(p, theta)
    u0, c0 = ambc_step(state, ref, p, ctrl, DT)
    u1, c1 = ambc_step(state, dataclasses.replace(ref, preview=ahead), p, ctrl, DT)
    inc = _w_d_theta(ahead, theta) - _w_d_theta(ref, theta)
    assert np.abs(inc).max() > 1.0  # the case is not trivial
    np.testing.assert_allclose(u1 - u0, inc, rtol=1e-9, atol=1e-9)
    # the update law (5.28) keeps the regressor at t
    np.testing.assert_array_equal(c1.theta, c0.theta)
    np.testing.assert_array_equal(c1.theta_dot, c0.theta_dot)
    # the same increment in MBC
    m = MBCParams(theta=theta)
    um0 = mbc_step(state, ref, m, MBCState(), DT)[0]
    um1 = mbc_step(state, dataclasses.replace(ref, preview=ahead), m, MBCState(), DT)[0]
    np.testing.assert_allclose(um1 - um0, inc, rtol=1e-9, atol=1e-9)


def test_closed_loop_mask_applies_to_the_increment():
    traj, ref, state, theta = _case(1)
    ahead = traj.at(1234.6)
    mask = np.array([True, True, True, False, True, True])
    p = _params()
    ctrl = ambc_init(p, theta)
    r = dataclasses.replace(ref, closed_loop=mask)
    u0, _ = ambc_step(state, r, p, ctrl, DT)
    u1, _ = ambc_step(state, dataclasses.replace(r, preview=ahead), p, ctrl, DT)
    assert u0[3] == u1[3] == 0.0
    assert np.abs(u1 - u0).max() > 0.0


# ------------------------------------------------------------------------------------- in core
def _samples(t_ns):
    return dict(ins=InsSample(t_ns=t_ns, roll=0.0, pitch=0.0, heading=0.0,
                              omega_body=np.zeros(3)),
                dvl=DvlSample(t_ns=t_ns, velocity_body=np.zeros(3), bottom_lock=True),
                depth=DepthSample(t_ns=t_ns, depth_m=1.0))


class _Traj:
    """reftraj1 whose desired state from ``bad_after_s`` on is not finite."""

    def __init__(self, bad_after_s=math.inf):
        self.traj = reftraj1()
        self.bad = bad_after_s

    def at(self, t):
        r = self.traj.at(t)
        if t >= self.bad:
            return dataclasses.replace(r, vdot=np.full(6, np.nan))
        return r


def _cfg(preview_s, traj=None):
    p = ambc_params("decoupled", K=np.zeros(16), allocator=Allocator.from_vehicle(VEH))
    theta = theta_of(VEH.params, "decoupled")
    return core.CoreConfig(nav=NavConfig(ins_timeout_s=0.25),
                           controller=core.ControllerSpec("ambc", ambc_step, p,
                                                          ambc_init(p, theta)),
                           reference=traj or _Traj(), allocator=Allocator.from_vehicle(VEH),
                           k_thrust=VEH.k_thrust, ff_preview_s=preview_s)


def test_core_off_by_default_and_hands_the_reference_ahead_when_on():
    assert core.CoreConfig.__dataclass_fields__["ff_preview_s"].default == 0.0
    inp = core.CoreInputs(t_ns=0, **_samples(0))
    off, _ = core.step(_cfg(0.0), inp, core.core_init(_cfg(0.0)), DT)
    assert off.reference.preview is None
    d = actuation_delay_s(DT, TAU, compensated=True)
    on, _ = core.step(_cfg(d), inp, core.core_init(_cfg(d)), DT)
    assert on.status == off.status == "ok"
    ahead = reftraj1().at(d)
    np.testing.assert_array_equal(on.reference.preview.vdot, ahead.vdot)
    np.testing.assert_array_equal(on.reference.H, off.reference.H)
    assert np.abs(on.u_cmd - off.u_cmd).max() > 0.0


def test_core_non_finite_preview_is_zero_thrust():
    cfg = _cfg(0.1, _Traj(bad_after_s=0.05))  # reference at t fine, preview at t + δ NaN
    out, st = core.step(cfg, core.CoreInputs(t_ns=0, **_samples(0)), core.core_init(cfg), DT)
    assert out.status == "non-finite"
    assert not out.thrust_n.any()
    assert st.ctrl is cfg.controller.init_state


@pytest.mark.parametrize("bad", [-0.01, math.nan, math.inf])
def test_core_rejects_a_bad_preview(bad):
    with pytest.raises(ValueError):
        _cfg(bad)

