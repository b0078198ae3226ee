"""uvd-fdc as a source of thruster effectiveness η: the ``[faults.fdc]`` rule and the cycle's
decision on a fault sample (issue 33).

uvd-fdc (:mod:`uvd.fdc.client`, a separate process) publishes what it detects on
``uvd/<vehicle>/fault/<kind>`` (``uvd.fault.v1``). The daemon's Zenoh face subscribes to its own
vehicle's ``uvd/<vehicle>/fault/**`` (the router's ACL lets only the ``fdc`` user put there,
config/zenoh/router.json5) and queues each sample as a
:class:`~uvd.runtime.commands.FaultReport`; the cycle applies it at its next boundary like any
command — recorded, and applied again at the same cycle by ``uvd replay --lockstep`` — and what
it decides goes through the one η path (:class:`~uvd.runtime.commands.SetThrusterEta`'s:
allocation, the STATUSTEXT, the Zenoh event).

``accept`` says what a sample may do:

``advisory``
    logged and told to the operator (the command's event, a STATUSTEXT); η never changes.
``auto``
    a ``thruster`` sample sets that thruster's η = 1 + relative_change (clipped to [0, 1]).
``confirm`` (the default)
    as ``auto``, but only when the daemon's own evidence confirms it. **Confirmation**: the
    cycle keeps its own thrust residual (:mod:`uvd.estimation.thrust_evidence`: the wrench the
    vehicle model (2.44) says the vehicle received, from the cycle's navigation, minus the
    commanded B f, over segments of ``segment_s``, the last ``window_s`` kept). For the named
    thruster i it fits ηᵢ by least squares over the segments since the change time uvd-fdc gives
    (``explanation.since_t_ns``; the whole window when absent). The sample is confirmed when
    |η̂ᵢ − η| ≤ ``tolerance`` with a standard error ≤ ``tolerance``/2 over at least
    ``MIN_SEGMENTS`` segments, and η̂ᵢ is nearer the sample's η than a healthy 1
    (|η̂ᵢ − η| < |η̂ᵢ − 1|: the fault explains the residual better than no fault). It is
    **contradicted** when the fit is that precise but either fails (the thruster pushes as
    commanded; or a small claimed loss the residual does not see). A fit not yet that precise
    (uvd-fdc named the change moments ago: fewer segments than that since it; or the thruster
    barely commanded) **awaits** the residual: the sample is kept in the cycle's state and
    decided again at each segment that closes, up to ``confirm_wait_s`` after it came —
    confirmed then, it sets η as at once (told as an ``accommodated`` failsafe event of trigger
    ``fdc``); contradicted then, or still not precise when the wait ends (**unconfirmed**), it
    is refused (a ``refused`` event). Contradicted and unconfirmed samples are refused —
    logged, counted, told to the operator — and not acted on. Before session 34 a sample was
    decided when it came: uvd-fdc naming a weak thruster of the BlueROV2 1.7 s after the fault
    left the daemon no segment since, and the default ``confirm`` never acted on it.

Samples of another kind (buoyancy, entanglement, …) never change η: they are told, whatever
``accept`` says. The evidence is the configured vehicle model's: a model far from the vehicle
(an unidentified one) widens the fit's spread, and a sample is then unconfirmed rather than
confirmed wrongly.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, NamedTuple

import numpy as np

from uvd.runtime.schema import section, setting

if TYPE_CHECKING:
    from uvd.estimation.thrust_evidence import Evidence, EvidenceConfig

# the evidence's numerics (uvd.estimation, uvd.model) are imported by the functions that run
# them: the configuration imports this module for its sections

__all__ = ["FdcSourceSection", "FaultsSection", "FdcRule", "FdcState", "Awaiting", "Verdict",
           "fdc_init", "fdc_observe", "decide", "fdc_awaited", "MIN_SEGMENTS"]

#: the fewest residual segments a confirmation is made from
MIN_SEGMENTS = 3

#: ``thruster<i>``, i in ASCII digits (``\d`` also took "thruster٤", Arabic-Indic 4, as 4)
_THRUSTER = re.compile(r"thruster([0-9]+)$")


@dataclass(frozen=True)
class FdcSourceSection:
    """uvd-fdc over Zenoh as a source of η (``[faults.fdc]``, docs/zenoh.md)."""

    enabled: bool = setting(False, doc="subscribe to uvd/<key>/fault/** on the daemon's Zenoh "
                                       "face (needs [telemetry.zenoh] enabled) and decide on "
                                       "each sample by accept")
    accept: Literal["confirm", "advisory", "auto"] = setting(
        "confirm", doc="confirm: act on a thruster sample only when the daemon's own thrust "
                       "residual confirms its η; advisory: log and tell the operator, never "
                       "act; auto: act on every thruster sample (docs/zenoh.md)")
    tolerance: float = setting(0.2, min=0.01, max=1.0,
                               doc="confirm: the largest |η̂ − η| between the daemon's fit and "
                                   "the sample's η; the fit's standard error must be below "
                                   "half of it")
    window_s: float = setting(120.0, unit="s", gt=0.0, max=3600.0,
                              doc="confirm: how far back the daemon's residual segments reach")
    segment_s: float = setting(1.0, unit="s", gt=0.0, max=60.0,
                               doc="confirm: length of one residual segment")
    confirm_wait_s: float = setting(
        30.0, unit="s", min=0.0, max=3600.0,
        doc="confirm: how long a sample whose η the residual cannot yet tell (too few or too "
            "imprecise segments since the change) waits for more, decided again at each "
            "segment; then unconfirmed (0: decided when it comes)")


@dataclass(frozen=True)
class FaultsSection:
    """Sources of thruster effectiveness η and their rules (``[faults]``)."""

    fdc: FdcSourceSection = section(FdcSourceSection)


@dataclass(frozen=True)
class FdcRule:
    """The cycle's constant part of the source: ``accept``, ``tolerance``, the evidence's model
    and window, and the per-thruster k of f = k ω|ω| (the amplifiers' speed feedback)."""

    accept: str
    tolerance: float
    evidence: EvidenceConfig
    k_thrust: np.ndarray
    wait_s: float = 0.0

    @classmethod
    def of(cls, s: FdcSourceSection, vehicle) -> FdcRule | None:
        """The rule of ``[faults.fdc]`` for ``vehicle`` (None: the source is off)."""
        if not s.enabled:
            return None
        from uvd.estimation.thrust_evidence import EvidenceConfig
        ev = EvidenceConfig.from_params(vehicle.params, vehicle.B, segment_s=s.segment_s,
                                        window_s=s.window_s)
        return cls(s.accept, s.tolerance, ev, np.asarray(vehicle.k_thrust, dtype=float),
                   s.confirm_wait_s)


class Awaiting(NamedTuple):
    """A thruster sample that awaits the residual (module docstring): the thruster (1-based)
    and η it claims, the change time it gives (s; None: not given), until when it waits (s),
    the claim's words and whose it is."""

    thruster: int
    eta: float
    since_s: float | None
    until_s: float
    claim: str
    source: str


class FdcState(NamedTuple):
    """The source's part of the cycle's state: the evidence, the last thrust commanded (what
    the thrusters are told until the next cycle), the samples counted by outcome and those
    that await the residual (at most one a thruster: a newer sample replaces it)."""

    evidence: Evidence
    f_last: np.ndarray
    acted: int = 0
    contradicted: int = 0
    unconfirmed: int = 0
    advisory: int = 0
    awaiting: tuple[Awaiting, ...] = ()

    def counts(self) -> dict[str, int]:
        return {"acted": self.acted, "contradicted": self.contradicted,
                "unconfirmed": self.unconfirmed, "advisory": self.advisory,
                "awaiting": len(self.awaiting)}


def fdc_init(rule: FdcRule) -> FdcState:
    from uvd.estimation.thrust_evidence import evidence_init
    return FdcState(evidence_init(rule.evidence), np.zeros(rule.evidence.B.shape[1]))


def fdc_observe(rule: FdcRule, st: FdcState, t_ns: int, nav_ok: bool, v, R, speeds,
                thrust) -> FdcState:
    """One cycle's sample for the evidence: the thrust over the interval that ends now is the
    amplifiers' measured k ω|ω| when every speed is finite, else the last command; ``thrust``
    (this cycle's command) is kept for the next. Navigation not valid restarts the open
    segment."""
    from uvd.estimation.thrust_evidence import evidence_step
    if speeds is not None and np.isfinite(speeds).all():
        f = rule.k_thrust * speeds * np.abs(speeds)
    else:
        f = st.f_last
    ev = evidence_step(rule.evidence, st.evidence, t_ns * 1e-9 if nav_ok else math.nan, v,
                       R, f)
    return st._replace(evidence=ev, f_last=np.asarray(thrust, dtype=float))


class Verdict(NamedTuple):
    """What the cycle does with a sample: set η (``thruster``, ``eta``) or not (None), the
    text for the operator, whether the sample was accepted (a refused one is ``ok`` False),
    the new state and whose the sample was."""

    thruster: int | None
    eta: float | None
    text: str
    ok: bool
    state: FdcState | None
    source: str = "uvd-fdc"


def _parse(c: Any, n: int) -> tuple[int, float] | str:
    """(thruster, η) of a thruster sample, or why it is not one."""
    m = _THRUSTER.match(str(c.channel))
    if c.kind != "thruster" or m is None:
        return f"a {c.kind} fault ({c.channel}), not a thruster's"
    i = int(m.group(1))
    rc = c.relative_change
    if not 1 <= i <= n:
        return f"thruster {i} is not one of 1..{n}"
    if isinstance(rc, bool) or not isinstance(rc, (int, float)) or not math.isfinite(rc):
        return f"relative_change {rc!r} is not a finite number"
    return i, min(1.0, max(0.0, 1.0 + float(rc)))


def decide(rule: FdcRule | None, st: FdcState | None, c: Any, n: int, t_ns: int) -> Verdict:
    """The cycle's decision on the :class:`~uvd.runtime.commands.FaultReport` ``c`` for a
    vehicle of ``n`` thrusters, at the cycle of time ``t_ns`` (module docstring)."""
    if rule is None:
        return Verdict(None, None, "[faults.fdc] is not enabled", False, st)
    st = st if st is not None else fdc_init(rule)  # no cycle since the rule came in
    parsed = _parse(c, n)
    conf = f"confidence {c.confidence:.3g}" if isinstance(c.confidence, (int, float)) else ""
    if isinstance(parsed, str):
        return Verdict(None, None, f"{c.source}: {parsed}; told, not acted on ({conf})",
                       True, st._replace(advisory=st.advisory + 1))
    i, eta = parsed
    claim = f"{c.source}: thruster {i} eta {eta:.2f} ({conf})"
    if rule.accept == "advisory":
        return Verdict(None, None, f"{claim}; advisory, not acted on", True,
                       st._replace(advisory=st.advisory + 1))
    if rule.accept == "auto":
        return Verdict(i, eta, f"{claim}; accepted (auto)", True,
                       st._replace(acted=st.acted + 1))
    since = None if c.since_t_ns is None else int(c.since_t_ns) * 1e-9
    waiting = Awaiting(i, eta, since, t_ns * 1e-9 + rule.wait_s, claim, c.source)
    # a newer sample of the thruster replaces one that awaits, decided now or awaiting itself
    st = st._replace(awaiting=tuple(a for a in st.awaiting if a.thruster != i))
    v, seen = _judge(rule, st, waiting, final=not rule.wait_s > 0.0)
    if v is not None:
        return v
    return Verdict(None, None, f"{claim}; awaiting the daemon's residual ({seen}, not yet "
                               f"precise to {rule.tolerance / 2:g}): decided at each segment, "
                               f"within {rule.wait_s:g} s", True,
                   st._replace(awaiting=(*st.awaiting, waiting)))


def _judge(rule: FdcRule, st: FdcState, a: Awaiting, final: bool
           ) -> tuple[Verdict | None, str]:
    """The verdict on ``a`` by the evidence in ``st`` — confirmed or contradicted when the fit
    is precise enough; else unconfirmed when ``final``, None (it waits on) when not — and what
    the residual gives, in words."""
    from uvd.estimation.thrust_evidence import thruster_fit
    fit = thruster_fit(rule.evidence, st.evidence, a.thruster, a.since_s)
    seen = (f"the daemon's residual gives eta {fit.eta:.2f} ± {fit.se:.2f} over "
            f"{fit.seconds:.0f} s ({fit.segments} segments)")
    tol = rule.tolerance
    if fit.segments < MIN_SEGMENTS or not fit.se <= tol / 2:  # NaN: never commanded
        if not final:
            return None, seen
        return Verdict(None, None, f"{a.claim}; unconfirmed: {seen}, not precise to "
                                   f"{tol / 2:g}; not acted on", False,
                       st._replace(unconfirmed=st.unconfirmed + 1)), seen
    if abs(fit.eta - a.eta) > tol or abs(fit.eta - a.eta) >= abs(fit.eta - 1.0):
        why = f"not within {tol:g}" if abs(fit.eta - a.eta) > tol else "nearer a healthy 1"
        return Verdict(None, None, f"{a.claim}; contradicted: {seen}, {why}; not acted on",
                       False, st._replace(contradicted=st.contradicted + 1)), seen
    return Verdict(a.thruster, a.eta, f"{a.claim}; confirmed: {seen}", True,
                   st._replace(acted=st.acted + 1), a.source), seen


def fdc_awaited(rule: FdcRule, st: FdcState, t_s: float, segment_closed: bool
                ) -> tuple[FdcState, tuple[Verdict, ...]]:
    """The samples that await the residual, decided again (module docstring): at a segment
    that closed this cycle, and at the end of each one's wait (``t_s``: this cycle's time).
    Returns the state without the decided ones and their verdicts, in the order they came."""
    if not st.awaiting:
        return st, ()
    kept: list[Awaiting] = []
    verdicts: list[Verdict] = []
    for a in st.awaiting:
        final = t_s >= a.until_s
        v = _judge(rule, st, a, final)[0] if segment_closed or final else None
        if v is None:
            kept.append(a)
        else:
            verdicts.append(v)
            st = v.state
    return st._replace(awaiting=tuple(kept)), tuple(verdicts)
