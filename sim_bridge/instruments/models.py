"""Instrument models of the simulated vehicle (thesis App. A.1, Table A.1) — pure, no I/O.

Each model turns the plant's true state into the samples of :mod:`drivers.samples` at its own
rate, with noise from a seeded ``numpy.random.Generator`` passed in (the core is deterministic;
randomness lives only here). Defaults are Table A.1:

============  =======================  =======  ==============================================
state         source                   rate     noise (std dev)
============  =======================  =======  ==============================================
heading       PHINS III                10 Hz    0.13°
pitch, roll   PHINS III                10 Hz    0.01°
angular vel.  PHINS III                10 Hz    0.01°/s
body velocity 1200 kHz RDI DVL         6 Hz     0.003 m/s, zero bias
depth         Digiquartz 8CDP010-1     7 Hz     see ``depth_std_m``
x, y          DVLNAV dead reckoning    10 Hz    drift ≤ 0.5 % of distance travelled
============  =======================  =======  ==============================================

Table A.1 gives the Digiquartz only as a resolution (2 ppm of its 10 m range = 20 µm; the
extracted text's ">0.75 …" has lost its unit). We use 0.75 mm standard deviation, which also
covers the tank's surface disturbance; set ``depth_std_m`` to change it.

**Noise streams.** By default every draw comes from the one generator passed in, in the order
the samples fall due (the thesis experiments' streams, docs/RESULTS.md). With ``frame_seed``
the noise of each frame is keyed instead: frame f of an instrument draws from its own
generator seeded ``(frame_seed, instrument, 0, f)``, f counted from the *epoch* (t = 0, or
:meth:`Instruments.set_epoch`, which also starts the instruments' schedules again there). Two
runs with the same ``frame_seed`` then carry the same noise on their f-th frame, at the same
time after the epoch, whatever else draws and whichever frames a late caller skipped — so
the demo's hardware-in-the-loop run (sim-bridge, epoch = the start of the plant step that
carries the first thrust command) and its lockstep simulation (epoch = the first cycle) see
one realisation of noise and sample times, and their comparison measures the daemon's timing
rather than the luck of two draws. Frames before the epoch (the vehicle held while the daemon
boots; ``set_epoch(None)``) draw from ``(frame_seed, instrument, 1, k)``, k counted from the
start.

XY: the thesis's DVLNAV dead-reckons DVL velocity; here the simulated DVLNAV integrates the
*noisy* DVL velocity rotated by the *noisy* INS attitude, plus a scale error drawn once per run
(uniform within ±``xy_scale_error`` = 0.5 %), so its drift matches Table A.1. The daemon's own
navigation (``uvd.estimation.navigation``) does its own dead reckoning from the raw DVL/INS
samples; this model is what a lockstep run uses when it wants DVLNAV's XY.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivers.samples import DepthSample, DvlSample, InsSample
from sim_bridge.instruments import _kernels as _kn
from uvd.geometry import R_to_euler, euler_to_R, wrap_angle

_DEG = math.pi / 180.0


@dataclass(frozen=True)
class InstrumentConfig:
    """Rates (Hz) and noise (SI units) of the simulated instruments; defaults: Table A.1."""

    noise: bool = True
    ins_rate_hz: float = 10.0
    heading_std_rad: float = 0.13 * _DEG
    roll_pitch_std_rad: float = 0.01 * _DEG
    rate_std_rad_s: float = 0.01 * _DEG
    dvl_rate_hz: float = 6.0
    dvl_std_m_s: float = 0.003
    dvl_altitude_m: float = 2.0  # the vehicle's height above the tank floor at depth 0
    depth_rate_hz: float = 7.0
    depth_std_m: float = 0.00075
    xy_scale_error: float = 0.005
    #: resolution of the DVL's velocity output (0: none): PD0 carries 1 mm/s, to which
    #: sim-bridge's wire rounds; the demo's lockstep run models it (lockstep_config)
    dvl_resolution_m_s: float = 0.0
    #: the INS samples at k/ins_rate_hz + ins_offset_s: its phase against a control loop
    #: ticking at k/rate (0: on the tick, as lockstep runs; a real INS has its own clock)
    ins_offset_s: float = 0.0

    def __post_init__(self) -> None:
        for name in ("ins_rate_hz", "dvl_rate_hz", "depth_rate_hz"):
            if not getattr(self, name) > 0:
                raise ValueError(f"instrument {name} must be > 0, got {getattr(self, name)}")
        if not 0.0 <= self.ins_offset_s < 1.0 / self.ins_rate_hz:
            raise ValueError(f"instrument ins_offset_s must be in [0, 1/ins_rate_hz), got "
                             f"{self.ins_offset_s}")


def instrument_config(section) -> InstrumentConfig:
    """The :class:`InstrumentConfig` of a configuration's ``[simulation.instruments]``
    (``uvd.runtime.config.SimInstrumentsSection``: the same fields)."""
    return InstrumentConfig(**vars(section))


class _Periodic:
    """Fires at t = k/rate on a simulated clock: the k-th due time is computed from k, so no
    rounding error accumulates (6 Hz gives exactly 360 samples a minute)."""

    def __init__(self, rate_hz: float, offset_ns: int = 0) -> None:
        self.rate_hz = rate_hz
        self.offset_ns = offset_ns
        self.k = 0
        self.next_ns = offset_ns

    def fire(self, t_ns: int) -> None:
        """A due time at or before ``t_ns`` (≥ :attr:`next_ns`) fired: on to the next one,
        skipping the due times already passed (a coarse caller never gets a burst)."""
        self.k = max(self.k + 1, math.floor((t_ns - self.offset_ns) * self.rate_hz / 1e9) + 1)
        self.next_ns = self.offset_ns + round(self.k * 1e9 / self.rate_hz)


#: key of each instrument's noise in the frame-keyed streams (module docstring)
_NOISE_KEY = {"ins": 0, "dvl": 1, "depth": 2, "dvlnav": 3}


class Instruments:
    """INS, DVL, depth and DVLNAV models sampling a plant's true state.

    Call :meth:`sample` after every plant step with the simulated time and true (H, v); it
    returns the samples that fell due (possibly none).

    Parameters
    ----------
    config : InstrumentConfig
    rng : numpy.random.Generator
        The one noise stream (and whatever else of the caller's draws from it).
    frame_seed : int, optional
        Key each frame's noise by (instrument, frame index since the epoch) instead
        (module docstring, "Noise streams"); the epoch is t = 0 until :meth:`set_epoch`.
    """

    def __init__(self, config: InstrumentConfig, rng: np.random.Generator, *,
                 frame_seed: int | None = None) -> None:
        self.config = config
        self.rng = rng
        self.frame_seed = frame_seed
        self._ins = _Periodic(config.ins_rate_hz, round(config.ins_offset_s * 1e9))
        self._dvl = _Periodic(config.dvl_rate_hz)
        self._depth = _Periodic(config.depth_rate_hz)
        self._before_epoch = False  # the construction is the epoch (t = 0)
        self._draw = rng  # the generator of the frame being made
        self.dr_north = 0.0
        self.dr_east = 0.0
        if frame_seed is not None:
            self._draw = np.random.default_rng((frame_seed, _NOISE_KEY["dvlnav"]))
        self._dr_scale = 1.0 + (self._draw.uniform(-1, 1) * config.xy_scale_error
                                if config.noise else 0)
        self._last_dvl: DvlSample | None = None
        self._last_dr_ns: int | None = None
        self._last_ins: InsSample | None = None
        #: the INS frame's six standard deviations (heading, roll, pitch, ω) when all six are
        #: drawn in one call (:meth:`_ins_noise`); None: one draw per nonzero std (:meth:`_n`)
        stds = (config.heading_std_rad, config.roll_pitch_std_rad, config.roll_pitch_std_rad,
                config.rate_std_rad_s, config.rate_std_rad_s, config.rate_std_rad_s)
        self._ins_stds = np.array(stds) if config.noise and all(stds) else None
        self._trace_buffers: _TraceBuffers | None = None

    def set_epoch(self, t_ns: int | None) -> None:
        """Start every instrument's schedule again at ``t_ns``: frame f of each falls due at
        t_ns + f/rate, as in a lockstep run from t = 0, and with frame-keyed noise draws from
        the key of f. The epoch is already past when sim-bridge sets it (one plant step): the
        DVL's and depth's frame 0 are made at the next call, late — the DVL's velocity is
        integrated into the position, and lockstep's first cycles dead-reckon with frame 0 —
        while the INS's frame 0 is the one made at or before the epoch (a second one would
        run one more sensor-synchronous cycle). With None the schedules go on and the noise
        draws from the before-the-epoch keys until the next call (the vehicle held)."""
        if t_ns is None:
            self._before_epoch = True
            return
        c = self.config
        for name, rate, offset, first in (
                ("_ins", c.ins_rate_hz, round(c.ins_offset_s * 1e9), 1),
                ("_dvl", c.dvl_rate_hz, 0, 0), ("_depth", c.depth_rate_hz, 0, 0)):
            p = _Periodic(rate, t_ns + offset)
            p.k, p.next_ns = first, p.offset_ns + round(first * 1e9 / rate)
            setattr(self, name, p)
        self._before_epoch = False

    @property
    def next_due_ns(self) -> int:
        """The earliest time a sample falls due: :meth:`sample` before it returns nothing
        and changes nothing."""
        return min(self._ins.next_ns, self._dvl.next_ns, self._depth.next_ns)

    def _frame(self, name: str, periodic: _Periodic) -> None:
        """With ``frame_seed``, point the noise at the frame that just fell due (its own
        generator; without, the one stream draws on)."""
        k = periodic.k - 1  # the index of the due time that fired (_Periodic.fire)
        self._draw = np.random.default_rng(
            (self.frame_seed, _NOISE_KEY[name], int(self._before_epoch), k))

    def _n(self, std: float, size: int | None = None):
        if not self.config.noise or std == 0.0:
            return 0.0 if size is None else np.zeros(size)
        return self._draw.normal(0.0, std, size)

    def _ins_noise(self) -> tuple[float, float, float, np.ndarray]:
        """The noise of an INS frame: (heading, roll, pitch, ω (3,)), drawn in that order.

        With every std nonzero the six come from one ``standard_normal(6)``, scaled: numpy's
        ``normal(0, s)`` is ``0 + s·z`` of the very same standard-normal stream, so this is
        bit for bit the six :meth:`_n` draws (the ``+ 0.0`` turns a −0.0 into 0.0 as that
        sum does; tests/test_instruments.py compares the two) at a quarter of the calls."""
        stds = self._ins_stds
        if stds is None:
            c = self.config
            return (self._n(c.heading_std_rad), self._n(c.roll_pitch_std_rad),
                    self._n(c.roll_pitch_std_rad), self._n(c.rate_std_rad_s, 3))
        z = self._draw.standard_normal(6)
        z *= stds
        z += 0.0
        h, r, p = z[:3].tolist()
        return h, r, p, z[3:]

    def sample(self, t_ns: int, H: np.ndarray, v: np.ndarray
               ) -> tuple[InsSample | None, DvlSample | None, DepthSample | None]:
        """Samples due at t_ns from the true pose H (4×4) and body velocity v = [ν; ω]."""
        ins_p, dvl_p, depth_p = self._ins, self._dvl, self._depth
        if t_ns < ins_p.next_ns and t_ns < dvl_p.next_ns and t_ns < depth_p.next_ns:
            return None, None, None
        c = self.config
        keyed = self.frame_seed is not None
        ins = dvl = depth = None
        if t_ns >= ins_p.next_ns:
            ins_p.fire(t_ns)
            if keyed:
                self._frame("ins", ins_p)
            roll, pitch, heading = R_to_euler(H[:3, :3])
            n_heading, n_roll, n_pitch, n_omega = self._ins_noise()
            ins = InsSample(t_ns, roll + n_roll, pitch + n_pitch,
                            wrap_angle(heading + n_heading), v[3:] + n_omega)
            self._last_ins = ins
        if t_ns >= dvl_p.next_ns:
            dvl_p.fire(t_ns)
            if keyed:
                self._frame("dvl", dvl_p)
            altitude = c.dvl_altitude_m - float(H[2, 3])
            vel = v[:3] + self._n(c.dvl_std_m_s, 3)
            if c.dvl_resolution_m_s > 0.0:
                vel = np.round(vel / c.dvl_resolution_m_s) * c.dvl_resolution_m_s
            dvl = DvlSample(t_ns, vel, True, altitude)
            self._dead_reckon(t_ns, H, dvl)
        if t_ns >= depth_p.next_ns:
            depth_p.fire(t_ns)
            if keyed:
                self._frame("depth", depth_p)
            depth = DepthSample(t_ns, float(H[2, 3]) + self._n(c.depth_std_m))
        return ins, dvl, depth

    def sample_steps(self, t0_ns: int, step_ns: int, H_trace: np.ndarray,
                     v_trace: np.ndarray, at=None) -> list:
        """:meth:`sample` at every step of a plant's period where a sample falls due
        (:attr:`next_due_ns`: before it :meth:`sample` returns nothing and changes nothing),
        in time order: the state after step i (t0 + i·step, i = 1…n) is ``H_trace[i - 1]``,
        ``v_trace[i - 1]``; ``at(t_ns)`` is called before each. Returns the newest sample of
        each instrument ([ins, dvl, depth], None where none came)."""
        n = H_trace.shape[0]
        newest = [None, None, None]
        i = 0  # the step whose state was sampled last (0: none)
        while True:
            # the first step after i at or after the next due time
            i = max(i + 1, -((t0_ns - self.next_due_ns) // step_ns))
            if i > n:
                return newest
            t_ns = t0_ns + i * step_ns
            if at is not None:
                at(t_ns)
            for j, s in enumerate(self.sample(t_ns, H_trace[i - 1], v_trace[i - 1])):
                if s is not None:
                    newest[j] = s

    @property
    def can_sample_trace(self) -> bool:
        """:meth:`sample_trace` makes what :meth:`sample` would: the noise is the one stream."""
        return self.frame_seed is None

    def sample_trace(self, t0_ns: int, step_ns: int, H_trace: np.ndarray,
                     v_trace: np.ndarray) -> list:
        """:meth:`sample_steps` compiled (:mod:`sim_bridge.instruments._kernels`), bit for bit
        (tests/test_instruments.py): every sample of the period draws its noise and enters the
        dead reckoning, the newest of each instrument is returned. Only when
        :attr:`can_sample_trace`."""
        n = H_trace.shape[0]
        b = self._trace_buffers
        if b is None or b.steps.shape[0] < n:
            b = self._trace_buffers = _TraceBuffers(self, n)
        ins_p, dvl_p, depth_p = self._ins, self._dvl, self._depth
        sched = b.sched
        sched[:] = ((ins_p.k, ins_p.next_ns, ins_p.offset_ns),
                    (dvl_p.k, dvl_p.next_ns, dvl_p.offset_ns),
                    (depth_p.k, depth_p.next_ns, depth_p.offset_ns))
        m, n_normals = _kn.due_steps(t0_ns, step_ns, n, sched, b.rates, b.draws, b.steps,
                                     b.masks)
        if m == 0:
            return [None, None, None]
        z = self.rng.standard_normal(n_normals) if n_normals else b.no_normals
        ins, dvl, times = self._last_ins, self._last_dvl, b.times
        # the dead reckoning's state (_kernels.S_*): the newest INS attitude, the last DVL
        # velocity and its time
        b.state[:] = (self.dr_north, self.dr_east, self._dr_scale,
                      *((0.0, 0.0, 0.0, 0.0) if ins is None else
                        (1.0, ins.roll, ins.pitch, ins.heading)),
                      *((0.0, 0.0, 0.0, 0.0) if dvl is None or self._last_dr_ns is None else
                        (1.0, *dvl.velocity_body.tolist())))
        times[:] = (-1, -1, -1, -1 if self._last_dr_ns is None else self._last_dr_ns)
        _kn.make_samples(t0_ns, step_ns, b.steps, b.masks, m, H_trace, v_trace, z, b.params,
                         b.state, times, b.ins_out, b.dvl_out, b.depth_out)
        (ins_p.k, ins_p.next_ns, _), (dvl_p.k, dvl_p.next_ns, _), \
            (depth_p.k, depth_p.next_ns, _) = sched.tolist()
        self.dr_north, self.dr_east = b.state[:2].tolist()
        t_ins, t_dvl, t_depth, t_dr = times.tolist()
        newest = [None, None, None]
        if t_ins >= 0:
            roll, pitch, heading = b.ins_out[:3].tolist()
            newest[0] = self._last_ins = InsSample(t_ins, roll, pitch, heading,
                                                   b.ins_out[3:].copy())
        if t_dvl >= 0:
            out = b.dvl_out
            newest[1] = self._last_dvl = DvlSample(t_dvl, out[:3].copy(), True, float(out[3]))
            self._last_dr_ns = t_dr
        if t_depth >= 0:
            newest[2] = DepthSample(t_depth, float(b.depth_out[0]))
        return newest

    def _dead_reckon(self, t_ns: int, H: np.ndarray, dvl: DvlSample) -> None:
        """DVLNAV: integrate the previous DVL velocity, rotated by the measured attitude."""
        if self._last_dvl is not None and self._last_dr_ns is not None:
            dt = (t_ns - self._last_dr_ns) * 1e-9
            if self._last_ins is not None:
                R = euler_to_R(self._last_ins.roll, self._last_ins.pitch, self._last_ins.heading)
            else:
                R = H[:3, :3]
            vw_n, vw_e = (R @ self._last_dvl.velocity_body)[:2].tolist()  # Python floats, as
            self.dr_north += self._dr_scale * vw_n * dt                  # the compiled walk's
            self.dr_east += self._dr_scale * vw_e * dt
        self._last_dvl = dvl
        self._last_dr_ns = t_ns


class _TraceBuffers:
    """The arrays :meth:`Instruments.sample_trace` hands its kernels, made once."""

    def __init__(self, inst: Instruments, n: int) -> None:
        c = inst.config
        self.sched = np.zeros((3, 3), dtype=np.int64)
        self.rates = np.array([c.ins_rate_hz, c.dvl_rate_hz, c.depth_rate_hz], dtype=float)
        one_draw = inst._ins_stds is not None
        if not c.noise:
            ins_draws = 0
        elif one_draw:
            ins_draws = 6
        else:
            ins_draws = ((c.heading_std_rad != 0.0) + 2 * (c.roll_pitch_std_rad != 0.0)
                         + 3 * (c.rate_std_rad_s != 0.0))
        self.draws = np.array([ins_draws, 3 * (c.noise and c.dvl_std_m_s != 0.0),
                               c.noise and c.depth_std_m != 0.0], dtype=np.int64)
        self.steps = np.zeros(n, dtype=np.int64)
        self.masks = np.zeros(n, dtype=np.int64)
        p = np.zeros(_kn.N_PARAMS)
        p[_kn.P_NOISE] = float(c.noise)
        p[_kn.P_INS_ONE_DRAW] = float(one_draw)
        p[_kn.P_HEADING_STD], p[_kn.P_RP_STD], p[_kn.P_RATE_STD] = \
            c.heading_std_rad, c.roll_pitch_std_rad, c.rate_std_rad_s
        p[_kn.P_DVL_STD], p[_kn.P_DVL_ALTITUDE] = c.dvl_std_m_s, c.dvl_altitude_m
        p[_kn.P_DEPTH_STD], p[_kn.P_DVL_RESOLUTION] = c.depth_std_m, c.dvl_resolution_m_s
        self.params = p
        self.state = np.zeros(_kn.N_STATE)
        self.times = np.zeros(4, dtype=np.int64)
        self.ins_out = np.zeros(6)
        self.dvl_out = np.zeros(4)
        self.depth_out = np.zeros(1)
        self.no_normals = np.zeros(0)
