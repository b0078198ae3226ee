"""`uvd experiment fault-tolerance`, short arms: the cycle told of a dead thruster at the fault
reallocates in that cycle (the JHU ROV gives up pitch, the BlueROV2 none); the amplifier's own
fault does the same through the cycle's amplifier source where depth and attitude stay
actuated, and is not accommodated where they would not."""

import pytest

from uvd.experiments.fault_tolerance import run_arm


@pytest.mark.parametrize("config, given_up", [("sim-bluerov2.toml", []),
                                               ("sim.toml", ["pitch"])])
def test_a_dead_thruster_is_reallocated_in_the_cycle_that_is_told(config, given_up):
    r = run_arm(config, 4, 0.0, "told", t_fault_s=5.0, duration_s=20.0)
    assert r["given_up"] == given_up and r["cycles_not_ok"] == 0
    assert r["fault_s"] == r["detected_s"] == r["reallocated_s"] == pytest.approx(5.0)
    blind = run_arm(config, 4, 0.0, "none", t_fault_s=5.0, duration_s=20.0)
    assert blind["given_up"] == [] and blind["detected_s"] is None


def test_the_amplifier_arm_is_the_cycles_own_source():
    r = run_arm("sim-bluerov2.toml", 4, 0.0, "amplifier", t_fault_s=5.0, duration_s=20.0)
    assert r["given_up"] == [] and r["reallocated_s"] == pytest.approx(5.0)
    assert r["events"] == ["thruster 4 eta 0 (amplifier); given up: none"]
    aft = run_arm("sim.toml", 1, 0.0, "amplifier", t_fault_s=5.0, duration_s=20.0)
    assert aft["given_up"] == ["surge"] and aft["reallocated_s"] == pytest.approx(5.0)
    bow = run_arm("sim.toml", 4, 0.0, "amplifier", t_fault_s=5.0, duration_s=20.0)
    assert bow["reallocated_s"] is None and bow["events"] == []  # pitch would be lost
    with pytest.raises(ValueError, match="η 0 only"):
        run_arm("sim.toml", 4, 0.5, "amplifier")


def test_every_thruster_reading_separates_under_actuation_from_saturation():
    """fault-tolerance-every's page text, from a JSON of two misses: a thruster whose loss gives
    up a DOF the bound covers (no allocation can meet it) and one that gives up a DOF outside
    it (the miss is the remaining thrusters' saturation), and one that meets the bound."""
    from uvd.experiments.fault_tolerance_every import note

    def row(worst, ratio, given_up, ok):
        return {"worst_kept": worst, "ratio_after": {worst: ratio}, "given_up": given_up,
                "saturated_fraction_after": [0.28, 0.0], "meets_bound": ok}
    res = {"vehicles": {"six": {"thrusters": 3, "bound": 2.0,
                                "bound_dofs": ["z", "roll", "pitch", "heading"],
                                "dead": {"1": row("z", 3.5, ["surge"], False),
                                         "2": row("pitch", 7.0, ["pitch"], False),
                                         "3": row("z", 1.1, [], True)}}}}
    text = note(res)
    assert "six: 1 of 3 thrusters meet the bound" in text
    assert "thruster 1 (z 3.50×, given up: surge, worst saturation 28%)" in text
    assert "Thrusters 2: the remaining ones no longer reach" in text
    assert "Thrusters 1: every DOF of the bound is still allocated" in text
    assert note({}) is None
    # the drive's own fault: accommodated with its event, or the failsafe that disarms
    told = "thruster 1 eta 0 (amplifier); given up: surge"
    res["vehicles"]["six"]["dead"]["1"]["amplifier"] = {
        "accommodated": [told], "disarmed": False,
        "failsafes": {"count": 1, "kinds": {"accommodated amplifier_fault": 1}}}
    res["vehicles"]["six"]["dead"]["2"]["amplifier"] = {
        "accommodated": [], "disarmed": True,
        "failsafes": {"count": 2, "kinds": {"fired amplifier_fault": 1,
                                            "FAILSAFE->STANDBY": 1}}}
    text = note(res)
    assert f"accommodated for thrusters 1, each told by an `accommodated` event naming what " \
           f"was given up ({told}), 0 other events" in text
    assert "for thrusters 2 not (depth and attitude would not stay actuated): the daemon " \
           "disarms — 1 FAILSAFE->STANDBY, 1 fired amplifier_fault" in text


def test_a_supervised_run_names_the_dof_given_up_holds_its_adaptation_and_fires_nothing():
    """fault-tolerance-every's runs go through the daemon's cycle: the JHU ROV's aft-port
    thruster dead, the command event names surge given up, no failsafe fires, and two-step
    AMBC's θ̂ rows of surge (m₁, d₁) stay at their value at the fault while others adapt."""
    from uvd.experiments.fault_tolerance_every import adaptation_held, theta_rows
    r = run_arm("sim.toml", 1, 0.0, "told", t_fault_s=5.0, duration_s=20.0, supervised=True)
    assert r["told"] == "thruster 1 eta 0 (schedule); given up: surge"
    assert r["given_up"] == ["surge"] and r["failsafe_events"] == []
    held = adaptation_held(r)
    assert held["rows"] == [0, 6] and held["held"] and held["max_change_given_up"] == 0.0
    assert held["max_change_others"] > 0.0
    assert theta_rows(16, ["pitch"]) == [4, 10, 12, 13, 14, 15]
    assert theta_rows(241, ["sway"]) == list(range(241)) and theta_rows(16, []) == []


def _jhu_aft(dead: int | None, heading_scale: float = 1.0):
    """fault-tolerance's lockstep run of the JHU ROV (``run_arm``, seed 0, 180 s) on RefTraj1
    with its heading swing scaled, thruster ``dead`` failing and the cycle told at the fault:
    after the settling, |τ_z| commanded, |f_x| applied, the thrusters at their limit, the
    position MAE."""
    import numpy as np

    from uvd.control.trajectory import REFTRAJ1_SPEC, CosineTerm, CosineTrajectory, reftraj1
    from uvd.experiments.fault_tolerance import SETTLE_S, T_FAULT_S

    spec = [*REFTRAJ1_SPEC[:5], (REFTRAJ1_SPEC[5][0] * heading_scale, REFTRAJ1_SPEC[5][1])]
    ref = reftraj1() if heading_scale == 1.0 else CosineTrajectory(
        center=reftraj1().center, terms=tuple((CosineTerm(a, w),) for a, w in spec))
    r = run_arm("sim.toml", dead or 1, 0.0 if dead else 1.0, "told" if dead else "fault-free",
                reference=ref, keep_log=True)
    log = r["log"]
    after = log.t >= T_FAULT_S + SETTLE_S
    return np.abs(log.u_cmd[after, 5]), np.abs(log.u_applied[after, 0]), \
        log.saturated[after], r["after"]


def _jhu_allocator():
    """The JHU ROV's allocator as fault-tolerance's runs build it (B, the thrusters' limits)."""
    from uvd.experiments.fault_tolerance import _config_dir
    from uvd.runtime.build import build_core
    from uvd.runtime.config import load_config

    cfg = load_config(_config_dir() / "sim.toml")
    assert cfg.control.reference == "reftraj1"
    return build_core(cfg, cfg.load_vehicle()).allocator


def test_an_aft_thruster_dead_keeps_the_jhu_rov_heading_though_reftraj1_asks_more_yaw():
    """The JHU ROV with an aft thruster dead (surge given up) keeps heading, roll and pitch
    within the issue's 2x of its fault-free error (docs/experiments.md), although the
    fault-free run commands more yaw torque than the remaining aft thruster alone can give (its
    full thrust at its lever arm, from the vehicle's own B) in a fifth of the cycles after the
    settling: with thruster 1 told dead the yaw command is held at that most and the couple's
    surge force, which nothing left cancels, is applied ten times over. What used to cost the
    heading (3.4x) was the lateral thruster chasing, to its limit, the sway error the surge
    drift became as the heading turned; with horizontal position given up along both axes
    (uvd.control.given_up) it is at its limit in none of the cycles. Depth misses
    the 2x (2.12x: the drift's speed through the pitching vehicle's Coriolis terms, which the
    controller's masses, learning from g and b alone (``vehicle-gb``) for 60 s at the fault,
    under-model; from θ̂ = 0 it holds, the test further down): held here as a figure, not
    met."""
    import numpy as np

    tau_z, surge, saturated, mae = _jhu_aft(None)
    alloc = _jhu_allocator()
    B, f_max = alloc.B, alloc.max_thrust_n
    one_aft = abs(B[5, 1]) * f_max[1]  # thruster 2 alone (thruster 1 dead), N m
    assert B[0, 0] == B[0, 1] == 1.0 and one_aft == pytest.approx(0.35 * 300.0)
    assert B[5, 2] == 0.0 and B[1, 2] == 1.0  # the lateral thruster: sway only, no yaw
    assert not saturated.any()  # fault-free: the command is the controller's
    share = float(np.mean(tau_z > one_aft))
    tau_z_dead, surge_dead, saturated_dead, mae_dead = _jhu_aft(1)
    ratio = {d: mae_dead[d] / mae[d] for d in mae}
    print(f"fault-free: |tau_z| > {one_aft:.0f} N m in {share:.1%} of cycles; p90 "
          f"{np.percentile(tau_z, 90):.1f}, max {tau_z.max():.1f} N m; median |f_x| "
          f"{np.median(surge):.1f} N. Thruster 1 dead: |tau_z| p90 "
          f"{np.percentile(tau_z_dead, 90):.1f}, max {tau_z_dead.max():.1f} N m; median |f_x| "
          f"{np.median(surge_dead):.1f} N; at their limit "
          f"{np.round(saturated_dead.mean(axis=0), 3)}; MAE ratios "
          + " ".join(f"{d} {r:.2f}" for d, r in ratio.items()))
    assert share > 0.15 and tau_z.max() > 1.3 * one_aft
    assert tau_z_dead.max() <= one_aft * (1 + 1e-9)
    assert np.median(surge_dead) > 5 * np.median(surge)
    assert saturated_dead[:, 2].mean() < 0.05  # the lateral thruster does not chase drift
    for dof in ("roll", "pitch", "heading"):
        assert ratio[dof] <= 2.0, (dof, ratio[dof])
    assert ratio["z"] < 2.2  # 2.11x measured: the 2x is not met on depth


@pytest.mark.parametrize("dead", [1, 2, 3])
def test_a_converged_controller_keeps_the_jhu_rov_on_depth_and_attitude_with_a_thruster_dead(dead):
    """Two-step AMBC whose θ̂ starts at the vehicle's parameters (``[control] theta0 =
    "vehicle"``: a controller that has converged, as one on a vehicle in service has), the JHU
    ROV's aft or lateral thruster dead at 60 s: depth and attitude within the issue's 2× of the
    same controller's fault-free run. With the slid reference taking the trajectory's
    acceleration, not its own, this missed by far (z 8.0×, 8.1× and 3.2×; heading 3.5× with
    thruster 1): the drift's acceleration went unmodelled into a heave loop that a converged
    model leaves damped by k_d alone (uvd.control.given_up). Measured now, seed 0: z 0.45×,
    0.85×, 0.50×, every attitude DOF under 1×. And the horizontal thruster left is not made to
    chatter: with the kept horizontal translation in the loop, the measured acceleration fed
    forward moved the lateral thruster's command a median 38 N from cycle to cycle (4 N
    fault-free); out of it (uvd.control.given_up.controlled_dofs), no more than fault-free."""
    import numpy as np

    from uvd.experiments.fault_tolerance import SETTLE_S, T_FAULT_S

    free = run_arm("sim.toml", 1, 1.0, "fault-free", theta0="vehicle", keep_log=True)
    r = run_arm("sim.toml", dead, 0.0, "told", theta0="vehicle", keep_log=True)
    ratio = {d: r["after"][d] / free["after"][d] for d in ("z", "roll", "pitch", "heading")}

    def step(log, j):  # median |change| of thruster j's command from one cycle to the next
        return float(np.median(np.abs(np.diff(log.thrust[log.t >= T_FAULT_S + SETTLE_S, j]))))

    jumps = step(r["log"], 2), step(free["log"], 2)  # the lateral thruster (3)
    print(f"theta0 vehicle, thruster {dead} dead:", {d: round(x, 2) for d, x in ratio.items()},
          "given up", r["given_up"], f"the lateral thruster's median step {jumps[0]:.1f} N "
          f"(fault-free {jumps[1]:.1f} N)")
    assert r["given_up"] == (["surge"] if dead < 3 else ["sway"])
    assert max(ratio.values()) <= 2.0, ratio
    if dead < 3:  # an aft thruster dead: the lateral one is all sway, and sway is out of the loop
        assert jumps[0] <= jumps[1]


@pytest.mark.parametrize("dead", [1, 2])
def test_learning_from_theta_zero_the_jhu_rov_keeps_depth_and_attitude_with_an_aft_thruster_dead(
        dead):
    """Two-step AMBC learning from θ̂ = 0 (``[control] theta0 = "zero"``, §5.3.5 step 1's
    start), the JHU ROV's aft thruster 1 or 2 dead at 60 s: depth and attitude within the
    issue's 2× of the same controller's fault-free run. The published experiment starts from
    ``vehicle-gb`` (g and b known, M and D zero) and there depth misses (2.09–2.12×, held by
    the test above); from zero it holds (docs/experiments.md, seeds 0/1/2: z 1.39–1.52×), so the
    miss belongs to one stage of learning, not to learning as such."""
    free = run_arm("sim.toml", 1, 1.0, "fault-free", theta0="zero")
    r = run_arm("sim.toml", dead, 0.0, "told", theta0="zero")
    ratio = {d: r["after"][d] / free["after"][d] for d in ("z", "roll", "pitch", "heading")}
    print(f"theta0 zero, thruster {dead} dead:", {d: round(x, 2) for d, x in ratio.items()})
    assert r["given_up"] == ["surge"]
    assert max(ratio.values()) <= 2.0, ratio
    assert ratio["z"] > 1.2  # the fault costs depth (1.39x, 1.51x): a run that saw it


def test_half_reftraj1s_heading_swing_keeps_every_dof_of_the_bound_within_2x():
    """RefTraj1 with half its heading swing (67.5°: the yaw asked stays within one aft
    thruster's reach) and the JHU ROV's thruster 1 dead: depth and attitude within the issue's
    2× of the fault-free run (docs/experiments.md: z 1.17×, heading 0.95×). With the reference
    sliding along surge only the same run missed (heading 2.46×, the lateral thruster at its
    limit in 59 % of the cycles): the miss was the sway error the drift became, not the yaw."""
    _, _, _, mae = _jhu_aft(None, heading_scale=0.5)
    tau_z, _, saturated, mae_dead = _jhu_aft(1, heading_scale=0.5)
    alloc = _jhu_allocator()
    assert tau_z.max() < 0.5 * abs(alloc.B[5, 1]) * alloc.max_thrust_n[1]
    ratio = {d: mae_dead[d] / mae[d] for d in ("z", "roll", "pitch", "heading")}
    print("half heading swing, thruster 1 dead:", {d: round(r, 2) for d, r in ratio.items()},
          "at their limit", saturated.mean(axis=0).round(3))
    assert max(ratio.values()) <= 2.0, ratio
    assert saturated[:, 2].mean() < 0.05
