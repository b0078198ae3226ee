"""After the daemon's warm-up, no cycle compiles anything: a numba specialisation met first
in the running loop is compiled there — seconds with an empty cache, enough for the drives'
command timeout to disarm the vehicle (seen on fresh-clone CI)."""

from __future__ import annotations

import sys

import numpy as np
from numba.core.registry import CPUDispatcher

from drivers.samples import DepthSample, DvlSample, InsSample, R_to_euler
from uvd import core
from uvd.runtime.config import load_config
from uvd.runtime.daemon import Daemon, start_pose


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


def test_cycles_disarmed_and_armed_with_read_only_inputs_compile_nothing_new():
    cfg = load_config("config/sim.toml")
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
        speeds = _readonly(np.full(d.allocator.n_thrusters, 3.0))  # as decoded from CAN
        out, st = core.step(d.core_cfg, core.CoreInputs(
            t_ns=t, ins=ins, dvl=dvl, depth=depth, armed=k % 2 == 1,
            propeller_speed_rad_s=speeds), st, 0.1)
        assert out.status in ("ok", "disarmed")
    after = _signatures()
    grown = {f: (before.get(f, 0), n) for f, n in after.items() if n > before.get(f, 0)}
    assert not grown, f"compiled in the loop (signatures before, after): {grown}"
