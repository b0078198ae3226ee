"""``uvd compile [--config FILE]``: compile the numeric kernels into their cache ahead of the
first start.

numba compiles uvd's kernels the first time they run and keeps them on disk
(:mod:`uvd._jitcache`). After an install, an upgrade or an edit of a kernel module, the first
start of the daemon compiles for tens of seconds to a minute (34 s on the CI machine), and so
do sim-bridge's and uvd-fdc's. This command does that work ahead, for one configuration:

* the daemon's warm-up: every mode of the core, with and without a thruster lost
  (:func:`uvd.runtime.startup.warm_up`);
* uvd-fdc's residual (:func:`uvd.fdc.residual.warm`);
* two simulated seconds of the configuration in lockstep: sim-bridge's plant and instruments,
  through the daemon's own cycle (:func:`uvd.commands.demo.lockstep_run`).

It fills the cache of the environment it runs in (:func:`uvd._jitcache.configure`) and says
where. For the systemd unit, run it with the service's user and ``CacheDirectory=``:
``sudo systemd-run -P -p User=uvd -p CacheDirectory=uvd /opt/uvd/.venv/bin/uvd compile
--config /etc/uvd/uvd.toml`` (docs/runtime.md). ``make test`` runs it beside the suite's
first tests.

Exit code 0 when every part compiled, 1 when one raised (named; the others still run), 2 when
the configuration is invalid.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

#: simulated seconds of lockstep: enough for every instrument's first sample and for arming
LOCKSTEP_S = 2.0


def register(sub) -> None:
    p = sub.add_parser("compile", help="compile the numeric kernels into their cache (once "
                                       "after an install or upgrade)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="configuration (default: the embedded config/sim.toml)")
    p.add_argument("--quiet", action="store_true", help="print only the summary line")
    p.set_defaults(handler=_run)


def kernel_files(cache: str | None) -> int:
    """How many compiled kernels (numba index files) ``cache`` holds (0: none or no cache)."""
    if not cache or not Path(cache).is_dir():
        return 0
    return sum(1 for _ in Path(cache).rglob("*.nbi"))


def _parts(cfg):
    """(name, callable) of every part, in order."""
    def daemon():
        from uvd.runtime.build import make_cycle, start_pose
        from uvd.runtime.startup import warm_up
        warm_up(make_cycle(cfg), start_pose(cfg)[0])

    def fdc():
        from uvd.fdc.residual import warm
        warm()

    def lockstep():
        from uvd.commands.demo import lockstep_run
        lockstep_run(cfg, LOCKSTEP_S, 0)

    return (("the daemon's cycle", daemon), ("uvd-fdc's residual", fdc),
            ("sim-bridge's plant and instruments", lockstep))


def compile_kernels(cfg, progress=print) -> tuple[list[tuple[str, float]], list[str]]:
    """Run every part (module docstring) on the validated configuration ``cfg``; returns
    ((name, seconds) of the parts done, "name: error" of those that raised)."""
    done, failed = [], []
    for name, part in _parts(cfg):
        t0 = time.perf_counter()
        try:
            part()
        except Exception as exc:  # one part's failure is told; the others still compile
            failed.append(f"{name}: {type(exc).__name__}: {exc}")
            continue
        done.append((name, time.perf_counter() - t0))
        progress(f"  {name}: {done[-1][1]:.1f} s")
    return done, failed


def _run(args) -> int:
    from uvd.commands import checked_config
    cfg = checked_config(args.config, "compile", "nothing compiled")
    if cfg is None:
        return 2
    cache = os.environ.get("NUMBA_CACHE_DIR")
    before, t0 = kernel_files(cache), time.perf_counter()
    if not args.quiet:
        print(f"uvd compile: the kernels of {cfg.source or 'the embedded configuration'} into "
              f"{cache or 'numba default place (beside the sources)'}")
    done, failed = compile_kernels(cfg, progress=(lambda _: None) if args.quiet else print)
    after = kernel_files(cache)
    print(f"uvd compile: {after} kernels in the cache ({after - before} new) in "
          f"{time.perf_counter() - t0:.1f} s" + (f"; {len(failed)} failed" if failed else ""))
    for line in failed:
        print(f"uvd compile: {line}", file=sys.stderr)
    return 1 if failed else 0
