"""The skip helper for recordings that cannot live in the repository names the missing folder."""

from __future__ import annotations

import conftest
import pytest


def test_a_missing_folder_skips_by_name(monkeypatch, tmp_path):
    monkeypatch.setattr(conftest, "SHARED_DATA", tmp_path)
    with pytest.raises(pytest.skip.Exception, match=r"recordings bluerov-exjobb/ not found"):
        conftest.shared_recordings("bluerov-exjobb")


def test_a_present_folder_is_returned(monkeypatch, tmp_path):
    (tmp_path / "bluerov-exjobb").mkdir()
    monkeypatch.setattr(conftest, "SHARED_DATA", tmp_path)
    assert conftest.shared_recordings("bluerov-exjobb") == tmp_path / "bluerov-exjobb"


def test_licensed_recordings_are_in_the_repository():
    from driver_strategies import DATA
    for rel in ("pd0/adcp_auv_51.pd0", "phins/log_STDBIN_V3.log", "ardusub/small.tlog",
                "pd0/NOTICE", "phins/NOTICE", "ardusub/NOTICE"):
        assert (DATA / rel).is_file(), rel
