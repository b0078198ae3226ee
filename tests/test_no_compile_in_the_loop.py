"""After the daemon's warm-up, no cycle compiles anything: a numba specialisation met first
in the running loop is compiled there — seconds with an empty cache, enough for the drives'
command timeout to disarm the vehicle (seen on fresh-clone CI)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from numba.core.registry import CPUDispatcher

from drivers.samples import DepthSample, DvlSample, InsSample
from sim_bridge.bridge import write_local_config
from uvd import core
from uvd.geometry import R_to_euler
from uvd.runtime.build import start_pose
from uvd.runtime.config import load_config
from uvd.runtime.daemon import Daemon

ROOT = Path(__file__).resolve().parents[1]


def _signatures() -> dict[str, int]:
    out = {}
    for name, mod in list(sys.modules.items()):
        if not name.startswith(("uvd", "drivers")) or mod is None:
            continue
        for attr, obj in list(vars(mod).items()):
            if isinstance(obj, CPUDispatcher):
                out[f"{name}.{attr}"] = len(obj.signatures)
    return out


def _readonly(a) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


# every controller, parameter model and the online identification; one process each, so that
# no case finds its kernels compiled by another
VARIANTS = {
    "default": {},
    "pdc+aid": {"control": {"controller": "pdc"}, "estimation": {"aid": True}},
    "ambc": {"control": {"controller": "ambc", "robust_adaptation": False}},
    "ambc-full+aid": {"control": {"controller": "ambc", "model": "full"},
                      "estimation": {"aid": True}},
    "two-step-full": {"control": {"controller": "two-step-ambc", "model": "full"}},
}


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_cycles_disarmed_and_armed_with_read_only_inputs_compile_nothing_new(variant, tmp_path):
    probe = (f"import sys; sys.path.insert(0, {str(ROOT / 'tests')!r}); "
             f"import test_no_compile_in_the_loop as t; t.check({variant!r}, {str(tmp_path)!r})")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().endswith("no new signatures"), out.stdout[-1000:]


def check(variant: str, run_dir: str) -> None:
    """Build the daemon of ``variant`` (warm-up included), then run cycles as in flight."""
    cfg = load_config(write_local_config(Path(run_dir), changes=VARIANTS[variant]))
    d = Daemon(cfg, realtime=False)
    before = _signatures()
    H, _ = start_pose(cfg)
    roll, pitch, heading = R_to_euler(H[:3, :3])
    st = d.state
    for k in range(6):
        t = (k + 10) * 100_000_000
        # stamped before the cycle and apart from each other, as samples arrive in flight
        ins = InsSample(t_ns=t - 63_000_000, roll=roll, pitch=pitch, heading=heading,
                        omega_body=_readonly([0.01, 0.0, -0.02 - 0.01 * k]))
        dvl = DvlSample(t_ns=t - 41_000_000, velocity_body=_readonly([0.1, 0.0, 0.0]),
                        bottom_lock=True)
        depth = DepthSample(t_ns=t - 7_000_000, depth_m=float(H[2, 3]))
        speeds = _readonly(np.full(d.core_cfg.allocator.n_thrusters, 3.0))  # as decoded from CAN
        out, st = core.step(d.core_cfg, core.CoreInputs(
            t_ns=t, ins=ins, dvl=dvl, depth=depth, armed=k % 2 == 1,
            propeller_speed_rad_s=speeds), st, 0.1)
        assert out.status in ("ok", "disarmed")
    after = _signatures()
    grown = {f: (before.get(f, 0), n) for f, n in after.items() if n > before.get(f, 0)}
    assert not grown, f"compiled in the loop (signatures before, after): {grown}"
    print("no new signatures")
