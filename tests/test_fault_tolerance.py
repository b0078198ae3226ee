"""`uvd experiment fault-tolerance`, one short arm per vehicle: the cycle told of a dead
thruster at the fault reallocates in that cycle; the JHU ROV gives up pitch, the BlueROV2 none."""

import pytest

from uvd.experiments.fault_tolerance import run_arm


@pytest.mark.parametrize("config, given_up", [("sim-bluerov2.toml", []),
                                               ("sim.toml", ["pitch"])])
def test_a_dead_thruster_is_reallocated_in_the_cycle_that_is_told(config, given_up):
    r = run_arm(config, 4, 0.0, "amplifier", t_fault_s=5.0, duration_s=20.0)
    assert r["given_up"] == given_up and r["cycles_not_ok"] == 0
    assert r["fault_s"] == r["detected_s"] == r["reallocated_s"] == pytest.approx(5.0)
    blind = run_arm(config, 4, 0.0, "none", t_fault_s=5.0, duration_s=20.0)
    assert blind["given_up"] == [] and blind["detected_s"] is None
