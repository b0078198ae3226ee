"""``uvd bench lockstep``: each side's run is a child process (this checkout's and an older
commit's ``uvd experiment``). A run that fails is the bench's one-line error naming the side
and the child's last words — found by probing (session 33): ``--hours 1e9`` ended in
CalledProcessError's traceback beneath the child's numpy _ArrayMemoryError traceback."""

from __future__ import annotations

import pytest

from uvd.bench.lockstep import ROOT, _one
from uvd.errors import ExperimentError


def test_a_side_that_fails_is_named_with_its_last_words(tmp_path):
    with pytest.raises(ExperimentError) as err:
        _one(ROOT, "ambc-robust", 1e9, tmp_path / "x.json", "this checkout")
    text = str(err.value)
    assert text.startswith("this checkout: uvd experiment ambc-robust --hours 1e+09 ended "
                           "with exit code 1: uvd experiment: error: out of memory"), text
    assert "Traceback" not in text


def test_a_run_that_succeeds_gives_its_cpu_and_wall_seconds(tmp_path):
    cpu, wall = _one(ROOT, "ambc-robust", 0.01, tmp_path / "x.json", "this checkout")
    assert 0.0 < cpu and 0.0 < wall < 120.0
    assert (tmp_path / "x.json").read_text().startswith("{")
