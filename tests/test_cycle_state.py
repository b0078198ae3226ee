"""The cycle is a constant configuration and one state value (uvd/runtime/cycle.py): the
update returns a new state and leaves the one it was given — and the configuration — as they
were; the reference, the hold pose, the operator's mode and the arbiter's memory live in the
state."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from drivers.samples import DepthSample, DvlSample, InsSample
from uvd.runtime import commands as cmd
from uvd.runtime import cycle
from uvd.runtime.build import make_cycle
from uvd.runtime.config import load_config
from uvd.runtime.cycle import ActuatorStatus, CycleInputs

DT_NS = 100_000_000


def _inputs(k: int, n: int, depth_m: float = 1.0) -> CycleInputs:
    t = (k + 1) * DT_NS
    return CycleInputs(t, InsSample(t, 0.0, 0.0, 0.3, np.zeros(3)),
                       DvlSample(t, np.zeros(3), True, 2.0),
                       DepthSample(t, depth_m + 1e-4 * (k % 3)),
                       ActuatorStatus(np.zeros(n), True, (), t))


def test_update_is_a_function_of_configuration_state_and_inputs():
    cfg = load_config("config/sim.toml")
    vehicle = cfg.load_vehicle()
    config = replace(make_cycle(cfg, vehicle), hold_on_arm=True)
    configured_reference = config.core.reference
    n = vehicle.n_thrusters
    s0 = cycle.cycle_init(config)
    _, s = cycle.boot_complete(s0, 0)
    assert s0.lifecycle.state.value == "BOOT" and s.lifecycle.state.value == "STANDBY"
    for k in range(3):
        _, s = cycle.update(config, s, _inputs(k, n), 0.1)
    res, armed, effects = cycle.apply(config, s, cmd.Arm(), 3 * DT_NS)
    assert res.ok and armed.armed and not s.armed and effects  # the transition, as data
    r1, s1 = cycle.update(config, armed, _inputs(3, n), 0.1)
    r2, s2 = cycle.update(config, armed, _inputs(3, n), 0.1)
    # the same configuration, state and inputs give the same result, bit for bit
    assert np.array_equal(r1.out.thrust_n, r2.out.thrust_n)
    assert r1.armed_at_ns == 4 * DT_NS and s1.armed_at_ns == 4 * DT_NS
    # "hold" on arming: the state's reference is the pose then; the configuration's is not
    assert config.core.reference is configured_reference
    assert s1.core.reference is not configured_reference
    assert armed.core.reference is configured_reference  # the state given is untouched
    held = s1.core.reference.at(0.0).H
    assert held[2, 3] == r1.out.nav.H[2, 3]
    # a pose to hold and the operator's mode are state too
    _, s3, _ = cycle.apply(config, s1, cmd.HoldPose(1.0, 2.0, 3.0, 0.5), 5 * DT_NS)
    _, s3, _ = cycle.apply(config, s3, cmd.SetMode("pdc"), 5 * DT_NS)
    assert s1.operator_mode == "auto" and s1.pending_hold is None
    r4, s4 = cycle.update(config, s3, _inputs(4, n), 0.1)
    assert r4.out.mode == "pdc-fallback" and s4.operator_mode == "pdc"
    assert s4.pending_hold is None
    np.testing.assert_allclose(s4.core.reference.at(0.0).H[:3, 3], [1.0, 2.0, 3.0])


def test_finite_sum_answers_as_the_reduction_does():
    """The shortcut for three moderate entries never answers otherwise than np.add.reduce,
    including sums that overflow and NaN/inf anywhere (the non-finite-input trigger's test)."""
    import math

    rng = np.random.default_rng(31)
    big = [0.0, 1.0, -1.0, 1e300, -1e300, 9.9e299, 1e308, -1e308, 1.7e308, np.inf, -np.inf,
           np.nan]
    cases = [np.array(x, dtype=float) for x in
             rng.choice(big, size=(3000, 3)).tolist() + rng.normal(0, 1e3, (300, 3)).tolist()]
    cases += [np.array([1e308, 1e308, -1e308]), np.arange(4.0), np.array([1.0, 2.0]),
              np.array([1.0, 2.0, 3.0])[::-1], (1.0, float("nan"), 0.0)]
    with np.errstate(over="ignore", invalid="ignore"):  # the overflowing sums are the point
        for x in cases:
            assert cycle._finite_sum(x) == math.isfinite(float(np.add.reduce(x, axis=None))), x
