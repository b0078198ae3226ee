"""The plug-in failsafe triggers of a configuration — one list for the daemon and replay.

Built-in triggers live in :mod:`uvd.runtime.failsafe`; the ones here belong to optional
subsystems and read their signal from ``Health.extra`` (filled by the daemon's read phase and
recorded with the cycle's inputs, so a replay sees the same values):

=========================  ==============================  ========================  =======
trigger                    signal (``extra``)              action                    rule
=========================  ==============================  ========================  =======
leak_sensor_fault          ``leak_sensor_fault``           WARN                      clear
operator_heartbeat_lost    ``operator_heartbeat_age_s``    ``[mavlink]               clear
                                                           operator_action``
=========================  ==============================  ========================  =======

``operator_heartbeat_age_s`` is the age of the newest HEARTBEAT of a configured ground
station (``[mavlink] gcs_system_ids``), present only while armed and after one was heard
(docs/mavlink.md): loss of the operator for ``[mavlink] operator_timeout_s`` fires the
trigger; it clears once heartbeats are back (or the vehicle disarmed) for ``clear_after_s``.
"""

from __future__ import annotations

from typing import Any

from uvd.runtime.failsafe import Action, Health, Thresholds, TriggerDef
from uvd.runtime.leak import leak_sensor_fault_trigger

__all__ = ["operator_loss_trigger", "plugin_triggers", "OperatorHeartbeat", "OPERATOR_AGE"]

OPERATOR_AGE = "operator_heartbeat_age_s"
_ACTIONS = {"warn": Action.WARN, "fallback": Action.FALLBACK, "hold-depth": Action.HOLD_DEPTH,
            "zero-thrust": Action.ZERO_THRUST, "disarm": Action.DISARM}


def operator_loss_trigger(timeout_s: float, action: str) -> TriggerDef:
    """``operator_heartbeat_lost``: the operator's heartbeat older than ``timeout_s``."""

    def condition(h: Health, th: Thresholds, mem: Any) -> tuple[str | None, Any]:
        age = None if h.extra is None else h.extra.get(OPERATOR_AGE)
        if age is None or age <= timeout_s:
            return None, mem
        return f"no ground-station heartbeat for {age:.3g} s > {timeout_s:g} s", mem

    return TriggerDef("operator_heartbeat_lost", _ACTIONS[action], condition,
                      doc="ground-station heartbeat lost while armed")


def plugin_triggers(config) -> list[TriggerDef]:
    """The plug-in triggers a :class:`~uvd.runtime.config.Config` asks for."""
    out = []
    if config.sensors.leak.enabled:
        out.append(leak_sensor_fault_trigger())
    m = config.mavlink
    if m.enabled and m.operator_timeout_s > 0:
        out.append(operator_loss_trigger(m.operator_timeout_s, m.operator_action))
    return out


class OperatorHeartbeat:
    """A ground-station link's part of the cycle's inputs (a hardware interface,
    :mod:`uvd.runtime.interfaces`): ``operator_heartbeat_age_s``, the age of the operator's
    newest heartbeat while armed, once one was heard (``link.operator_heartbeat_ns``)."""

    def __init__(self, link) -> None:
        self.link = link

    def read(self, t_ns: int, armed: bool, parts) -> None:
        hb = self.link.operator_heartbeat_ns
        parts.signal(OPERATOR_AGE, None if hb is None or not armed else (t_ns - hb) * 1e-9)
