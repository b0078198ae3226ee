"""Change detection on a vehicle's parameter estimates (thesis §6.2): CUSUM on normalised
deviations from a learned baseline. Pure: numbers in, detections out.

Why CUSUM. A fault changes the vehicle's parameters once and for good (a net caught on it, a
flooded housing, a lost float), so the estimates' mean steps and stays; Page's cumulative sum
is the optimal detector of such a step in the sense of Lorden (the shortest worst-case delay
for a given mean time between false alarms) when the step size is known, and robust when it is
not. For each channel i the estimate x is normalised, z = (x − μᵢ)/σᵢ, and two one-sided sums
run, S⁺ = max(0, S⁺ + z − k), S⁻ = max(0, S⁻ − z − k); an alarm is S > h.

The trade-off, in the units of z: k is half the smallest step worth detecting (k = 1: steps of
2σ and more; smaller steps pass unnoticed, drifts slower than k per sample never accumulate);
h sets the false-alarm rate against the delay. For independent Gaussian z, Siegmund's
approximation gives a mean run length to a false alarm of about e^{2k(h+1.166)}/(2k²) samples
(≈ 4·10¹¹ for k = 1, h = 12) and a delay of about (h + 1.166)/(δ − k) samples for a step of δσ
(δ = 5: 3.3 samples). AID's estimates are not independent samples — they are filtered, so
noise is correlated and the real rate of false alarms is higher than the formula says; the
margins above (and σ floored at ``rel_floor`` of the baseline value, so a slow drift of a few
per cent an hour, as the unexcited drift of `aid-hover`, never accumulates) are what
`uvd experiment fdc` checks over a fault-free run of hours.

Baseline. μ and σ are learned from the first ``baseline_s`` of estimates after ``warmup_s``:
the median, and the larger of the median absolute deviation (×1.4826, Gaussian-consistent)
and the standard deviation (which sees the slow wander of a filtered estimate that the MAD of
near neighbours misses: with the MAD alone, b₂ of a fault-free hour alarmed); σ is floored at
``rel_floor``·|μ| and ``abs_floor``.

Kinds (the channel group whose sum crosses h first): drags up → ``entanglement``; masses up →
``flooding``, down → ``lost-part``; g or b → ``buoyancy``. A thruster that turns but pushes
less (a fouled propeller) is not separable from these by the estimates alone: AID attributes
the missing thrust to b and the masses of the DOFs it drives (measured, docs/zenoh.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["CusumSettings", "Detection", "VehicleDetector", "channels_of"]


@dataclass(frozen=True)
class CusumSettings:
    warmup_s: float = 300.0
    baseline_s: float = 1200.0
    k: float = 1.0
    h: float = 12.0
    rel_floor: float = 0.02
    abs_floor: float = 0.1


@dataclass(frozen=True)
class Detection:
    """One fault: ``kind``, when (the estimate's ``t_ns``), which channel crossed, its
    normalised deviation and the sum at the crossing (``confidence``: S/h ≥ 1)."""

    vehicle: str
    kind: str
    t_ns: int
    channel: str
    magnitude: float
    relative_change: float
    confidence: float

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def channels_of(payload: dict) -> dict[str, float]:
    """The monitored numbers of an estimate payload (``uvd.zestimate.v1``): the six masses,
    the six diagonal drags (as magnitudes), g and b."""
    out: dict[str, float] = {}
    for name, key in (("mass", "masses"), ("drag", "drags")):
        vals = payload.get(key)
        if vals is not None:
            for i, x in enumerate(vals):
                if x is not None:
                    out[f"{name}{i + 1}"] = abs(float(x)) if name == "drag" else float(x)
    if payload.get("g") is not None:
        out["g"] = float(payload["g"])
    for i, x in enumerate(payload.get("b") or ()):
        if x is not None:
            out[f"b{i + 1}"] = float(x)
    return out


def _kind(channel: str, direction: float) -> str:
    if channel.startswith("drag"):
        return "entanglement" if direction > 0 else "drag-decrease"
    if channel.startswith("mass"):
        return "flooding" if direction > 0 else "lost-part"
    return "buoyancy"


@dataclass
class VehicleDetector:
    """The detector of one vehicle; feed it every estimate payload with :meth:`update`."""

    vehicle: str
    settings: CusumSettings = field(default_factory=CusumSettings)
    t0_ns: int | None = None
    baseline: dict[str, list[float]] = field(default_factory=dict)
    mu: dict[str, float] = field(default_factory=dict)
    sigma: dict[str, float] = field(default_factory=dict)
    s_pos: dict[str, float] = field(default_factory=dict)
    s_neg: dict[str, float] = field(default_factory=dict)
    alarmed: bool = False

    @property
    def ready(self) -> bool:
        return bool(self.mu)

    def update(self, payload: dict) -> list[Detection]:
        """Take one estimate payload; returns the detections it completes (at most one: after
        an alarm the vehicle is faulty until :meth:`reset`)."""
        t_ns = int(payload["t_ns"])
        if payload.get("frozen"):
            return []
        ch = {k: v for k, v in channels_of(payload).items() if math.isfinite(v)}
        if self.t0_ns is None:
            self.t0_ns = t_ns
        age = (t_ns - self.t0_ns) * 1e-9
        st = self.settings
        if not self.mu:
            if age < st.warmup_s:
                return []
            if age < st.warmup_s + st.baseline_s:
                for k, v in ch.items():
                    self.baseline.setdefault(k, []).append(v)
                return []
            self._learn()
        if self.alarmed:
            return []
        best: tuple[float, str, float] | None = None
        for k, v in ch.items():
            if k not in self.mu:
                continue
            z = (v - self.mu[k]) / self.sigma[k]
            sp = self.s_pos[k] = max(0.0, self.s_pos.get(k, 0.0) + z - st.k)
            sn = self.s_neg[k] = max(0.0, self.s_neg.get(k, 0.0) - z - st.k)
            s, sign = (sp, 1.0) if sp >= sn else (sn, -1.0)
            if s > st.h and (best is None or s > best[0]):
                best = (s, k, sign * abs(z))
        if best is None:
            return []
        s, k, z = best
        self.alarmed = True
        rel = (ch[k] - self.mu[k]) / abs(self.mu[k]) if self.mu[k] else math.inf
        return [Detection(self.vehicle, _kind(k, z), t_ns, k, float(z), float(rel),
                          float(s / st.h))]

    def _learn(self) -> None:
        st = self.settings
        for k, xs in self.baseline.items():
            if len(xs) < 5:
                continue
            a = np.asarray(xs)
            mu = float(np.median(a))
            mad = 1.4826 * float(np.median(np.abs(a - mu)))
            self.mu[k] = mu
            # the estimates wander slowly (filtered, autocorrelated): the baseline's standard
            # deviation sees that wander where the MAD of near neighbours does not
            self.sigma[k] = max(mad, float(np.std(a)), st.rel_floor * abs(mu), st.abs_floor)
        self.baseline.clear()

    def reset(self) -> None:
        """Forget the baseline and the sums (the vehicle came back, repaired or restarted)."""
        self.t0_ns = None
        self.baseline.clear()
        self.mu.clear()
        self.sigma.clear()
        self.s_pos.clear()
        self.s_neg.clear()
        self.alarmed = False
