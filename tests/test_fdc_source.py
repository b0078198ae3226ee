"""uvd-fdc as a source of η through the one cycle (lockstep, the JHU ROV tracking RefTraj1):
``[faults.fdc] accept`` decides; in ``confirm`` mode the daemon's own thrust residual
(uvd.estimation.thrust_evidence) must agree with the sample before η changes.

The plant's thruster 4 is really weakened (``plant.thrusters.health``) or left healthy; the
fault sample is the FaultReport the daemon's Zenoh face would queue (tests/test_fdc_zenoh.py
carries one over a real router)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from uvd.lockstep import of_config
from uvd.runtime import commands as cmd
from uvd.runtime.config import DEFAULT_CONFIG, ConfigValidationError, load_config
from uvd.runtime.fdc_source import FaultsSection, FdcSourceSection
from uvd.runtime.schema import with_values


def _cfg(accept="confirm", enabled=True):
    cfg = load_config(DEFAULT_CONFIG)  # the JHU ROV, six thrusters, RefTraj1
    return replace(cfg, control=replace(cfg.control, controller="pdc"),
                   faults=FaultsSection(FdcSourceSection(enabled=enabled, accept=accept)))


def _sim(cfg):
    return of_config(cfg)


def _run(sim, seconds):
    outs = []
    for _ in range(round(seconds / sim.dt_control)):
        outs.append(sim.advance().thrust_n.copy())
    return outs


def _report(sim, thruster=4, eta=0.5, since_s=None):
    since = None if since_s is None else int(since_s * 1e9)
    return cmd.FaultReport("thruster", f"thruster{thruster}", eta - 1.0, sim.t_ns, 2.0, since)


def _faulty_run(accept, health, claim=0.5, fault_at=20.0, detect_at=50.0):
    sim = _sim(_cfg(accept))
    _run(sim, fault_at)
    sim.plant.thrusters.health[3] = health
    _run(sim, detect_at - fault_at)
    res = sim.command(_report(sim, eta=claim, since_s=fault_at))
    after = _run(sim, 2.0)
    return sim, res, after


def test_confirm_acts_on_a_weak_thruster_its_own_residual_sees():
    sim, res, _ = _faulty_run("confirm", 0.5)
    print(res.reason)
    assert res.ok, res.reason
    assert "confirmed" in res.reason and "thruster 4 eta 0.5 (uvd-fdc)" in res.reason
    eta_hat = float(res.reason.split("gives eta ")[1].split(" ")[0])
    assert abs(eta_hat - 0.5) <= 0.1, res.reason
    assert sim.supervisor.data.thruster_eta.tolist() == [1, 1, 1, 0.5, 1, 1]
    assert sim.supervisor.data.fdc.counts() == {"acted": 1, "contradicted": 0,
                                                "unconfirmed": 0, "advisory": 0}


@pytest.mark.parametrize("claim, why", [(0.5, "not within 0.2"),
                                        (0.95, "nearer a healthy 1")])
def test_confirm_refuses_and_counts_a_sample_its_evidence_contradicts(claim, why):
    """A healthy thruster named weak (a false alarm): at half its thrust, or at 95 % — within
    the tolerance of the fit, but the fit is nearer a healthy thruster than the claim (the
    campaign's false alarm of uvd-fdc was thruster 2 at 95 %, docs/zenoh.md)."""
    sim, res, _ = _faulty_run("confirm", 1.0, claim=claim)
    print(res.reason)
    assert not res.ok and "contradicted" in res.reason and why in res.reason, res.reason
    eta_hat = float(res.reason.split("gives eta ")[1].split(" ")[0])
    assert abs(eta_hat - 1.0) <= 0.1, res.reason
    assert sim.supervisor.data.thruster_eta is None  # not acted on
    assert sim.supervisor.data.fdc.contradicted == 1


def test_advisory_never_acts_and_auto_acts_without_evidence():
    sim, res, _ = _faulty_run("advisory", 0.5)
    assert res.ok and "advisory, not acted on" in res.reason
    assert sim.supervisor.data.thruster_eta is None and sim.supervisor.data.fdc.advisory == 1
    sim, res, _ = _faulty_run("auto", 1.0)  # auto believes even a false alarm
    assert res.ok and "accepted (auto)" in res.reason
    assert sim.supervisor.data.thruster_eta.tolist() == [1, 1, 1, 0.5, 1, 1]


def test_confirm_without_evidence_is_unconfirmed():
    """Right after start the residual has no segment since the claimed change time."""
    sim = _sim(_cfg("confirm"))
    _run(sim, 1.0)
    res = sim.command(_report(sim, since_s=sim.t_ns * 1e-9))
    assert not res.ok and "unconfirmed" in res.reason and sim.supervisor.data.fdc.unconfirmed == 1


@pytest.mark.parametrize("c, why", [
    (cmd.FaultReport("buoyancy", "g", 0.1, 0), "a buoyancy fault (g), not a thruster's"),
    (cmd.FaultReport("thruster", "thruster9", -0.5, 0), "thruster 9 is not one of 1..6"),
    (cmd.FaultReport("thruster", "thruster2", None, 0), "relative_change None is not a finite"),
    # a channel in other digits than uvd-fdc's ASCII ones: "thruster٤" was acted on as 4
    (cmd.FaultReport("thruster", "thruster\u0664", -0.5, 0),
     "a thruster fault (thruster\u0664), not a thruster's"),
])
def test_samples_that_name_no_thruster_are_told_not_acted_on(c, why):
    sim = _sim(_cfg("auto"))
    res = sim.command(c)
    assert why in res.reason and sim.supervisor.data.thruster_eta is None


def test_a_sample_without_the_source_enabled_is_refused():
    sim = _sim(_cfg(enabled=False))
    res = sim.command(_report(sim))
    assert not res.ok and res.reason == "[faults.fdc] is not enabled"


def test_the_decision_is_deterministic_through_the_cycle():
    """Same run twice, the sample at the same cycle: the same η and bit-identical thrust
    (what ``uvd replay --lockstep`` relies on)."""
    runs = []
    for _ in range(2):
        sim, res, after = _faulty_run("confirm", 0.5, fault_at=10.0, detect_at=30.0)
        runs.append((res.reason, np.array(after)))
    assert runs[0][0] == runs[1][0]
    np.testing.assert_array_equal(runs[0][1], runs[1][1])


def test_the_rule_is_validated_with_named_errors(tmp_path):
    cfg = load_config(DEFAULT_CONFIG)
    assert cfg.faults.fdc.accept == "confirm" and not cfg.faults.fdc.enabled
    _, errors = with_values(cfg, {"faults.fdc.accept": "sometimes"})
    assert any(k == "faults.fdc.accept" and "sometimes" in r for k, r in errors), errors
    p = tmp_path / "c.toml"  # the shipped configuration (Zenoh off) with the source on
    text = DEFAULT_CONFIG.read_text().replace("[vehicle]", "[faults.fdc]\nenabled = true\n\n"
                                              "[vehicle]", 1)
    zenoh_on = '[telemetry.zenoh]\n' + text.split("[telemetry.zenoh]\n")[1].split("[")[0]
    p.write_text(text.replace(zenoh_on, zenoh_on.replace("enabled = true", "enabled = false")))
    with pytest.raises(ConfigValidationError, match=r"faults\.fdc\.enabled: .*telemetry\.zenoh"):
        load_config(p)
