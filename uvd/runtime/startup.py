"""What the daemon does once before its loop starts: the parameters a ground station kept
(:func:`kept_params`), the numeric kernels loaded off the clock (:func:`warm_up`) and the
``"start"`` record a replay needs (:func:`start_record`)."""

from __future__ import annotations

import gc
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from drivers.samples import DepthSample, DvlSample, InsSample
from uvd import __version__, core
from uvd.geometry import R_to_euler
from uvd.runtime.config import Config
from uvd.runtime.cycle import CycleConfig, CycleState
from uvd.runtime.schema import with_values

__all__ = ["kept_params", "warm_up", "prepare", "start_record"]

log = logging.getLogger("uvd.daemon")


def kept_params(config: Config, path: str) -> tuple[Config, dict[str, Any]]:
    """``config`` with the parameters a ground station set (``[mavlink] params_file``,
    docs/mavlink.md), and those applied; a value that is no longer valid is named in the log
    and skipped."""
    from uvd.links.mavlink.params import read_params_file
    try:
        values = read_params_file(path)
    except ValueError as exc:
        log.error("%s (parameters kept over MAVLink not applied)", exc)
        return config, {}
    applied = {}
    for key, value in values.items():
        new, errors = with_values(config, {key: value})
        if errors:
            log.error("%s: %s (not applied)", path, "; ".join(f"{k}: {r}" for k, r in errors))
            continue
        config, applied[key] = new, value
    if applied:
        log.info("parameters set over MAVLink applied from %s: %s", path, ", ".join(applied))
    return config, applied


def warm_up(cycle: CycleConfig, H: np.ndarray) -> float:
    """Run every numeric path of the core once on synthetic samples at pose ``H``, off the
    clock; returns the seconds spent.

    The compiled kernels (numba, cached on disk) load on their first call — tens to hundreds
    of ms; done in the first armed cycle, that would starve the amplifiers past their command
    timeout. Every mode of :func:`uvd.core.act` runs (the supervised update reaches a mode
    only through a failsafe), with and without a thruster mask, on a scratch state.
    """
    t0 = time.perf_counter()
    cfg = cycle.core
    roll, pitch, heading = R_to_euler(H[:3, :3])
    n = cfg.allocator.n_thrusters
    modes = [(False, core.Mode.CONTROL)] + [(True, m) for m in core.Mode]
    for mask in (None, np.arange(n) != 0):
        st = core.core_init(cfg)
        for k, (armed, mode) in enumerate(modes):
            t = (k + 1) * 100_000_000
            # stamped before the cycle and apart, as in flight: the INS sample carried to the
            # cycle's time, the DVL's attitude carried to its own stamp
            ins = InsSample(t_ns=t - 30_000_000, roll=roll, pitch=pitch, heading=heading,
                            omega_body=np.zeros(3))
            dvl = DvlSample(t_ns=t - 50_000_000, velocity_body=np.zeros(3), bottom_lock=True)
            depth = DepthSample(t_ns=t - 20_000_000, depth_m=float(H[2, 3]))
            _, st = core.step(cfg, core.CoreInputs(
                t, ins, dvl, depth, np.zeros(n), armed, mode, np.zeros(6), mask), st, 0.1)
            cfg.controller.diagnostics(st.ctrl)
    return time.perf_counter() - t0


def prepare(cycle: CycleConfig, H: np.ndarray, status, *, cold: bool, t_init: float
            ) -> float:
    """Before the loop: :func:`warm_up` (saying what it does through ``status``, systemctl
    status shows it), then the long garbage collection once at normal priority and a freeze
    (``GcFreeze`` then only walks what the drivers add when they start). ``cold``: the
    kernel cache was empty when the daemon began (:func:`uvd._jitcache.cache_is_empty`,
    taken before anything called a kernel); ``t_init``: when it began (``perf_counter``).
    Returns the warm-up's seconds."""
    what = "compiling the numeric kernels (once after an install or upgrade: up to a minute)" \
        if cold else "loading the compiled kernels"
    status(what)
    log.info("%s", what)
    spent = warm_up(cycle, H)
    log.info("kernels ready in %.1f s", time.perf_counter() - t_init)
    gc.collect()
    gc.freeze()
    return spent


def start_record(config: Config, params_kept: dict[str, Any], cycle: CycleConfig,
                 state: CycleState) -> dict[str, Any]:
    """The ``"start"`` record: what a replay needs besides the cycles — the configuration
    file's text, the parameters kept over MAVLink applied on top of it, and the online
    estimators' θ̂(0) (a resumed estimate starts elsewhere than the file says), and the BLAS
    kernels this machine's arithmetic used (:func:`uvd.blas.kernels`: a replay elsewhere can
    round differently)."""
    from uvd.blas import kernels
    text = None
    if config.source:
        try:
            text = Path(config.source).read_text(encoding="utf-8")
        except OSError as exc:
            log.warning("the start record carries no configuration: %s", exc)
    return {"type": "start", "t_ns": time.monotonic_ns(), "version": __version__,
            "config_path": str(config.source or ""), "config_toml": text,
            "params_kept": dict(params_kept),
            "estimators": {spec.name: spec.diagnostics(st).theta for spec, st in
                           zip(cycle.core.estimators, state.core.est, strict=True)},
            "blas": kernels()}
