"""sim-bridge loads its compiled plant code before it is ready, not at the first thrust."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# a fresh process, so no other test has called the kernel before
PROBE = f"""
import sys
sys.path.insert(0, {str(ROOT)!r})
import numpy as np
from sim_bridge import plant
from sim_bridge.bridge import SimBridge
from uvd.commands.sim_bridge import bridge_config
from uvd.runtime.config import load_config
# the kernel every live step calls (Plant.step → steps_held, 31-speed's one compiled call)
assert not plant._steps_held.signatures
b = SimBridge(bridge_config(load_config({str(ROOT / "config" / "sim.toml")!r})), hold=True)
assert b.held and b.plant.steps == 0  # the real plant did not move
n_warm = len(plant._steps_held.signatures)
# the live plant's first step (released from the cradle) needs no other compiled version: the
# warm-up steps a copy, and a copy's arrays must be the same types as the original's
b.plant.step(np.zeros(len(b.plant.thrusters.specs)))
print(n_warm, len(plant._steps_held.signatures), b.warm_up_s)
"""


def test_the_fused_plant_kernel_is_loaded_at_construction():
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                         timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    n_warm, n_after_live_step, warm_up_s = out.stdout.split()
    assert int(n_warm) >= 1 and float(warm_up_s) > 0.0
    assert int(n_after_live_step) == int(n_warm)
