"""``uvd demo``'s lockstep reference and the daemon over ``sim-bridge`` run the same supervised
cycle (uvd.runtime.build.make_cycle): a failsafe that fires in one fires in the other.

The demo configuration (config/sim.toml, two-step AMBC) with ``[failsafe] theta_abs_max``
lowered to 320: the adapting estimate crosses it by itself about 5.6 s after arming
(tests/test_failsafe_scenario.py), the arbiter's parameter_divergence fires and the cycle
falls back to PDC with adaptation frozen — in the demo's reference run as in HIL.
"""

from __future__ import annotations

import asyncio
import time

import pytest

from tests.hil_daemon import run_scenario, running_bridge
from uvd.runtime.config import load_config

pytestmark = pytest.mark.slow

CHANGES = {"failsafe": {"theta_abs_max": 320.0}}
RUN_S = 9.0


def _fired(events) -> list[str]:
    return [e["trigger"] for e in events if e.get("type") == "failsafe"
            and e.get("kind") == "fired"]


def test_the_demo_reference_and_hil_fire_the_same_failsafe(tmp_path):
    from uvd.commands.demo import lockstep_run

    with running_bridge(tmp_path, CHANGES) as (cfg_path, _proc):
        cfg = load_config(cfg_path)
        assert cfg.failsafe.theta_abs_max == 320.0
        # the demo's lockstep reference of this very configuration
        log = lockstep_run(cfg, RUN_S, seed=0)
        lock_fired = _fired(log.failsafe_events)
        assert lock_fired == ["parameter_divergence"], log.failsafe_events
        lock_first = next(e for e in log.failsafe_events
                          if e.get("trigger") == "parameter_divergence")
        assert lock_first["action"] == "fallback" and "pdc-fallback" in log.mode

        async def scenario(d):
            await asyncio.sleep(d.armed_at_ns * 1e-9 + RUN_S - time.monotonic())

        d, cycles = run_scenario(cfg, scenario, tracking_s=0.0)
        hil_fired = [t for t in _fired(d.supervisor.failsafe_events())
                     if t == "parameter_divergence"]
        assert hil_fired == ["parameter_divergence"], d.supervisor.failsafe_events()
        modes = {r["mode"] for r in cycles if r["t_ns"] >= d.armed_at_ns}
        assert "pdc-fallback" in modes, modes
        # about when: both about 5.6 s after arming (HIL's own sensor noise moves it a little)
        t_lock = lock_first["t_ns"] * 1e-9
        t_hil = next(e["t_ns"] for e in d.supervisor.failsafe_events()
                     if e.get("trigger") == "parameter_divergence") - d.armed_at_ns
        print(f"parameter_divergence: lockstep {t_lock:.2f} s, HIL {t_hil * 1e-9:.2f} s after "
              "arming")
        assert abs(t_lock - t_hil * 1e-9) < 2.0
