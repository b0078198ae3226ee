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


def test_reftraj1_asks_more_yaw_torque_than_one_aft_thruster_of_the_jhu_rov_gives():
    """Why the JHU ROV with an aft thruster dead misses the issue's 2× on heading whatever the
    allocation (docs/experiments.md): the fault-free run of fault-tolerance's experiment
    commands more yaw torque than the remaining aft thruster alone can give (its full thrust
    at its lever arm, from the vehicle's own B) in a fifth of the cycles after the settling,
    while the fault-free allocation stays within every thruster's limit. With thruster 1 told
    dead at the fault, the yaw command is held at that most, and the couple's surge force,
    which nothing left cancels, is applied ten times over."""
    import numpy as np

    from uvd.experiments.fault_tolerance import SETTLE_S, T_FAULT_S, _config_dir
    from uvd.lockstep import Lockstep, lockstep_config, run
    from uvd.runtime import commands as cmd
    from uvd.runtime.build import build_core, start_pose
    from uvd.runtime.config import load_config
    from uvd.runtime.cycle import unsupervised

    cfg = load_config(_config_dir() / "sim.toml")
    vehicle = cfg.load_vehicle()
    H0, v0 = start_pose(cfg)
    core_cfg = build_core(cfg, vehicle)

    def run_jhu(dead: int | None):
        sim = Lockstep(vehicle, unsupervised(core_cfg), lockstep_config(cfg, 0), H0=H0, v0=v0)
        step, told = sim.advance, []

        def advance():  # thruster ``dead`` fails and the cycle is told at the fault
            if dead and not told and sim.t_ns >= T_FAULT_S * 1e9:
                sim.plant.thrusters.health[dead - 1] = 0.0
                told.append(sim.command(cmd.SetThrusterEta(dead, 0.0, source="schedule")))
            return step()
        sim.advance = advance
        log = run(sim, 180.0)
        assert dead is None or told[0].ok
        after = log.t >= T_FAULT_S + SETTLE_S
        return np.abs(log.u_cmd[after, 5]), np.abs(log.u_applied[after, 0]), \
            log.saturated[after]

    B, f_max = core_cfg.allocator.B, core_cfg.allocator.max_thrust_n
    one_aft = abs(B[5, 1]) * f_max[1]  # thruster 2 alone (thruster 1 dead), N m
    assert B[0, 0] == B[0, 1] == 1.0 and one_aft == pytest.approx(0.35 * 300.0)
    tau_z, surge, saturated = run_jhu(None)
    assert not saturated.any()  # fault-free: the command is the controller's
    share = float(np.mean(tau_z > one_aft))
    tau_z_dead, surge_dead, _ = run_jhu(1)
    print(f"fault-free: |tau_z| > {one_aft:.0f} N m in {share:.1%} of cycles; p90 "
          f"{np.percentile(tau_z, 90):.1f}, max {tau_z.max():.1f} N m; median |f_x| "
          f"{np.median(surge):.1f} N. Thruster 1 dead: |tau_z| p90 "
          f"{np.percentile(tau_z_dead, 90):.1f}, max {tau_z_dead.max():.1f} N m; median |f_x| "
          f"{np.median(surge_dead):.1f} N")
    assert share > 0.15 and tau_z.max() > 1.3 * one_aft
    assert tau_z_dead.max() <= one_aft * (1 + 1e-9)
    assert np.median(surge_dead) > 5 * np.median(surge)
