"""``uvd identify`` and ``uvd xval`` round trip on a short recorded run."""

from __future__ import annotations

import json

import numpy as np
import pytest
from driver_strategies import DATA

from uvd.cli import main
from uvd.estimation.runlog import RunLog
from uvd.experiments.identification import dataset_6dof, record
from uvd.io.params import params_from_toml
from uvd.io.runlog import load_runlog, save_runlog

#: the pose of a cycle record at the origin, level, heading north (p and row-major R)
ZERO_POSE = {"p": [0.0] * 3, "R": np.eye(3).ravel().tolist()}


@pytest.fixture(scope="module")
def run_file(tmp_path_factory):
    """Four simulated minutes of the IDDAT inputs (lockstep, noise and thrusters on), saved in
    the run-log format the commands read."""
    rec = record(dataset_6dof("IDDAT"), kind="6dof", seed=5, minutes=4.0)
    path = tmp_path_factory.mktemp("runs") / "iddat-short.npz"
    save_runlog(rec.run, path)
    return path


def test_runlog_round_trip(run_file):
    run = load_runlog(run_file)
    assert len(run.t) == 2400 and run.input_interp == "linear" and run.name == "IDDAT"
    assert run.R_true is not None and np.allclose(run.dt, 0.1)


@pytest.mark.parametrize("method", ["ls", "ls-consistent", "aid"])
def test_identify_then_xval(run_file, tmp_path, capsys, method):
    out = tmp_path / f"{method}.toml"
    summary = tmp_path / f"{method}.json"
    assert main(["identify", "--log", str(run_file), "--method", method, "--out", str(out),
                 "--json", str(summary)]) == 0
    params = params_from_toml(out)
    info = json.loads(summary.read_text())
    assert info["method"] == method and info["samples"] == 2400
    if method == "ls-consistent":
        params.validate()
        assert info["validity"].startswith("valid")
        # four minutes of IDDAT leave the roll drag D4 undetermined: the unconstrained fit's
        # D4 is not dissipative (symmetric-part eigenvalue +132, like the thesis's Table 4.11)
        # and the consistent fit puts it on its bound — and says so
        assert info["active_bounds"] == ["D4"] and info["unobserved"] == []
    if method == "aid":
        assert info["frozen"] is False and info["steps"] == 2399
        # the convergence figures are the aid-6dof experiment's measure over the last minute
        from uvd.commands.identify import identify_aid
        from uvd.estimation.aid import INITP_6DOF, AID6Gains
        from uvd.experiments.identification import velocity_estimate_errors

        run = load_runlog(run_file)
        st, dv = identify_aid(run, INITP_6DOF.theta, AID6Gains())
        ref = velocity_estimate_errors(run.t, dv, run.v, width_s=60.0)
        for part in ("translational", "angular"):
            assert info[f"velocity_estimate_{part}_relative"] == pytest.approx(
                ref[f"{part}_relative"][-1], rel=1e-12)
        assert info["theta_moved_relative"] == pytest.approx(
            np.linalg.norm(st.theta - INITP_6DOF.theta) / np.linalg.norm(INITP_6DOF.theta))
        assert info["velocity_estimate_window_s"] == pytest.approx(60.0)
        assert params.mass_min_eigenvalue() > 0
    xv = tmp_path / f"{method}-xval.json"
    assert main(["xval", "--params", str(out), "--log", str(run_file), "--json",
                 str(xv)]) == 0
    text = capsys.readouterr().out
    assert "Roll (deg)" in text
    assert ("velocity estimate over the last 60 s: RMS error " in text) == (method == "aid")
    res = json.loads(xv.read_text())
    assert set(res["mae"]) == {"roll_deg", "pitch_deg", "u_mps", "v_mps", "w_mps", "p_degps",
                               "q_degps", "r_degps"}
    assert ("WARNING: the fit rests on its consistency bound for D4 " in text) \
        == (method == "ls-consistent")
    assert "no data for" not in text and "may diverge" not in text
    if method.startswith("ls"):  # LS of the same run predicts it well
        assert res["mae"]["u_mps"] < 0.02 and res["mae"]["roll_deg"] < 1.0
    # --out in a folder not there yet: made, as every command's output (uvd.cliargs; one under
    # a file is refused before anything starts, tests/test_cli_args.py)
    assert main(["identify", "--log", str(run_file), "--method", method, "--out",
                 str(tmp_path / "new" / "p.toml")]) == 0
    assert (tmp_path / "new" / "p.toml").read_text() == out.read_text()


def test_bad_inputs_are_clear_errors(tmp_path, capsys):
    bogus = tmp_path / "bogus.npz"
    bogus.write_bytes(b"not a zip")
    assert main(["identify", "--log", str(bogus), "--method", "ls", "--out",
                 str(tmp_path / "x.toml")]) == 2
    err = capsys.readouterr().err
    assert "not a readable run log" in err and "not a zip archive" in err
    assert "--profile" not in err  # nothing names it another system's recording
    # a real ArduSub telemetry log given without its profile: the error says what to add
    assert main(["identify", "--log", str(DATA / "ardusub" / "small.tlog"), "--method", "ls",
                 "--out", str(tmp_path / "x.toml")]) == 2
    err = capsys.readouterr().err
    assert "another system's recording (MAVLink telemetry log" in err
    assert "add --profile NAME (built-in: ardusub-bin, ardusub-tlog," in err
    np.savez(tmp_path / "partial.npz", t=np.arange(3.0))
    assert main(["xval", "--params", str(tmp_path / "none.toml"), "--log",
                 str(tmp_path / "partial.npz")]) == 2
    assert "cannot read parameters" in capsys.readouterr().err
    good = tmp_path / "p.toml"
    from uvd.estimation.aid import INITP_6DOF
    from uvd.io.params import save_params

    save_params(INITP_6DOF, good)
    assert main(["xval", "--params", str(good), "--log", str(tmp_path / "partial.npz")]) == 2
    assert "lacks array(s)" in capsys.readouterr().err


def test_an_observer_gain_the_run_cannot_carry_is_refused(run_file, tmp_path, capsys):
    """Session 33: `--gains 1e308,…` froze AID at its first step and wrote the file, with
    numpy's overflow warning and "RMS error inf %"; a·dt ≥ 2 diverges whatever the run."""
    out = tmp_path / "x.toml"
    assert main(["identify", "--log", str(run_file), "--method", "aid", "--gains",
                 "20,5000,20000,2000,2000", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--gains: the observer gain a = 20 at a step of 0.1 s makes a·dt = 2 ≥ 2" in err, err
    assert "a must stay under 2/dt = 20 (the run's sample period)" in err and not out.exists()
    from uvd.estimation.aid import observer_problem
    assert observer_problem(19.9, 0.1) is None and observer_problem(10.0, 0.02) is None


def test_runlog_from_uvd_run_telemetry(run_file, tmp_path, capsys):
    """The daemon's JSON-lines cycle records as a run: nominal grid, longest stretch."""
    run = load_runlog(run_file)
    rng = np.random.default_rng(1)
    lines = [json.dumps({"type": "lifecycle", "to": "STANDBY"})]
    for k in range(len(run.t)):
        if 100 <= k < 103:  # an overrun and a navigation outage: a gap
            if k == 101:
                lines.append(json.dumps({"type": "cycle", "t_ns": k * 100_000_000,
                                         "nav_valid": False, **ZERO_POSE, "v": [0] * 6,
                                         "u": [0] * 6}))
            continue
        pose = {"p": run.p[k].tolist(), "R": run.R[k].ravel().tolist()}
        jitter = int(rng.integers(0, 50_000))  # the loop wakes up to 50 µs late
        lines.append(json.dumps({"type": "cycle", "t_ns": 5_000_000_000 + k * 100_000_000
                                 + jitter, "nav_valid": True, **pose,
                                 "v": run.v[k].tolist(), "u": run.u[k].tolist()}))
    lines.append(json.dumps({"type": "cycle", "nav_valid": True, **ZERO_POSE, "v": [0] * 6,
                             "u": [0] * 6}))  # no time stamp: unusable
    for k in range(50):  # the daemon restarted after a reboot: its clock starts lower
        lines.append(json.dumps({"type": "cycle", "t_ns": 1_000_000 + k * 100_000_000,
                                 "nav_valid": True, **ZERO_POSE, "v": [0] * 6,
                                 "u": [0] * 6}))
    lines.append('{"type": "cycle", "t_ns": 9')  # cut by a crash
    f = tmp_path / "telemetry.jsonl"
    f.write_text("\n".join(lines))
    tel = load_runlog(f)
    assert tel.extra["segments"] == [[0, 100], [100, 2297], [2397, 50]]
    assert tel.extra["kept_segment"] == [100, 2297] and tel.extra["bad_lines"] == 2
    assert len(tel) == 2297 and abs(tel.dt - 0.1) < 1e-6 and tel.input_interp == "linear"
    np.testing.assert_allclose(tel.R, run.R[103:], atol=1e-12)
    np.testing.assert_array_equal(tel.v, run.v[103:])
    np.testing.assert_array_equal(tel.u, run.u[103:])
    np.testing.assert_array_equal(tel.p, run.p[103:])
    # uvd identify takes it as it is
    out = tmp_path / "ls.toml"
    assert main(["identify", "--log", str(f), "--method", "ls", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "rank 241/241" in text
    assert "3 uninterrupted stretches (cut where samples are missing or a run restarts); " \
           "using the longest, 2297 of 2447 samples; 2 unreadable line(s) skipped" in text
    # a file with no usable cycle record says what it needs
    empty = tmp_path / "empty.jsonl"
    empty.write_text(lines[0] + "\n")
    assert main(["xval", "--params", str(out), "--log", str(empty)]) == 2
    assert "0 cycle record(s) with valid navigation" in capsys.readouterr().err


def test_identify_says_what_the_data_do_not_determine(run_file, tmp_path, capsys):
    """30 s of IDDAT with sway, roll and pitch rate held at exactly 0: ls-consistent is still
    admissible, but says which blocks had no data and which rest on their bounds."""
    run = load_runlog(run_file)
    n = 300
    v = run.v[:n].copy()
    v[:, [1, 3, 4]] = 0.0
    short = tmp_path / "short.npz"
    save_runlog(RunLog(t=run.t[:n], R=run.R[:n], p=run.p[:n], v=v, u=run.u[:n],
                       input_interp=run.input_interp, name="short"), short)
    summary = tmp_path / "lsc.json"
    assert main(["identify", "--log", str(short), "--method", "ls-consistent", "--out",
                 str(tmp_path / "lsc.toml"), "--json", str(summary)]) == 0
    text = capsys.readouterr().out
    info = json.loads(summary.read_text())
    assert info["unobserved"] == ["D2", "D4", "D5"]
    assert "WARNING: no data for D2, D4, D5: sway v, roll rate p, pitch rate q stayed " \
           "exactly 0" in text
    params = params_from_toml(tmp_path / "lsc.toml")
    params.validate()
    np.testing.assert_allclose(params.D[3], -1e-3 * np.eye(6), rtol=0, atol=1e-9)
    bound = [b for b in info["active_bounds"] if b not in info["unobserved"]]
    assert bound, info["active_bounds"]  # 0.5 min for 241 parameters: some rest on a bound
    assert f"WARNING: the fit rests on its consistency bound for {', '.join(bound)}" in text
    assert "not identified by this run (0.5 min;" in text


def test_xval_warns_of_a_mass_matrix_no_vehicle_has_and_still_simulates_it(run_file, tmp_path,
                                                                           capsys):
    from uvd.io.params import save_params
    from uvd.model.params import UVParams

    good = UVParams.decoupled([50.0] * 6, [-20.0] * 6, 0.0, [0.0, 0.0, 5.0])
    bad = UVParams.decoupled([50.0, 50.0, 50.0, -5.0, 50.0, 50.0], [-20.0] * 6, 0.0,
                             [0.0, 0.0, 5.0])
    for name, p in (("good", good), ("bad", bad)):
        save_params(p, tmp_path / f"{name}.toml")
        assert main(["xval", "--params", str(tmp_path / f"{name}.toml"), "--log",
                     str(run_file)]) == 0
        out, err = capsys.readouterr()
        assert "MAE of" in out
        if name == "good":
            assert "warning" not in err
        else:
            assert f"warning: {tmp_path / 'bad.toml'}: M is not positive definite (smallest " \
                   "eigenvalue -5)" in err


def _arrays(n: int = 20) -> dict:
    return {"t": np.arange(n) * 0.1, "R": np.tile(np.eye(3), (n, 1, 1)), "p": np.zeros((n, 3)),
            "v": np.zeros((n, 6)), "u": np.zeros((n, 6))}


@pytest.mark.parametrize("change, words", [
    ({"meta": np.array(json.dumps([1, 2]))}, r"meta must be a JSON object, got \[1, 2\]"),
    ({"meta": np.array(json.dumps({"name": 5}))}, "name must be a string, got 5"),
    ({"t": np.array(["a"] * 20)}, "t must hold numbers, got an array of <U1"),
    ({"u": np.zeros((20, 6), dtype=bool)}, "u must hold numbers, got an array of bool"),
    ({"t": np.zeros((20, 2))}, r"t must hold one time stamp a sample \(1-D\), got shape"),
    ({"t": np.where(np.arange(20) == 3, np.nan, np.arange(20) * 0.1)},
     "t has non-finite entries"),
    ({"R_true": np.zeros((3, 3))}, r"R_true has shape \(3, 3\), expected \(20, 3, 3\)"),
    ({"v_true": np.full((20, 6), np.nan)}, "v_true has non-finite entries"),
])
def test_a_malformed_run_log_is_named_not_a_traceback(tmp_path, change, words):
    # found by fuzzing (session 19): the first four were tracebacks, the last two accepted
    from uvd.errors import ConfigError

    f = tmp_path / "run.npz"
    np.savez(f, **{**_arrays(), **change})
    with pytest.raises(ConfigError, match=words):
        load_runlog(f)
    np.savez(f, **_arrays())
    assert len(load_runlog(f)) == 20


@pytest.mark.parametrize("t_ns", [2**70, -2**70, True])
def test_a_cycle_record_whose_time_is_no_int64_is_an_unreadable_line(tmp_path, capsys, t_ns):
    # found by probing (session 21): a time stamp beyond int64 ns was an OverflowError
    # traceback from uvd identify and xval; a boolean one was taken as t = 1 ns
    def line(t):
        return json.dumps({"type": "cycle", "t_ns": t, "nav_valid": True, **ZERO_POSE,
                           "v": [0.1] * 6, "u": [1.0] * 6})
    lines = [line(5_000_000_000 + k * 100_000_000) for k in range(50)]
    lines.insert(20, line(t_ns))
    f = tmp_path / "telemetry.jsonl"
    f.write_text("\n".join(lines) + "\n")
    run = load_runlog(f)
    assert len(run) == 50 and run.extra["bad_lines"] == 1 and run.extra["segments"] == [[0, 50]]
    assert main(["identify", "--log", str(f), "--method", "ls", "--out",
                 str(tmp_path / "ls.toml")]) == 0
    assert f"{f}: 1 unreadable line(s) skipped" in capsys.readouterr().out
