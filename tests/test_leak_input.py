"""The leak input ([sensors.leak], uvd.runtime.leak): reading, debounce, faults, config."""

from __future__ import annotations

import asyncio
import tomllib
from pathlib import Path

import pytest

from uvd.runtime.config import ConfigValidationError, parse_config
from uvd.runtime.cycle import CycleConfig
from uvd.runtime.failsafe import Action, Health
from uvd.runtime.leak import LeakInput, LeakSection, leak_sensor_fault_trigger, read_level
from uvd.runtime.supervisor import Supervisor

ROOT = Path(__file__).resolve().parents[1]
S = 1_000_000_000


class Clock:
    t = 0

    def __call__(self) -> int:
        return self.t


def make(tmp_path, level="0", **kw):
    p = tmp_path / "value"
    p.write_text(level + "\n")
    clock = Clock()
    return p, clock, LeakInput(LeakSection(enabled=True, path=str(p), **kw), clock=clock)


def test_active_high_and_low_and_debounce(tmp_path):
    p, clock, li = make(tmp_path, confirm_samples=2)
    li.poll_once()
    assert li.health(0) == (False, None)
    p.write_text("1\n")
    li.poll_once()
    assert li.health(0) == (False, None)  # one reading is not enough
    li.poll_once()
    assert li.health(0) == (True, None)
    p.write_text("0")
    li.poll_once()
    assert li.health(0) == (False, None)
    p2, _, low = make(tmp_path / "low" if (tmp_path / "low").mkdir() is None else None,
                      level="0", active_level=0)
    low.poll_once()
    assert low.health(0)[0] is True


def test_unreadable_garbage_and_stale_input_are_faults_not_leaks(tmp_path):
    p, clock, li = make(tmp_path, stale_s=0.5)
    li.poll_once()
    p.write_text("x7")
    li.poll_once()
    leak, err = li.health(0)
    assert not leak and "expected 0 or 1" in err and str(p) in err
    p.unlink()
    li.poll_once()
    assert "No such file" in li.health(0)[1]
    p.write_text("0")
    li.poll_once()
    assert li.health(0) == (False, None)
    clock.t = int(0.6 * S)  # the poller stopped reading
    assert "no reading for 0.60 s" in li.health(clock.t)[1]
    assert li.counters["errors"] == 2


def test_start_fails_naming_the_path_and_polls_in_its_own_thread(tmp_path):
    li = LeakInput(LeakSection(enabled=True, path=str(tmp_path / "missing")))
    with pytest.raises(OSError, match="missing"):
        asyncio.run(li.start())
    p = tmp_path / "v"
    p.write_text("0")
    li = LeakInput(LeakSection(enabled=True, path=str(p), poll_interval_s=0.01))

    async def main():
        await li.start()
        p.write_text("1")
        for _ in range(200):
            if li.health(0)[0]:
                break
            await asyncio.sleep(0.01)
        await li.stop()
    asyncio.run(main())
    assert li.health(0)[0] and li._thread.name == "uvd-leak"
    assert read_level(str(p)) == 1


def test_the_leak_disarms_and_latches_and_the_sensor_fault_warns():
    sup = Supervisor(CycleConfig(None, extra_triggers=(leak_sensor_fault_trigger(),)))
    ok = dict(ins_age_s=0.01, dvl_age_s=0.01, depth_age_s=0.01, bottom_lock=True,
              amplifiers_enabled=True, feedback_age_s=0.01)
    d = sup.step(Health(t_ns=S, depth_m=1.0, leak=False,
                        extra={"leak_sensor_fault": "gone"}, **ok))
    assert d.action is Action.WARN and "leak_sensor_fault: gone" in d.causes
    d = sup.step(Health(t_ns=2 * S, depth_m=1.1, leak=True,
                        extra={"leak_sensor_fault": None}, **ok))
    assert d.action is Action.DISARM and "leak: leak detected" in d.causes


def _sim():
    return tomllib.loads((ROOT / "config" / "sim.toml").read_text())


@pytest.mark.parametrize("leak,key", [
    ({"enabled": True, "path": None}, "sensors.leak.path"),
    ({"enabled": True, "path": "relative/value"}, "sensors.leak.path"),
    ({"enabled": True, "path": "/x", "active_level": 2}, "sensors.leak.active_level"),
    ({"enabled": True, "path": "/x", "poll_interval_s": 0.5, "stale_s": 0.2},
     "sensors.leak.stale_s"),
    ({"enabled": True, "path": "/x", "confirm_samples": 0}, "sensors.leak.confirm_samples"),
    ({"enabled": "yes", "path": "/x"}, "sensors.leak.enabled"),
    ({"enabled": True, "path": "/x", "pin": 4}, "sensors.leak.pin"),
])
def test_config_errors_name_the_key(leak, key):
    data = _sim()
    data["sensors"]["leak"] = {k: v for k, v in leak.items() if v is not None}
    with pytest.raises(ConfigValidationError) as ei:
        parse_config(data, source="f.toml")
    assert f"f.toml: {key}:" in str(ei.value)


def test_absent_means_no_leak_sensor():
    data = _sim()
    del data["sensors"]["leak"]
    assert parse_config(data).sensors.leak.enabled is False
    assert Health().leak is None  # the trigger never fires without a sensor
