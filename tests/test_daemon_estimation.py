"""Online identification in the daemon: the estimate leaves the process and comes back.

``uvd run`` with ``[estimation] aid = true`` against ``sim-bridge`` (second process, real
pseudo-terminals and ``udp_multicast`` CAN bus): the loop publishes ``"estimate"`` records
(θ̂ ∈ R²⁴¹ of 6-DOF AID) at ``publish_every_s``; ``save_path`` holds the newest θ̂ as a
parameters file, rewritten once more at shutdown; AID replayed offline over the daemon's
JSON-lines telemetry ends at the online estimate; a second daemon configured with the saved
file as ``initial_params``, or with ``resume = true``, starts its AID from it.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest

from sim_bridge.bridge import write_local_config
from tests.hil_daemon import ListSink, run_scenario, running_bridge
from uvd.commands.identify import identify_aid
from uvd.estimation.aid import INITP_6DOF, AID6Gains
from uvd.io.params import params_from_toml
from uvd.io.runlog import load_runlog
from uvd.runtime.config import load_config
from uvd.runtime.daemon import Daemon

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def hil(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("hil-aid")
    changes = {"telemetry": {"jsonl": {"enabled": True, "path": str(run_dir / "tel.jsonl")}},
               "estimation": {"aid": True, "publish_every_s": 0.2,
                              "save_path": str(run_dir / "aid-params.toml"),
                              "save_every_s": 1.0}}
    with running_bridge(run_dir, changes, duration_s=120.0) as b:
        yield b


def run_daemon(cfg, seconds: float):
    """Run the daemon (auto-arm) for ``seconds`` after arming, stop it; all its records."""
    sink = ListSink()
    d, _ = run_scenario(cfg, lambda d: asyncio.sleep(seconds), tracking_s=0.0, sink=sink)
    return d, sink.records


def test_aid_estimate_is_published_saved_and_resumed(hil, tmp_path):
    cfg_path, proc = hil
    assert proc.call("reset")["ok"] and proc.call("place", hold=True)["ok"]
    cfg = load_config(cfg_path)
    save_path = cfg.estimation.save_path
    d, records = run_daemon(cfg, 3.0)

    every = [r for r in records if r.get("type") == "estimate"]
    est = [r for r in every if r["source"] == "estimator"]
    cycles = [r for r in records if r.get("type") == "cycle"]
    # the adaptive controller's own θ̂ beside AID's, named as the controller (issue 19: "AID
    # and AMBC separately"), each aged from its last step (within a cycle or two here)
    ctl = [r for r in every if r["source"] == "controller"]
    assert len(ctl) == len(est) and {r["estimator"] for r in ctl} == {cfg.control.controller}
    assert all(r["theta"] is not None for r in ctl)
    ages = [r["age_s"] for r in every]
    assert all(a is None or 0.0 <= a <= 0.25 for a in ages), ages  # None: not stepped yet
    assert all(a is not None for a in ages[-10:]), ages
    # every 0.2 s from the first cycle on, plus the final one at shutdown
    span_s = (cycles[-1]["t_ns"] - cycles[0]["t_ns"]) * 1e-9
    assert int(span_s / 0.2) + 1 <= len(est) <= int(span_s / 0.2) + 3, (len(est), span_s)
    assert all(r["estimator"] == "aid6" and r["theta"].shape == (241,) for r in est)
    assert np.all(np.diff([r["t_ns"] for r in est]) >= 0)
    last = est[-1]
    assert last["t_ns"] == cycles[-1]["t_ns"]  # the shutdown record: the newest θ̂
    np.testing.assert_array_equal(last["theta"], d.state.est[0].theta)
    assert last["steps"] > 20 and not last["frozen"] and last["m_min_eig"] > 0
    assert np.linalg.norm(last["theta"] - INITP_6DOF.theta) > 0  # it adapted
    assert last["velocity_error"] < 0.5

    # the file holds exactly the newest estimate, and the temporary file is gone
    saved = params_from_toml(save_path)
    np.testing.assert_array_equal(saved.theta, last["theta"])
    assert not any(p.name.endswith(".tmp") for p in Path(save_path).parent.iterdir())
    stats = d.app.shutdown_report["telemetry"]["params-file"]
    assert stats["errors"] == 0 and stats["dropped"] == 0
    assert stats["written"] == len(every)  # only estimate records reach that sink
    # rewritten at the first estimate, then at most once per save_every_s = 1 s, and at close
    sink = next(s for s in d.app.hub.sinks if s.name == "params-file")
    assert 3 <= sink.writes <= int(span_s / 1.0) + 2, (sink.writes, span_s)
    assert d.app.shutdown_report["steps"]["publish the final estimate"] == "ok"

    # the daemon's own telemetry is an identification log: AID replayed over it offline
    # (uvd identify --method aid) ends where the online estimate ended — same samples, same
    # steps; only the period differs (measured in the loop, nominal in the replay)
    run = load_runlog(cfg.telemetry.jsonl.path)
    assert run.extra["bad_lines"] == 0 and len(run) >= len(cycles) - 2, run.extra
    assert abs(run.dt - 0.1) < 1e-6
    st, _ = identify_aid(run, INITP_6DOF.theta, AID6Gains())
    assert st.steps == last["steps"]
    rel = np.linalg.norm(st.theta - last["theta"]) / np.linalg.norm(last["theta"])
    jitter = max(abs(r["dt"] - 0.1) / 0.1 for r in cycles[1:])  # the loop's, this run
    assert rel < max(1e-4, 10 * jitter), (rel, jitter)

    # a second daemon starts its AID from the saved file
    cfg2_path = tmp_path / "resume.toml"
    cfg2_path.write_text(_with_initial_params(cfg_path.read_text(), save_path))
    cfg2 = load_config(cfg2_path)
    d2 = Daemon(cfg2)
    np.testing.assert_array_equal(d2.state.est[0].theta, saved.theta)
    # ... and so does one with resume = true and the same save_path, with no initial_params
    cfg3_path = tmp_path / "resume3.toml"
    cfg3_path.write_text(cfg_path.read_text().replace("[estimation]",
                                                      "[estimation]\nresume = true", 1))
    d3 = Daemon(load_config(cfg3_path))
    np.testing.assert_array_equal(d3.state.est[0].theta, saved.theta)


def _with_initial_params(text: str, path: str) -> str:
    """The config text with ``[estimation] initial_params`` set."""
    assert "[estimation]" in text
    return text.replace("[estimation]", f"[estimation]\ninitial_params = {path!r}", 1)


def test_a_frozen_estimate_is_published_and_logged_once(tmp_path, caplog):
    from dataclasses import replace

    cfg = load_config(write_local_config(tmp_path, changes={"estimation": {"aid": True}}))
    d = Daemon(cfg)  # not run: no port is opened
    lane = next(la for la in d.app.hub._lanes if la.sink.name == "jsonl")
    st = d.state.est[0]
    d.state.est = (replace(st, frozen=True, freeze_reason="M̂ not positive definite at t = 9 s"),)
    # two-step AMBC's "frozen" is its last update skipped (saturation, reversal hold, dead
    # zone): published as it is, never logged as having stopped adapting (it was, with an
    # empty reason and AID's explanation, session 25)
    d.state.ctrl = replace(d.state.ctrl, ambc=replace(d.state.ctrl.ambc, frozen=True))
    with caplog.at_level("WARNING", logger="uvd.daemon"):
        d.estimates.publish(123)
        d.estimates.publish(456)
    drained = lane.queue.drain()
    recs = [r for r in drained  # not the start record nor the controller's
            if r["type"] == "estimate" and r["source"] == "estimator"]
    ctrl = [r for r in drained if r["type"] == "estimate" and r["source"] == "controller"]
    assert [(r["estimator"], r["frozen"]) for r in ctrl] == [("two-step-ambc", True)] * 2
    assert [r["t_ns"] for r in recs] == [123, 456]
    assert all(r["frozen"] and "t = 9 s" in r["freeze_reason"] for r in recs)
    np.testing.assert_array_equal(recs[0]["theta"], st.theta)
    assert recs[0]["theta"] is not st.theta  # a copy: the record never changes afterwards
    # age_s: the time since the estimator last stepped, not a constant
    d.state.est_t_ns = 10**9
    d.estimates.publish(int(3.5e9))
    (rec,) = [r for r in lane.queue.drain() if r["type"] == "estimate" and
              r["source"] == "estimator"]
    assert rec["age_s"] == pytest.approx(2.5)
    warnings = [r.getMessage() for r in caplog.records if "stopped adapting" in r.getMessage()]
    assert len(warnings) == 1 and "aid6" in warnings[0] and "t = 9 s" in warnings[0]


def test_a_reload_keeps_the_running_estimate_and_does_not_read_initial_params(tmp_path):
    from dataclasses import replace

    from uvd.io.params import save_params
    from uvd.model.params import params_from_theta

    start = params_from_theta(INITP_6DOF.theta * 1.01)
    save_params(start, tmp_path / "start.toml")
    cfg_path = write_local_config(tmp_path, changes={"estimation": {"aid": True}})
    cfg_path.write_text(_with_initial_params(cfg_path.read_text(), str(tmp_path / "start.toml")))
    d = Daemon(load_config(cfg_path))  # not run: no port is opened
    spec = d.core_cfg.estimators[0]
    np.testing.assert_array_equal(d.state.est[0].theta, start.theta)
    # the file may be gone (or rewritten) while the daemon runs; the estimate it started
    # from lives in the daemon, and a SIGHUP that changes a gain must still apply
    (tmp_path / "start.toml").unlink()
    new = replace(d.config, control=replace(d.config.control, kp=123.0))
    d._on_reload(new, ["control.kp"])
    assert d.core_cfg.pd.kp == 123.0
    assert d.core_cfg.estimators == (spec,)
