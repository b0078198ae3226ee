"""``make results-check`` (``python -m uvd.experiments.reproduce NAME …``): every run named in
docs/RESULTS.md's tables re-run from its printed command and compared with the committed JSON.

Each NAME is run exactly as RESULTS.md prints it, ``uvd experiment NAME --json OUT`` (seed 0,
default duration), into a temporary folder; :func:`compare` then walks the committed
``docs/results/NAME.json`` and the new one side by side. A number counts as reproduced within
``--rel`` (1e-9 relative by default: the last bits the compiled kernels may round differently
on another processor, docs/experiments.md "Reproducibility"); anything else — a string, a
flag, a key or a list length — must be equal. Timings (keys naming wall or CPU time, and
phrases of a text that quote a wall time) are not compared; lines another process printed in
the order samples reached it (:data:`ARRIVAL_ORDER_KEYS`) are compared whatever their order.
Exit status 1 when any experiment does not reproduce; the figures go to stdout.

``--against DIR`` compares JSON files already written (e.g. by ``make results --out DIR``)
instead of running.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REL = 1e-9
#: the OpenBLAS kernels docs/results/ were written with (measured: on an AVX-512 machine,
#: aid-rot, aid-hover, fault-tolerance and fault-tolerance-every reproduce with these and not
#: with its own SkylakeX kernels, docs/experiments.md "Reproducibility")
RESULTS_BLAS = "Haswell"
#: keys not compared: how long a run took, not what it computed
TIMING_KEYS = frozenset({"wall_seconds", "sim_wall_s", "cpu_s", "rows_cpu_s",
                         "real_time_factor", "recordings",
                         # fdc-fleet: sample → uvd-fdc through Zenoh, on the wall clock
                         "latency_ms"})
#: lists of lines another process printed as its samples arrived (fdc-fleet's uvd-fdc: the
#: vehicles' "up" lines in the order their first samples came): compared as multisets
ARRIVAL_ORDER_KEYS = frozenset({"fdc_output"})


#: runs in real time (sim-bridge and the daemon as processes on the wall clock), whose figures
#: move with the machine's timing (docs/experiments.md "Reproducibility"): the keys named here
#: are computed in lockstep or fixed by the command and are judged like any run's; the others
#: are compared with their texts' digits masked and their numbers reported, not judged (the
#: summary, which prints them, not at all)
REAL_TIME_RUNS = {
    "fault-tolerance-hil": frozenset({"lockstep_fault_free", "thruster", "t_fault_s",
                                      "duration_s", "settle_s", "thesis_reference",
                                      "experiment", "seed"}),
}

_DIGITS = re.compile(r"\d+(?:\.\d+)?")


def _timing(key: str) -> bool:
    return key in TIMING_KEYS or "wall" in key


#: a phrase of a text that quotes a wall time ("lockstep 53.3 s wall", "wall: LS 0.5 s, …"):
#: up to the next ";" or line end
_WALL_PHRASE = re.compile(r"[^;\n]*\bwall\b[^;\n]*")


def _untimed(text: str) -> str:
    """``text`` without its phrases that quote a wall time (the summaries print how long
    their run took; that is not what it computed)."""
    return _WALL_PHRASE.sub("", text)


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def relative_difference(a: float, b: float) -> float:
    """|a − b| / max(|a|, |b|); 0 when equal (NaN equals NaN, like signs of inf are equal)."""
    if a == b or (math.isnan(a) and math.isnan(b)):
        return 0.0
    if math.isinf(a) or math.isinf(b) or math.isnan(a) or math.isnan(b):
        return math.inf
    return abs(a - b) / max(abs(a), abs(b))


def compare(committed, rerun, rel: float = REL, path: str = "") -> dict:
    """Walk two JSON values side by side.

    Returns
    -------
    dict
        ``numbers`` (how many compared), ``max_rel`` and ``max_rel_at`` (the largest relative
        difference of a number and its path), ``over`` ([path, committed, re-run, rel] of every
        number off by more than ``rel``), ``unequal`` ([path, what] of every other difference:
        a key missing on one side, a list length, a string, a flag, a type).
    """
    out = {"numbers": 0, "max_rel": 0.0, "max_rel_at": None, "over": [], "unequal": []}
    _walk(committed, rerun, rel, path or "$", out)
    return out


def _walk(a, b, rel: float, path: str, out: dict) -> None:
    if _number(a) and _number(b):
        r = relative_difference(float(a), float(b))
        out["numbers"] += 1
        if r > out["max_rel"]:
            out["max_rel"], out["max_rel_at"] = r, path
        if r > rel:
            out["over"].append([path, a, b, r])
    elif isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if _timing(k):
                continue
            if k not in a or k not in b:
                out["unequal"].append([f"{path}.{k}", "only in the "
                                       + ("re-run" if k not in a else "committed JSON")])
                continue
            if k in ARRIVAL_ORDER_KEYS and isinstance(a[k], list) and isinstance(b[k], list):
                _walk(sorted(a[k], key=str), sorted(b[k], key=str), rel, f"{path}.{k}(sorted)",
                      out)
                continue
            _walk(a[k], b[k], rel, f"{path}.{k}", out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out["unequal"].append([path, f"length {len(a)} committed, {len(b)} re-run"])
            return
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _walk(x, y, rel, f"{path}[{i}]", out)
    elif isinstance(a, str) and isinstance(b, str) and _untimed(a) == _untimed(b):
        return  # equal but for a wall time quoted in the text
    elif type(a) is not type(b) or a != b:
        what = "differs" if type(a) is type(b) else f"{type(a).__name__} vs {type(b).__name__}"
        out["unequal"].append([path, what])


def _masked(x):
    """``x`` with every run of digits in its texts replaced by ``#``."""
    if isinstance(x, dict):
        return {k: _masked(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_masked(v) for v in x]
    return _DIGITS.sub("#", x) if isinstance(x, str) else x


def compare_real_time(committed: dict, rerun: dict, strict: frozenset,
                      rel: float = REL) -> dict:
    """:func:`compare` of a real-time run (:data:`REAL_TIME_RUNS`): the ``strict`` keys as any
    run's; the rest must have the same keys, lengths, flags and texts (digits masked), its
    numbers go to ``real_time`` (how many, the largest relative difference and where) and
    are not judged. Its ``summary`` is not compared: it prints those numbers and words that
    follow them ("largest: x" or "y"; seen on a fresh clone's re-run of fault-tolerance-hil)."""
    def part(d, inside):
        return {k: v for k, v in d.items() if (k in strict) == inside
                and (inside or k != "summary")}
    out = compare(part(committed, True), part(rerun, True), rel)
    loose = compare(_masked(part(committed, False)), _masked(part(rerun, False)), math.inf)
    out["unequal"] += loose["unequal"]
    out["real_time"] = {k: loose[k] for k in ("numbers", "max_rel", "max_rel_at")}
    return out


def reproduced(result: dict) -> bool:
    return not result["over"] and not result["unequal"]


def report_line(name: str, result: dict) -> str:
    """One line per experiment: verdict, how many numbers, the largest relative difference."""
    verdict = "reproduced" if reproduced(result) else "NOT reproduced"
    line = (f"{name}: {verdict} — {result['numbers']} numbers, max relative difference "
            f"{result['max_rel']:.2g}" + (f" at {result['max_rel_at']}"
                                          if result["max_rel_at"] else ""))
    if result["over"]:
        line += f"; {len(result['over'])} over the tolerance, first " + ", ".join(
            f"{p} {a!r} -> {b!r}" for p, a, b, _ in result["over"][:3])
    if result["unequal"]:
        line += f"; {len(result['unequal'])} other differences, first " + ", ".join(
            f"{p} ({w})" for p, w in result["unequal"][:3])
    if "real_time" in result:
        rt = result["real_time"]
        line += (f"; measured in real time, not judged: {rt['numbers']} numbers, max relative "
                 f"difference {rt['max_rel']:.2g}"
                 + (f" at {rt['max_rel_at']}" if rt["max_rel_at"] else ""))
    return line


def run_command(name: str, out: Path, seed: int = 0) -> float:
    """``uvd experiment NAME --json OUT`` in a fresh process (the command RESULTS.md prints);
    returns its wall seconds."""
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "uvd", "experiment", name, "--json", str(out), "--quiet"]
    if seed:
        cmd += ["--seed", str(seed)]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    from uvd import experiments
    from uvd.experiments.results import ORDER
    ap = argparse.ArgumentParser(prog="python -m uvd.experiments.reproduce",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("names", nargs="*", metavar="NAME",
                    help="experiments to re-run (default: every one with a committed JSON)")
    ap.add_argument("--committed", type=Path, default=Path("docs/results"),
                    help="folder of the committed JSON (docs/results)")
    ap.add_argument("--against", type=Path, metavar="DIR",
                    help="do not run: compare the JSON already in DIR")
    ap.add_argument("--rel", type=float, default=REL, help="relative tolerance (1e-9)")
    args = ap.parse_args(argv)
    reg = experiments.registry()
    names = args.names or [n for n in [*ORDER, *sorted(set(reg) - set(ORDER))]
                           if n in reg and (args.committed / f"{n}.json").exists()]
    unknown = [n for n in names if n not in reg]
    if unknown:
        ap.error(f"unknown experiment(s) {unknown}; known: {sorted(reg)}")
    failed = 0
    with tempfile.TemporaryDirectory(prefix="uvd-reproduce-") as tmp:
        for name in names:
            committed = args.committed / f"{name}.json"
            if not committed.exists():
                print(f"{name}: no committed JSON at {committed}")
                failed += 1
                continue
            if args.against is not None:
                new, wall = args.against / f"{name}.json", None
            else:
                new = Path(tmp) / f"{name}.json"
                print(f"[reproduce] uvd experiment {name} --json {new}", file=sys.stderr,
                      flush=True)
                wall = run_command(name, new)
            a, b = json.loads(committed.read_text()), json.loads(new.read_text())
            result = (compare_real_time(a, b, REAL_TIME_RUNS[name], args.rel)
                      if name in REAL_TIME_RUNS else compare(a, b, args.rel))
            failed += not reproduced(result)
            print(report_line(name, result)
                  + (f" ({wall:.0f} s wall)" if wall is not None else ""), flush=True)
    if failed and args.against is None:
        print(_kernels_note(), flush=True)
    return 1 if failed else 0


def _kernels_note() -> str:
    """Which BLAS kernels the runs used against those the committed files were written with:
    runs that amplify rounding move with them (docs/experiments.md, Reproducibility)."""
    from uvd.blas import kernel_names
    here = kernel_names()
    if here == RESULTS_BLAS:
        return (f"the runs used the BLAS kernels docs/results/ was written with "
                f"({RESULTS_BLAS}): the difference is not theirs")
    return (f"the runs used the BLAS kernels {here or 'unknown'}; docs/results/ was "
            f"written with {RESULTS_BLAS}'s, and runs that amplify rounding move with them "
            f"(docs/experiments.md, Reproducibility). On a CPU with AVX2: "
            f"OPENBLAS_CORETYPE={RESULTS_BLAS} make results-check")


if __name__ == "__main__":
    raise SystemExit(main())
