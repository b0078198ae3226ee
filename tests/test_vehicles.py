"""Built-in vehicles: values of the thesis's tables, physical validity, actuation."""

from pathlib import Path

import numpy as np
import pytest

from uvd.errors import ConfigError
from uvd.io.vehicle import builtin_vehicles, load_vehicle


def test_builtins_exist():
    assert {"jhu-rov", "jhu-rov-coupled"} <= set(builtin_vehicles())


def test_jhu_rov_is_tables_5_4_and_5_5():
    p = load_vehicle("jhu-rov").params
    np.testing.assert_array_equal(p.decoupled_view(), [
        628, 791, 1043, 95.7, 145.3, 110.2, -1259, -1429, -3083, -727.1, -783.4, -465.6,
        3.59, 1.696, 3.09, 300])
    assert p.is_decoupled()


def test_jhu_rov_coupled_is_tables_4_8_and_4_9_and_physical():
    p = load_vehicle("jhu-rov-coupled").params
    assert p.M[0, 0] == 996.9 and p.M[5, 5] == 467.4 and p.M[0, 5] == 111.7
    assert p.g == -21.77
    np.testing.assert_array_equal(p.b, [5.966, -0.9802, 342.8])
    assert p.D[0][0, 0] == -466.7 and p.D[0][0, 5] == -3.236 and p.D[0][1, 0] == 71.43
    assert p.D[5][5, 5] == -109.2
    np.testing.assert_array_equal(p.M, p.M.T)
    assert p.mass_min_eigenvalue() == pytest.approx(261.5956, abs=1e-3)
    assert all(np.linalg.eigvalsh(0.5 * (Di + Di.T))[-1] < 0 for Di in p.D)  # each D_i
    assert p.drag_dissipativity_max() < 0


@pytest.mark.parametrize("name", ["jhu-rov", "jhu-rov-coupled"])
def test_six_thrusters_full_rank(name):
    v = load_vehicle(name)
    assert v.n_thrusters == 6 and np.linalg.matrix_rank(v.B) == 6


def test_bad_vehicle_files_name_the_problem(tmp_path):
    f = tmp_path / "v.toml"
    f.write_text("[parameters]\nm=[1,1,1,1,1,1]\nd=[-1,-1,-1,-1,-1,-1]\ng=0\nb=[0,0,1]\n")
    with pytest.raises(ConfigError, match=">= 6 thrusters"):
        load_vehicle(f)
    f.write_text("colour = 'red'\n[parameters]\nm=[1,1,1,1,1,1]\n")
    with pytest.raises(ConfigError, match="unknown key.*colour"):
        load_vehicle(f)
    with pytest.raises(ConfigError, match="unknown vehicle"):
        load_vehicle("no-such-rov")


_ROOT = Path(__file__).resolve().parents[1]


def _jhu_with(tmp_path, key: str, value: str, where: str = "thruster_defaults"):
    """The JHU ROV's vehicle file with ``key = value`` in ``[thruster_defaults]`` (every
    thruster takes it) or in the first thruster (``where="thrusters[0]"``)."""
    text = (_ROOT / "uvd" / "vehicles" / "jhu-rov.toml").read_text()
    anchor = "[thruster_defaults]\n" if where == "thruster_defaults" else "[[thrusters]]\n"
    head, _, tail = text.partition(anchor)
    lines = tail.splitlines(keepends=True)
    # the first table after the anchor: drop its own line for the key, then set the key
    end = next((i for i, ln in enumerate(lines) if ln.startswith("[")), len(lines))
    table = [ln for ln in lines[:end] if not ln.startswith(f"{key} ")]
    f = tmp_path / "v.toml"
    f.write_text(head + anchor + f"{key} = {value}\n" + "".join(table + lines[end:]))
    return f


@pytest.mark.parametrize("key,value,words", [
    ("k_thrust", "nan", "k_thrust must be a finite number"),
    ("k_thrust", "true", "k_thrust must be a finite number"),
    ("k_thrust", "0.0", "k_thrust must be > 0"),
    ("max_thrust_n", "inf", "max_thrust_n must be a finite number"),
    ("max_thrust_n", "-300.0", "max_thrust_n must be > 0"),
    ("time_constant_s", "nan", "time_constant_s must be a finite number"),
    ("time_constant_s", "-0.1", "time_constant_s must be >= 0"),
    ("stiction_n", "'x'", "stiction_n must be a finite number"),
    ("stiction_n", "-5.0", "stiction_n must be >= 0"),
    ("curve", "[1, 2]", "curve must be the name of a thrust curve"),
])
def test_a_thrusters_bad_number_is_refused_naming_the_file_thruster_and_key(tmp_path, key,
                                                                             value, words):
    """A NaN, infinite, boolean or text value, or one of the wrong sign, in a thruster's
    gain, limit or constant is refused when the file is loaded, naming the file, the
    thruster and the key — not taken into the loop (whose guard would hold zero thrust for
    ever) and not a bare ValueError or TypeError."""
    f = _jhu_with(tmp_path, key, value)
    with pytest.raises(ConfigError, match=words) as e:
        load_vehicle(f)
    assert str(f) in str(e.value) and "thrusters[0]" in str(e.value)


@pytest.mark.parametrize("value,words", [
    ("'x'", "direction needs 3 entries"), ("['a', 'b', 'c']", "direction must be a finite"),
    ("[1e308, 1e308, 0.0]", "finite length"), ("[0.0, 0.0, 0.0]", "non-zero"),
    ("[nan, 0.0, 1.0]", "direction must be a finite number"),
])
def test_a_thrusters_bad_direction_is_refused_by_name(tmp_path, value, words):
    f = _jhu_with(tmp_path, "direction", value, where="thrusters[0]")
    with pytest.raises(ConfigError, match=words) as e:
        load_vehicle(f)
    assert "thrusters[0]" in str(e.value) and "aft-port" in str(e.value)


def test_a_vehicle_name_that_is_not_text_is_refused(tmp_path):
    f = tmp_path / "v.toml"
    f.write_text((_ROOT / "uvd" / "vehicles" / "jhu-rov.toml").read_text()
                 .replace('name = "jhu-rov"', "name = 7", 1))
    with pytest.raises(ConfigError, match="name must be a string"):
        load_vehicle(f)


def test_the_edited_file_of_the_bad_value_tests_is_otherwise_the_jhu_rov(tmp_path):
    """The helper's file with a good value loads as the built-in vehicle (so the tests above
    fail on the value, not on the edit)."""
    a = load_vehicle(_jhu_with(tmp_path, "stiction_n", "5.0"))
    b = load_vehicle("jhu-rov")
    assert a.thrusters == b.thrusters and np.array_equal(a.B, b.B)
