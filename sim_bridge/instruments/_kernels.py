"""The instruments' sampling of one lockstep control period, compiled: the very arithmetic of
:meth:`sim_bridge.instruments.models.Instruments.sample` called at every plant step where a
sample falls due (:meth:`Instruments.sample_trace`; tests/test_instruments.py holds the two
equal bit for bit on whole runs).

Two calls, because the noise is drawn in between by numpy: :func:`due_steps` walks the
instruments' schedules (``_Periodic``) over the period and says which instruments fire at
which step; the caller then draws every standard normal the period needs in one
``standard_normal(N)`` — the one stream hands out the same numbers in one call as in the
per-sample calls it replaces, as numpy's ``normal(0, s)`` is ``0 + s·z`` of that stream — and
:func:`make_samples` makes the samples from them (a numpy ``Generator`` passed into a compiled
function costs ~17 µs a call here, more than the work).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from uvd.model.lie import R_euler, euler_R

#: rows of the schedule array: the instruments, in the order ``sample`` makes them
INS, DVL, DEPTH = 0, 1, 2
#: columns of the schedule array: ``_Periodic``'s k, next due time and offset (ns)
K, NEXT_NS, OFFSET_NS = 0, 1, 2

#: entries of the parameter array of :func:`make_samples`
(P_NOISE, P_INS_ONE_DRAW, P_HEADING_STD, P_RP_STD, P_RATE_STD, P_DVL_STD, P_DVL_ALTITUDE,
 P_DEPTH_STD, P_DVL_RESOLUTION) = range(9)
N_PARAMS = 9

#: entries of the dead-reckoning state array (floats; the time of the last DVL is an int)
(S_NORTH, S_EAST, S_SCALE, S_HAVE_INS, S_INS_ROLL, S_INS_PITCH, S_INS_HEADING, S_HAVE_DVL,
 S_DVL_U, S_DVL_V, S_DVL_W) = range(11)
N_STATE = 11

_TWO_PI = 2.0 * math.pi


@numba.njit(cache=True)
def due_steps(t0_ns, step_ns, n, sched, rates_hz, draws, steps, masks):
    """The steps 1…n of the period starting at ``t0_ns`` (step i at t0 + i·step) at which
    samples fall due, in order, into ``steps``; the instruments firing at each as a bit mask
    (1 INS, 2 DVL, 4 depth) into ``masks``; ``sched`` (3 × 3: k, next due, offset) advanced
    as ``_Periodic.fire`` does. Returns how many steps, and how many standard normals their
    samples draw (``draws``: each instrument's a sample)."""
    m = 0
    n_normals = 0
    i = 0
    while True:
        next_due = min(sched[INS, NEXT_NS], sched[DVL, NEXT_NS], sched[DEPTH, NEXT_NS])
        i = max(i + 1, -((t0_ns - next_due) // step_ns))
        if i > n:
            break
        t = t0_ns + i * step_ns
        mask = 0
        for j in range(3):
            if t >= sched[j, NEXT_NS]:
                rate = rates_hz[j]
                offset = sched[j, OFFSET_NS]
                k = max(sched[j, K] + 1, math.floor((t - offset) * rate / 1e9) + 1)
                sched[j, K] = k
                sched[j, NEXT_NS] = offset + np.int64(np.rint(k * 1e9 / rate))
                mask |= 1 << j
                n_normals += draws[j]
        steps[m] = i
        masks[m] = mask
        m += 1
    return m, n_normals


@numba.njit(cache=True)
def _remainder(x, y):
    """IEEE 754 remainder of finite x by y > 0 (``math.remainder``): exact, so equal to any
    exact implementation's; this is the usual fmod-based one (np.fmod: C fmod, exact)."""
    absx = abs(x)
    m = np.fmod(absx, y)
    c = y - m
    if m < c:
        r = m
    elif m > c:
        r = -c
    else:  # halfway: the even multiple
        r = m - 2.0 * np.fmod(0.5 * (absx - m), y)
    return math.copysign(1.0, x) * r


@numba.njit(cache=True)
def _wrap_angle(a):
    """:func:`uvd.geometry.wrap_angle`."""
    if not math.isfinite(a):
        return math.nan
    r = _remainder(a, _TWO_PI)
    return math.pi if r == -math.pi else r


@numba.njit(cache=True)
def _noise(p, std, z, c):
    """A draw of ``Instruments._n``: 0 + std·z[c] (one standard normal used), or 0 without a
    draw when the noise is off or std is 0. Returns (value, next c)."""
    if p[P_NOISE] == 0.0 or std == 0.0:
        return 0.0, c
    return 0.0 + std * z[c], c + 1


@numba.njit(cache=True)
def make_samples(t0_ns, step_ns, steps, masks, m, H_trace, v_trace, z, p, state, times,
                 ins_out, dvl_out, depth_out):
    """The samples of the ``m`` due steps of :func:`due_steps` from the plant's trace (the
    state after step i in ``H_trace[i - 1]``, ``v_trace[i - 1]``), drawing the standard
    normals ``z`` in order; the newest sample of each instrument into ``ins_out`` (roll,
    pitch, heading, ω), ``dvl_out`` (velocity, altitude), ``depth_out`` (depth) with its time
    in ``times[:3]`` (left as they were for an instrument that made none). ``state`` and
    ``times[3]`` (the time of the last DVL sample, read only when ``state`` has one) carry
    DVLNAV's dead reckoning, which integrates every DVL sample of the period, as
    ``Instruments._dead_reckon``. Returns how many normals were used."""
    c = 0
    for e in range(m):
        i = steps[e]
        mask = masks[e]
        t = t0_ns + i * step_ns
        H = H_trace[i - 1]
        v = v_trace[i - 1]
        if mask & 1:
            roll, pitch, heading = R_euler(H[:3, :3])
            if p[P_INS_ONE_DRAW] != 0.0:  # Instruments._ins_noise: six scaled normals
                n_heading = z[c] * p[P_HEADING_STD] + 0.0
                n_roll = z[c + 1] * p[P_RP_STD] + 0.0
                n_pitch = z[c + 2] * p[P_RP_STD] + 0.0
                for j in range(3):
                    ins_out[3 + j] = v[3 + j] + (z[c + 3 + j] * p[P_RATE_STD] + 0.0)
                c += 6
            else:
                n_heading, c = _noise(p, p[P_HEADING_STD], z, c)
                n_roll, c = _noise(p, p[P_RP_STD], z, c)
                n_pitch, c = _noise(p, p[P_RP_STD], z, c)
                for j in range(3):
                    w, c = _noise(p, p[P_RATE_STD], z, c)
                    ins_out[3 + j] = v[3 + j] + w
            ins_out[0] = roll + n_roll
            ins_out[1] = pitch + n_pitch
            ins_out[2] = _wrap_angle(heading + n_heading)
            times[INS] = t
            state[S_HAVE_INS] = 1.0
            state[S_INS_ROLL] = ins_out[0]
            state[S_INS_PITCH] = ins_out[1]
            state[S_INS_HEADING] = ins_out[2]
        if mask & 2:
            res = p[P_DVL_RESOLUTION]
            vel = np.empty(3)
            for j in range(3):
                w, c = _noise(p, p[P_DVL_STD], z, c)
                vel[j] = v[j] + w
                if res > 0.0:
                    vel[j] = np.rint(vel[j] / res) * res
                dvl_out[j] = vel[j]
            dvl_out[3] = p[P_DVL_ALTITUDE] - H[2, 3]
            times[DVL] = t
            # DVLNAV: the previous DVL velocity, rotated by the newest INS attitude
            if state[S_HAVE_DVL] != 0.0:
                dt = (t - times[3]) * 1e-9
                if state[S_HAVE_INS] != 0.0:
                    R = euler_R(state[S_INS_ROLL], state[S_INS_PITCH], state[S_INS_HEADING])
                else:
                    R = H[:3, :3].copy()
                vw = R @ state[S_DVL_U:S_DVL_W + 1].copy()
                state[S_NORTH] += state[S_SCALE] * vw[0] * dt
                state[S_EAST] += state[S_SCALE] * vw[1] * dt
            state[S_HAVE_DVL] = 1.0
            for j in range(3):
                state[S_DVL_U + j] = vel[j]
            times[3] = t
        if mask & 4:
            n_depth, c = _noise(p, p[P_DEPTH_STD], z, c)
            depth_out[0] = H[2, 3] + n_depth
            times[DEPTH] = t
    return c
