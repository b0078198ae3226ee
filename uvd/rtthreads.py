"""Scheduling of *every* thread of a real-time process, not only the loop's.

Why: the control loop runs Python code, so it needs the GIL. When another thread of the same
process holds the GIL (the logging listener formatting a record, a telemetry sink encoding a
batch, python-can's receive thread decoding a frame, an executor worker) and that thread is
scheduled normally (``SCHED_OTHER``), any normally scheduled process of the machine can
preempt it *while it holds the GIL*: the ``SCHED_FIFO`` loop then waits for the GIL for as long
as the kernel keeps the holder off the CPU — with four CPU hogs on two CPUs, tens of ms
(priority inversion through the GIL; ``sys.setswitchinterval`` only helps once the holder runs
again). A thread inherits its creator's policy only when created *after* the policy was set,
so the threads started before :func:`uvd.runtime.loop.apply_realtime` (the logging listener,
numpy's and scipy's OpenBLAS workers, anything a library started at import) keep
``SCHED_OTHER``.

Policy (:func:`promote_threads`): every thread of the process other than the loop's runs at
``SCHED_FIFO`` one priority below the loop (``helper``), on the loop's CPU set when one is
configured. The loop still preempts any helper at once; a helper holding the GIL is preempted
only by the loop itself (which then blocks on the GIL and lets it finish, within the switch
interval) or by higher real-time priorities — never by the machine's normal load. The policy
is applied by thread id (``sched_setscheduler`` and ``sched_setaffinity`` act on one thread on
Linux) to the threads that exist, and threads created later inherit it from their creator
(worker pools get :func:`helper_initializer`). :func:`restore_threads` puts back what was
changed (a daemon run inside a test process).

Never raises: a refusal becomes a message (``CAP_SYS_NICE``, ``LimitRTPRIO=``).
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

__all__ = ["ThreadInfo", "ThreadPolicyReport", "thread_table", "promote_threads",
           "restore_threads", "helper_initializer", "POLICY_NAMES"]

POLICY_NAMES = {0: "SCHED_OTHER", 1: "SCHED_FIFO", 2: "SCHED_RR", 3: "SCHED_BATCH",
                5: "SCHED_IDLE", 6: "SCHED_DEADLINE"}


@dataclass(frozen=True)
class ThreadInfo:
    """One thread of a process, as ``/proc/PID/task/TID`` shows it."""

    tid: int
    name: str
    policy: str
    priority: int
    cpus: tuple[int, ...]

    def as_dict(self) -> dict[str, Any]:
        return {"tid": self.tid, "name": self.name, "policy": self.policy,
                "priority": self.priority, "cpus": list(self.cpus)}


def _python_names() -> dict[int, str]:
    return {t.native_id: t.name for t in threading.enumerate() if t.native_id is not None}


def _task_ids(pid: int | str = "self") -> list[int]:
    try:
        return sorted(int(t) for t in os.listdir(f"/proc/{pid}/task"))
    except OSError:
        return []


def thread_info(tid: int, pid: int | str = "self", names: dict[int, str] | None = None
                ) -> ThreadInfo | None:
    """Policy, real-time priority and CPUs of one thread (None when it has ended)."""
    try:
        with open(f"/proc/{pid}/task/{tid}/stat", encoding="ascii", errors="replace") as f:
            stat = f.read()
        with open(f"/proc/{pid}/task/{tid}/comm", encoding="utf-8", errors="replace") as f:
            comm = f.read().strip()
    except OSError:
        return None
    rest = stat[stat.rfind(")") + 2:].split()  # fields 3.. (comm may hold spaces)
    rt_priority, policy = int(rest[40 - 3]), int(rest[41 - 3])
    try:
        cpus = tuple(sorted(os.sched_getaffinity(tid)))
    except OSError:
        cpus = ()
    name = (names or {}).get(tid)
    if name is None:
        name = f"{comm} (native)" if pid == "self" else comm
    return ThreadInfo(tid, name, POLICY_NAMES.get(policy, str(policy)), rt_priority, cpus)


def thread_table(pid: int | str = "self") -> list[ThreadInfo]:
    """Every thread of the process ``pid`` (this one by default), with its scheduling.

    Threads of this process are named after their :mod:`threading` name when they have one;
    the others (OpenBLAS workers, threads of C extensions) are marked ``(native)``.
    """
    names = _python_names() if pid == "self" else {}
    out = []
    for tid in _task_ids(pid):
        info = thread_info(tid, pid, names)
        if info is not None:
            out.append(info)
    return out


@dataclass
class ThreadPolicyReport:
    """What :func:`promote_threads` did (accumulates over several calls)."""

    helper_priority: int = 0
    cpus: tuple[int, ...] = ()
    changed: dict[int, tuple[int, int, tuple[int, ...]]] = field(default_factory=dict)
    messages: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.messages


def _sched_of(tid: int) -> tuple[int, int, tuple[int, ...]]:
    return (os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority,
            tuple(sorted(os.sched_getaffinity(tid))))


def promote_threads(helper_priority: int, cpus: Sequence[int] = (), *,
                    exclude: Iterable[int] = (),
                    report: ThreadPolicyReport | None = None) -> ThreadPolicyReport:
    """Put every thread of this process except ``exclude`` at SCHED_FIFO ``helper_priority``.

    With ``cpus``, the threads are also confined to those CPUs (the loop's set: a helper
    holding the GIL on another CPU could be preempted there by other real-time work). Threads
    already at exactly that policy, priority and CPU set are left alone. The previous
    scheduling of every changed thread is remembered in the report for
    :func:`restore_threads`. Never raises.
    """
    rep = report if report is not None else ThreadPolicyReport()
    rep.helper_priority = int(helper_priority)
    want_cpus = tuple(sorted(set(int(c) for c in cpus)))
    rep.cpus = want_cpus
    if helper_priority <= 0:
        return rep
    skip = set(exclude)
    refused: list[str] = []
    for tid in _task_ids():
        if tid in skip:
            continue
        try:
            before = _sched_of(tid)
        except OSError:  # ended meanwhile
            continue
        pol, prio, aff = before
        try:
            if want_cpus and aff != want_cpus:
                os.sched_setaffinity(tid, want_cpus)
            if pol != os.SCHED_FIFO or prio != helper_priority:
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(helper_priority))
        except ProcessLookupError:
            continue
        except OSError as exc:
            refused.append(f"{tid}: {exc.strerror or exc}")
            continue
        finally:
            if tid not in rep.changed:
                with contextlib.suppress(OSError):
                    if _sched_of(tid) != before:
                        rep.changed[tid] = before
    if refused:
        rep.messages.append(
            f"helper threads not moved to SCHED_FIFO {helper_priority} (threads "
            f"{', '.join(refused)}): they can hold the GIL while normal load preempts "
            "them, delaying the loop. Grant "
            "CAP_SYS_NICE or LimitRTPRIO= (docs/runtime.md)")
    return rep


def restore_threads(report: ThreadPolicyReport) -> int:
    """Give every thread :func:`promote_threads` changed its previous scheduling back.

    Returns how many threads were restored (ended threads are skipped). Never raises.
    """
    n = 0
    ours = set(_task_ids())  # an ended thread's id may since belong to another process
    for tid, (pol, prio, aff) in list(report.changed.items()):
        if tid not in ours:
            report.changed.pop(tid, None)
            continue
        try:
            os.sched_setscheduler(tid, pol, os.sched_param(prio))
            os.sched_setaffinity(tid, aff)
            n += 1
        except OSError:
            pass
        report.changed.pop(tid, None)
    return n


def helper_initializer(priority_of: Any) -> Any:
    """A worker-pool initializer putting each new worker at ``priority_of()`` (SCHED_FIFO),
    or at normal scheduling when it returns 0 (real time not asked for or refused)."""

    def init() -> None:
        prio = int(priority_of() or 0)
        with contextlib.suppress(OSError, AttributeError):
            if prio > 0:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
            elif os.sched_getscheduler(0) != os.SCHED_OTHER:
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return init
