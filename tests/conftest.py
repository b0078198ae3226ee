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
import signal
from pathlib import Path

import pytest

# Tests press Ctrl-C on the commands they start (SIGINT to `uvd watch`, `uvd demo`…). A shell
# that runs the suite in the background (`make test &`, `nohup … &` in a script) starts it with
# SIGINT ignored, every child inherits that, and a Python started so never raises
# KeyboardInterrupt: the command runs on and the test times out (both `uvd watch` tests of
# tests/test_fdc.py, 20 s each). The children get the terminal's default back; the suite
# itself is then interruptible as usual.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

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
def synced_paths(monkeypatch) -> list[str]:
    """The paths ``os.fsync`` forces to the disk from now on, in order (the calls made: no
    test can cut the power)."""
    import os
    synced: list[str] = []
    real_fsync = os.fsync

    def fsync(fd):
        synced.append(os.readlink(f"/proc/self/fd/{fd}"))
        real_fsync(fd)
    monkeypatch.setattr(os, "fsync", fsync)
    return synced


@pytest.fixture
def shared_data():
    """``shared_data("bluerov-exjobb")``: the folder of unlicensed recordings, or a skip that
    names it (:func:`shared_recordings`)."""
    return shared_recordings


#: Modules whose tests run the daemon's loop, ``sim-bridge``, ``uvd demo`` or a link in real
#: time and bound what they see in wall-clock time (lateness, failsafe delays, heartbeats, a
#: datagram flood, bus rates), or load the machine on purpose (test_fdc's busy processes).
#: ``make test`` runs the suite on two xdist workers with ``--dist loadgroup``; these go to one
#: group, so they run one after another on one worker and never beside each other (the other
#: worker runs the rest). A new module of that kind belongs here. A test of such a module that
#: runs nothing in real time and bounds nothing in wall-clock time (a command refused before
#: it starts, a lockstep run) is marked ``untimed`` and runs on either worker: the group is
#: the suite's longest path.
REAL_TIME_GROUP = "real-time"
REAL_TIME_MODULES = frozenset(f"test_{name}" for name in (
    "amplifier_eta", "can_bench", "can_bus", "can_contract", "can_fuzz", "can_logging", "cli",
    "daemon_config", "daemon_estimation", "daemon_faults", "demo_failsafe", "demo_fault",
    "demo_spread", "demo_steal", "drivers_bench", "drivers_emulators", "drivers_transport",
    "eta_cli", "failsafe_scenario", "fdc", "fdc_zenoh", "hil_process", "ins_age", "leak_input",
    "links", "mavlink", "mavlink_link", "notify", "recording", "replay_realtime",
    "runtime_app", "runtime_bench", "runtime_lifecycle", "runtime_loop", "runtime_telemetry",
    "runtime_threads", "runtime_zero_thrust", "sensor_sync_hil", "sim_bridge_faults", "zenoh",
    "zenoh_bench", "zenoh_security",
))


#: Real-time modules that call (next to) no compiled kernel, measured one by one on an empty
#: kernel cache: the group runs them first (about 90 s), while ``make test``'s ``uvd compile``
#: fills the cache for the daemons and sim-bridges of the rest (45 s alone; they compiled
#: it themselves before, about a minute of the group's first HIL test).
REAL_TIME_FIRST = ("mavlink_link", "zenoh_bench", "can_contract", "notify", "can_fuzz",
                   "runtime_app", "can_bench", "zenoh_security", "can_bus", "runtime_threads",
                   "runtime_loop", "links", "drivers_transport")
assert {f"test_{name}" for name in REAL_TIME_FIRST} <= REAL_TIME_MODULES, "a typo?"


#: Modules that ``make test`` runs alone, after the two workers are done (marker ``serial``):
#: test_mavlink floods the link's UDP socket with 10 000 datagrams and counts ≥ 9 000 read; its
#: receiver process, descheduled by a CPU-bound test on the other worker, let the socket's
#: buffer overflow (4989 read, under -n 2 at load 2–3.5).
SERIAL_MODULES = frozenset({"test_mavlink"})


def _real_time(item) -> bool:
    return item.path.stem in REAL_TIME_MODULES and item.get_closest_marker("untimed") is None


@pytest.hookimpl(tryfirst=True)  # before xdist reads the groups (its own modifyitems)
def pytest_collection_modifyitems(items):
    """Put the tests of :data:`REAL_TIME_MODULES` (but those marked ``untimed``) in the xdist
    group :data:`REAL_TIME_GROUP`, those of :data:`REAL_TIME_FIRST` first, and mark those of
    :data:`SERIAL_MODULES` ``serial``."""
    first = {f"test_{name}" for name in REAL_TIME_FIRST}
    items.sort(key=lambda i: not (i.path.stem in first and _real_time(i)))  # stable
    for item in items:
        if _real_time(item):
            item.add_marker(pytest.mark.xdist_group(REAL_TIME_GROUP))
        if item.path.stem in SERIAL_MODULES:
            item.add_marker(pytest.mark.serial)


def pytest_collection_finish(session):
    """Under ``--dist loadgroup``, stop at once if xdist did not take the real-time group: the
    grouping lives in the node ids, and a pytest that changes how they are stored silently
    undoes it (pytest 9.2 with pytest-xdist 3.8, pytest-xdist#1386; pyproject.toml pins below)."""
    if not getattr(session.config.option, "loadgroup", False):  # set on xdist workers only
        return
    lost = [i.nodeid for i in session.items
            if _real_time(i) and not i.nodeid.endswith(f"@{REAL_TIME_GROUP}")]
    if lost:
        raise pytest.UsageError(f"--dist loadgroup: xdist did not group {len(lost)} real-time "
                                f"tests (e.g. {lost[0]}); see tests/conftest.py")
