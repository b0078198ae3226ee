"""The telemetry records the daemon publishes on its :class:`~uvd.telemetry.sink.TelemetryHub`.

One typed record per cycle, shared by the writer (the daemon, lockstep runs) and every reader
(JSON-lines files, ``uvd identify``, ``uvd demo``, the Zenoh, MAVLink and MCAP sinks). On the
hub a record travels as a plain mapping (``to_dict``) whose ``"type"`` names its kind:

=============  =================================================================================
``type``       what
=============  =================================================================================
``cycle``      :class:`CycleRecord` — one per control cycle (decimated per sink)
``estimate``   one per online estimator every ``[estimation] publish_every_s`` (θ̂, M̂'s
               eigenvalues, frozen flag and reason, steps …; see ``Daemon.estimate_records``)
``failsafe``   a failsafe event (trigger raised / cleared / reset), ``FailsafeEvent.as_dict``
``lifecycle``  a lifecycle transition (BOOT → STANDBY → ARMED …), ``Transition.as_dict``
``command``    an operator command and its result (:mod:`uvd.runtime.commands`)
=============  =================================================================================

The pose travels as the position ``p`` (north, east, down, m) and the rotation matrix ``R``
(body → world, row-major 3×3), not as Euler angles: a reader that wants angles calls
:func:`euler_of`. Arrays stay numpy arrays on the hub (no conversion on the loop's path); the
sinks convert (:func:`uvd.jsonio.to_jsonable`). :meth:`CycleRecord.from_dict` reads both forms.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from uvd.geometry import R_to_euler
from uvd.jsonio import is_int64

__all__ = ["CycleRecord", "estimate_record", "euler_of", "eta_of_record", "CYCLE",
           "tracking_error_norms", "array_shape", "cycle_record_problem"]

CYCLE = "cycle"


def _arr(x: Any, shape: tuple[int, ...] | None = None) -> np.ndarray | None:
    if x is None:
        return None
    a = np.asarray(x, dtype=float)
    return a.reshape(shape) if shape is not None else a


def _opt_int(x: Any) -> int | None:
    return None if x is None else int(x)


def _age(x: Any) -> float:
    return math.inf if x is None else float(x)


@dataclass(frozen=True, slots=True)
class CycleRecord:
    """What one control cycle saw, decided and commanded.

    Attributes
    ----------
    t_ns : int
        Monotonic time of the cycle (ns).
    dt : float
        Measured period handed to the cycle (s).
    state : str
        Lifecycle state (``standby``, ``armed`` …).
    action : str
        Failsafe action in force (``none``, ``fallback``, ``hold-depth`` …).
    mode : str
        Control mode the cycle applied (:class:`uvd.core.Mode` value).
    status : str
        The core's status (``ok``, ``disarmed``, ``nav-invalid``, ``non-finite``).
    p : ndarray, shape (3,)
        Navigation position, world NED (m).
    R : ndarray, shape (3, 3)
        Navigation attitude, body → world.
    v : ndarray, shape (6,)
        Navigation body velocity [ν; ω] (m/s, rad/s).
    nav_valid : bool
    u : ndarray, shape (6,)
        Wrench applied over the last cycle as the estimators saw it (N, N m).
    u_cmd : ndarray, shape (6,)
        Wrench of this cycle's thruster command (N, N m).
    thrust : ndarray, shape (n,)
        Per-thruster command (N) — exactly what the amplifiers were sent.
    ages : tuple of float
        Ages of INS, DVL, depth and amplifier feedback (s; inf: none yet).
    ins_rx_ns, dvl_rx_ns, depth_rx_ns : int or None
        Receive stamps of the samples this cycle took (None: none new) — which recorded
        frames a replay feeds to this cycle.
    inputs : mapping or None
        The rest of the cycle's inputs, as the read phase gathered them
        (``uvd.runtime.cycle.inputs_record``: amplifier status, loop overrun streak, leak,
        plug-in signals) — with the frames, everything a replay needs.
    triggers : tuple of str
        Active failsafe triggers.
    operator_mode : str
        The operator's mode (``uvd.runtime.commands.OPERATOR_MODES``); ``mode`` is what the
        cycle applied after the failsafe arbiter.
    p_ref, R_ref, v_ref : ndarray or None
        The reference (None while there is none).
    armed_at_ns : int or None
        When the vehicle was last armed.
    """

    t_ns: int
    dt: float
    state: str
    action: str
    mode: str
    status: str
    p: np.ndarray
    R: np.ndarray
    v: np.ndarray
    nav_valid: bool
    u: np.ndarray
    u_cmd: np.ndarray
    thrust: np.ndarray
    ages: tuple[float, float, float, float]
    ins_rx_ns: int | None = None
    dvl_rx_ns: int | None = None
    depth_rx_ns: int | None = None
    inputs: Mapping[str, Any] | None = None
    triggers: tuple[str, ...] = ()
    operator_mode: str = "auto"
    p_ref: np.ndarray | None = None
    R_ref: np.ndarray | None = None
    v_ref: np.ndarray | None = None
    armed_at_ns: int | None = None

    def to_dict(self) -> dict[str, Any]:
        """The hub's form: ``{"type": "cycle", field: value, …}`` (arrays kept as arrays)."""
        d = {f: getattr(self, f) for f in self.__slots__}
        d["type"] = CYCLE
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> CycleRecord:
        """Read a record from its hub or JSON form (lists, ``null`` for inf ages).

        Raises
        ------
        KeyError
            A required field is missing (the message names it).
        ValueError
            A field has the wrong shape.
        """
        ages = d.get("ages") or (None, None, None, None)
        return cls(
            t_ns=int(d["t_ns"]), dt=float(d["dt"]), state=str(d["state"]),
            action=str(d["action"]), mode=str(d["mode"]), status=str(d["status"]),
            p=_arr(d["p"], (3,)), R=_arr(d["R"], (3, 3)), v=_arr(d["v"], (6,)),
            nav_valid=bool(d["nav_valid"]), u=_arr(d["u"], (6,)),
            u_cmd=_arr(d.get("u_cmd", d["u"]), (6,)), thrust=_arr(d["thrust"]),
            ages=tuple(_age(a) for a in ages),
            ins_rx_ns=_opt_int(d.get("ins_rx_ns")), dvl_rx_ns=_opt_int(d.get("dvl_rx_ns")),
            depth_rx_ns=_opt_int(d.get("depth_rx_ns")), inputs=d.get("inputs"),
            triggers=tuple(d.get("triggers") or ()),
            operator_mode=str(d.get("operator_mode", "auto")),
            p_ref=_arr(d.get("p_ref"), (3,)), R_ref=_arr(d.get("R_ref"), (3, 3)),
            v_ref=_arr(d.get("v_ref"), (6,)),
            armed_at_ns=_opt_int(d.get("armed_at_ns")))

    def eta(self) -> np.ndarray:
        """[north, east, down, roll, pitch, heading] of the navigation pose."""
        return np.array([*self.p, *euler_of(self.R)])

    def eta_ref(self) -> np.ndarray | None:
        """The same of the reference (None without one)."""
        if self.p_ref is None or self.R_ref is None:
            return None
        return np.array([*self.p_ref, *euler_of(self.R_ref)])


def estimate_record(t_ns: int, estimator: str, g, age_s: float | None = None,
                    source: str = "estimator") -> dict[str, Any]:
    """The ``"estimate"`` record of an online estimator (``source`` ``"estimator"``) or of an
    adaptive controller's own θ̂ (``"controller"``) from its spec's diagnostics
    (:class:`uvd.control.types.Diagnostics`): θ̂ (a copy), M̂'s extreme eigenvalues, frozen
    and why, the counters, ‖v̂ − v‖, ``age_s``, the time since θ̂ was last stepped (None:
    not known), and ``hold_reason``: the DOFs whose parameters are held because no thruster
    reaches them any more ("" : none)."""
    return {"type": "estimate", "t_ns": int(t_ns), "estimator": estimator, "source": source,
            "theta": None if g.theta is None else np.array(g.theta, dtype=float),
            "m_min_eig": g.m_min_eig, "m_max_eig": g.m_max_eig, "frozen": bool(g.frozen),
            "freeze_reason": g.freeze_reason, "steps": g.steps, "skipped": g.skipped,
            "resyncs": g.resyncs, "velocity_error": g.velocity_error, "age_s": age_s,
            "hold_reason": g.hold_reason}


def estimate_records(core_cfg, state, t_ns: int) -> list[dict[str, Any]]:
    """The ``"estimate"`` records of one cycle's state (:class:`uvd.core.CoreState`): one per
    online estimator (``[estimation]``), aged from when the estimators last stepped
    (``state.est_t_ns``: they skip cycles without valid navigation), and one for the
    controller when it adapts a θ̂ of its own (AMBC; named as the controller, e.g.
    ``two-step-ambc``), aged from the last cycle that ran it in control
    (``state.ctrl_t_ns``)."""
    def age(since: int | None) -> float | None:
        return None if since is None else max(0.0, (t_ns - since) * 1e-9)
    out = [estimate_record(t_ns, spec.name, spec.diagnostics(st), age(state.est_t_ns))
           for spec, st in zip(core_cfg.estimators, state.est, strict=True)]
    c = core_cfg.controller
    g = c.diagnostics(state.ctrl)
    if g.theta is not None:
        out.append(estimate_record(t_ns, c.name, g, age(state.ctrl_t_ns), "controller"))
    return out


def euler_of(R: Any) -> tuple[float, float, float]:
    """(roll, pitch, heading) of a rotation given as 3×3 or 9 row-major numbers (App. A)."""
    return R_to_euler(np.asarray(R, dtype=float).reshape(3, 3))


def eta_of_record(d: Mapping[str, Any], *, ref: bool = False) -> np.ndarray:
    """[north, east, down, roll, pitch, heading] of a cycle record in hub or JSON form (JSON's
    null, as a navigation state that is not valid is written: NaN); of its reference with
    ``ref``."""
    p, R = (d["p_ref"], d["R_ref"]) if ref else (d["p"], d["R"])
    return np.array([*np.asarray(p, dtype=float), *euler_of(R)])


def tracking_error_norms(d: Mapping[str, Any]) -> tuple[float, float]:
    """‖Δψ‖ (5.3) and ‖Δv‖ (5.4) of one cycle record: its navigation state against its
    reference (the record must carry ``p_ref``, ``R_ref`` and ``v_ref``)."""
    from uvd.control.errors import error_coordinates

    H, Hr = np.eye(4), np.eye(4)
    H[:3, :3], H[:3, 3] = np.asarray(d["R"], float), np.asarray(d["p"], float)
    Hr[:3, :3], Hr[:3, 3] = np.asarray(d["R_ref"], float), np.asarray(d["p_ref"], float)
    _, e_psi, e_v, _ = error_coordinates(H, np.asarray(d["v"], float), Hr,
                                         np.asarray(d["v_ref"], float))
    return float(np.linalg.norm(e_psi)), float(np.linalg.norm(e_v))


#: a cycle record's arrays (uvd.cycle.v1) and their shapes; the reference's may be null
_CYCLE_ARRAYS = {"p": (3,), "R": (3, 3), "v": (6,), "u": (6,)}
_REFERENCE_ARRAYS = {"p_ref": (3,), "R_ref": (3, 3), "v_ref": (6,)}


def array_shape(x: Any) -> tuple[int, ...] | None:
    """The shape of ``x`` as an array of numbers (null as NaN); None: not one."""
    if isinstance(x, (str, bytes, Mapping)):
        return None
    try:
        return np.asarray(x, dtype=float).shape
    except (TypeError, ValueError):
        return None


def cycle_record_problem(d: Any) -> str | None:
    """What makes ``d`` (a cycle record read back, JSON form) not what uvd.cycle.v1 promises in
    the fields its readers use — ``uvd report`` skips and counts such a record, a replay ends
    there; None: nothing. The time and receive stamps are int64, ``state``, ``action`` and
    ``mode`` strings, ``dt`` a finite number, ``p``, ``R``, ``v``, ``u`` of their shapes (null:
    NaN, as an invalid navigation state is written), ``thrust`` one row of finite numbers,
    the reference's three arrays all there or all null, ``inputs`` an object or null."""
    if not isinstance(d, Mapping):
        return f"a JSON {type(d).__name__}, not an object"
    if not is_int64(d.get("t_ns")):
        return f"t_ns {d.get('t_ns')!r:.40} is not a 64-bit integer"
    for k in ("state", "action", "mode"):
        if not isinstance(d.get(k), str):
            return f"{k} {d.get(k)!r:.40} is not a string"
    dt = d.get("dt")
    if not isinstance(dt, (int, float)) or isinstance(dt, bool) or not math.isfinite(dt):
        return f"dt {dt!r:.40} is not a finite number"
    for k in ("ins_rx_ns", "dvl_rx_ns", "depth_rx_ns"):
        if d.get(k) is not None and not is_int64(d[k]):
            return f"{k} {d[k]!r:.40} is not a 64-bit integer"
    ref = [d.get(k) is not None for k in _REFERENCE_ARRAYS]
    if any(ref) and not all(ref):
        return "a reference needs p_ref, R_ref and v_ref together"
    want = {**_CYCLE_ARRAYS, **(_REFERENCE_ARRAYS if all(ref) else {})}
    for k, shape in want.items():
        if array_shape(d.get(k)) != shape:
            return f"{k} is not {'×'.join(map(str, shape))} numbers"
    thrust = array_shape(d.get("thrust"))
    if thrust is None or len(thrust) != 1 or thrust[0] == 0 \
            or not np.all(np.isfinite(np.asarray(d["thrust"], dtype=float))):
        return "thrust is not a row of finite numbers"
    if d.get("inputs") is not None and not isinstance(d["inputs"], Mapping):
        return f"inputs {d['inputs']!r:.40} is not an object"
    return None
