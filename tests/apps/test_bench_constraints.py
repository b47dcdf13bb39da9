"""mjkin bench constraints: its judge is MuJoCo's, its rows say what the solvers did."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mjkin.apps.bench import constraints as bc
from mjkin.kinematics.geoms import contact_pairs


def test_the_judge_is_the_least_mujoco_distance_over_every_contact_pair():
    tree = bc.obstacle_scene("panda")
    judge = bc.Judge(tree, bc.MARGIN)
    m, d = tree.model, mujoco.MjData(tree.model)
    cap = bc.MARGIN + 0.01
    for q in tree.random_q(np.random.default_rng(1), 20):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        every = min(mujoco.mj_geomDistance(m, d, int(a), int(b), 10.0, None) for a, b in contact_pairs(tree))
        assert judge.clearance(q) == pytest.approx(min(every, cap), abs=1e-9)
    assert {"ball_a", "ball_b", "ball_c", "table"} <= {m.geom(g).name for g in range(m.ngeom)}


def test_a_small_run_has_every_row_and_no_violation_where_clearance_holds():
    report = bc.bench_constraints(targets=4)
    arms, figures, speed = list(report.tables.values())[:3]
    solvers = {(r["model"], r["solver"]) for r in arms}
    assert {("arm7", "mjkin Clearance"), ("panda", "reject-and-retry")} <= solvers
    for r in arms:
        if r["solver"] in ("mjkin Clearance", "reject-and-retry"):
            assert r["violations_in_successes"] == 0 and r["deepest_below_margin_mm"] == 0
    assert all(r.get("self_penetration_in_successes", 0) == 0 for r in figures if r["goals"] != "no clearance")
    limited, = (r for r in speed if r["frames_over_limit"] is not None)
    assert limited["frames_over_limit"] == 0 and limited["peak_joint_speed_rad_s"] <= 1.0 + 1e-6
