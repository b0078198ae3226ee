"""``uvd demo`` and ``uvd bench loop`` report the CPU time the VM host took (steal), to tell a
host pause from a bug."""

from __future__ import annotations

import os

import pytest

from uvd.bench import host_steal_s
from uvd.commands.demo import _steal_summary


def test_steal_summary_finds_the_interval_the_host_paused_us():
    n = os.cpu_count() or 1
    # 1 s samples; in the third interval every CPU lost 0.6 s to the host
    samples = [(0.0, 10.0), (1.0, 10.0), (2.0, 10.0 + 0.01 * n), (3.0, 10.0 + 0.61 * n),
               (4.0, 10.0 + 0.61 * n)]
    s = _steal_summary(samples)
    assert s["total_s"] == pytest.approx(0.61 * n)
    assert s["max_share_per_interval"] == pytest.approx(0.6)
    assert s["interval_s"] == pytest.approx(1.0)
    assert _steal_summary(samples[:1]) is None


def test_steal_counter_is_read_and_never_decreases():
    a = host_steal_s()
    if a is None:
        pytest.skip("no /proc/stat steal field here")
    assert a >= 0.0 and host_steal_s() >= a


def test_steal_of_every_cpu_adds_up_to_the_total():
    cpus = sorted(os.sched_getaffinity(0))
    before = host_steal_s()
    if before is None:
        pytest.skip("no /proc/stat steal field here")
    per_cpu = [host_steal_s([c]) for c in range(os.cpu_count() or 1)]
    after = host_steal_s()
    assert all(x is not None and x >= 0.0 for x in per_cpu)
    # the counters move while they are read: within one tick per CPU of the total
    tick = 1.0 / os.sysconf("SC_CLK_TCK")
    assert before - len(per_cpu) * tick <= sum(per_cpu) <= after + len(per_cpu) * tick
    assert host_steal_s(cpus[:1]) <= after
    assert host_steal_s([10_000]) == 0.0  # a CPU the machine does not have: nothing stolen
