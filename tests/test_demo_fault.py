"""``uvd demo --fault``: in hardware in the loop (sim-bridge + the daemon + uvd-fdc + uvd watch,
over Zenoh on loopback), a thruster weakened by sim-bridge is named by uvd-fdc, confirmed by the
daemon's own residual and accommodated; the operator's clearing follows; the demo measures
fault → detection → reallocation; ``uvd replay --lockstep`` of the run's black box reproduces
every command bit for bit. Bounded: every process of the demo is (its own bounds), and
the run is 60 s of armed tracking."""

from __future__ import annotations

import pytest

from uvd.commands.demo_fault import FaultSpec


@pytest.mark.parametrize("text, why", [
    ("thruster:4:0.5", "expected thruster:I:ETA@T"),
    ("thruster:4:1.5@30", "ETA 1.5 is not in"),
    ("thruster:4:0.5@5", "leaves uvd-fdc no baseline"),
    ("thruster:4:1.2.3@30", "expected thruster:I:ETA@T"),  # was float()'s own message
    ("thruster:4:0.5@1..5", "expected thruster:I:ETA@T"),
])
def test_a_bad_fault_spec_is_named(text, why):
    with pytest.raises(ValueError, match=why):
        FaultSpec.parse(text)


@pytest.mark.parametrize("thruster", [0, 9])
def test_a_thruster_the_vehicle_does_not_have_is_a_command_line_error(thruster, capsys):
    """``uvd demo --fault thruster:9:…`` on the six-thruster JHU ROV says so in one line and
    exits 2, before any process starts (it was a Python traceback)."""
    from uvd.cli import main
    assert main(["demo", "--duration", "60", "--fault", f"thruster:{thruster}:0.5@30"]) == 2
    err = capsys.readouterr().err
    assert err.strip() == (f"uvd demo: error: --fault: thruster {thruster} is not one of 1…6 "
                           "of jhu-rov")


def test_a_fault_after_the_run_is_a_command_line_error(capsys):
    """``--fault …@100`` in a 3 s demo ran the whole demo and ended "no reallocation", exit 1
    (found by probing the option's values); it is refused before anything starts."""
    from uvd.cli import main
    assert main(["demo", "--duration", "3", "--fault", "thruster:4:0.5@100"]) == 2
    assert capsys.readouterr().err.strip() == (
        "uvd demo: --fault 'thruster:4:0.5@100': T 100 s is not within the run's 3 s of armed "
        "tracking (--duration)")


@pytest.mark.parametrize("options", [["--false-alarm"], ["--accept", "auto"],
                                     ["--accept", "confirm"]])
def test_the_fault_options_without_a_fault_are_a_command_line_error(options, capsys):
    """``--accept`` and ``--false-alarm`` act only with ``--fault``: without it they were
    silently ignored (a 60 s demo with no fault ran)."""
    from uvd.cli import main
    assert main(["demo", "--duration", "1", *options]) == 2
    assert capsys.readouterr().err.strip() == ("uvd demo: --accept and --false-alarm need "
                                               "--fault")


def test_a_fault_spec_reads_as_the_issue_writes_it():
    assert FaultSpec.parse("thruster:4:0.5@30") == FaultSpec(4, 0.5, 30.0)
    assert FaultSpec.parse("thruster:4:.5@30.") == FaultSpec(4, 0.5, 30.0)


def test_a_ctrl_c_before_the_fault_or_its_detection_is_said_so():
    # an interrupted run used to say "not detected" of a fault that was never put
    from uvd.commands.demo_fault import report
    base = {"thruster": 4, "eta": 0.5, "at_s": 20.0}

    def lines(**f) -> list[str]:
        out: list[str] = []
        report({**base, **f}, out.append)
        return [ln.strip() for ln in out]
    assert lines(interrupted_after_s=7.26) == [
        "fault: thruster 4 at eta 0.5, 20 s after arming (sim-bridge)",
        "not put: Ctrl-C 7.3 s after arming, before the fault's 20 s"]
    assert lines(interrupted_after_s=23.0)[1] == (
        "fault → detection (uvd-fdc's sample)  not detected in the 3.0 s before the Ctrl-C")
    assert lines()[1:3] == ["fault → detection (uvd-fdc's sample)  not detected",
                            "fault → reallocation                  no reallocation"]
    assert lines(interrupted_after_s=30.0, fault_to_detection_s=4.2)[1] == (
        "fault → detection (uvd-fdc's sample)     4.2 s")


@pytest.mark.slow
def test_a_weak_thruster_is_detected_over_zenoh_and_reallocated_in_hil(tmp_path):
    from uvd.commands.demo import run_demo

    said: list[str] = []
    figures, _ = run_demo(60.0, record=tmp_path, fault=FaultSpec(4, 0.5, 20.0),
                          false_alarm=True, progress=said.append)
    # the operator is told where the run's MAVLink listens (a free port, not 14551)
    from uvd.runtime.config import load_config
    listen = load_config(tmp_path / "uvd.toml").mavlink.listen
    assert any(f"MAVLink on udp {listen} (uvd eta 4 clear --to {listen})" in ln
               for ln in said), said
    f = figures["fault"]
    print({k: v for k, v in f.items() if k.endswith("_s")})
    assert f["detected"] is not None, (tmp_path / "fdc.log").read_text()
    assert f["detected"]["sample"]["channel"] == "thruster4", f["detected"]
    assert f["reallocated"] is not None, f["refused"]
    text = f["reallocated"]["text"]
    assert "confirmed" in text and "→ thruster 4 eta" in text, text
    assert f["fault_to_detection_s"] > 0.0 and f["fault_to_reallocation_s"] > 0.0
    # the false alarm (healthy thruster 5 named at η 0.5, 5 s before the fault): refused by
    # the daemon's own evidence, counted, not acted on
    assert len(f["refused"]) == 1 and "thruster 5 eta 0.50" in f["refused"][0], f["refused"]
    assert "not acted on" in f["refused"][0] and "refused" in f["refused"][0]
    counts = f["daemon_counts"]
    assert counts["acted"] == 1 and counts["contradicted"] + counts["unconfirmed"] == 1, counts
    # the operator's clearing after the repair, and uvd watch showed both
    assert f["cleared"] is not None and "thruster 4 eta 1 (mavlink" in f["cleared"]["text"]
    watched = "\n".join(f["watch_events"])
    assert "event: FaultReport from uvd-fdc: ok" in watched, watched
    assert "event: SetThrusterEta from mavlink" in watched, watched
    # the clearing station sends no HEARTBEAT: no operator-heartbeat failsafe follows it
    assert not [e for e in figures["failsafe_events"] if "heartbeat" in str(e)]

    # the decision went through the one cycle: replayed in lockstep from the black box, the
    # FaultReport is applied at the same cycle, confirmed again, and every command matches
    from uvd.runtime.replay.lockstep import replay_lockstep
    (mcap,) = tmp_path.glob("uvd-*.mcap")
    rep = replay_lockstep(mcap)
    print(rep.as_dict())
    assert rep.stopped is None and rep.cycles == rep.commands_compared > 0
    assert rep.mismatches == 0 and rep.operator_commands >= 2
    # and uvd report draws it: AID's θ̂ and the controller's side by side, one figure each
    # (the two in one array ended the report in numpy's "inhomogeneous shape" ValueError)
    from uvd.telemetry.report import write_report
    summary = write_report(mcap, tmp_path / "report")
    assert {"estimates-aid6.png", "estimates-two-step-ambc.png"} <= set(summary["figures"]), \
        summary["figures"]
