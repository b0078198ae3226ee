"""A deterministic core scenario whose outputs were recorded before the cycle's glue was compiled.

``run(name)`` drives :func:`uvd.core.step` through 600 cycles at 1 kHz with samples arriving
as they do in flight (INS every 10 cycles, DVL every 7 with its own stamp so the attitude is
propagated to the DVL's time, depth every 5), propeller-speed feedback (one cycle non-finite,
a stretch without), INS rates missing for a while (rates derived from attitude), a disarmed
stretch, a navigation outage, and a saturating command. ``tests/data/core_replay.npz`` holds
the outputs of the plain-numpy cycle (commit before "core: compiled glue"), which
``test_core_replay.py`` compares with the current one to 1e-12 relative.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from drivers.samples import DepthSample, DvlSample, InsSample
from uvd import core
from uvd.bench.loop import ambc_aid_config
from uvd.control.allocation import Allocator
from uvd.control.pdc import PDGains, PDState, pdc_step
from uvd.control.trajectory import reftraj2
from uvd.estimation.navigation import NavConfig, nav_set_position
from uvd.io.vehicle import load_vehicle

SCENARIOS = ("ambc-aid", "pdc-reftraj2")
N_CYCLES = 600
FIELDS = ("thrust_n", "u_cmd", "u_applied", "nav_H", "nav_v", "ref_H", "ref_v", "ref_vdot",
          "saturated", "status", "ctrl_theta", "est_theta", "est_vhat", "north_east")


def _config(name: str) -> core.CoreConfig:
    # the recording predates carrying the INS sample to the cycle's time (navigation's
    # ``propagate_ins``), a change of behaviour, not of the glue this replay checks: off here
    if name == "ambc-aid":
        cfg = ambc_aid_config()
        return replace(cfg, nav=replace(cfg.nav, propagate_ins=False))
    vehicle = load_vehicle("jhu-rov")
    nav = NavConfig(dvl_mount_R=np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
                    dvl_lever_arm_m=np.array([0.1, 0.0, 0.2]), propagate_ins=False)
    return core.CoreConfig(nav=nav, controller=core.ControllerSpec(
        "pdc", pdc_step, PDGains(kp=20.0, kd=20.0), PDState()), reference=reftraj2(),
        allocator=Allocator.from_vehicle(vehicle), k_thrust=vehicle.k_thrust)


def run(name: str) -> dict[str, np.ndarray]:
    cfg = _config(name)
    ref0 = cfg.reference.at(0.0)
    st = core.core_init(cfg, north_m=float(ref0.H[0, 3]) + 0.05,
                        east_m=float(ref0.H[1, 3]) - 0.03)
    n_thr = cfg.allocator.n_thrusters
    rows: dict[str, list] = {k: [] for k in FIELDS}
    t0 = 1_000_000_000
    for k in range(N_CYCLES):
        t_ns = t0 + k * 1_000_000
        s = 1e-3 * k
        ins = dvl = depth = None
        if k % 10 == 0 and not 300 <= k < 420:  # INS outage 300..420 (> 100 ms timeout)
            rates_ok = not 150 <= k < 220
            ins = InsSample(t_ns=t_ns - 200_000, roll=0.02 * np.sin(3 * s),
                            pitch=-0.01 + 0.03 * np.cos(2 * s), heading=0.4 + 0.2 * s,
                            omega_body=(np.array([0.01 + 0.02 * s, -0.02, 0.2])
                                        if rates_ok else np.full(3, np.nan)),
                            rates_valid=rates_ok)
        if k % 7 == 3:
            dvl = DvlSample(t_ns=t_ns - 1_300_000,
                            velocity_body=np.array([0.3 + 0.1 * np.sin(s), 0.05, -0.02]),
                            bottom_lock=k % 49 != 3)
        if k % 5 == 1:
            depth = DepthSample(t_ns=t_ns - 500_000, depth_m=2.0 + 0.1 * np.sin(4 * s))
        if k == 111:
            speeds = np.full(n_thr, np.nan)
        elif 200 <= k < 230:
            speeds = None
        else:
            speeds = 15.0 * np.sin(0.01 * k + np.arange(n_thr))
        armed = not 250 <= k < 270
        inputs = core.CoreInputs(t_ns=t_ns, ins=ins, dvl=dvl, depth=depth,
                                 propeller_speed_rad_s=speeds, armed=armed)
        if k == 480:  # a position fix 40 m away: a huge error, the command saturates
            st.nav = nav_set_position(st.nav, st.nav.north_m + 40.0, st.nav.east_m)
        out, st = core.step(cfg, inputs, st, 1e-3)
        rows["thrust_n"].append(out.thrust_n)
        rows["u_cmd"].append(out.u_cmd)
        rows["u_applied"].append(out.u_applied)
        rows["nav_H"].append(out.nav.H)
        rows["nav_v"].append(out.nav.v)
        rows["ref_H"].append(out.reference.H)
        rows["ref_v"].append(out.reference.v)
        rows["ref_vdot"].append(out.reference.vdot)
        rows["saturated"].append(out.saturated)
        rows["status"].append(out.status)
        if k % 20 == 19:  # the 241-vectors every 20 cycles (they carry the history)
            rows["ctrl_theta"].append(getattr(st.ctrl, "theta", np.zeros(0)))
            rows["est_theta"].append(st.est[0].theta if st.est else np.zeros(0))
        rows["est_vhat"].append(st.est[0].v_hat if st.est else np.zeros(0))
        rows["north_east"].append(np.array([st.nav.north_m, st.nav.east_m]))
    return {k: np.array(v) for k, v in rows.items()}


def record(path: str) -> None:
    data = {f"{name}/{k}": v for name in SCENARIOS for k, v in run(name).items()}
    np.savez_compressed(path, **data)


if __name__ == "__main__":  # python -m tests.core_replay tests/data/core_replay.npz
    import sys
    record(sys.argv[1])
