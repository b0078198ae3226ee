"""Identification of a real vehicle's rotational model from runs (pure; ``uvd identify
--profile``, ``uvd xval --profile``, the real-vehicle experiment): AID (Theorem 4.2.1), LS or
physically consistent LS (§4.4) of (2.40) over several runs at once, the DOFs the data cannot
identify with the reason, and the identified rotational part inside a vehicle's θ_UV.
"""

from __future__ import annotations

import numpy as np

ROT_DOFS = ("roll", "pitch", "yaw")
TRANS_DOFS = ("surge", "sway", "heave")

def refused_dofs(has_linear_velocity: bool, runs, source: str = "the recordings"
                 ) -> dict[str, str]:
    """DOF → the reason the data cannot identify it (empty: all six identifiable)."""
    out = {}
    if not has_linear_velocity:
        for d in TRANS_DOFS:
            out[d] = (f"no linear-velocity sensor in {source} (no DVL, no "
                      "position fix): the mass and drag of surge, sway and heave act on "
                      "velocities the recording does not contain; an accelerometer or a "
                      "pressure depth alone does not give them without integrating noise "
                      "and bias into invented velocities")
    v = np.vstack([r.v for r in runs])
    for i, d in enumerate(ROT_DOFS):
        if not np.any(np.abs(v[:, 3 + i]) > 1e-6):
            out[d] = f"the {d} rate stayed 0 throughout: nothing to identify"
    return out


def aid_rotational(runs, theta0, gains, progress=None):
    """Rotational AID (Theorem 4.2.1) over the runs one after another, θ̂ carried across and the
    observer re-synchronised (ω̂ = ω) at each run's start; returns (state, ∆ω per sample)."""
    from uvd.control.types import VehicleState
    from uvd.estimation.aid import AID3Params, aid3_init, aid3_step

    st = aid3_init(theta0)
    total = sum(len(r) for r in runs)
    dws, done = [], 0
    for run in runs:
        prm = AID3Params(gains=gains, input_interp=run.input_interp)
        H = run.H
        dw = np.empty((len(run), 3))
        for k in range(len(run)):
            st = aid3_step(VehicleState(H=H[k], v=run.v[k]), run.u[k], prm, st,
                           0.0 if k == 0 else run.dt)
            dw[k] = st.dv
            done += 1
            if progress is not None and done % 1000 == 0:
                progress(done, total)
        dws.append(dw)
    return st, np.vstack(dws)


def identify_rotational(runs, method: str, *, theta0=None, gains=None, window_s: float = 1.0,
                        progress=None, linear_damping: bool = False) -> dict:
    """θ_UVR (2.41) from the runs by ``method`` (aid, ls, ls-consistent); returns a dict with
    ``params`` (RotParams) and the method's figures. ``linear_damping`` (LS methods only):
    identify a diagonal linear damping D_L beside θ_UVR (model ``"rot-lin"`` of
    :mod:`uvd.estimation.ls`), returned as ``linear_damping`` = [d_p, d_q, d_r] (N m s/rad)."""
    from uvd.estimation.aid import aid3_params
    from uvd.estimation.ls import DiffFilter, ls_identify, ls_reduce_runs

    if method == "aid" and linear_damping:
        raise ValueError("AID identifies the thesis's model (2.40), which has no linear "
                         "damping: linear damping is for the LS methods")
    if method == "aid":
        st, dw = aid_rotational(runs, theta0, gains, progress)
        w = np.vstack([r.v[:, 3:] for r in runs])
        tail = slice(max(0, len(dw) - len(dw) // 4), len(dw))
        rel = float(np.sqrt(np.mean(np.sum(dw[tail] ** 2, 1)) / np.mean(np.sum(w[tail] ** 2, 1))))
        return {"params": aid3_params(st), "frozen": st.frozen,
                "freeze_reason": st.freeze_reason, "steps": st.steps,
                "rate_estimate_error_last_quarter": rel,
                "gains": [gains.a, gains.gamma1, gains.gamma2, gains.gamma3]}
    filt = DiffFilter(window_s=window_s)
    model = "rot-lin" if linear_damping else "rot"
    red = ls_reduce_runs(runs, model, filt, progress)
    res = ls_identify(runs, model, filt=filt, consistent=method == "ls-consistent",
                      reduced=red)
    return {"params": res.params, **res.summary()}


def embed_identified(vehicle_params, rot):
    """θ_UV with the rotational block of M, the rotational drag blocks and b from ``rot``
    (RotParams) and everything else from ``vehicle_params`` (the vehicle file)."""
    from uvd.model.params import UVParams

    M = np.array(vehicle_params.M, dtype=float)
    M[3:, :3] = 0.0
    M[:3, 3:] = 0.0
    M[3:, 3:] = 0.5 * (np.asarray(rot.I) + np.asarray(rot.I).T)
    D = np.array(vehicle_params.D, dtype=float)
    for c in range(3):
        D[3 + c, 3:, 3:] = np.asarray(rot.C)[c]
    return UVParams(M=M, D=D, g=float(vehicle_params.g), b=np.asarray(rot.b, dtype=float))


def rot_of(params):
    """The rotational view (2.41) of a θ_UV parameter set."""
    from uvd.model.params import RotParams, theta_uvr_from_theta

    return RotParams.from_theta(theta_uvr_from_theta(params.theta))
