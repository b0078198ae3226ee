"""Change detection for one vehicle (thesis §6.2): CUSUM on its parameter estimates, and the
GLR of the commanded vs realised wrench (:mod:`uvd.fdc.residual`) to say which fault it is.
Pure: numbers in, detections out.

Why CUSUM. A fault changes the vehicle's parameters once and for good (a net caught on it, a
flooded housing, a lost float), so the estimates' mean steps and stays; Page's cumulative sum
is the optimal detector of such a step in the sense of Lorden (the shortest worst-case delay
for a given mean time between false alarms). For a step of δ in Gaussian noise of standard
deviation σ the sum of log-likelihood ratios is

    S⁺ = max(0, S⁺ + (δ/σ²)(d − δ/2)),   S⁻ = max(0, S⁻ + (δ/σ²)(−d − δ/2)),

d = x − μ the deviation from the baseline's median μ (then beyond both μ and a reference that
follows AID's slow drift: "The reference" and "The interval" below), and an alarm S > h comes
at most once in about eʰ fault-free samples (Lorden; h = 15: one in 3·10⁶ estimates, a year
of one every 10 s).

δ is the size of the fault to find, in the parameter's own units, not a multiple of the
baseline's σ: a mass up 10 % (``mass_change``), a drag up 50 % (``drag_change``), a net
buoyancy change of 20 N (``g_change_n``), the buoyancy torque b judged as one vector on the
scale of ‖b‖ (``b_change``·‖b‖: b₁, b₂ of a centre-of-gravity offset are tiny beside b₃).
The allowance δ/2 is what makes the detector sound against what the baseline cannot see:
AID's estimates are filtered (lag-1 autocorrelation 0.99 for the masses and drags) and wander
slowly over hours further than the spread of a 20-minute baseline (measured over six 4 h
fault-free runs of `uvd experiment fdc`'s vehicle: masses up to 2.9 %, drags 6 %, g 6 N) — a
σ-scaled allowance (k = 1σ of the baseline) alarmed on that wander once in each of the six,
40–50 minutes in; a wander below δ/2 never accumulates, whatever its duration (there the
largest deviation was 0.61 of δ/2). What it costs: a change of less than δ/2 is not found.

The reference. A drift that keeps going reaches δ/2 in the end, however slow, and AID's
does: on RefTraj2 (open-loop roll and pitch torques) with instrument noise at twice Table A.1
the JHU ROV's m̂₃ rose 17 % and m̂₄ 15 % in 4 h, steadily (4.8 and 3.7 % an hour; at 1× 5.3
and 5.5 %, at 0.63× 2.6 and 4.3 %), and a CUSUM against the first baseline alarmed in every
fdc-false-alarms run of that kind with noise ≥ 0.99× (12 of 12, `mass4`, 64–192 min in). So
the deviations are taken from a reference that follows such a drift but not a fault: the
median of the ``baseline_s`` (20 min) of estimates that ended ``reference_lag_s`` (20 min)
ago — the baseline itself until that window has moved past it. A fault steps the estimates
within minutes (AID's delays: 30–190 s for a mass, ~10 min for b₃ after a buoyancy change),
all of it inside the 20 minutes before the window catches up, while the drift seen over the
30 minutes from the window's middle to now is at most 2.4 %, half of δ/2 for a mass.
Measured on those recordings (CUSUM replayed on AID's estimates every 10 s): the fault-free
4 h runs at noise 0.63×, 0.99× and 1.99× on RefTraj2 no longer alarm (the largest sum stays
0 with a lag of 20 min; 0.38 h with 30 min, 1.95 h with 40 min: this is why 20); a mass
+5 % and thruster η 0.8 are found as before (1.3–3.2 min after onset); what it costs: a
change at the edge of δ/2 that the old baseline's drift used to push over is missed (a
buoyancy +5 N, a mass +5 % on RefTraj2 at noise 2×), and a slow leak that changes a
parameter by less than δ/2 in half an hour is never found. σ and δ stay the baseline's.

The interval. A drift that comes back is not a fault either. On RefTraj1 at noise ≥ 1.76× the
JHU ROV's b̂₃ rises 2–3 % within the first 105 minutes and returns (RefTraj1 repeats every
2π/0.001 s = 104.7 min, its frequencies' common divisor; in the later periods b̂₃ stays within
1.1 % in five 4 h recordings at noise 0.5–2×); the reference follows the rise, and the return —
2.5 % below the reference, on the baseline — alarmed in 5 of the 7 fdc-false-alarms runs of
that kind (0c41972's code, 104–109 min in, named by the residual as thruster 2 or 4, a drag
decrease or a flooding; one of them replayed on its recorded estimates: b̂₃ −2.6 % at 106.8
min, confidence 1.04). So d is the deviation beyond *both* the baseline's μ and the reference:
the signed distance of x from the interval between them, 0 inside (:func:`deviation`); while
the reference is the baseline, or stands on it, it is x − μ as before. A fault steps beyond
both (a step from a steady level: the two agree; on top of a drift, the nearer one is the
reference, as above). What it costs: a fault against the direction of a drift or excursion
counts only what it carries the estimate beyond the baseline (a mass −5 % after a +3 %
excursion: −2 %, found once the excursion has gone). Measured: those 7 runs again, 0 alarms; on
the recordings, the two b̂₃ alarms of the fault-free 4 h runs (2× and 1.85×) are gone, and of
the 22 faults injected at minute 57 the same 18 are found, at the same times but one (a mass
+5 % at 2×: 59.0 → 59.2 min). b's δ (5 % of ‖b‖) is what finds a weak thruster (η 0.8 moves
b̂₃ +10 %), so it stays.

σ. The estimates are autocorrelated, so n of them carry the information of n/τ independent
ones, τ = 1 + 2 Σ ρₗ the integrated autocorrelation time (Sokal's window: the sum stops at the
first lag L ≥ 5τ); the sums use σ² = τ·s², s² the baseline's variance — the long-run variance
of the estimate, with which a sum of n deviations has its true spread. Baseline: median μ and
that σ over the first ``baseline_s`` after ``warmup_s``. σ is never below the quantity's
resolution in its own units (``*_resolution``: 1 g of mass, 1 mN of g, 1 mN·m of b, 10⁻³ of a
drag's unit): an estimate constant over the baseline (b₁ of a vehicle without a lateral
centre-of-gravity offset, a parameter the estimator does not excite) has no spread of its own,
and a deviation is then counted in steps of what the vehicle's instruments cannot tell apart —
not in units of floating-point rounding (a floor of 10⁻¹² once reported a b₁ of 20 N·m as
"+2·10¹³ σ"). The floor sets only the σ of a deviation's report and the CUSUM's scale for such
a channel; δ, and with it what is a fault, stays in physical units.

Which fault. The estimates alone cannot tell a weak thruster from a buoyancy change (AID puts
the missing thrust into b and the masses). With the state stream (velocity, attitude and the
per-thruster commands) and the thruster matrix B, the detector freezes the plant model of the
baseline (the medians of θ̂) and tests, on 10 s segments of commanded vs realised wrench, which
explanation — thruster i at efficiency ηᵢ, a buoyancy change, an entanglement, a flooding —
fits (:func:`uvd.fdc.residual.explain`, GLR with an unknown change time over the last
``window`` segments). Its score Λ − p ln n is compared with 2h (Λ is twice a log-likelihood
ratio). A residual whose best explanation scores above it is a detection of that kind
(``thruster``, naming the thruster, with ηᵢ − 1 as its relative change); a CUSUM alarm waits up
to ``confirm_s`` for the residual to name the fault and otherwise keeps the kind of its channel
group: drags up → ``entanglement``; masses up → ``flooding``, down → ``lost-part``; g or b →
``buoyancy``. Without a state stream or B the CUSUM alone decides, as before.

Why the residual names and does not detect: run alone as a sliding GLR it alarmed in each of
six fault-free 4 h runs about 40 minutes in (a thruster 1 or 2 at η 0.81–1.03, scores 39–51):
the model frozen from the first 25 minutes mispredicts the surge where the trajectory goes
beyond what the baseline excited. Behind the CUSUM it decides only once the estimates moved.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, fields

import numpy as np

__all__ = ["CusumSettings", "Detection", "VehicleDetector", "autocorrelation_time",
           "channels_of", "deviation", "thruster_matrix"]


#: the reference's window is taken again when it has moved this far (s of the estimates' clock)
REFERENCE_STEP_S = 10.0

#: state samples kept for the residual's baseline (20 minutes at 100 Hz and some, 200 B each;
#: a faster stream keeps its first ones only)
MAX_BASELINE_STATES = 150_000


#: what each of :class:`CusumSettings`' numbers may be (a test, its text); the rest: _POSITIVE
_POSITIVE = (lambda x: math.isfinite(x) and x > 0, "a finite number > 0")
_SETTING_RULES = {
    "window": (lambda x: isinstance(x, int) and x >= 1, "an integer >= 1"),
    "warmup_s": (lambda x: math.isfinite(x) and x >= 0, "a finite number >= 0"),
    "reference_lag_s": (lambda x: x >= 0, "a number >= 0 or inf"),  # NaN >= 0 is False
}


@dataclass(frozen=True)
class CusumSettings:
    """The detector's settings (module docstring): baseline window, the lag of the
    reference's window behind it, the CUSUM's threshold h and the fault sizes δ it is tuned
    for, the residual's segments, window and wait."""

    warmup_s: float = 300.0
    baseline_s: float = 1200.0
    reference_lag_s: float = 1200.0
    h: float = 15.0
    mass_change: float = 0.10
    drag_change: float = 0.5
    g_change_n: float = 20.0
    b_change: float = 0.05
    segment_s: float = 10.0
    window: int = 12
    confirm_s: float = 30.0
    mass_resolution_kg: float = 1e-3
    drag_resolution: float = 1e-3
    g_resolution_n: float = 1e-3
    b_resolution_nm: float = 1e-3

    def __post_init__(self) -> None:
        """Every setting a finite number > 0, but the warm-up ≥ 0, the reference's lag ≥ 0 or
        infinite (a reference that never follows the drift) and the window an integer ≥ 1: a
        NaN threshold would never detect, a negative window never fill. ValueError names the
        setting."""
        for f in fields(self):
            x = getattr(self, f.name)
            ok, want = _SETTING_RULES.get(f.name, _POSITIVE)
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not ok(x):
                raise ValueError(f"CusumSettings.{f.name} must be {want}, got {x!r}")

    def resolution(self, channel: str) -> float:
        """The smallest σ of ``channel`` in its own units (module docstring, "σ")."""
        return (self.mass_resolution_kg if channel.startswith("mass") else
                self.drag_resolution if channel.startswith("drag") else
                self.g_resolution_n if channel == "g" else self.b_resolution_nm)


@dataclass(frozen=True)
class Detection:
    """One fault: ``kind``, when (the ``t_ns`` of the sample that completed it), which channel
    (a parameter, or the residual's explanation: ``thruster4``, ``buoyancy`` …), its deviation
    in σ, its relative change (for a thruster ηᵢ − 1) and ``confidence`` (the sum or score over
    its threshold, ≥ 1). ``explanation``: the residual's fit when it named the fault (its
    unknowns ``coef`` and the change time ``since_t_ns``), else None."""

    vehicle: str
    kind: str
    t_ns: int
    channel: str
    magnitude: float
    relative_change: float | None
    confidence: float
    explanation: dict | None = None

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


def deviation(x: float, mu: float, ref: float) -> float:
    """How far ``x`` lies beyond both the baseline's ``mu`` and the reference ``ref``: its
    signed distance from the interval between them, 0 inside it (module docstring, "The
    interval"); x − μ while the reference is the baseline."""
    lo, hi = (mu, ref) if mu <= ref else (ref, mu)
    return x - hi if x > hi else x - lo if x < lo else 0.0


def _kind(channel: str, direction: float) -> str:
    if channel.startswith("drag"):
        return "entanglement" if direction > 0 else "drag-decrease"
    if channel.startswith("mass"):
        return "flooding" if direction > 0 else "lost-part"
    return "buoyancy"


def thruster_matrix(B) -> np.ndarray:
    """B (``params``' ``configuration.thruster_matrix``) as a 6 × N array; anything but 6 rows
    of N finite numbers is refused with a ValueError naming it."""
    try:
        B = np.asarray(B, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"thruster matrix: not numbers ({exc})") from exc
    if B.ndim != 2 or B.shape[0] != 6 or B.shape[1] < 1 or not np.isfinite(B).all():
        raise ValueError(f"thruster matrix: 6 × N finite numbers expected, got shape "
                         f"{B.shape}")
    return B


def _theta(x) -> np.ndarray | None:
    """θ_UV of an estimate payload when it is 241 finite numbers, else None (not used)."""
    try:
        th = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        return None
    return th if th.shape == (241,) and np.isfinite(th).all() else None


def autocorrelation_time(x) -> float:
    """τ = 1 + 2 Σₗ ρₗ of a series, the sum stopped at the first lag L ≥ 5τ (Sokal's window)
    or at a quarter of its length; at least 1."""
    x = np.asarray(x, dtype=float) - np.mean(x)
    n, var = x.size, float(x @ x)
    if n < 8 or var <= 0.0:
        return 1.0
    tau = 1.0
    for lag in range(1, n // 4):
        tau += 2.0 * float(x[:-lag] @ x[lag:]) / var
        if lag >= 5.0 * tau:
            break
    return max(1.0, tau)


class VehicleDetector:
    """The detector of one vehicle: feed it every estimate payload with :meth:`update` and,
    when there is one, every state payload with :meth:`update_state` (after
    :meth:`set_thrusters`); each returns the detections it completes (at most one: after it
    the vehicle is faulty until :meth:`reset`)."""

    def __init__(self, vehicle: str, settings: CusumSettings | None = None, B=None) -> None:
        self.vehicle = vehicle
        self.settings = settings or CusumSettings()
        self.B = None
        if B is not None:
            self.set_thrusters(B)
        self.reset()

    def reset(self) -> None:
        """Forget the baseline and the sums (the vehicle came back, repaired or restarted)."""
        self.t0_ns: int | None = None
        self.baseline: dict[str, list[float]] = {}
        self.thetas: list = []
        self.mu: dict[str, float] = {}
        self.history: dict[str, deque] = {}  # channel → (age, value) since the reference's start
        self.ref: dict[str, float] = {}  # the reference deviations are taken from
        self.ref_start = -math.inf  # where its window starts (age, s)
        self.delta: dict[str, float] = {}
        self.sigma: dict[str, float] = {}
        self.s_pos: dict[str, float] = {}
        self.s_neg: dict[str, float] = {}
        self.alarmed = False
        self.pending: tuple[Detection, float] | None = None  # a CUSUM alarm awaiting a kind
        self.states: list[np.ndarray] = []  # state samples until the model is frozen
        self.model = None
        self.integrator = None
        self.bias = self.spread = None
        self.segments: deque = deque(maxlen=self.settings.window)

    def set_thrusters(self, B) -> None:
        """The thruster matrix B (6 × N, u = B f) of the vehicle (its ``params``)."""
        self.B = thruster_matrix(B)

    @property
    def ready(self) -> bool:
        return bool(self.mu)

    @property
    def explains(self) -> bool:
        """The residual is running (the model is frozen and its baseline learned)."""
        return self.spread is not None

    def _age(self, t_ns: int) -> float:
        return (t_ns - self.t0_ns) * 1e-9

    # -- the estimates --

    def update(self, payload: dict) -> list[Detection]:
        """Take one estimate payload (``uvd.zestimate.v1``)."""
        t_ns = int(payload["t_ns"])
        if payload.get("frozen"):
            return []
        ch = {k: v for k, v in channels_of(payload).items() if math.isfinite(v)}
        if self.t0_ns is None:
            self.t0_ns = t_ns
        age = self._age(t_ns)
        st = self.settings
        if not self.mu:
            if age < st.warmup_s:
                return []
            if age < st.warmup_s + st.baseline_s:
                for k, v in ch.items():
                    self.baseline.setdefault(k, []).append(v)
                    self.history.setdefault(k, deque()).append((age, v))
                theta = _theta(payload.get("theta"))
                if theta is not None:
                    self.thetas.append(theta)
                return []
            self._learn()
        if self.alarmed:
            return []
        if self.pending is not None:
            return self._settle(t_ns)
        ref = self._reference(age, ch)
        best: tuple[float, str, float] | None = None
        for k, v in ch.items():
            if k not in self.mu:
                continue
            d, delta, var = deviation(v, self.mu[k], ref[k]), self.delta[k], self.sigma[k] ** 2
            sp = self.s_pos[k] = max(0.0, self.s_pos.get(k, 0.0) + delta / var * (d - delta / 2))
            sn = self.s_neg[k] = max(0.0, self.s_neg.get(k, 0.0) + delta / var * (-d - delta / 2))
            s, sign = (sp, 1.0) if sp >= sn else (sn, -1.0)
            if s > st.h and (best is None or s > best[0]):
                best = (s, k, sign)
        if best is None:
            return []
        s, k, sign = best
        d = deviation(ch[k], self.mu[k], ref[k])
        edge = ch[k] - d  # the nearer of the baseline's μ and the reference (x inside: x)
        rel = float(d / abs(edge)) if edge else None  # from 0
        det = Detection(self.vehicle, _kind(k, sign), t_ns, k, float(d / self.sigma[k]), rel,
                        float(s / st.h))
        if self.model is None:
            self.alarmed = True
            return [det]
        self.pending = (det, t_ns + st.confirm_s * 1e9)
        return []

    def _reference(self, age: float, ch: dict[str, float]) -> dict[str, float]:
        """Each channel's reference at ``age`` (module docstring, "The reference"): the
        baseline's μ until the window [age − lag − baseline_s, age − lag) has moved past the
        baseline, then the median of that window, taken again each time the window has moved
        by ``REFERENCE_STEP_S``; the sample ``ch`` joins the history."""
        st = self.settings
        start = age - st.reference_lag_s - st.baseline_s
        if start > st.warmup_s and start - self.ref_start >= REFERENCE_STEP_S:
            self.ref, self.ref_start = dict(self.mu), start
            end = start + st.baseline_s
            for k, hist in self.history.items():
                while hist and hist[0][0] < start:
                    hist.popleft()
                window = [x for a, x in hist if a < end]
                if window:
                    self.ref[k] = float(np.median(window))
        for k, v in ch.items():
            if k in self.mu:
                self.history[k].append((age, v))
        return self.ref

    def _settle(self, t_ns: int) -> list[Detection]:
        """A pending CUSUM alarm whose wait for the residual is over keeps its own kind."""
        det, deadline = self.pending
        if t_ns < deadline:
            return []
        self.pending, self.alarmed = None, True
        return [det]

    def _learn(self) -> None:
        st = self.settings
        for k, xs in self.baseline.items():
            if len(xs) < 5:
                continue
            a = np.asarray(xs)
            self.mu[k] = float(np.median(a))
            self.sigma[k] = max(float(np.std(a)) * math.sqrt(autocorrelation_time(a)),
                                st.resolution(k))
        self.ref = self.mu
        self.history = {k: h for k, h in self.history.items() if k in self.mu}
        b_norm = math.sqrt(sum(self.mu.get(f"b{i}", 0.0) ** 2 for i in (1, 2, 3)))
        for k, mu in self.mu.items():
            self.delta[k] = (st.mass_change * abs(mu) if k.startswith("mass") else
                             st.drag_change * abs(mu) if k.startswith("drag") else
                             st.g_change_n if k == "g" else st.b_change * b_norm)
        if self.B is not None and len(self.thetas) >= 5:
            from uvd.fdc.residual import FrozenModel, SegmentIntegrator
            self.model = FrozenModel.from_theta(np.median(self.thetas, axis=0), self.B)
            self.integrator = SegmentIntegrator(self.model, st.segment_s)
            end = self.t0_ns + int((st.warmup_s + st.baseline_s) * 1e9)
            rows = [(x[0], x[1:7], x[7:16], x[16:]) for x in self.states]
            segs = [g for g in (self.integrator.add(*x) for x in rows if x[0] * 1e9 < end)
                    if g is not None]
            self._learn_residual(segs)
            for x in rows:
                if x[0] * 1e9 >= end:
                    self.integrator.add(*x)
        self.baseline.clear()
        self.thetas.clear()
        self.states.clear()

    def _learn_residual(self, segs) -> None:
        """The healthy residual's mean rate and spread per DOF, from the baseline's segments."""
        if len(segs) < 10:
            self.model = None
            return
        rates = np.array([g.e / g.duration for g in segs])
        self.bias = np.median(rates, axis=0)
        dev = np.array([g.e - self.bias * g.duration for g in segs])
        self.spread = np.maximum(dev.std(axis=0), 1e-9)

    # -- the state stream --

    def update_state(self, payload: dict) -> list[Detection]:
        """Take one state payload (``uvd.state.v1``: ``t_ns``, ``v``, ``R``, ``thrust``)."""
        if self.B is None or self.t0_ns is None or self.alarmed:
            return []
        from uvd.fdc.residual import state_sample
        t = int(payload["t_ns"]) * 1e-9
        if self.model is None:
            v, R, f = state_sample(payload["v"], payload["R"], payload["thrust"],
                                   self.B.shape[1])
            if not self.mu and self._age(int(payload["t_ns"])) >= self.settings.warmup_s:
                if len(self.states) < MAX_BASELINE_STATES:  # one row: t, v, R, f
                    self.states.append(np.concatenate([[t], v, R.ravel(), f]))
            return []
        # the integrator checks the sample itself (state_sample): a ValueError names it
        seg = self.integrator.add(t, payload["v"], payload["R"], payload["thrust"])
        if seg is not None and self.spread is not None:
            self.segments.append(seg)
            if self.pending:
                return self._explain(int(payload["t_ns"]))
        return self._settle(int(payload["t_ns"])) if self.pending else []

    def _explain(self, t_ns: int) -> list[Detection]:
        from uvd.fdc.residual import explain
        best = explain(list(self.segments), self.model, self.bias, self.spread)[0]
        limit = 2.0 * self.settings.h
        if best.score <= limit:
            return self._settle(t_ns)
        self.pending, self.alarmed = None, True
        coef = best.coef
        if best.kind.startswith("thruster"):
            kind, rel = "thruster", -float(coef[0])
        elif best.kind == "buoyancy":
            mu_g = self.mu.get("g", self.model.g)
            kind, rel = "buoyancy", float(coef[0]) / max(abs(mu_g), 1e-9)
        else:
            kind, rel = best.kind, float(coef[0])
        if kind in ("entanglement", "flooding") and rel < 0:
            kind = "drag-decrease" if kind == "entanglement" else "lost-part"
        return [Detection(self.vehicle, kind, t_ns, best.kind,
                          float(math.sqrt(max(best.glr, 0.0))), rel, float(best.score / limit),
                          {"coef": [float(x) for x in coef],
                           "since_t_ns": int(round(best.since * 1e9))})]
