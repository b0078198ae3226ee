"""A lockstep run of any control rate ``[loop] rate_hz`` allows: the plant steps at the least
integer multiple of the control rate that is at least sim-bridge's 100 Hz. ``uvd demo`` of a
configuration at 30 Hz or 1 kHz (its lockstep twin first) ended in "ValueError: plant_rate_hz
must be an integer multiple of control_rate_hz" before session 34."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from uvd.lockstep import LockstepConfig, lockstep_config, of_config, plant_rate_for, run
from uvd.runtime.config import DEFAULT_CONFIG, load_config


@pytest.mark.parametrize("control, plant", [(10.0, 100.0), (50.0, 100.0), (25.0, 100.0),
                                            (30.0, 120.0), (7.0, 105.0), (0.5, 100.0),
                                            (1000.0, 1000.0), (2000.0, 2000.0)])
def test_the_plant_rate_is_the_least_multiple_of_the_control_rate_from_100_hz(control, plant):
    assert plant_rate_for(control) == pytest.approx(plant, rel=1e-12)
    assert LockstepConfig(control_rate_hz=control).plant_rate_hz == pytest.approx(plant)
    # a rate that divides 100 Hz keeps exactly 100 Hz: every result recorded before stays
    assert LockstepConfig(control_rate_hz=10.0).plant_rate_hz == 100.0
    with pytest.raises(ValueError, match="integer multiple"):  # a given one is still checked
        LockstepConfig(plant_rate_hz=100.0, control_rate_hz=30.0)


def test_the_demo_configurations_lockstep_twin_runs_at_30_hz():
    cfg = load_config(DEFAULT_CONFIG)
    cfg = replace(cfg, loop=replace(cfg.loop, rate_hz=30.0))
    sim = of_config(cfg, lockstep_config(cfg, 0))
    log = run(sim, 3.0)
    assert sim.substeps == 4 and len(log.t) == 90
    assert np.isfinite(log.thrust).all()
