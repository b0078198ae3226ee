"""fig51-hunt's criteria and pdc-vs-ambc's one-axis heading account (small and fast)."""

from __future__ import annotations

import numpy as np
import pytest

from uvd.experiments._one_axis import fit_gain, one_axis_pd
from uvd.experiments.fig51_hunt import THESIS_RATE_PER_H, selective, thesis_like
from uvd.io.vehicle import load_vehicle

P = load_vehicle("jhu-rov").params


def _theta(n=5):
    th = np.tile(np.array([600, 800, 1000, 100, 140, 110, -1200, -1400, -3000, -700, -780, -400,
                           3.6, 1.0, 3.0, 300.0]), (n, 1))
    return th


def test_selective_needs_m4_or_m5_below_zero_and_the_others_bounded():
    th = _theta()
    assert not selective(th)
    th[-1, 3] = -1.0
    assert selective(th)
    th[-1, 0] = 1300.0  # m1 more than doubled: not selective
    assert not selective(th)
    th[-1, 0] = 600.0
    th[2, 7] = -600.0  # d2 below half its start on the way: not selective
    assert not selective(th)


def test_thesis_like_compares_the_rate_per_hour_with_the_thesis():
    th = _theta(2)
    r = {"initial": th[0].tolist(), "final": th[1].tolist()}
    assert not thesis_like(r, 1800.0)
    r["final"][4] = th[0, 4] + 0.5 * THESIS_RATE_PER_H[1] * 0.5 - 1.0  # just over half, 0.5 h
    assert thesis_like(r, 1800.0)
    assert not thesis_like(r, 7200.0)  # the same fall over 2 h is too slow


def test_one_axis_pd_error_falls_with_the_gain():
    mae = one_axis_pd(P, "heading", [300.0, 1000.0, 3000.0], 100.0, seconds=120.0)
    assert np.all(np.diff(mae[:, 0]) < 0)


@pytest.mark.parametrize("kp", [700.0, 2000.0])
def test_the_yaw_gain_fit_recovers_the_gain_that_made_the_pair(kp):
    pair = tuple(one_axis_pd(P, "heading", [kp], 100.0, seconds=120.0)[0])
    fit = fit_gain(P, "heading", pair, 100.0, kp_grid=np.geomspace(100.0, 10000.0, 121),
                   seconds=120.0)
    assert fit["kp"] == pytest.approx(kp, rel=0.04)  # grid step 3.9 %


def test_the_plan_covers_every_cause_of_issue_32_alone_and_from_table_5_2():
    """Each switch of sim_bridge.tank is on alone in one cause (mounting bias of both signs,
    latency, tether, buoyancy with depth, advance-speed loss, wider, held and hysteretic dead
    band), the instrument rates have their contrast, the coupled plant runs from Table 5.2 at
    ε 0.1, its bound and 1; every cause from the plant's and from Table 5.2's values."""
    from dataclasses import fields

    from sim_bridge.tank import TankEffects
    from uvd.experiments.fig51_hunt import CAUSES, eps_bound, plan
    geometry = {"tether_anchor_m", "tether_attach_m", "buoyancy_centre_m"}
    default = TankEffects()
    alone = {}
    for name, _, kw in CAUSES:
        if "tank" in kw:
            on = [f.name for f in fields(TankEffects)
                  if getattr(kw["tank"], f.name) != getattr(default, f.name)
                  and f.name not in geometry]
            if len(on) == 1:
                alone.setdefault(on[0], []).append(name)
    assert set(alone) == {f.name for f in fields(TankEffects)} - geometry
    biases = {CAUSES[[n for n, _, _ in CAUSES].index(c)][2]["tank"].mounting_bias_rad[0]
              for c in alone["mounting_bias_rad"]}
    assert min(biases) < 0 < max(biases)
    names = {n for n, _, _ in CAUSES}
    assert {"dvl-depth-10hz", "coupled-plant", "all"} <= names
    items = plan()
    for name in names:
        assert {i for n, i, _ in items if n == name} == {"plant", "table-5.2"}, name
    coupled = sorted(kw.get("eps", 0.1) for n, i, kw in items
                     if n == "coupled-plant" and i == "table-5.2")
    assert coupled == pytest.approx(sorted([0.1, eps_bound("jhu-rov-coupled"), 1.0]))
