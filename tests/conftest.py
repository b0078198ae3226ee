"""Fixtures shared by every test module.

Real recordings come in two kinds:

* those whose licence lets them live in the repository are copied into ``tests/data/``
  (sources and licences: ``tests/data/README.md``) and read from there
  (``driver_strategies.DATA``);
* those without a licence stay outside it, in ``../shared/data/<folder>`` beside the checkout
  (or in the folder ``$UVD_SHARED_DATA`` names). A test that needs one asks for it with the
  ``shared_data`` fixture, which skips the test *naming the missing folder* when it is not
  there — a clone of the repository alone runs every other test (CI has the folder).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: recordings outside the repository (no licence to copy them in): ../shared/data/
SHARED_DATA = Path(os.environ.get("UVD_SHARED_DATA", ROOT.parent / "shared" / "data"))


def shared_recordings(folder: str) -> Path:
    """``SHARED_DATA/folder``, or skip the calling test naming the folder that is missing."""
    path = SHARED_DATA / folder
    if not path.is_dir():
        pytest.skip(f"recordings {folder}/ not found at {path} (no licence to copy them into "
                    f"the repository; set UVD_SHARED_DATA or put ../shared/data beside the "
                    f"checkout)")
    return path


@pytest.fixture
def shared_data():
    """``shared_data("bluerov-exjobb")``: the folder of unlicensed recordings, or a skip that
    names it (:func:`shared_recordings`)."""
    return shared_recordings
