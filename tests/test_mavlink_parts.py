"""The MAVLink link's parts without a network: keys changed through the schema, the parameter
table derived from it, the operator-loss trigger in the arbiter, the signing key file, the
custom modes and the parameters kept across a restart."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from uvd.links.mavlink.link import custom_mode_of
from uvd.links.mavlink.params import PARAMS, check_value, param_table, write_params_file
from uvd.links.mavlink.signing import SigningError, load_key, load_timestamp, save_timestamp
from uvd.runtime import schema
from uvd.runtime.config import DEFAULT_CONFIG, load_config
from uvd.runtime.cycle import CycleConfig
from uvd.runtime.daemon import kept_params
from uvd.runtime.failsafe import Action, Health, Thresholds
from uvd.runtime.schema import setting
from uvd.runtime.supervisor import Supervisor
from uvd.runtime.triggers import OPERATOR_AGE, operator_loss_trigger, plugin_triggers


def sim_config():
    return load_config(DEFAULT_CONFIG)


def test_with_values_validates_each_key_and_names_what_is_wrong():
    cfg = sim_config()
    new, err = schema.with_values(cfg, {"control.kp": 350.0, "failsafe.ins_stale_s": 0.2})
    assert not err and new.control.kp == 350.0 and new.failsafe.ins_stale_s == 0.2
    assert cfg.control.kp == 300.0  # the old one is untouched
    _, err = schema.with_values(cfg, {"control.kp": -1.0})
    assert err[0][0] == "control.kp" and "out of range" in err[0][1]
    _, err = schema.with_values(cfg, {"control.nope": 1.0})
    assert err == [("control.nope", "unknown key")]
    _, err = schema.with_values(cfg, {"control.eps": 2.0}, reload_only=True)
    assert "needs a restart" in err[0][1]
    new, err = schema.with_values(cfg, {"estimation.gains": (1.0, 2.0, 3.0, 4.0, 5.0)})
    assert not err and new.estimation.gains[4] == 5.0
    _, err = schema.with_values(cfg, {"estimation.gains": (0.0, 2.0, 3.0, 4.0, 5.0)})
    assert err and err[0][0] == "estimation.gains"  # the section's own check ran


@dataclass(frozen=True)
class VectorControl:  # kp as six per-axis values, as another branch is making it
    kp: tuple[float, ...] = setting((300.0,) * 6, min=0.0, reload=True)
    depth_sensor_stale_s: float = setting(1.0, reload=True)


@dataclass(frozen=True)
class VectorConfig:
    control: VectorControl = schema.section(VectorControl)


def test_parameters_come_from_the_schema_and_a_vector_becomes_per_axis_names():
    assert all(len(p.name) <= 16 for p in PARAMS)
    assert len({p.name for p in PARAMS}) == len(PARAMS)
    assert {"CTL_KP_1", "CTL_KD_6", "FS_INS_STALE_S", "EST_GAINS_1"} <= {p.name for p in PARAMS}
    kp = next(p for p in PARAMS if p.name == "CTL_KP_1")
    assert kp.reload and check_value(kp, -1.0) and check_value(kp, float("nan"))
    assert check_value(kp, 350.0) is None

    names = [p.name for p in param_table(VectorConfig)]
    assert names[:6] == [f"CTL_KP_{i}" for i in range(1, 7)]
    assert len(names[6]) <= 16 and names[6].startswith("CTL_")


def test_operator_loss_fires_after_the_timeout_with_the_configured_action_and_clears():
    sup = Supervisor(CycleConfig(None, Thresholds(clear_after_s=1.0),
                                 extra_triggers=(operator_loss_trigger(5.0, "hold-depth"),)))

    def step(t_s, age):
        d = sup.step(Health(t_ns=int(t_s * 1e9), extra={OPERATOR_AGE: age}))
        return [a for a in d.active if a.name == "operator_heartbeat_lost"]

    assert not step(0.0, None)  # never heard / disarmed: no signal
    assert not step(1.0, 5.0)
    act = step(1.1, 5.1)
    assert act and act[0].action is Action.HOLD_DEPTH and "5.1 s > 5 s" in act[0].reason
    assert step(1.5, 0.1)  # back, but the clear rule holds it for clear_after_s
    assert not step(2.6, 0.1)


def test_plugin_triggers_follow_the_configuration():
    cfg = sim_config()  # leak sensor and MAVLink on
    trig = plugin_triggers(cfg)
    assert [t.name for t in trig] == ["leak_sensor_fault", "operator_heartbeat_lost"]
    assert trig[1].action is Action.HOLD_DEPTH
    off, err = schema.with_values(cfg, {"mavlink.operator_timeout_s": 0.0})
    assert not err and [t.name for t in plugin_triggers(off)] == ["leak_sensor_fault"]


def test_the_signing_key_file_must_be_private_and_32_bytes(tmp_path):
    f = tmp_path / "key"
    f.write_bytes(bytes(range(32)))
    f.chmod(0o644)
    with pytest.raises(SigningError, match="0644.*chmod 600"):
        load_key(f)
    f.chmod(0o600)
    assert load_key(f) == bytes(range(32))
    f.write_text(bytes(range(32)).hex() + "\n")
    assert load_key(f) == bytes(range(32))
    f.write_text("abcd")
    with pytest.raises(SigningError, match="not a 32-byte key"):
        load_key(f)
    with pytest.raises(SigningError, match="missing"):
        load_key(tmp_path / "missing")


def test_the_signing_timestamp_file_is_whole_or_the_old_one(tmp_path, synced_paths):
    """The timestamp is kept as write_whole keeps a file: forced to the disk before it
    replaces the old one (a file lost to a power cut read 0), and a write that fails leaves
    the old value and no temporary file, with an error naming the file."""
    f = tmp_path / "signing.ts"
    save_timestamp(f, 123_456)
    assert load_timestamp(f) == 123_456
    assert synced_paths == [str(tmp_path / "signing.ts.tmp"), str(tmp_path)]
    (tmp_path / "signing.ts.tmp").symlink_to("/dev/full")  # a disk with no room
    with pytest.raises(OSError, match="cannot write the signing timestamp file .*signing.ts: "
                                      "No space left on device"):
        save_timestamp(f, 999)
    assert load_timestamp(f) == 123_456
    assert sorted(p.name for p in tmp_path.iterdir()) == ["signing.ts"]


def test_custom_mode_reports_the_operator_mode_and_what_the_cycle_applies():
    rec = {"operator_mode": "auto", "mode": "control", "state": "ARMED", "t_ns": 10**9,
           "armed_at_ns": 0}
    assert custom_mode_of(rec, "two-step-ambc", 5.0) == 1 | 3 << 8  # step 1
    assert custom_mode_of(rec, "two-step-ambc", 0.5) == 1 | 4 << 8  # step 2
    assert custom_mode_of(rec, "ambc", 0.0) == 1 | 2 << 8
    assert custom_mode_of({**rec, "state": "STANDBY"}, "pdc", 0.0) == 1
    assert custom_mode_of({**rec, "operator_mode": "observe", "mode": "zero"}, "pdc",
                          0.0) == 5 | 5 << 8
    assert custom_mode_of({**rec, "mode": "hold-depth"}, "pdc", 0.0) == 1 | 7 << 8


def test_kept_parameters_apply_at_start_and_a_bad_one_is_skipped(tmp_path, caplog):
    f = tmp_path / "params.toml"
    write_params_file(f, {"control.kp": 420.0, "control.kd": -3.0})
    cfg, applied = kept_params(sim_config(), str(f))
    assert cfg.control.kp == 420.0 and cfg.control.kd == 100.0
    assert applied == {"control.kp": 420.0}
    assert "control.kd" in caplog.text and "out of range" in caplog.text


def test_a_kept_parameters_file_that_does_not_read_is_named_and_nothing_applied(tmp_path,
                                                                               caplog):
    # found by probing (session 21): a folder was taken as "no parameters kept", silently;
    # the file is now read as every TOML file is (uvd.io.toml.read_toml)
    good = tmp_path / "params.toml"
    write_params_file(good, {"control.kp": 420.0, "control.kd": 90.0})
    cut = tmp_path / "cut.toml"
    cut.write_bytes(good.read_bytes()[:-15])  # a write cut short inside the last key
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b"[values]\n\xff\xfe")
    for f, what in [(tmp_path, "cannot read the parameters kept over MAVLink: Is a directory"),
                    (binary, "not a TOML file: not UTF-8 text (byte 0xff at offset 9)"),
                    (cut, "not valid TOML: Unterminated string (at end of document)")]:
        caplog.clear()
        cfg, applied = kept_params(sim_config(), str(f))
        assert applied == {} and cfg.control.kp == sim_config().control.kp
        assert f"{f}: {what} (parameters kept over MAVLink not applied)" in caplog.text
    assert kept_params(sim_config(), str(tmp_path / "none.toml"))[1] == {}  # none kept yet

def test_docs_mavlink_md_lists_the_parameters_generated_from_the_schema():
    from pathlib import Path

    from uvd.links.mavlink.params import refresh_doc
    doc = Path(__file__).resolve().parents[1] / "docs" / "mavlink.md"
    text = doc.read_text(encoding="utf-8")
    assert refresh_doc(text) == text, "run: uvd check-config --doc-out docs/config.md"
    assert "`CTL_KP_1`" in text and "| 4 | `manual` |" in text


def test_a_replay_applies_the_parameters_kept_at_start_on_top_of_the_recorded_file(tmp_path):
    from uvd.runtime.replay.lockstep import Recording, _config_of
    text = DEFAULT_CONFIG.read_text(encoding="utf-8")
    rec = Recording(tmp_path / "run.mcap", {"config_toml": text,
                                            "config_path": str(DEFAULT_CONFIG),
                                            "params_kept": {"control.kp": 420.0,
                                                            "estimation.gains": [1, 2, 3, 4,
                                                                                 5]}},
                    [], [], [], [], [])
    cfg, same = _config_of(rec, None)
    assert same and cfg.control.kp == 420.0 and cfg.estimation.gains == (1, 2, 3, 4, 5)


def test_operator_loss_in_lockstep_holds_depth_through_the_one_cycle():
    """The same plug-in trigger and cycle in lockstep: the station heard until 1 s after
    arming, then silent; with the sim's 5 s timeout the cycle holds depth from the first cycle
    past 6 s (no surge, sway or yaw thrust), and the event says why."""
    from uvd.lockstep import of_config
    from uvd.runtime import commands as cmd
    cfg = sim_config()
    sim = of_config(cfg, armed=False)
    sim.advance()
    assert sim.command(cmd.Arm()).ok
    t_arm = sim.t_ns
    fired = None
    for _ in range(80):  # 8 s at 10 Hz
        t = (sim.t_ns - t_arm) * 1e-9
        sim.extra = {OPERATOR_AGE: max(0.0, t - 1.0), "leak_sensor_fault": False}
        out = sim.advance()
        ev = [e for e in sim.last_result.decision.events if e.trigger == "operator_heartbeat_lost"]
        if ev and fired is None:
            fired = (t, ev[0].kind, out.mode)
    assert fired is not None and 6.0 < fired[0] <= 6.0 + 0.1 + 1e-9
    assert fired[1] == "fired" and fired[2] == "hold-depth"
    assert sim.last_result.decision.action is Action.HOLD_DEPTH
    u = sim.last_result.out.u_cmd
    assert u[0] == u[1] == u[5] == 0.0
