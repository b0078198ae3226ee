"""Run a campaign on Dask — the only scheduler: a ``LocalCluster`` of worker processes (one
thread each: a lockstep run holds the GIL) or the scheduler of a lab's cluster
(``tcp://HOST:PORT``, e.g. one that dask-jobqueue started on an HPC queue). Each run not yet in
the :class:`~uvd.campaign.store.RowStore` is one task; its row is written as soon as it
completes, so Ctrl-C, a lost worker or a crash loses at most the runs under way.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from uvd.campaign.spec import CampaignError, CampaignSpec
from uvd.campaign.store import RowStore, code_version, make_row, run_key
from uvd.cliargs import machine_cores


@dataclass
class CampaignOutcome:
    """What one invocation did: runs in the campaign, found done, run now (of which failed),
    the wall time and the table written."""

    total: int
    skipped: int
    ran: int
    failed: int
    wall_s: float
    table: Path | None
    workers: int


def default_workers() -> int:
    """The machine's cores (those this process may run on)."""
    return machine_cores()


#: where a local cluster's scheduler, workers and dashboard listen
LOOPBACK = "127.0.0.1"


#: seconds a campaign waits for a scheduler to answer, and then for its first worker
CONNECT_S = 30.0
WORKER_WAIT_S = 60.0


def _client(workers: int, scheduler: str | None, worker_wait_s: float = WORKER_WAIT_S):
    from dask.distributed import Client, LocalCluster
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=CONNECT_S)
        except (OSError, ValueError, TypeError) as exc:   # unreachable, or not an address
            raise CampaignError(f"scheduler {scheduler!r}: cannot connect: {exc}") from None
        try:   # a lab's scheduler whose workers have not joined (yet): say so, do not hang
            client.wait_for_workers(1, timeout=worker_wait_s)
        except TimeoutError:
            client.close()
            raise CampaignError(f"scheduler {scheduler!r}: no worker joined in "
                                f"{worker_wait_s:g} s; nothing was run") from None
        return client, None
    # loopback only; the dashboard on a free port (None does not switch it off, and 8787 may
    # be another cluster's: distributed then warns and takes another anyway)
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           host=LOOPBACK, dashboard_address=f"{LOOPBACK}:0", silence_logs=40,
                           preload=[__name__])  # dask_setup/teardown below, in each worker
    return Client(cluster), cluster


def _close(client, cluster) -> None:
    """Close the client, then the local cluster, with Dask's own logging quiet below
    CRITICAL meanwhile (in this process, the local cluster's scheduler's). Closed on Ctrl-C
    with runs under way, its scheduler logged their results it could no longer gather
    ("Couldn't gather keys … forgotten", an ERROR); the campaign has every row it finished,
    and says that it was interrupted."""
    import logging
    import signal
    import threading
    log = logging.getLogger("distributed")
    level = log.level
    log.setLevel(logging.CRITICAL)
    # a second Ctrl-C (an impatient operator) broke off the close it lands in, and the
    # campaign then ended 10.5 s after the first instead of 1.9 s: the close, bounded, ends
    main = threading.current_thread() is threading.main_thread()
    handler = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    try:
        client.close()
        if cluster is not None:
            cluster.close()
    finally:
        log.setLevel(level)
        if main:
            signal.signal(signal.SIGINT, handler)


def dask_setup(worker) -> None:
    """Run by Dask in each worker process of a local cluster as it starts (``preload``): the
    worker ignores SIGINT. Ctrl-C in the terminal reaches the whole process group; the
    campaign, interrupted, closes its cluster, which ends the workers. Before (session 32)
    each worker died of the Ctrl-C itself and printed two tracebacks (CancelledError, then
    KeyboardInterrupt) above the campaign's "interrupted"."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def dask_teardown(worker) -> None:
    """Run by Dask as a local cluster's worker begins to close: from then on it logs nothing
    below CRITICAL. A worker closed while its thread computes a run (the campaign
    interrupted) often had a heartbeat under way when it closed its own connections, and
    logged that as an ERROR with a 30-line traceback ("Failed to communicate with scheduler
    during heartbeat", measured in 1 of 2 interruptions); a closing worker has nothing left to
    tell the campaign, which has every row it finished and counts the others as not run."""
    import logging
    logging.getLogger("distributed").setLevel(logging.CRITICAL)


def run_campaign(spec: CampaignSpec, directory: str | Path, *, workers: int | None = None,
                 scheduler: str | None = None,
                 on_row: Callable[[dict, int, int], None] | None = None,
                 limit: int | None = None,
                 worker_wait_s: float = WORKER_WAIT_S) -> CampaignOutcome:
    """Run every run of ``spec`` not already stored in ``directory``; ``on_row(row, done,
    todo)`` after each row is written (progress); ``limit`` runs at most that many now (a
    test's partial campaign). A ``scheduler`` that cannot be reached, or that has no worker
    within ``worker_wait_s``, is a :class:`CampaignError` before any run. Returns what was
    done; ``directory/runs.parquet`` holds the rows of the campaign stored so far, in run
    order."""
    from dask.distributed import as_completed

    from uvd.campaign.runs import execute

    t0 = time.perf_counter()
    store = RowStore(directory)
    version = code_version()
    keys = [run_key(spec.kind, inputs, version) for inputs in spec.runs]
    done = store.done()
    todo = [i for i, k in enumerate(keys) if k not in done]
    if limit is not None:
        todo = todo[:limit]
    skipped = sum(1 for k in keys if k in done)
    ran = failed = 0
    n_workers = 0
    if todo:
        client, cluster = _client(workers or default_workers(), scheduler, worker_wait_s)
        try:
            n_workers = len(client.scheduler_info()["workers"])
            futures = {client.submit(execute, spec.kind, spec.runs[i], key=f"run-{keys[i]}",
                                     pure=False): i for i in todo}
            for fut in as_completed(futures):
                i = futures[fut]
                try:
                    result = fut.result()
                except Exception as exc:  # the task itself was lost (a worker died)
                    result = {"figures": {}, "error": f"{type(exc).__name__}: {exc}",
                              "wall_s": float("nan"), "worker": "lost"}
                row = make_row(spec.name, spec.kind, i, keys[i], version, spec.runs[i], result)
                store.write(row)
                ran += 1
                failed += row["error"] is not None
                if on_row is not None:
                    on_row(row, ran, len(todo))
        finally:
            _close(client, cluster)
    have = store.done()
    table = store.write_table([k for k in keys if k in have]) if have else None
    return CampaignOutcome(total=len(keys), skipped=skipped, ran=ran, failed=failed,
                           wall_s=time.perf_counter() - t0, table=table, workers=n_workers)
