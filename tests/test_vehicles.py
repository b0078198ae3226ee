"""Built-in vehicles: values of the thesis's tables, physical validity, actuation."""

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
