"""``uvd bench cycle``: where a lockstep cycle's time goes — the supervised update (navigation,
the estimators, reference + controller + allocation, the arbiter and lifecycle, the update's
own glue), the plant, the instruments, and what the run does outside the cycle (uvd-fdc's
detector, the records) — in µs a cycle, on one campaign run (``--kind fdc``: a fault-free
vehicle under uvd-fdc, as ``fdc-false-alarms`` and ``fdc-detection`` run it; ``--kind
control``: the two-step AMBC run of ``control-model-error``).

How: the run is :func:`uvd.campaign.runs.execute` itself, in this process, with a timer wrapped
around each part's function (``time.perf_counter_ns`` on entry and exit, the module attribute
or method the cycle calls replaced for the run and put back after). The timers are inclusive,
so a part's figure holds the parts inside it, and each timer costs a fraction of a µs a call
of its own (``timer_overhead_us``, measured on an empty function: 0.4–0.8 µs on a busy 2-core
VM; a part's figure holds it once per call, an enclosing part's once per call of every part
inside). The run is cut in blocks of ``--block`` cycles; every figure is the median over the
blocks of the part's time per cycle (``p90`` beside it), so a stretch where the machine was busy
moves it little. Figures, never asserted: the next step of issue 31's "compiled end to end"
starts from them.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

from uvd.bench import Bench
from uvd.cliargs import positive_float, positive_int

#: (part, owner, attribute): the function each part's timer wraps, as the run looks it up
_PARTS = (
    ("cycle", "uvd.lockstep:Lockstep", "advance"),
    ("update", "uvd.runtime.supervisor:Supervisor", "update"),
    ("sense", "uvd.core", "sense"),
    ("navigation", "uvd.core", "nav_step"),
    ("act", "uvd.core", "act"),
    ("arbiter+lifecycle", "uvd.runtime.cycle", "_supervise"),
    ("plant", "sim_bridge.plant:Plant", "steps_held"),
    # the compiled walk of a period's samples (no campaign run injects an instrument fault,
    # which would sample one call at a time)
    ("instruments", "sim_bridge.instruments.models:Instruments", "sample_trace"),
    ("fdc state", "uvd.fdc.detector:VehicleDetector", "update_state"),
    ("fdc estimates", "uvd.fdc.detector:VehicleDetector", "update"),
)

#: parts given as what is left of one part once the parts inside it are taken out
_REST = (
    ("update glue (health, mode, state)", "update", ("sense", "act", "arbiter+lifecycle")),
    ("sense: estimators and the rest", "sense", ("navigation",)),
    ("lockstep glue", "cycle", ("update", "plant", "instruments")),
)


def _add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--kind", choices=("fdc", "control"), default="fdc",
                   help="the campaign run timed (default fdc: a fault-free vehicle under "
                        "uvd-fdc)")
    p.add_argument("--vehicle", default="jhu-rov", choices=("jhu-rov", "bluerov2-heavy"),
                   help="--kind fdc: the vehicle (default jhu-rov)")
    p.add_argument("--minutes", type=positive_float, default=40.0,
                   help="simulated minutes (default 40; fdc runs need >= 25, the baseline)")
    p.add_argument("--block", type=positive_int, default=2000, help="cycles a block (default 2000)")


def _owner(spec: str):
    import importlib
    module, _, cls = spec.partition(":")
    m = importlib.import_module(module)
    return getattr(m, cls) if cls else m


class _Timers:
    """Inclusive timers per part, totals snapshotted every ``block`` cycles."""

    def __init__(self, block: int) -> None:
        self.block = block
        self.total = {name: 0 for name, _, _ in _PARTS}
        self.cycles = 0
        self.blocks: list[dict[str, int]] = []
        self.run_ns = 0
        self._last = dict(self.total)
        self._t_block = 0

    def start(self) -> int:
        """The first block starts now; returns the time (ns)."""
        self._t_block = time.perf_counter_ns()
        return self._t_block

    def wrap(self, name: str, fn: Callable) -> Callable:
        clock, total = time.perf_counter_ns, self.total
        counted = name == "cycle"

        def timed(*args, **kwargs):
            t = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                total[name] += clock() - t
                if counted:
                    self._cycle_done()
        return timed

    def _cycle_done(self) -> None:
        self.cycles += 1
        if self.cycles % self.block == 0:
            now = time.perf_counter_ns()
            block = {k: v - self._last[k] for k, v in self.total.items()}
            block["all"] = now - self._t_block
            self.blocks.append(block)
            self._last, self._t_block = dict(self.total), now


def _overhead_us() -> float:
    """One timer's own cost a call (µs): the wrapper around an empty function, against the
    empty function, median of 5 blocks of 20 000 calls."""
    t = _Timers(10 ** 9)

    def empty():
        return None
    timed = t.wrap("update", empty)
    runs = []
    for _ in range(5):
        c0 = time.perf_counter_ns()
        for _ in range(20_000):
            timed()
        c1 = time.perf_counter_ns()
        for _ in range(20_000):
            empty()
        c2 = time.perf_counter_ns()
        runs.append(((c1 - c0) - (c2 - c1)) / 20_000 / 1e3)
    return statistics.median(runs)


def _inputs(args: argparse.Namespace) -> dict:
    if args.kind == "fdc":
        return {"vehicle": args.vehicle, "seed": 3, "fault": "none", "fault_size": 0.0,
                "fault_thruster": 0, "onset_min": 25.0,
                "after_min": max(0.0, args.minutes - 25.0), "noise_scale": 1.0,
                "reference": "reftraj1"}
    return {"controller": "two-step", "seed": 3, "duration_h": args.minutes / 60.0,
            "mass_error": 0.0, "drag_error": 0.0, "kp": 300.0, "kd": 100.0,
            "window_min": min(15.0, args.minutes / 2.0)}


def run(args: argparse.Namespace) -> dict:
    from uvd.campaign.runs import execute

    if args.kind == "fdc" and args.minutes < 25.0:
        raise SystemExit("--minutes must be >= 25 for --kind fdc (the detector's baseline)")
    inputs = _inputs(args)
    # warm-up: the kernels compiled or loaded, the modules imported (not the cycle's cost)
    execute(args.kind, {**inputs, **({"after_min": 0.5} if args.kind == "fdc" else
                                     {"duration_h": 0.01, "window_min": 0.2})})
    timers = _Timers(args.block)
    saved = []
    for name, owner_spec, attr in _PARTS:
        owner = _owner(owner_spec)
        fn = owner.__dict__[attr] if isinstance(owner, type) else getattr(owner, attr)
        saved.append((owner, attr, fn))
        setattr(owner, attr, timers.wrap(name, fn))
    try:
        t0 = timers.start()
        c0 = time.process_time()
        result = execute(args.kind, inputs)
        cpu = time.process_time() - c0
        timers.run_ns = time.perf_counter_ns() - t0
    finally:
        for owner, attr, fn in reversed(saved):
            setattr(owner, attr, fn)
    if result["error"]:
        raise RuntimeError(f"the timed run failed: {result['error']}")
    if not timers.blocks:
        raise SystemExit(f"fewer cycles ({timers.cycles}) than one block ({args.block})")

    def per_cycle(values: list[float]) -> dict:
        us = sorted(v / args.block / 1e3 for v in values)
        return {"median_us": statistics.median(us),
                "p90_us": us[min(len(us) - 1, int(0.9 * len(us)))]}

    blocks = timers.blocks
    parts = {name: per_cycle([b[name] for b in blocks]) for name, _, _ in _PARTS
             if any(b[name] for b in blocks)}
    for label, whole, inside in _REST:
        if whole in parts:
            parts[label] = per_cycle([b[whole] - sum(b[i] for i in inside) for b in blocks])
    parts["outside the cycle (detector, records, run glue)"] = per_cycle(
        [b["all"] - b["cycle"] for b in blocks])
    parts["all"] = per_cycle([b["all"] for b in blocks])
    overhead = _overhead_us()
    lines = [f"uvd bench cycle: {args.kind}"
             + (f" {args.vehicle}" if args.kind == "fdc" else " two-step AMBC, jhu-rov")
             + f", {timers.cycles} cycles in {len(blocks)} blocks of {args.block}; "
             f"µs a cycle, median [p90] over the blocks (inclusive; timer ~{overhead:.2f} µs "
             "a call)"]
    for name, fig in parts.items():
        lines.append(f"  {name:<48} {fig['median_us']:8.1f} [{fig['p90_us']:.1f}]")
    lines.append(f"  run: {timers.run_ns / 1e9:.1f} s wall, {cpu:.1f} s CPU, "
                 f"{timers.cycles / (timers.run_ns / 1e9):.0f} cycles/s")
    print("\n".join(lines))
    return {"kind": args.kind, "vehicle": args.vehicle if args.kind == "fdc" else "jhu-rov",
            "cycles": timers.cycles, "block": args.block, "blocks": len(blocks),
            "parts_us_per_cycle": parts, "timer_overhead_us": overhead,
            "run_wall_s": timers.run_ns / 1e9, "run_cpu_s": cpu}


BENCH = Bench("cycle", "where a lockstep cycle's time goes (µs a cycle per part: navigation, "
                       "estimators, control, arbiter, plant, instruments, uvd-fdc), one "
                       "campaign run", run, _add_arguments)
