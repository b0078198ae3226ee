"""The cycle a configuration describes: :func:`make_cycle` turns a validated
:class:`~uvd.runtime.config.Config` into the cycle's constant
:class:`~uvd.runtime.cycle.CycleConfig` — the pure core's :class:`uvd.core.CoreConfig`
(:func:`build_core`: navigation timeouts, the controller, the reference, allocation, the online
estimators, the gains of the PDC and hold-depth modes), the failsafe thresholds, the plug-in
triggers and the arming rule. The one assembly of the daemon (at start and on every reload),
``uvd demo``'s lockstep reference and replay, so all three run the very same cycle.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from uvd import core
from uvd.control.allocation import Allocator
from uvd.control.pdc import PDGains, PDState, pdc_step
from uvd.control.trajectory import named, setpoint
from uvd.control.trajectory import start_pose as trajectory_start_pose
from uvd.control.types import ControllerSpec
from uvd.estimation.navigation import NavConfig
from uvd.geometry import eta_of
from uvd.runtime.config import Config
from uvd.runtime.cycle import CycleConfig
from uvd.runtime.triggers import plugin_triggers

__all__ = ["make_cycle", "build_core", "make_controller", "nav_config", "make_reference",
           "start_pose", "aid_theta0", "pd_gains", "adaptation_gains"]

log = logging.getLogger("uvd.daemon")


def nav_config(cfg: Config) -> NavConfig:
    """Navigation timeouts from the failsafe thresholds: a source is valid exactly as long as
    its stale trigger is quiet."""
    th = cfg.failsafe
    return NavConfig(ins_timeout_s=th.ins_stale_s, dvl_timeout_s=th.dvl_stale_s,
                     depth_timeout_s=th.depth_stale_s,
                     propagate_ins=cfg.navigation.propagate_ins)


def make_reference(cfg: Config, center=None):
    """The trajectory of ``[control] reference`` (None for ``hold``: set when armed)."""
    return named(cfg.control.reference) if center is None else \
        named(cfg.control.reference, center)


def start_pose(cfg: Config) -> tuple[np.ndarray, np.ndarray]:
    """Where a run of this configuration starts (:func:`uvd.control.trajectory.start_pose`
    at ``[navigation] initial_north_m``/``initial_east_m``)."""
    n = cfg.navigation
    return trajectory_start_pose(cfg.control.reference, n.initial_north_m, n.initial_east_m)


def _axes(value):
    """A per-axis key (:data:`uvd.runtime.schema.PerAxis`) as the pure layers take it: the
    float, or six as a (6,) array."""
    return np.array(value, dtype=float) if isinstance(value, tuple) else value


def pd_gains(cfg: Config) -> PDGains:
    """k_p, k_d of ``[control]``: PDC's, and those of the PDC and hold-depth modes."""
    return PDGains(kp=_axes(cfg.control.kp), kd=_axes(cfg.control.kd))


def adaptation_gains(cfg: Config) -> dict:
    """γ_m, γ_d, γ_g, γ_b of ``[control]`` as :func:`uvd.control.ambc.adaptation_gains` takes
    them."""
    c = cfg.control
    return {"gamma_m": _axes(c.gamma_m), "gamma_d": _axes(c.gamma_d), "gamma_g": c.gamma_g,
            "gamma_b": c.gamma_b}


def _theta0(cfg: Config, vehicle, model: str) -> np.ndarray:
    from uvd.control.ambc import gravity_index, theta_of
    truth = theta_of(vehicle.params, model)
    kind = cfg.control.theta0
    if kind == "vehicle":
        return truth.copy()
    th = np.zeros_like(truth)
    if kind == "vehicle-gb":
        gi = gravity_index(model)
        th[gi] = truth[gi]
    return th


def _robust(cfg: Config):
    from dataclasses import replace

    from uvd.control.ambc import ROBUST_DAEMON_DEFAULT, RobustAdaptation
    if not cfg.control.robust_adaptation:
        return RobustAdaptation()
    return replace(ROBUST_DAEMON_DEFAULT, mass_floor=_axes(cfg.control.mass_floor))


def make_controller(cfg: Config, vehicle, allocator: Allocator) -> ControllerSpec:
    """The ``[control]`` controller as a :class:`~uvd.control.types.ControllerSpec`."""
    c = cfg.control
    if c.controller == "pdc":
        return ControllerSpec("pdc", pdc_step, pd_gains(cfg), PDState())
    if c.controller == "ambc":
        from uvd.control.ambc import ambc_params, ambc_spec
        p = ambc_params(c.model, kp=_axes(c.kp), kd=_axes(c.kd), eps=c.eps,
                        robust=_robust(cfg), allocator=allocator, **adaptation_gains(cfg))
        return ambc_spec(p, _theta0(cfg, vehicle, c.model))
    from uvd.control.twostep import two_step_params, two_step_spec
    p = two_step_params(c.model, kp=_axes(c.kp), kd=_axes(c.kd), eps=c.eps, robust=_robust(cfg),
                        allocator=allocator, theta0=_theta0(cfg, vehicle, c.model),
                        step1_duration_s=c.step1_duration_s, **adaptation_gains(cfg))
    return two_step_spec(p)


def build_core(cfg: Config, vehicle=None, estimators: tuple | None = None
               ) -> core.CoreConfig:
    """The :class:`uvd.core.CoreConfig` of a configuration.

    For ``reference = "hold"`` the reference is a setpoint at the start pose until the cycle
    replaces it with the pose the vehicle has when armed. ``estimators`` given (a reload: the
    ``[estimation]`` keys need a restart) are kept as they are; None builds them from
    ``[estimation]``, reading ``initial_params``.
    """
    vehicle = vehicle if vehicle is not None else cfg.load_vehicle()
    alloc = Allocator.from_vehicle(vehicle)
    traj = make_reference(cfg)
    if traj is None:
        traj = setpoint(eta_of(start_pose(cfg)[0]))
    if estimators is None:
        estimators = ()
        if cfg.estimation.aid:
            from uvd.estimation.aid import aid6_estimator
            estimators = (aid6_estimator(aid_theta0(cfg, vehicle),
                                         cfg.estimation.aid_params(vehicle)),)
    return core.CoreConfig(nav=nav_config(cfg), controller=make_controller(cfg, vehicle, alloc),
                           reference=traj, allocator=alloc, k_thrust=vehicle.k_thrust,
                           estimators=estimators, lag_compensation=cfg.control.lag_compensation,
                           pd=pd_gains(cfg), dof_priority=cfg.control.dof_priority)


def make_cycle(cfg: Config, vehicle=None, *, estimators: tuple | None = None) -> CycleConfig:
    """The cycle of a configuration (module docstring). ``estimators`` as :func:`build_core`
    (a reload keeps the running ones; a replay starts them where the recording did)."""
    from uvd.runtime.fdc_source import FdcRule
    nav = cfg.navigation
    vehicle = vehicle if vehicle is not None else cfg.load_vehicle()
    return CycleConfig(build_core(cfg, vehicle, estimators), cfg.failsafe,
                       tuple(plugin_triggers(cfg)), hold_on_arm=cfg.control.reference == "hold",
                       north_m=nav.initial_north_m, east_m=nav.initial_east_m,
                       fdc=FdcRule.of(cfg.faults.fdc, vehicle))


def aid_theta0(cfg: Config, vehicle=None) -> np.ndarray | None:
    """θ̂(0) of online AID: the last run's ``save_path`` file (``resume``), else
    ``[estimation] initial_params``, else INITP of §4.6 — scaled to ``vehicle``'s masses with
    ``[estimation] scale_to_vehicle`` (:func:`uvd.estimation.aid.scaled_initp`; INITP itself
    on the JHU ROV), or None (INITP)."""
    base = Path(cfg.source).parent if cfg.source else Path.cwd()
    path = cfg.estimation.start_path(base)
    if path is None and vehicle is not None and cfg.estimation.scale_to_vehicle:
        from uvd.estimation.aid import scaled_initp
        log.info("AID starts from INITP (§4.6) scaled to %s's first guess", vehicle.name)
        return scaled_initp(vehicle.params).theta
    log.info("AID starts from %s", path or "INITP (§4.6, Tables 4.6-4.7)")
    if path is None:
        return None
    from uvd.io.params import params_from_toml
    return params_from_toml(path).theta

