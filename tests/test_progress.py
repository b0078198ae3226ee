"""The one progress helper of the long commands: a bar on a terminal, plain lines with an ETA
otherwise, nothing with --quiet."""

from __future__ import annotations

import io

from uvd.progress import Pace, Progress


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_plain_lines_every_interval_with_eta_when_not_a_terminal():
    out, clock = io.StringIO(), _Clock()
    p = Progress("replay", unit="cycles", stream=out, every_s=10.0, clock=clock)
    for k in range(1, 101):
        clock.t = k * 0.5  # 2 items a second: 50 s for 100
        p.update(k, 100)
    p.note("a stage")
    p.close()
    lines = out.getvalue().splitlines()
    assert lines[:-1] == [f"  replay: {k} / 100 cycles ({k} %, {k / 2:.0f} s elapsed, "
                          f"ETA {(100 - k) / 2:.0f} s)" for k in (20, 40, 60, 80, 100)]
    assert lines[-1] == "a stage"


def test_a_bar_on_a_terminal_and_a_new_run_starts_over():
    out = _Tty()
    with Progress("two-step", unit="s", stream=out) as p:
        p.update(50, 100, "step 1")
        p.note("between")
        p.update(10, 200, "step 2")  # a smaller count: the next run
        p.update(200, 200)
    text = out.getvalue()
    assert "step 1" in text and "step 2" in text and "between" in text
    assert "0/100" in text and "/200" in text


def test_quiet_is_silent():
    out = _Tty()
    p = Progress("x", quiet=True, stream=out)
    p.update(1, 2)
    p.note("nothing")
    p.close()
    assert out.getvalue() == ""


def test_the_time_left_is_the_recent_paces_so_a_slow_start_is_forgotten():
    """30 runs in the first hour (the machine shared), then one a minute: at 40 of 130 the
    time left is 90 minutes at the last ten minutes' pace, not the 158 the mean since the start
    gives; before ten minutes have passed the pace is the one since the start."""
    pace = Pace(0.0)
    for k in range(1, 31):
        pace.mark(k, 130, k * 120.0)
    for k in range(31, 40):
        pace.mark(k, 130, 3600.0 + (k - 30) * 60.0)
    assert pace.mark(40, 130, 4200.0) == 90 * 60.0
    young = Pace(0.0)
    assert young.mark(0, 10, 5.0) is None  # nothing done yet: nothing to go by
    assert young.mark(2, 10, 60.0) == 240.0
    assert young.mark(10, 10, 300.0) == 0.0 and young.mark(3, None, 301.0) is None
