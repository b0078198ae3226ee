"""``uvd compile`` (uvd/commands/compile.py): the kernels compiled ahead of the first start,
so that a second run — the daemon's start after it — compiles nothing."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from argparse import Namespace
from pathlib import Path

from uvd.commands import compile as compile_cmd

ROOT = Path(__file__).resolve().parents[1]


def _uvd(*args, cache: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    env.pop("UVD_NUMBA_CACHE_AUTO", None)  # the test's own place, not uvd's choice
    return subprocess.run([sys.executable, "-m", "uvd", "compile", *args], capture_output=True,
                          text=True, timeout=600, cwd=ROOT, env=env)


def test_an_empty_cache_is_filled_and_a_second_run_compiles_nothing(tmp_path):
    cache = tmp_path / "numba"
    first = _uvd(cache=cache)
    assert first.returncode == 0, first.stderr
    for part in ("the daemon's cycle", "uvd-fdc's residual", "sim-bridge's plant and"):
        assert part in first.stdout, first.stdout
    n, new = map(int, re.search(r"(\d+) kernels in the cache \((\d+) new\)",
                                first.stdout).groups())
    assert n == new == compile_cmd.kernel_files(str(cache)) and n >= 40, first.stdout
    second = _uvd("--quiet", cache=cache)
    assert second.returncode == 0, second.stderr
    assert f"{n} kernels in the cache (0 new)" in second.stdout, second.stdout
    print(first.stdout, second.stdout)


def test_a_wrong_configuration_compiles_nothing_and_names_the_key(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[loop]\nrate_hz = -1\n", encoding="utf-8")
    out = _uvd("--config", str(bad), cache=tmp_path / "numba")
    assert out.returncode == 2
    assert "invalid configuration, nothing compiled" in out.stderr and "rate_hz" in out.stderr
    assert compile_cmd.kernel_files(str(tmp_path / "numba")) == 0


def test_a_part_that_raises_is_named_and_the_others_still_run(monkeypatch, capsys):
    ran = []

    def broken():
        raise RuntimeError("no locator available")
    monkeypatch.setattr(compile_cmd, "_parts", lambda cfg: (
        ("first", broken), ("second", lambda: ran.append("second"))))
    assert compile_cmd._run(Namespace(config=None, quiet=False)) == 1
    out = capsys.readouterr()
    assert ran == ["second"] and "second:" in out.out and "1 failed" in out.out
    assert "uvd compile: first: RuntimeError: no locator available" in out.err
