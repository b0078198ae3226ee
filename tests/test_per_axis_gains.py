"""Per-axis gains: ``[control]`` kp, kd, gamma_m, gamma_d take one number or six (surge, sway,
heave, roll, pitch, yaw), are validated at load with the key named, reach the controllers as
(6,) vectors, and change on reload where the scalar did."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from uvd.control.ambc import adaptation_gains as ambc_gains
from uvd.runtime.build import build_core, pd_gains
from uvd.runtime.config import ConfigValidationError, load_config
from uvd.runtime.schema import describe, reloadable_changes

ROOT = Path(__file__).resolve().parents[1]
SIM = (ROOT / "config" / "sim.toml").read_text()


def config_with(tmp_path, old: str, new: str):
    assert old in SIM
    path = tmp_path / "uvd.toml"
    path.write_text(SIM.replace(old, new))
    return load_config(path)


def errors(tmp_path, old: str, new: str) -> dict[str, str]:
    with pytest.raises(ConfigValidationError) as exc:
        config_with(tmp_path, old, new)
    return dict(exc.value.errors)


def test_six_values_reach_every_controller_as_vectors(tmp_path):
    kp = (20.0, 21.0, 22.0, 3.0, 4.0, 5.0)
    cfg = config_with(tmp_path, "kp = 300.0\nkd = 100.0",
                      "kp = [20, 21, 22, 3, 4, 5]\nkd = 10.0\n"
                      "gamma_m = [1, 2, 3, 0.01, 0.02, 0.03]")
    assert cfg.control.kp == kp and cfg.control.kd == 10.0
    np.testing.assert_array_equal(pd_gains(cfg)._kp, kp)
    np.testing.assert_array_equal(pd_gains(cfg)._kd, np.full(6, 10.0))
    core = build_core(cfg, estimators=())       # two-step AMBC (config/sim.toml)
    step2 = core.controller.params.step2
    np.testing.assert_array_equal(step2._c[1], kp)
    # γ_m per DOF in step 2's K_θ, γ_d, γ_g, γ_b at the thesis's values
    np.testing.assert_array_equal(step2.K[:6], [1, 2, 3, 0.01, 0.02, 0.03])
    np.testing.assert_array_equal(step2.K[6:12], np.full(6, 5000.0))
    np.testing.assert_array_equal(core.pd._kp, kp)   # the PDC and hold-depth modes too


def test_the_defaults_are_the_thesis_scalars(tmp_path):
    cfg = load_config(ROOT / "config" / "sim.toml")
    c = cfg.control
    assert (c.kp, c.kd, c.gamma_m, c.gamma_d, c.gamma_g, c.gamma_b) == \
        (300.0, 100.0, 1000.0, 5000.0, 0.5, (0.5, 0.5, 10.0))
    K = build_core(cfg, estimators=()).controller.params.step2.K
    ref = ambc_gains("decoupled")
    ref[12:] = 0.0                        # step 2 holds g, b
    np.testing.assert_array_equal(K, ref)


@pytest.mark.parametrize("new,key,words", [
    ("kp = [1, 2, 3]", "control.kp", "expected one number or 6 (surge, sway, heave, roll, "
                                     "pitch, yaw), got 3 values"),
    ("kp = [1, 2, 3, 4, 5, -6]", "control.kp[5]", "out of range"),
    ("kp = [1, 2, 3, 4, 5, inf]", "control.kp[5]", "expected a finite number, got inf"),
    ("kp = [1, 2, 3, 4, 5, nan]", "control.kp[5]", "expected a finite number, got nan"),
    ("kp = [1, 2, 3, 4, 5, \"x\"]", "control.kp[5]", "expected a number"),
    ("kp = inf", "control.kp", "expected a finite number, got inf"),
    ("kp = \"high\"", "control.kp", "expected a number"),
])
def test_bad_gains_are_refused_naming_the_key(tmp_path, new, key, words):
    errs = errors(tmp_path, "kp = 300.0", new)
    assert key in errs, errs
    assert words in errs[key]


def test_mass_floor_reaches_the_robust_projection(tmp_path):
    floor = "mass_floor = [2, 2, 3, 0.04, 0.03, 0.05]"
    cfg = config_with(tmp_path, "kp = 300.0", "kp = 300.0\n" + floor)
    step2 = build_core(cfg, estimators=()).controller.params.step2
    np.testing.assert_array_equal(step2._c[3], [2, 2, 3, 0.04, 0.03, 0.05])
    default = build_core(load_config(ROOT / "config" / "sim.toml"), estimators=())
    np.testing.assert_array_equal(default.controller.params.step2._c[3], np.full(6, 10.0))
    assert "control.mass_floor[1]" in errors(tmp_path, "kp = 300.0",
                                             "mass_floor = [1, 0, 1, 1, 1, 1]")


def test_full_model_takes_one_mass_and_drag_gain(tmp_path):
    errs = errors(tmp_path, 'model = "decoupled"',
                  'model = "full"\ngamma_d = [1, 1, 1, 1, 1, 2]')
    assert "six values need model = \"decoupled\"" in errs["control.gamma_d"]


def test_per_axis_gains_reload_where_the_scalar_did(tmp_path):
    old = load_config(ROOT / "config" / "sim.toml")
    new = config_with(tmp_path, "kp = 300.0", "kp = [300, 300, 300, 30, 30, 30]")
    merged, applied, refused = reloadable_changes(old, new)
    assert applied == ["control.kp"] and refused == []
    assert merged.control.kp == (300.0, 300.0, 300.0, 30.0, 30.0, 30.0)
    np.testing.assert_array_equal(pd_gains(merged)._kp, [300, 300, 300, 30, 30, 30])


def test_reference_names_the_per_axis_type():
    keys = {k.key: k for _, _, ks in describe(type(load_config(ROOT / "config" / "sim.toml")))
            for k in ks}
    for name in ("kp", "kd", "gamma_m", "gamma_d"):
        k = keys[f"control.{name}"]
        assert k.type == "number or list of 6 numbers" and k.reload
