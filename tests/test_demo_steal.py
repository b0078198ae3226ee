"""``uvd demo`` reports the CPU time the VM host took (steal), to tell a host pause from a bug."""

from __future__ import annotations

import os

import pytest

from uvd.commands.demo import _steal_s, _steal_summary


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
    a = _steal_s()
    if a is None:
        pytest.skip("no /proc/stat steal field here")
    assert a >= 0.0 and _steal_s() >= a
