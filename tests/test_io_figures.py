"""Figure files (uvd.io.figures): the series written are the series computed."""

from __future__ import annotations

import numpy as np

from uvd.estimation.runlog import RunLog
from uvd.estimation.xval import STATES_ROT, states_of
from uvd.io.figures import write_series, write_xval_figures
from uvd.model.lie import exp_so3


def _run(n: int = 50) -> RunLog:
    t = np.arange(n) * 0.1
    R = np.stack([exp_so3(np.array([0.1 * np.sin(x), 0.05 * x, 0.2])) for x in t])
    v = np.column_stack([np.sin(t + k) for k in range(6)])
    return RunLog(t=t, R=R, p=np.zeros((n, 3)), v=v, u=np.zeros((n, 6)), name="r")


def test_series_csv_holds_the_columns(tmp_path):
    cols = np.column_stack([np.arange(5.0), np.arange(5.0) ** 2])
    files = write_series(tmp_path / "new", "sq", ["t", "t2"], cols)
    assert files[0] == tmp_path / "new" / "sq.csv"
    back = np.loadtxt(files[0], delimiter=",", skiprows=1)
    np.testing.assert_array_equal(back, cols)
    assert (tmp_path / "new" / "sq.csv").read_text().splitlines()[0] == "t,t2"


def test_xval_figures_plot_measured_and_simulated(tmp_path):
    run = _run()
    sim_v = run.v + 0.5
    files = write_xval_figures(tmp_path, run, {"A": (run.R, sim_v)}, STATES_ROT,
                               window_s=(0.0, 2.0))
    assert len(files) == len(STATES_ROT)
    meas = states_of(run.R, run.v)
    sim = states_of(run.R, sim_v)
    for f, s in zip(files, STATES_ROT, strict=True):
        assert f.stem == s
        if f.suffix != ".csv":  # matplotlib installed: a PNG, nothing to read back
            assert f.stat().st_size > 0
            continue
        data = np.loadtxt(f, delimiter=",", skiprows=1)
        assert data.shape == (21, 3)  # t ≤ 2 s at 10 Hz
        np.testing.assert_allclose(data[:, 1], meas[s][:21])
        np.testing.assert_allclose(data[:, 2], sim[s][:21])


def test_the_figures_the_report_and_the_experiments_share(tmp_path):
    """write_estimates (Fig. 5.1: 16 decoupled parameters or θ_UV) and write_mne (Fig. 5.4):
    the CSV of what is drawn, and the PNG ``uvd report`` draws for the same data."""
    from uvd.io.figures import mass_drag_gb, write_estimates, write_mne
    from uvd.io.vehicle import load_vehicle
    from uvd.model.params import theta_from

    t = np.arange(5.0)
    th16 = np.outer(t + 1, np.arange(1.0, 17.0))
    files = write_estimates(tmp_path, "est", t, th16, ["t_s"] + [f"p{i}" for i in range(16)])
    assert [f.name for f in files] == ["est.csv", "est.png"]
    assert np.loadtxt(files[0], delimiter=",", skiprows=1).shape == (5, 17)
    m, d, gb = mass_drag_gb(th16)
    assert m.shape == d.shape == (5, 6) and gb.shape == (5, 4) and gb[0, 0] == 13.0
    veh = load_vehicle("jhu-rov")
    m241, _, gb241 = mass_drag_gb([theta_from(veh.params)])
    assert np.allclose(m241[0], np.diag(veh.params.M)) and gb241[0, 0] == veh.params.g
    files = write_mne(tmp_path, "mne", [0.0, 15.0], 15.0, [0.2, 0.1], [0.05, 0.04], (0.3, 0.06))
    assert [f.name for f in files] == ["mne.csv", "mne.png"]
    assert files[1].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
