"""The write phase's telemetry: one ``"cycle"`` record per cycle (:func:`cycle_record`) and,
every ``[estimation] publish_every_s``, the online estimates (:class:`Estimates`) — records on
the :class:`~uvd.telemetry.hub.TelemetryHub`, never a change to the command."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from uvd.runtime.app import ShutdownStep
from uvd.runtime.cycle import CycleInputs, CycleResult, inputs_record
from uvd.telemetry.records import CycleRecord, estimate_records

__all__ = ["cycle_record", "Estimates"]

log = logging.getLogger("uvd.daemon")


def cycle_record(t_ns: int, dt: float, inp: CycleInputs, r: CycleResult) -> dict[str, Any]:
    """The ``"cycle"`` record of one update (docs/zenoh.md, uvd.cycle.v1)."""
    out, d, h = r.out, r.decision, r.health
    nav, ref = out.nav, out.reference
    return CycleRecord(
        t_ns=t_ns, dt=dt, state=r.state.value, action=d.action.label, mode=out.mode,
        status=out.status, p=nav.H[:3, 3], R=nav.H[:3, :3], v=nav.v, nav_valid=nav.valid,
        u=out.u_applied, u_cmd=out.u_cmd, thrust=out.thrust_n,
        ages=(h.ins_age_s, h.dvl_age_s, h.depth_age_s, h.feedback_age_s),
        ins_rx_ns=None if inp.ins is None else inp.ins.t_ns,
        dvl_rx_ns=None if inp.dvl is None else inp.dvl.t_ns,
        depth_rx_ns=None if inp.depth is None else inp.depth.t_ns,
        inputs=inputs_record(inp, r.thruster_eta),
        triggers=tuple(a.name for a in d.active), operator_mode=r.operator_mode,
        p_ref=None if ref is None else ref.H[:3, 3],
        R_ref=None if ref is None else ref.H[:3, :3],
        v_ref=None if ref is None else np.asarray(ref.v),
        armed_at_ns=r.armed_at_ns).to_dict()


class Estimates:
    """The ``"estimate"`` records of the online estimators (``[estimation]``) and of an
    adaptive controller's own θ̂ (AMBC; :func:`uvd.telemetry.records.estimate_records`),
    published every ``period_s``.

    Keys: ``estimator`` (name), ``theta`` (θ̂, for AID θ_UV ∈ R²⁴¹ in the order of (2.48), a
    copy), ``m_min_eig``/``m_max_eig`` (M̂'s extreme eigenvalues), ``frozen`` and
    ``freeze_reason`` (AID stops adapting when M̂ would lose positive definiteness and keeps
    the last positive-definite θ̂), ``steps``, ``skipped`` (non-finite inputs), ``resyncs``
    (v̂ re-synchronised after a navigation gap), ``velocity_error`` (‖v̂ − v‖).
    """

    def __init__(self, hub, supervisor, period_s: float) -> None:
        self.hub = hub
        self.supervisor = supervisor  # the running cycle: its configuration and state
        self.period_ns = int(period_s * 1e9)
        self._next_ns = 0
        self.last_t_ns = 0
        self.cycled = False  # a cycle ran: there is an estimate of this run to publish
        self._frozen_logged: set[str] = set()
        c = supervisor.config.core
        #: anything to publish: online estimators, or a controller adapting its own θ̂
        self.adapts = bool(c.estimators) or \
            c.controller.diagnostics(supervisor.data.core.ctrl).theta is not None

    def attach(self, app) -> None:
        """With online estimators: a shutdown step of ``app`` — after the amplifiers are safe,
        before the sinks close (``[estimation] save_path``'s among them) — that publishes the
        newest θ̂ however long ago the last periodic record went out. A run whose start
        failed before any cycle publishes nothing: its θ̂ is the one it loaded, and writing it
        to ``save_path`` would overwrite an earlier run's estimate kept there."""
        if not self.supervisor.config.core.estimators:
            return

        async def final() -> None:
            if self.cycled:
                self.publish(self.last_t_ns)
        app.add_shutdown_step(ShutdownStep("publish the final estimate", final))

    def records(self, t_ns: int) -> list[dict[str, Any]]:
        return estimate_records(self.supervisor.config.core, self.supervisor.data.core, t_ns)

    def after_cycle(self, t_ns: int, dt: float) -> None:
        """Publish when due — within half a period of the due time: a cycle a few µs early
        is not skipped."""
        self.last_t_ns = t_ns
        self.cycled = True
        if self.adapts and t_ns >= self._next_ns - int(dt * 5e8):
            self._next_ns = t_ns + self.period_ns
            self.publish(t_ns)

    def publish(self, t_ns: int) -> None:
        for rec in self.records(t_ns):
            # an estimator's freeze is for good; a controller's a skipped update, not logged
            if rec["frozen"] and rec["source"] == "estimator" \
                    and rec["estimator"] not in self._frozen_logged:
                self._frozen_logged.add(rec["estimator"])
                log.warning("%s stopped adapting: %s (the estimate kept is the last with M̂ "
                            "positive definite)", rec["estimator"], rec["freeze_reason"])
            self.hub.publish(rec, always=True)
