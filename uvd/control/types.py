"""Small value types shared by controllers, estimators and the core."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class VehicleState:
    """Actual state: pose ʷₐH (4×4, body→world) and body velocity ᵃvₐ = [ν; ω] (5.1)."""

    H: np.ndarray
    v: np.ndarray


@dataclass(frozen=True, slots=True)
class Reference:
    """Desired state {ʷ_dH, ᵈv_d, ᵈv̇_d} (§5.2.4.1), velocities in the desired body frame.

    ``open_loop_wrench`` is added to the controller's output for DOFs driven open loop
    (RefTraj2's roll and pitch torques, Table 5.1); ``closed_loop`` masks which DOFs the
    controller acts on (all six by default). ``preview`` is the desired state δ seconds later,
    set by the core only when the feed-forward preview is on (``CoreConfig.ff_preview_s``);
    the model-based controllers then evaluate their feed-forward on it
    (:func:`uvd.control.ambc.ambc_step`).
    """

    H: np.ndarray
    v: np.ndarray
    vdot: np.ndarray
    open_loop_wrench: np.ndarray | None = None
    closed_loop: np.ndarray | None = None
    preview: Reference | None = None
