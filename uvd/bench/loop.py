"""``uvd bench loop``: how precisely the fixed-rate loop keeps its deadlines, vs naive asyncio.

Runs :class:`uvd.runtime.loop.FixedRateLoop` at ``--rate`` for ``--duration`` seconds with the
chosen per-cycle work (``--cycle``), then, in the same process, a naive loop that does the
same work and ``await asyncio.sleep(period)`` between cycles. Lateness is wake-up time minus
the deadline (for the naive loop: minus the time it asked to wake, ``now + period``, which
flatters it — its schedule also drifts by every cycle's compute time; ``achieved_rate_hz``
shows that). Compute is the cycle's own time. Percentiles are exact (from every sample, via
:func:`uvd.bench.percentiles`); the loop's own histogram snapshot is included as
``histogram`` for comparison.

Every overrun of our loop is sorted by its cause (``overrun_attribution``,
:func:`attribute_overruns`): the loop's thread *stalled* (runnable but not running — on a
virtual machine, the hypervisor's steal, measured per cycle by :class:`StallProbe`), was
*preempted* by a thread of this machine, *woke late* from its blocking coarse wait, was
*paused in the spin* (a busy-wait returned long after its deadline), or the cycle's own
*compute* was too long.

Per-cycle work (``--cycle``), registered in :data:`CYCLES`:

* ``none`` — nothing: the timer alone;
* ``pdc`` — the core's full PDC cycle (:func:`uvd.core.step`: navigation from fresh INS, DVL
  and depth samples → RefTraj1 reference → PD (5.11) → allocation) on ``jhu-rov``;
* ``ambc-aid`` — the same cycle with the full 241-parameter AMBC (robust adaptation) as the
  controller and 6-DOF AID as estimator, on ``jhu-rov-coupled``;
* ``fixed-work`` — a control: the same ~80 µs of compiled arithmetic every cycle, so any
  spread in its compute time is the machine's.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import resource
import subprocess
import sys
import time
from collections.abc import Callable

import numpy as np

from uvd.bench import Bench, host_steal_s, percentiles
from uvd.cliargs import (
    cpu_number,
    nonnegative_float,
    nonnegative_int,
    output_folder,
    positive_float,
    positive_int,
)
from uvd.runtime.clock import MonotonicClock
from uvd.runtime.loop import CpuLatencyRequest, FixedRateLoop, LoopSettings, apply_realtime

CycleFactory = Callable[[], Callable[[int, float], None]]


def _cycle_none() -> Callable[[int, float], None]:
    def cycle(t_ns: int, dt: float) -> None:
        return None
    return cycle


def _cycle_pdc() -> Callable[[int, float], None]:
    """The core's PDC cycle on jhu-rov tracking RefTraj1 (built as in ``uvd demo``)."""
    from drivers.samples import DepthSample, DvlSample, InsSample
    from uvd import core
    from uvd.control.allocation import Allocator
    from uvd.control.pdc import PDGains, PDState, pdc_step
    from uvd.control.trajectory import reftraj1
    from uvd.estimation.navigation import NavConfig
    from uvd.geometry import R_to_euler
    from uvd.io.vehicle import load_vehicle

    vehicle = load_vehicle("jhu-rov")
    traj = reftraj1()
    cfg = core.CoreConfig(
        nav=NavConfig(),
        controller=core.ControllerSpec("pdc", pdc_step, PDGains(kp=300.0, kd=100.0), PDState()),
        reference=traj, allocator=Allocator.from_vehicle(vehicle), k_thrust=vehicle.k_thrust)
    ref0 = traj.at(0.0)
    roll, pitch, heading = R_to_euler(ref0.H[:3, :3])
    offset = np.array([0.05, -0.03, 0.02])  # a tracking error, so PD has work to do
    omega = np.array([0.01, -0.02, 0.03])
    nu = ref0.v[:3] + 0.01
    depth0 = float(ref0.H[2, 3] + offset[2])
    st = {"state": core.core_init(cfg, north_m=ref0.H[0, 3] + offset[0],
                                  east_m=ref0.H[1, 3] + offset[1]),
          "n": 0}

    def cycle(t_ns: int, dt: float) -> None:
        k = st["n"]
        st["n"] = k + 1
        wobble = 1e-4 * (k % 7)
        ins = InsSample(t_ns=t_ns, roll=roll + wobble, pitch=pitch, heading=heading,
                        omega_body=omega)
        dvl = DvlSample(t_ns=t_ns, velocity_body=nu, bottom_lock=True)
        depth = DepthSample(t_ns=t_ns, depth_m=depth0 + wobble)
        inputs = core.CoreInputs(t_ns=t_ns, ins=ins, dvl=dvl, depth=depth)
        out, st["state"] = core.step(cfg, inputs, st["state"], dt)
        if out.status != "ok":
            raise RuntimeError(f"PDC cycle status {out.status!r}")

    # compile/warm the numba kernels off the clock
    t0 = time.monotonic_ns()
    for i in range(50):
        cycle(t0 + i * 1_000_000, 1e-3)
    st["state"] = core.core_init(cfg, north_m=ref0.H[0, 3] + offset[0],
                                 east_m=ref0.H[1, 3] + offset[1])
    return cycle


def ambc_aid_config():
    """The core configuration with full AMBC (θ̂ ∈ R²⁴¹, (2.48); robust adaptation as the
    daemon runs it) and 6-DOF AID (Theorem 4.3.1) both on, on ``jhu-rov-coupled`` tracking
    RefTraj1 (also the core replay test's ``ambc-aid`` scenario)."""
    from uvd import core
    from uvd.control.allocation import Allocator
    from uvd.control.ambc import ROBUST_DAEMON_DEFAULT, ambc_init, ambc_params, ambc_step, theta_of
    from uvd.control.trajectory import reftraj1
    from uvd.estimation.aid import aid6_estimator
    from uvd.estimation.navigation import NavConfig
    from uvd.io.vehicle import load_vehicle

    vehicle = load_vehicle("jhu-rov-coupled")
    alloc = Allocator.from_vehicle(vehicle)
    params = ambc_params("full", kp=300.0, kd=100.0, eps=1.0, robust=ROBUST_DAEMON_DEFAULT,
                         allocator=alloc)
    spec = core.ControllerSpec("ambc", ambc_step, params,
                               ambc_init(params, theta_of(vehicle.params, "full")))
    return core.CoreConfig(nav=NavConfig(), controller=spec, reference=reftraj1(),
                           allocator=alloc, k_thrust=vehicle.k_thrust,
                           estimators=(aid6_estimator(),))


def _cycle_ambc_aid() -> Callable[[int, float], None]:
    """The core cycle of :func:`ambc_aid_config` on fresh INS, DVL and depth samples."""
    from drivers.samples import DepthSample, DvlSample, InsSample
    from uvd import core
    from uvd.geometry import R_to_euler

    cfg = ambc_aid_config()
    traj = cfg.reference
    ref0 = traj.at(0.0)
    roll, pitch, heading = R_to_euler(ref0.H[:3, :3])
    offset = np.array([0.05, -0.03, 0.02])
    nu = ref0.v[:3] + 0.01
    depth0 = float(ref0.H[2, 3] + offset[2])
    speeds = np.full(cfg.allocator.n_thrusters, 20.0)

    def fresh():
        return core.core_init(cfg, north_m=ref0.H[0, 3] + offset[0],
                              east_m=ref0.H[1, 3] + offset[1])
    st = {"state": fresh(), "n": 0}

    def cycle(t_ns: int, dt: float) -> None:
        k = st["n"]
        st["n"] = k + 1
        wobble = 1e-4 * (k % 7)
        omega = np.array([0.01 + wobble, -0.02, 0.03])
        ins = InsSample(t_ns=t_ns, roll=roll + wobble, pitch=pitch, heading=heading,
                        omega_body=omega)
        dvl = DvlSample(t_ns=t_ns, velocity_body=nu + wobble, bottom_lock=True)
        depth = DepthSample(t_ns=t_ns, depth_m=depth0 + wobble)
        inputs = core.CoreInputs(t_ns=t_ns, ins=ins, dvl=dvl, depth=depth,
                                 propeller_speed_rad_s=speeds)
        out, st["state"] = core.step(cfg, inputs, st["state"], dt)
        if out.status != "ok":
            raise RuntimeError(f"AMBC+AID cycle status {out.status!r}")

    t0 = time.monotonic_ns()
    for i in range(50):  # compile/load the kernels off the clock
        cycle(t0 + i * 1_000_000, 1e-3)
    st["state"] = fresh()
    return cycle


class StallProbe:
    """The loop's clock, plus a record of how long the loop's thread was *runnable but not
    running* in each cycle — to tell an overrun caused by the host from one of ours.

    From the moment the coarse wait returns (the fine wait begins) to the cycle's end, the
    thread never blocks: it spins, then computes. Over that span the wall clock and the
    thread's CPU time (``CLOCK_THREAD_CPUTIME_ID``) advance together, except while the thread
    does not run. With ``CONFIG_PARAVIRT_TIME_ACCOUNTING`` (KVM guests) the thread's CPU time
    excludes the time the hypervisor ran something else on this virtual CPU (steal), so the
    gap — the *stall* — is steal, or preemption by a higher-priority thread of this machine,
    which the involuntary context switches in the span (``getrusage``) reveal. Both readings
    happen outside the timed compute (at the fine wait's start and in an ``after_cycle``
    hook); ~1 µs each.
    """

    def __init__(self, clock: MonotonicClock, capacity: int) -> None:
        self.clock = clock
        self.coarse, self.fine = clock.coarse, clock.fine
        z = lambda: np.zeros(capacity, dtype=np.int64)  # noqa: E731
        self.wall0, self.cpu0, self.csw0 = z(), z(), z()
        self.wall1, self.cpu1, self.csw1 = z(), z(), z()
        self.flt0, self.flt1 = z(), z()
        self.n = 0
        self._open = False

    # the Clock protocol, delegated
    def monotonic_ns(self) -> int:
        return self.clock.monotonic_ns()

    def sleep(self, seconds: float) -> None:
        self.clock.sleep(seconds)

    async def wait_until_ns(self, deadline_ns: int) -> None:
        await self.clock.wait_until_ns(deadline_ns)

    def sleep_until_ns(self, deadline_ns: int) -> None:
        i = self.n
        if i < self.wall0.shape[0]:
            ru = resource.getrusage(resource.RUSAGE_THREAD)
            self.csw0[i], self.flt0[i] = ru.ru_nivcsw, ru.ru_minflt + ru.ru_majflt
            self.cpu0[i] = time.thread_time_ns()
            self.wall0[i] = time.monotonic_ns()
            self._open = True
        self.clock.sleep_until_ns(deadline_ns)

    def after_cycle(self, t_end_ns: int, ok: bool) -> None:
        if not self._open:
            return
        i = self.n
        self.cpu1[i] = time.thread_time_ns()
        ru = resource.getrusage(resource.RUSAGE_THREAD)
        self.csw1[i], self.flt1[i] = ru.ru_nivcsw, ru.ru_minflt + ru.ru_majflt
        self.wall1[i] = t_end_ns
        self.n = i + 1
        self._open = False

    def reset(self) -> None:
        self.n = 0
        self._open = False

    def close(self) -> None:
        self.clock.close()

    def stalls_ns(self) -> np.ndarray:
        n = self.n
        return (self.wall1[:n] - self.wall0[:n]) - (self.cpu1[:n] - self.cpu0[:n])

    def preempted(self) -> np.ndarray:
        n = self.n
        return self.csw1[:n] > self.csw0[:n]

    def page_faults(self) -> np.ndarray:
        n = self.n
        return self.flt1[:n] - self.flt0[:n]


def attribute_overruns(lateness_ns: np.ndarray, compute_ns: np.ndarray, wake_ns: np.ndarray,
                       stall_ns: np.ndarray, preempted: np.ndarray, period_ns: int,
                       margin_ns: int, page_faults: np.ndarray | None = None) -> dict:
    """Sort each overrunning cycle by what made it end after the next deadline.

    Per cycle (arrays of equal length): the loop's lateness and compute, ``wake_ns`` the
    time the coarse wait returned, relative to the deadline (normally ≈ −margin), the stall
    of :class:`StallProbe` and whether the thread was preempted in the span. A cycle
    overruns by ``over = lateness + compute − period`` > 0. It is

    * ``stalled`` when the thread's stall alone covers ``over`` and no thread of this machine
      preempted it: the virtual CPU was not running (the hypervisor's steal);
    * ``preempted`` when the stall covers it but an involuntary context switch happened;
    * ``woke_late`` when only the stall plus the coarse wait's return after its planned time
      (``wake − (−margin)``, spent blocked: a halted vCPU or a late timer) covers it;
    * ``paused_in_spin`` when it takes the fine wait's overshoot to cover it: a busy-wait
      ends within a clock read of its deadline, so a spin that returns late (``lateness −
      max(wake, 0)``) was paused, though the thread's CPU time ran on (a long VM exit, or
      interrupt work charged to the thread; neither counts as steal);
    * ``compute`` otherwise: the cycle's own work, as executed, took too long. The first ten
      are listed in ``compute_examples_us``, with the thread's page faults in the span when
      ``page_faults`` is given.
    """
    lateness_ns = np.asarray(lateness_ns, dtype=np.int64)
    over = lateness_ns + np.asarray(compute_ns, dtype=np.int64) - period_ns
    stall = np.maximum(np.asarray(stall_ns, dtype=np.int64), 0)
    wake = np.asarray(wake_ns, dtype=np.int64)
    late_wake = np.maximum(wake + margin_ns, 0)
    overshoot = np.maximum(lateness_ns - np.maximum(wake, 0), 0)
    pre = np.asarray(preempted, dtype=bool)
    hit = over > 0
    by_stall = hit & (stall >= over)
    by_wake = hit & ~by_stall & (stall + late_wake >= over)
    # the stall spans spin and compute, the overshoot only the spin: count the larger
    by_spin = hit & ~by_stall & ~by_wake & (late_wake + np.maximum(stall, overshoot) >= over)
    own_mask = hit & ~by_stall & ~by_wake & ~by_spin
    counts = {
        "stalled": int(np.sum(by_stall & ~pre)),
        "preempted": int(np.sum(by_stall & pre)),
        "woke_late": int(np.sum(by_wake)),
        "paused_in_spin": int(np.sum(by_spin)),
        "compute": int(np.sum(own_mask)),
    }
    own = np.flatnonzero(own_mask)[:10]
    return {
        "overruns": int(hit.sum()),
        **counts,
        "stall_ms_total": float(stall.sum() * 1e-6),
        "stall_ms_in_overruns": float(stall[hit].sum() * 1e-6),
        "late_wake_ms_in_overruns": float(late_wake[hit].sum() * 1e-6),
        "spin_overshoot_ms_in_overruns": float(overshoot[hit].sum() * 1e-6),
        "compute_examples_us": [
            {"cycle": int(i), "lateness": float(lateness_ns[i]) * 1e-3,
             "compute": float(compute_ns[i]) * 1e-3, "stall": float(stall[i]) * 1e-3,
             "late_wake": float(late_wake[i]) * 1e-3,
             "page_faults": None if page_faults is None else int(page_faults[i])}
            for i in own],
        "max_stall_us": float(stall.max() * 1e-3) if stall.size else 0.0,
        "cycles_with_stall_over_100us": int(np.sum(stall > 100_000)),
    }


def _cycle_fixed_work() -> Callable[[int, float], None]:
    """A control: the same arithmetic every cycle (a compiled loop, a few bytes of memory),
    sized to take as long as the median ``ambc-aid`` cycle back to back (~80 µs here). Its
    compute time can vary only with the machine, so its spikes show what the machine adds
    to any cycle."""
    import numba

    @numba.njit(cache=True)
    def work(n):
        x = 1.0
        for _ in range(n):
            x = x * 1.0000001 + 1e-9
        return x

    work(10)
    t0 = time.perf_counter_ns()
    work(1_000_000)
    per_iter = max((time.perf_counter_ns() - t0) / 1_000_000, 1e-3)
    n = int(80_000 / per_iter)

    def cycle(t_ns: int, dt: float) -> None:
        work(n)
    return cycle


#: Per-cycle work selectable with ``--cycle``.
CYCLES: dict[str, CycleFactory] = {"none": _cycle_none, "pdc": _cycle_pdc,
                                   "ambc-aid": _cycle_ambc_aid,
                                   "fixed-work": _cycle_fixed_work}


def _add(p) -> None:
    p.add_argument("--rate", type=positive_float, default=1000.0,
                   help="loop rate, Hz (default 1000)")
    p.add_argument("--duration", type=positive_float, default=10.0,
                   help="seconds measured for each loop (default 10)")
    p.add_argument("--cycle", choices=sorted(CYCLES), default="none",
                   help="per-cycle work (default none)")
    p.add_argument("--timer", choices=("timerfd", "asyncio"), default="timerfd",
                   help="coarse wait of our loop (default timerfd)")
    p.add_argument("--fine", choices=("spin", "sleep"), default="spin",
                   help="fine wait of our loop (default spin)")
    p.add_argument("--margin-us", type=float, default=None,
                   help="coarse wait ends this long before the deadline (default per timer)")
    p.add_argument("--sched-fifo", type=nonnegative_int, default=0, metavar="PRIO",
                   help="SCHED_FIFO priority for the benchmark (default 0 = normal)")
    p.add_argument("--cpu", type=cpu_number, action="append", default=[],
                   help="pin to this CPU (repeatable)")
    p.add_argument("--warmup", type=nonnegative_float, default=0.5,
                   help="seconds run before measuring (default 0.5)")
    p.add_argument("--gc", choices=("slack", "python"), default="slack",
                   help="garbage collection while our loop runs (LoopSettings.gc; default "
                        "slack: start-up heap frozen, collections only in slack time)")
    p.add_argument("--no-naive", action="store_true", help="skip the naive asyncio loop")
    p.add_argument("--record", type=output_folder, metavar="DIR", default=None,
                   help="also publish a cycle record every cycle to the black-box recorder "
                        "writing MCAP into DIR (its cost on the loop: compare with a run "
                        "without)")
    p.add_argument("--mavlink-fuzz", type=nonnegative_int, default=0, metavar="N",
                   help="also run a MAVLink link (its sink fed a cycle record every cycle) on "
                        "a loopback port, in 2-s blocks, quiet and fuzzed in turn (--duration "
                        "of each): N random and malformed datagrams arrive in the fuzzed ones "
                        "from a second process; prints both lateness figures")
    p.add_argument("--fuzz-control", action="store_true",
                   help="with --mavlink-fuzz: no link; the datagrams go to a bare process that "
                        "judges them as the link's receiver does (off the loop's CPUs) — what "
                        "the fuzz then changes is the machine's, not the daemon's")
    p.add_argument("--zenoh-stall", type=nonnegative_float, default=0.0, metavar="SECONDS",
                   help="also publish every cycle's state over Zenoh (the daemon's sink) to a "
                        "uvd-fdc process, and measure blocks of SECONDS in turn: it reads, "
                        "it stops reading (SIGSTOP), it reads again (SIGCONT), …; lateness of "
                        "each (--duration is then ignored)")
    p.add_argument("--stall-rounds", type=positive_int, default=2, metavar="N",
                   help="with --zenoh-stall: N stops, so 2N + 1 blocks (default 2)")


@contextlib.contextmanager
def as_remote_peer(loop_cpus=()):
    """Start child processes, within this block, as a *remote peer* runs: normal scheduling,
    off the loop's CPUs (all CPUs when the loop has none of its own or takes them all).

    The loop's thread starts the benchmarks' peers — the Zenoh subscriber, the MAVLink fuzz
    sender — and a child inherits its creator's scheduling policy and CPU set at fork. From a
    loop at ``--sched-fifo`` on ``--cpu``, a peer would become a real-time process on the
    loop's own CPU at the loop's priority, which it cannot preempt: its Python work would then
    show in the loop's lateness, as no ground station or fault-detection client on another
    computer can. So the calling thread steps down to ``SCHED_OTHER`` on the other CPUs for
    the fork, and takes back its policy and CPU set after. Never raises."""
    try:
        policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
        cpus = os.sched_getaffinity(0)
    except (OSError, AttributeError):
        yield
        return
    every = set(range(os.cpu_count() or 1))
    peer = (every - set(loop_cpus)) or every
    with contextlib.suppress(OSError):
        os.sched_setaffinity(0, peer)
    with contextlib.suppress(OSError):
        if policy != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            if policy != os.SCHED_OTHER:
                os.sched_setscheduler(0, policy, param)
        with contextlib.suppress(OSError):
            os.sched_setaffinity(0, cpus)


async def _with_stalled_reader(settings: LoopSettings, cycle, seconds: float, rounds: int,
                               warmup: float, steal: Callable[[], float | None], hub,
                               endpoint: str, loop_cpus=()) -> dict:
    """The loop measured in one run of ``2 × rounds + 1`` blocks of ``seconds`` while a Zenoh
    subscriber (a ``uvd-fdc`` process taking every state sample) reads, is stopped (SIGSTOP:
    its socket fills, nothing is read), reads again (SIGCONT), … (:func:`_phased`). Returns
    the run's :func:`_measure` figures by phase and what the subscriber counted."""
    import signal

    from uvd.bench.zenoh import FdcProcess

    pump = asyncio.get_running_loop().create_task(hub.run())
    with as_remote_peer(loop_cpus):
        sub = FdcProcess([endpoint])
    try:
        await sub.subscribed()
        await asyncio.sleep(1.0)  # connected, samples flowing

        def block(k: int) -> None:
            sub.proc.send_signal(signal.SIGSTOP if k % 2 else signal.SIGCONT)
        out = await _phased(settings, cycle, warmup, steal, 2 * rounds + 1, seconds,
                            ("reading", "stalled"), time.monotonic() + warmup + 0.1, block)
    finally:
        sub.proc.send_signal(signal.SIGCONT)
        hub_stats = await hub.aclose()
        await pump
    out["hub"], out["subscriber"] = hub_stats, sub.finish()
    return out


async def _phased(settings: LoopSettings, cycle, warmup: float,
                  steal: Callable[[], float | None], n_blocks: int, block_s: float,
                  names: tuple[str, str], t0: float, on_block=None,
                  guard_s: float = 0.25) -> dict:
    """One :func:`_measure` run from ``t0`` (``time.monotonic``) over ``n_blocks`` blocks of
    ``block_s``: even blocks are ``names[0]`` (the baseline), odd ones ``names[1]`` (the
    condition), ``on_block(k)`` called as block k starts. Alternating blocks put the machine's
    drifting background load on both sides alike (two runs one after the other differ by more
    than the 10 % sought with nothing changed). The first ``guard_s`` of a baseline block
    counts with the condition block before it (the condition's tail: a backlog read, a
    subscriber catching up). The baseline's blocks 0, 4, 8… against 2, 6, 10…, two samples
    of the same condition, give the measurement's own resolution (``resolution``)."""
    stamps: list[int] = []

    def stamped(t_ns: int, dt: float) -> None:
        stamps.append(t_ns)
        cycle(t_ns, dt)

    async def blocks() -> None:
        for k in range(n_blocks):
            await asyncio.sleep(max(0.0, t0 + k * block_s - time.monotonic()))
            on_block(k)
    toggler = None if on_block is None else asyncio.get_running_loop().create_task(blocks())
    try:
        out = await _measure(settings, stamped, t0 + n_blocks * block_s - time.monotonic()
                             - warmup, warmup, steal)
    finally:
        if toggler is not None:
            toggler.cancel()
    n = out["trace_n"]
    t = (np.asarray(stamps[len(stamps) - n:], dtype=np.int64) - int(t0 * 1e9)) * 1e-9
    lat = out.pop("lateness_ns")[:len(t)]
    k = np.floor(t / block_s).astype(np.int64)
    k = np.where((k % 2 == 0) & (k > 0) & (t - k * block_s < guard_s), k - 1, k)
    valid = (t >= 0) & (k < n_blocks)
    base, cond = valid & (k % 2 == 0), valid & (k % 2 == 1)
    pct = {names[0]: percentiles(lat[base] * 1e-9), names[1]: percentiles(lat[cond] * 1e-9),
           "a": percentiles(lat[base & (k % 4 == 0)] * 1e-9),
           "b": percentiles(lat[base & (k % 4 == 2)] * 1e-9)}

    def change(x: dict, y: dict) -> float | None:
        return (y["p99"] - x["p99"]) / x["p99"] if x["n"] and y["n"] and x["p99"] else None
    # each block's own p99, and their median per condition: a burst of the host's that
    # lands in one or two blocks moves the pooled p99 but not this
    block_p99 = [float(np.percentile(lat[valid & (k == j)], 99)) * 1e-3
                 if np.any(valid & (k == j)) else None for j in range(n_blocks)]

    def median_p99(sel) -> float | None:
        xs = [x for j, x in enumerate(block_p99) if x is not None and sel(j)]
        return float(np.median(xs)) if xs else None
    med = {names[0]: median_p99(lambda j: j % 2 == 0), names[1]: median_p99(lambda j: j % 2),
           "a": median_p99(lambda j: j % 4 == 0), "b": median_p99(lambda j: j % 4 == 2)}

    def med_change(x: str, y: str) -> float | None:
        return med[y] / med[x] - 1.0 if med[x] and med[y] is not None else None
    ci = p99_change_ci(lat, k, valid, n_blocks)
    out["phases"] = {"blocks": n_blocks, "block_s": block_s, "guard_s": guard_s,
                     "lateness_p99_change_ci95": ci["ci95"],
                     "bootstrap_resamples": ci["resamples"],
                     "within_10pct": ci["within_10pct"],
                     "median_block_p99_change_ci95": ci["median_block_ci95"],
                     "median_block_within_10pct": ci["median_block_within_10pct"],
                     **{name: pct[name] for name in names},
                     f"{names[0]}_a": pct["a"], f"{names[0]}_b": pct["b"],
                     "lateness_p99_change": change(pct[names[0]], pct[names[1]]),
                     "resolution": change(pct["a"], pct["b"]),
                     "block_p99_us": block_p99,
                     "median_block_p99_us": {names[0]: med[names[0]], names[1]: med[names[1]]},
                     "median_block_p99_change": med_change(names[0], names[1]),
                     "median_block_p99_resolution": med_change("a", "b")}
    return out


def p99_change_ci(lat_ns: np.ndarray, block: np.ndarray, valid: np.ndarray, n_blocks: int,
                  *, resamples: int = 2000, bound: float = 0.10, seed: int = 0) -> dict:
    """The pooled lateness p99's relative change, condition vs baseline, with a 95 %
    confidence interval from a paired block bootstrap — what lets a run say whether the
    condition changes p99 by less than ``bound``.

    Blocks alternate (even: baseline, odd: condition, :func:`_phased`). The unit resampled is
    a *pair*: baseline block 2j with the condition block 2j + 1 that follows it (the last
    baseline block joins the last pair). A host burst or a drift of the machine's background
    load moves both blocks of a pair alike, so resampling pairs (with replacement, ``seed``
    fixed) carries exactly the run's own block-to-block variation into the interval, and the
    statistic of every resample is the one measured: p99 of the pooled baseline samples
    against p99 of the pooled condition samples. ``within_10pct`` is True when the whole
    interval lies inside ±``bound`` (the change is shown to be smaller), False when it lies
    wholly outside (shown to be larger), None when the run cannot tell — then more rounds
    narrow it (its width falls about as 1/√pairs).

    The same resamples give the interval of the change in the *median of the blocks' own
    p99* (``median_block_ci95``, ``median_block_within_10pct``): the pooled p99 of short
    blocks is carried by the few blocks a host burst lands in, the median of blocks is not —
    both are printed, neither is chosen after the fact."""
    blocks = [lat_ns[valid & (block == j)] for j in range(n_blocks)]
    pairs = n_blocks // 2
    if pairs < 2 or any(b.size == 0 for b in blocks):
        return {"ci95": None, "resamples": 0, "within_10pct": None,
                "median_block_ci95": None, "median_block_within_10pct": None}
    base = [blocks[2 * j] for j in range(pairs)]
    base[-1] = np.concatenate([base[-1]] + blocks[2 * pairs:])
    cond = [blocks[2 * j + 1] for j in range(pairs)]
    base_p99 = np.array([np.percentile(blocks[2 * j], 99) for j in range(pairs)])
    cond_p99 = np.array([np.percentile(x, 99) for x in cond])
    rng = np.random.default_rng(seed)
    change, med = np.empty(resamples), np.empty(resamples)
    for r in range(resamples):
        pick = rng.integers(0, pairs, size=pairs)
        b = np.percentile(np.concatenate([base[i] for i in pick]), 99)
        c = np.percentile(np.concatenate([cond[i] for i in pick]), 99)
        change[r] = c / b - 1.0 if b > 0 else np.nan
        mb = np.median(base_p99[pick])
        med[r] = np.median(cond_p99[pick]) / mb - 1.0 if mb > 0 else np.nan

    def verdict(x: np.ndarray) -> tuple[list[float], bool | None]:
        lo, hi = (float(v) for v in np.nanpercentile(x, [2.5, 97.5]))
        return [lo, hi], (True if -bound < lo and hi < bound else
                          False if lo >= bound or hi <= -bound else None)
    (ci, within), (mci, mwithin) = verdict(change), verdict(med)
    return {"ci95": ci, "resamples": resamples, "within_10pct": within,
            "median_block_ci95": mci, "median_block_within_10pct": mwithin}


async def _ours(settings: LoopSettings, cycle, duration: float, warmup: float,
                steal: Callable[[], float | None], hub=None) -> dict:
    pump = None if hub is None else asyncio.get_running_loop().create_task(hub.run())
    try:
        return await _measure(settings, cycle, duration, warmup, steal)
    finally:
        if hub is not None:
            await hub.aclose()
            await pump


async def _measure(settings: LoopSettings, cycle, duration: float, warmup: float,
                   steal: Callable[[], float | None]) -> dict:
    n_max = int(math.ceil(duration * settings.rate_hz)) + 16
    probe = StallProbe(MonotonicClock(coarse=settings.timer, fine=settings.fine),
                       max(n_max, int(math.ceil(warmup * settings.rate_hz)) + 16))
    loop = FixedRateLoop(cycle, settings, clock=probe, trace_capacity=n_max)
    loop.after_cycle.append(probe.after_cycle)
    try:
        if warmup > 0:
            await loop.run(duration_s=warmup)
            loop.reset_stats()
            loop.trace.n = 0
            probe.reset()
        steal0, wall0 = steal(), time.monotonic()
        snap = await loop.run(duration_s=duration)
        wall, steal1 = time.monotonic() - wall0, steal()
    finally:
        probe.close()
    n = min(loop.trace.n, probe.n)
    lat, comp = loop.trace.lateness_ns[:n], loop.trace.compute_ns[:n]
    wake = probe.wall0[:n] - (probe.wall1[:n] - comp - lat)  # coarse return − deadline
    attribution = attribute_overruns(lat, comp, wake, probe.stalls_ns()[:n],
                                     probe.preempted()[:n], loop.period_ns, loop.margin_ns,
                                     probe.page_faults()[:n])
    return {
        "overrun_attribution": attribution,
        "lateness_us": percentiles(loop.trace.lateness_ns[:n] * 1e-9),
        "compute_us": percentiles(loop.trace.compute_ns[:n] * 1e-9),
        "cycles": snap["cycles"],
        "overruns": snap["overruns"],
        "skipped": snap["skipped"],
        "max_overrun_streak": snap["max_overrun_streak"],
        "cycle_errors": snap["cycle_errors"],
        "last_error": snap["last_error"],
        "achieved_rate_hz": (snap["cycles"] + snap["skipped"]) / wall if wall > 0 else 0.0,
        "timer": snap["timer"],
        "gc": snap["gc"],
        "histogram": {"lateness_us": snap["lateness_us"], "compute_us": snap["compute_us"]},
        "host_steal_s": None if steal0 is None or steal1 is None else steal1 - steal0,
        "wall_s": wall,
        "trace_n": int(n),
        "lateness_ns": lat.copy(),
    }


async def _naive(rate: float, cycle, duration: float) -> dict:
    period = 1.0 / rate
    lat: list[int] = []
    comp: list[int] = []
    now = time.monotonic_ns
    t0 = now()
    end = t0 + int(duration * 1e9)
    prev = t0
    while True:
        want = now() + int(period * 1e9)
        if want > end:
            break
        await asyncio.sleep(period)
        t = now()
        lat.append(t - want)
        cycle(t, (t - prev) * 1e-9)
        prev = t
        comp.append(now() - t)
    wall = (now() - t0) * 1e-9
    return {
        "lateness_us": percentiles(np.asarray(lat) * 1e-9),
        "compute_us": percentiles(np.asarray(comp) * 1e-9),
        "cycles": len(lat),
        "achieved_rate_hz": len(lat) / wall if wall > 0 else 0.0,
    }


def _back_to_back(cycle, rate: float, n: int, burst: int = 10, lead: int = 2) -> dict:
    """The cycle's cost with the CPU's caches and predictors warm, for comparison with
    ``compute_us`` (at a low rate every cycle starts cold — docs/runtime.md, "Compute at low
    rates"): bursts of ``burst`` cycles run back to back, each on the next period's
    timestamp; the first ``lead`` of each burst warm up and are not counted. Between bursts
    the CPU is given back for a millisecond, so at real-time priority this never holds it
    for more than a burst (the HIL demo beside it keeps its INS and CAN deadlines)."""
    ns = np.empty(n, dtype=np.int64)
    period_ns = int(round(1e9 / rate))
    t = time.monotonic_ns()
    now = time.perf_counter_ns
    k = i = 0
    while i < n:
        for j in range(burst):
            t0 = now()
            cycle(t + k * period_ns, 1.0 / rate)
            dt_ns = now() - t0
            k += 1
            if j >= lead and i < n:
                ns[i] = dt_ns
                i += 1
        time.sleep(1e-3)
    return percentiles(ns * 1e-9)


def _fmt(d: dict) -> str:
    return "  ".join(f"{k} {d[k]:8.1f}" for k in ("p50", "p99", "p999", "max") if k in d)


_Z3, _Z6, _EYE = np.zeros(3), np.zeros(6), np.eye(3)


def bench_cycle_record(t_ns: int, dt: float) -> dict:
    """A cycle record as the daemon's write phase builds it (6 thrusters, tracking), as the
    hub's sinks get it."""
    from uvd.telemetry.records import CycleRecord
    z3, z6, eye = _Z3, _Z6, _EYE
    return CycleRecord(
        t_ns=t_ns, dt=dt, state="ARMED", action="none", mode="control", status="ok",
        p=z3, R=eye, v=z6, nav_valid=True, u=z6, u_cmd=z6, thrust=z6,
        ages=(0.01, 0.1, 0.05, 0.01), ins_rx_ns=t_ns, inputs={
            "actuators": {"omega_rad_s": z6, "enabled": True, "faults": [],
                          "feedback_t_ns": t_ns, "bus_off": False},
            "overrun_streak": 0, "overrun_streak_exceeded": False, "leak": False,
            "extra": None}, p_ref=z3, R_ref=eye, v_ref=z6).to_dict()


def _published(cycle, hub):
    """``cycle`` followed by what the daemon's write phase does for its sinks: build one cycle
    record and publish it to ``hub``."""
    def published(t_ns: int, dt: float) -> None:
        cycle(t_ns, dt)
        hub.publish(bench_cycle_record(t_ns, dt))
    return published


def _recorded(cycle, directory: str, times: dict[str, list]):
    """``cycle`` followed by what the daemon's write phase does for telemetry — build one cycle
    record (6 thrusters) and publish it — every cycle; every other cycle the hub has the MCAP
    recorder (the daemon's ``[recording]`` defaults) as its sink and the cycle's seven CAN
    sends (6 RPDOs + SYNC) pass its tap, the others publish to a hub without sinks. The daemon
    builds and publishes the record whether or not it records, so the difference is what
    ``[recording] enabled`` adds to a cycle. The time of each call goes to ``times["with"]``
    or ``times["without"]``: interleaved, in the same run, under the same load; the
    recorder's pump runs between cycles as in the daemon."""
    import can

    from uvd.links.mcap import McapRecorder
    from uvd.runtime.config import RecordingSection
    from uvd.telemetry.sink import TelemetryHub

    r = RecordingSection()  # the daemon's defaults: its data forced to the disk every 1 s
    rec = McapRecorder(directory, flush_interval_s=r.flush_interval_s,
                       sync_interval_s=r.sync_interval_s)
    hub, bare = TelemetryHub([rec]), TelemetryHub([])
    frames = [can.Message(arbitration_id=0x200 + n, data=bytes(4), is_extended_id=False)
              for n in range(1, 7)] + [can.Message(arbitration_id=0x80, data=b"",
                                                   is_extended_id=False)]
    clock = time.perf_counter
    with_s, without_s = times.setdefault("with", []), times.setdefault("without", [])

    def recorded(t_ns: int, dt: float) -> None:
        t0 = clock()
        cycle(t_ns, dt)
        recording = len(with_s) <= len(without_s)
        if recording:
            for m in frames:
                rec.tap_can(m, t_ns, False)
        (hub if recording else bare).publish(bench_cycle_record(t_ns, dt))
        (with_s if recording else without_s).append(clock() - t0)
    return recorded, hub


def _mavlink_link(loop_cpus=()):
    """A MAVLink link on a free loopback port, the sink of a hub, and the cycle that publishes
    one cycle record to that hub (as the daemon's write phase does)."""
    from uvd.links.mavlink.link import MavlinkLink
    from uvd.runtime.commands import CommandQueue
    from uvd.runtime.config import DEFAULT_CONFIG, MavlinkSection, load_config

    config = load_config(DEFAULT_CONFIG)
    link = MavlinkLink(MavlinkSection(enabled=True, listen="127.0.0.1:0", params_file=""),
                       CommandQueue(), lambda: config,
                       thresholds={"ins": 0.25, "dvl": 1.0, "depth": 0.5, "feedback": 0.5},
                       max_thrust_n=[20.0] * 6, loop_cpus=loop_cpus)
    from uvd.telemetry.sink import TelemetryHub
    hub = TelemetryHub([link])
    return link, _published(CYCLES["none"](), hub), hub


async def _with_fuzz(settings: LoopSettings, cycle, duration: float, warmup: float,
                     n_fuzz: int, steal, block_s: float = 2.0, loop_cpus=(),
                     control: bool = False) -> dict:
    """Our loop running ``cycle`` plus a MAVLink link's cycle record, in blocks of
    ``block_s``, quiet and fuzzed in turn (:func:`_phased`; ``duration`` of each): a second
    process sends the ``n_fuzz`` bad datagrams to the link in the fuzzed blocks only.

    ``control``: no link at all — the datagrams go to a process of their own that judges
    them as the link's receiver does (:func:`uvd.bench.mavlink_fuzz.receiver_process`, off
    the loop's CPUs). What the fuzz then changes in the loop is the machine's doing (the
    kernel's and the parser's work on the other CPUs), with nothing of the daemon on the
    datagrams' path."""
    from uvd.bench.mavlink_fuzz import fuzz_process, receiver_process, start_fuzz, wait_ready
    from uvd.telemetry.sink import TelemetryHub
    if control:  # forked from this thread, stepped down (a worker thread would not be)
        with as_remote_peer(loop_cpus):
            target, port = receiver_process()
        link, hub, both = None, TelemetryHub([]), cycle
    else:
        link, publish, hub = _mavlink_link(loop_cpus)
        target, port = None, 0  # the link's, once the hub has opened it

        def both(t_ns: int, dt: float) -> None:
            cycle(t_ns, dt)
            publish(t_ns, dt)

    from uvd.runtime.config import DaemonSection
    # as the daemon runs: another thread holding the interpreter yields it within this
    old_switch = sys.getswitchinterval()
    sys.setswitchinterval(DaemonSection().gil_switch_interval_us * 1e-6)
    pump = asyncio.get_running_loop().create_task(hub.run())
    await asyncio.sleep(0.2)  # the hub opens the link
    n_blocks = 2 * max(1, int(round(duration / block_s))) + 1
    with as_remote_peer(loop_cpus):
        sender = fuzz_process(port or link.port, n_fuzz)
    try:
        await asyncio.to_thread(wait_ready, sender)
        t0 = time.monotonic() + warmup + 0.5
        start_fuzz(sender, [(t0 + k * block_s, t0 + (k + 1) * block_s)
                            for k in range(1, n_blocks, 2)])
        out = await _phased(settings, both, warmup, steal, n_blocks, block_s,
                            ("quiet", "fuzzed"), t0)
    finally:
        try:
            await asyncio.to_thread(sender.wait, 30.0)
        except Exception:  # noqa: BLE001 - a sender that hangs is ended, never waited for
            sender.kill()
        await hub.aclose()
        await pump
        sys.setswitchinterval(old_switch)
        judged = []
        if target is not None:
            target.terminate()
            try:
                judged = (await asyncio.to_thread(target.communicate, timeout=10))[0].split()
            except subprocess.TimeoutExpired:
                target.kill()
    said = sender.stdout.read().split() if sender.stdout else []
    out["sent"] = int(said[-1]) if said and said[-1].isdigit() else 0
    out["mavlink"] = link.stats() if link is not None else {
        "control": True, "datagrams": int(judged[-1]) if judged and judged[-1].isdigit() else 0}
    return out


# _run is long (~150 lines): it owns the loop under test, its sinks and the peer processes
# (Zenoh subscriber, MAVLink fuzz sender) for the whole measurement and must stop each of
# them in one finally; its phases are the benchmark's printed protocol.
def _run(args) -> dict:
    settings = LoopSettings(rate_hz=args.rate, timer=args.timer, fine=args.fine,
                            fine_margin_us=args.margin_us, gc=args.gc)
    # Build the cycle and run it a few times (imports, compiled-code loading, first
    # allocations) *before* asking for real-time priority: at SCHED_FIFO that start-up work
    # would hold the CPU for hundreds of ms from every lower-priority task on it — the HIL
    # demo's daemon, which the acceptance runs beside this benchmark, included.
    cycle = CYCLES[args.cycle]()
    hub, rec_times, endpoint = None, {}, None
    if args.record and args.zenoh_stall > 0:
        raise SystemExit("uvd bench loop: --record and --zenoh-stall each measure one sink "
                         "against none; give one of them")
    if args.fuzz_control and not args.mavlink_fuzz:
        raise SystemExit("uvd bench loop: --fuzz-control is the control of --mavlink-fuzz N; "
                         "give both")
    if args.record:
        cycle, hub = _recorded(cycle, args.record, rec_times)
    if args.zenoh_stall > 0:
        from uvd.links.zenoh import ZenohSink, zenoh_config
        from uvd.netports import free_port
        from uvd.telemetry.sink import TelemetryHub
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        hub = TelemetryHub([ZenohSink("bench", zenoh_config(listen=[endpoint]),
                                      state_hz=args.rate, health_hz=0.0)])
        cycle = _published(cycle, hub)
    for _ in range(20):
        t = time.monotonic_ns()
        cycle(t, 1.0 / args.rate)
        time.sleep(1.0 / args.rate)
    rt = apply_realtime(args.sched_fifo, args.cpu)
    for m in rt.messages:
        print(f"uvd bench loop: {m}")
    # with real-time priority, keep idle CPUs from halting (as the daemon does)
    cpu_latency = CpuLatencyRequest(0).open() if args.sched_fifo else None
    if cpu_latency is not None and cpu_latency.message:
        print(f"uvd bench loop: {cpu_latency.message}")
    load0 = os.getloadavg()
    # the hypervisor's steal on the loop's CPUs: a paused vCPU stalls us whatever our priority
    steal_cpus = sorted(rt.cpu_affinity) if args.cpu else None
    stall = None
    if endpoint is not None:
        stall = asyncio.run(_with_stalled_reader(settings, cycle, args.zenoh_stall,
                                                 args.stall_rounds, args.warmup,
                                                 lambda: host_steal_s(steal_cpus), hub,
                                                 endpoint, loop_cpus=args.cpu or ()))
        ours = stall
    else:
        ours = asyncio.run(_ours(settings, cycle, args.duration, args.warmup,
                                 lambda: host_steal_s(steal_cpus), hub))
    # the measured cycles' (warm-up and back-to-back runs left out), half with the recorder
    recording = None
    if args.record:
        half = ours["cycles"] // 2
        w, wo = (percentiles(rec_times[k][-half:]) for k in ("with", "without"))
        recording = {"with_us": w, "without_us": wo, "p50_cost_us": w["p50"] - wo["p50"]}
    fuzz = None
    if args.mavlink_fuzz:
        f = asyncio.run(_with_fuzz(settings, cycle, args.duration, args.warmup,
                                   args.mavlink_fuzz, lambda: host_steal_s(steal_cpus),
                                   control=args.fuzz_control,
                                   loop_cpus=args.cpu or ()))
        fuzz = {"datagrams": args.mavlink_fuzz, "sent": f["sent"], "link_counters": f["mavlink"],
                "overruns": f["overruns"], **f["phases"]}
    warm = _back_to_back(cycle, args.rate, 2000) if args.cycle != "none" else None
    naive = None if args.no_naive else asyncio.run(_naive(args.rate, cycle, args.duration))
    figures = {
        "rate_hz": args.rate,
        "duration_s": args.duration if stall is None
        else (2 * args.stall_rounds + 1) * args.zenoh_stall,
        "cycle": args.cycle,
        "recording": recording,
        "lateness_us": ours["lateness_us"],
        "compute_us": ours["compute_us"],
        "compute_back_to_back_us": warm,
        "overruns": ours["overruns"],
        "overrun_attribution": ours["overrun_attribution"],
        "skipped": ours["skipped"],
        "cycles": ours["cycles"],
        "cycle_errors": ours["cycle_errors"],
        "achieved_rate_hz": ours["achieved_rate_hz"],
        "max_overrun_streak": ours["max_overrun_streak"],
        "timer": ours["timer"],
        "gc": ours["gc"],
        "histogram": ours["histogram"],
        "realtime": {"sched_fifo_priority": rt.sched_fifo_priority,
                     "cpu_affinity": list(rt.cpu_affinity), "messages": list(rt.messages),
                     "cpu_dma_latency_held": bool(cpu_latency and cpu_latency.held)},
        "loadavg_1min_at_start": load0[0],
        "host_steal": {"cpus": steal_cpus or "all", "seconds": ours["host_steal_s"],
                       "share": (ours["host_steal_s"] / ours["wall_s"] / (len(steal_cpus)
                                 if steal_cpus else os.cpu_count() or 1))
                       if ours["host_steal_s"] is not None and ours["wall_s"] > 0 else None},
    }
    if cpu_latency is not None:
        cpu_latency.close()
    if ours["last_error"]:
        figures["last_error"] = ours["last_error"]
    if naive is not None:
        figures["naive_asyncio"] = naive
    if fuzz is not None:
        figures["mavlink_fuzz"] = fuzz
    if stall is not None:
        figures["zenoh_stall"] = {"seconds": args.zenoh_stall, "rounds": args.stall_rounds,
                                  **stall["phases"], "hub": stall["hub"],
                                  "subscriber": stall["subscriber"]}
    seconds = f"{2 * args.stall_rounds + 1} × {args.zenoh_stall:g}" if stall is not None \
        else f"{args.duration:g}"
    print(f"uvd bench loop: {args.rate:g} Hz, {seconds} s, cycle '{args.cycle}', "
          f"load {load0[0]:.2f}")
    print(f"  lateness µs  ours  : {_fmt(ours['lateness_us'])}   overruns {ours['overruns']}"
          f"  skipped {ours['skipped']}")
    if naive is not None:
        print(f"  lateness µs  naive : {_fmt(naive['lateness_us'])}   achieved "
              f"{naive['achieved_rate_hz']:.1f} Hz")
    print(f"  compute  µs  ours  : {_fmt(ours['compute_us'])}")
    if recording is not None:
        print(f"  cycle µs with the black box   : {_fmt(recording['with_us'])}")
        print(f"  cycle µs without (interleaved): {_fmt(recording['without_us'])}   median "
              f"cost {recording['p50_cost_us']:.1f} µs")
    if stall is not None:
        z = figures["zenoh_stall"]
        _print_phases("Zenoh subscriber", z, ("reading", "stalled"))
        zs = z["hub"].get("zenoh", {})
        print(f"    hub dropped {zs.get('dropped')}; subscriber received "
              f"{sum(z['subscriber'].get('received', {}).values())}")
    if warm is not None:
        print(f"  compute  µs  back to back (warm caches, 2000 in bursts of 10): {_fmt(warm)}")
    hs = figures["host_steal"]
    if hs["seconds"] is not None:
        print(f"  host steal on CPUs {hs['cpus']}: {hs['seconds']:.2f} s over the run "
              f"({100 * hs['share']:.2f} % of their time)")
    oa = ours["overrun_attribution"]
    print(f"  overruns by cause: stalled {oa['stalled']} (thread runnable, vCPU not running: "
          f"host steal)  preempted {oa['preempted']}  woke late {oa['woke_late']}  paused in "
          f"spin {oa['paused_in_spin']}  compute {oa['compute']};  stall over the run "
          f"{oa['stall_ms_total']:.1f} ms, longest {oa['max_stall_us']:.0f} µs")
    if fuzz is not None:
        c = fuzz["link_counters"]
        _print_phases("MAVLink link" if not c.get("control") else
                      "MAVLink fuzz CONTROL (no link: a bare receiver process)", fuzz,
                      ("quiet", "fuzzed"))
        judged = (f"{c.get('datagrams', 0)} judged by the bare receiver" if c.get("control")
                  else f"{c.get('datagrams', 0)} read, {c.get('bad_datagrams', 0)} bad")
        print(f"    {fuzz['sent']} of {fuzz['datagrams']} datagrams sent, {judged}; "
              f"overruns {fuzz['overruns']}")
    g = ours["gc"]
    print(f"  gc ({g['policy']}): collections {g['collections']}  forced {g['forced']}  "
          f"max µs {[round(x, 1) for x in g['max_us']]}")
    return figures


def _print_phases(what: str, ph: dict, names: tuple[str, str]) -> None:
    def pct(x: float | None) -> str:
        return "n/a" if x is None else f"{100 * x:+.1f} %"
    print(f"  {what}: {ph['blocks']} blocks of {ph['block_s']:g} s, {names[0]} and {names[1]} "
          f"in turn (a {names[1]} block's next {ph['guard_s']:g} s count with it)")
    for k in names:
        print(f"    {k:<8}: lateness µs {_fmt(ph[k])}")
    print(f"    lateness p99 change, {names[1]} vs {names[0]}: "
          f"{pct(ph['lateness_p99_change'])}  (the {names[0]} blocks against each other, "
          f"the measurement's resolution here: {pct(ph['resolution'])})")
    verdicts = {True: "inside ±10 %: the change is shown to be smaller",
                False: "outside ±10 %: the change is shown to be larger",
                None: "straddles ±10 %: this run cannot tell"}
    ci = ph.get("lateness_p99_change_ci95")
    if ci is not None:
        print(f"    95 % interval of that change (paired block bootstrap, "
              f"{ph['blocks'] // 2} pairs): {pct(ci[0])} … {pct(ci[1])} — "
              f"{verdicts[ph['within_10pct']]}")
    m = ph["median_block_p99_us"]
    if m[names[0]] is not None and m[names[1]] is not None:
        print(f"    median of the blocks' own p99: {names[0]} {m[names[0]]:.1f} µs, {names[1]} "
              f"{m[names[1]]:.1f} µs: {pct(ph['median_block_p99_change'])}  (resolution "
              f"{pct(ph['median_block_p99_resolution'])})")
    mci = ph.get("median_block_p99_change_ci95")
    if mci is not None:
        print(f"    95 % interval of that change: {pct(mci[0])} … {pct(mci[1])} — "
              f"{verdicts[ph['median_block_within_10pct']]}")


BENCH = Bench(name="loop", summary="Fixed-rate loop deadline precision vs a naive asyncio.sleep "
                                   "loop (lateness, compute, overruns)",
              run=_run, add_arguments=_add)
