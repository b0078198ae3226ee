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
from sim_bridge import plant
from sim_bridge.bridge import SimBridge
from uvd.runtime.config import load_config
assert not plant._thrusters_then_rigid_body.signatures
b = SimBridge(load_config({str(ROOT / "config" / "sim.toml")!r}), hold=True)
assert b.held and b.plant.steps == 0  # the real plant did not move
print(len(plant._thrusters_then_rigid_body.signatures), b.warm_up_s)
"""


def test_the_fused_plant_kernel_is_loaded_at_construction():
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                         timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    n_signatures, warm_up_s = out.stdout.split()
    assert int(n_signatures) >= 1 and float(warm_up_s) > 0.0
