"""The INS is not synchronised with the control loop: its newest sample is up to one period
old when a cycle reads it. Lockstep runs of the demo's configuration (``config/sim.toml``)
with the INS sampled 80 ms before each tick: carried to the cycle's time
(``[navigation] propagate_ins``), the heading tracks as with an INS sampled on the tick;
without, the heading error grows by half (docs/runtime.md, "The INS sample's age")."""

from dataclasses import replace

import pytest

from sim_bridge.instruments.models import InstrumentConfig
from uvd.lockstep import Lockstep, LockstepConfig, run, tracking_errors
from uvd.runtime.build import build_core, start_pose
from uvd.runtime.config import load_config
from uvd.runtime.cycle import unsupervised

DURATION_S = 120.0


def _heading_mae(cfg, ins_offset_s: float, propagate: bool) -> float:
    cfg = replace(cfg, navigation=replace(cfg.navigation, propagate_ins=propagate))
    vehicle = cfg.load_vehicle()
    H0, v0 = start_pose(cfg)
    sim = Lockstep(vehicle, unsupervised(build_core(cfg, vehicle)),
                   LockstepConfig(control_rate_hz=cfg.loop.rate_hz, seed=0,
                                  instruments=InstrumentConfig(ins_offset_s=ins_offset_s)),
                   H0=H0, v0=v0)
    return tracking_errors(run(sim, DURATION_S), 0.0, DURATION_S)["position_mae"]["heading"]


def test_an_old_ins_sample_carried_to_the_cycle_time_tracks_heading_as_a_fresh_one():
    cfg = load_config("config/sim.toml")
    fresh = _heading_mae(cfg, 0.0, propagate=True)
    assert _heading_mae(cfg, 0.0, propagate=False) == pytest.approx(fresh, rel=1e-12)
    carried = _heading_mae(cfg, 0.02, propagate=True)   # sample 80 ms old at each tick
    held = _heading_mae(cfg, 0.02, propagate=False)
    assert held > 1.5 * fresh, (held, fresh)            # the delay matters ...
    assert carried < 1.1 * fresh, (carried, fresh)      # ... and is compensated
