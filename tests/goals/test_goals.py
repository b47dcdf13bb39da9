"""Every goal kind: its Jacobian, its effect, weights, priorities, frozen joints, batches."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mjkin
from conftest import tree_of
from mjkin import goals as G
from mjkin.ik import evaluate
from mjkin.spatial import quat_distance, quat_to_mat

TOL, ROT_TOL = 1e-6, 1e-5


def home(tree):
    return tree.model.key_qpos[0].copy()


def goal_zoo(tree, rng):
    """One goal of every kind on arm7 (targets from a reachable configuration)."""
    T = tree.pose(tree.random_q(rng), "ee")
    return [G.Position("ee", T[:3, 3]), G.Orientation("ee", quat=T[:3, :3]), G.Orientation("ee", T[:3, :3], axes="z"),
            G.Pose("ee", T=T), G.Aim("ee", axis=[0, 0, 1], point=[0.5, 0.2, 0.3]),
            G.Line("ee", point=[0.3, 0, 0.5], direction=[0, 1, 1]), G.Plane("ee", point=[0, 0, 0.6], normal=[1, 0, 1]),
            G.HalfSpace("ee", point=[0, 0, 1.5], normal=[0, 0, 1]), G.Rest(q_rest=home(tree), stiffness=2.0),
            G.Coupling(coefficients={"j1": 1.0, "j3": -0.5}, value=0.2), G.Position("link5", [0.1, 0.2, 0.6],
                                                                                     kind="body", offset=(0, 0, 0.1))]


def test_every_goal_jacobian_matches_finite_differences(rng):
    tree = tree_of("arm7")
    h = 1e-6
    for goal in goal_zoo(tree, rng):
        for q in tree.random_q(rng, 3):
            g, J, _ = evaluate(tree, goal, q)
            for i in range(tree.nv):
                e = np.zeros(tree.nv)
                e[i] = h
                gp = evaluate(tree, goal, tree.integrate(q, e))[0]
                gm = evaluate(tree, goal, tree.integrate(q, -e))[0]
                np.testing.assert_allclose(J[0, :, i], (gp - gm)[0] / (2 * h), atol=2e-6, err_msg=type(goal).__name__)


def test_ball_and_free_joint_goal_jacobians(rng):
    tree = tree_of("primate")
    h = 1e-6
    goals = [G.Pose("left_hand", T=tree.pose(tree.random_q(rng), "left_hand")),
             G.Aim("head", axis=[1, 0, 0], point=[1, 0, 1]), G.Rest(q_rest=tree.qpos0)]
    for goal in goals:
        q = tree.random_q(rng)
        _, J, _ = evaluate(tree, goal, q)
        for i in range(tree.nv):
            e = np.zeros(tree.nv)
            e[i] = h
            fd = (evaluate(tree, goal, tree.integrate(q, e))[0] - evaluate(tree, goal, tree.integrate(q, -e))[0])
            np.testing.assert_allclose(J[0, :, i], fd[0] / (2 * h), atol=2e-5, err_msg=type(goal).__name__)


def ee(tree, q):
    return tree.pose(q, "ee")


def test_line_plane_halfspace_aim_orientation_land_on_their_sets():
    tree = tree_of("arm7")
    q0 = home(tree)
    p, u = np.array([0.3, 0.0, 0.5]), np.array([0.0, 1.0, 1.0]) / np.sqrt(2)
    r = mjkin.solve(tree, G.Line("ee", point=p, direction=u), q0=q0)
    d = ee(tree, r.q)[:3, 3] - p
    assert r.success and np.linalg.norm(d - (d @ u) * u) <= TOL

    n = np.array([1.0, 0.0, 1.0]) / np.sqrt(2)
    r = mjkin.solve(tree, G.Plane("ee", point=[0, 0, 0.6], normal=n), q0=q0)
    assert r.success and abs((ee(tree, r.q)[:3, 3] - [0, 0, 0.6]) @ n) <= TOL

    assert ee(tree, q0)[2, 3] < 1.2  # start below the wall: the half-space pushes the hand up to it
    r = mjkin.solve(tree, G.HalfSpace("ee", point=[0, 0, 1.2], normal=[0, 0, 1]), q0=q0)
    assert r.success and ee(tree, r.q)[2, 3] >= 1.2 - TOL
    r = mjkin.solve(tree, G.HalfSpace("ee", point=[0, 0, 0.1], normal=[0, 0, 1]), q0=q0)  # already on its side
    assert r.success and r.iterations == 0 and np.array_equal(r.q, q0)

    target = np.array([0.5, 0.4, 0.2])
    r = mjkin.solve(tree, G.Aim("ee", axis=[0, 0, 1], point=target), q0=q0)
    T = ee(tree, r.q)
    direction = (target - T[:3, 3]) / np.linalg.norm(target - T[:3, 3])
    assert r.success and np.arccos(np.clip(T[:3, 2] @ direction, -1, 1)) <= ROT_TOL

    R = quat_to_mat([0.0, 1.0, 0.0, 0.0])  # flange pointing down
    r = mjkin.solve(tree, G.Orientation("ee", R, axes="z"), q0=q0)
    assert r.success and np.linalg.norm(ee(tree, r.q)[:3, 2] - R[:, 2]) <= ROT_TOL
    r = mjkin.solve(tree, G.Orientation("ee", [0.0, 1.0, 0.0, 0.0]), q0=q0)
    assert r.success and quat_distance(mjkin.spatial.mat_to_quat(ee(tree, r.q)[:3, :3]), [0, 1, 0, 0]) <= ROT_TOL


def test_coupling_and_rest():
    tree = tree_of("arm7")
    q0 = home(tree)
    target = ee(tree, q0)[:3, 3] + [0.1, 0.1, -0.05]
    r = mjkin.solve(tree, [G.Position("ee", target), G.Coupling(coefficients={"j1": 1.0, "j3": -1.0}, value=0.1)],
                    q0=q0)
    assert r.success and abs(r.q[0] - r.q[2] - 0.1) <= TOL
    q_rest = q0.copy()
    free = mjkin.solve(tree, G.Position("ee", target), q0=tree.qpos0, restarts=0)
    rested = mjkin.solve(tree, [G.Position("ee", target), G.Rest(q_rest=q_rest, priority=1)], q0=tree.qpos0)
    assert rested.success
    assert np.linalg.norm(rested.q - q_rest) < np.linalg.norm(free.q - q_rest)


def test_zero_weight_goals_have_no_effect(rng):
    tree = tree_of("arm7")
    T = ee(tree, tree.random_q(rng))
    base = mjkin.solve(tree, G.Position("ee", T[:3, 3]), q0=home(tree))
    extra = mjkin.solve(tree, [G.Position("ee", T[:3, 3]), G.Orientation("ee", [0, 1, 0, 0], weight=0.0),
                               G.Position("link4", [5, 5, 5], kind="body", weight=0)], q0=home(tree))
    np.testing.assert_allclose(base.q, extra.q, atol=1e-12)  # zero rows change only rounding
    assert extra.success


def test_priorities_protect_the_higher_goal(rng):
    tree = tree_of("arm7")
    for q in tree.random_q(rng, 5):
        T = ee(tree, q)
        far = T[:3, 3] + [0.0, 0.0, 2.0]  # conflicts: cannot also put link4 there
        r = mjkin.solve(tree, [G.Pose("ee", T=T), G.Position("link4", far, kind="body", priority=1)],
                        q0=home(tree))
        assert r.goal_errors[0, 0] <= TOL and r.goal_errors[0, 1] <= ROT_TOL
        assert not r.success  # the lower goal is unreachable and reported so


def test_only_the_chosen_joints_move(rng):
    tree = tree_of("arm7")
    q0 = home(tree)
    target = ee(tree, q0)[:3, 3] + [0.05, -0.05, 0.05]
    r = mjkin.solve(tree, G.Position("ee", target), q0=q0, joints=["j2", "j4", "j6", "j1"])
    assert r.success
    np.testing.assert_array_equal(r.q[[2, 4, 6]], q0[[2, 4, 6]])
    moved = q0 + [0, 0, 0, 0.2, -0.3, 0.25, 0.1]  # a target the joints below link3 can reach
    r = mjkin.solve(tree, G.Position("ee", ee(tree, moved)[:3, 3]), q0=q0, base="link3")  # j4..j7 only
    np.testing.assert_array_equal(r.q[:3], q0[:3])
    assert r.success


def test_root_change_plants_a_foot():
    tree = tree_of("primate")
    foot = tree.pose(tree.qpos0, "left_foot", "body")
    r = mjkin.solve(tree, [G.Position("left_hand", [0.4, 0.3, 1.2]), G.Aim("head", axis=[1, 0, 0],
                                                                          point=[0.4, 0.3, 1.2])], root="left_foot")
    assert r.success
    np.testing.assert_allclose(tree.pose(r.q, "left_foot", "body"), foot, atol=1e-6)
    assert not np.allclose(r.q[:7], tree.qpos0[:7])  # the pelvis (free root joint) moved instead
    np.testing.assert_allclose(np.linalg.norm(r.q[tree.layout.quats], axis=-1), 1.0, atol=1e-12)


def test_batched_equals_looped(rng):
    tree = tree_of("arm7")
    T = tree.pose(tree.random_q(rng, 6), "ee")
    batch = mjkin.solve(tree, G.Pose("ee", T=T), q0=home(tree))
    for b in range(6):
        one = mjkin.solve(tree, G.Pose("ee", T=T[b]), q0=home(tree))
        np.testing.assert_array_equal(batch.q[b], one.q)
        assert batch.status[b] == one.status and batch.iterations[b] == one.iterations


def test_batched_start_per_target(rng):
    tree = tree_of("arm7")
    Q = tree.random_q(rng, 4)
    T = tree.pose(tree.random_q(rng, 4), "ee")
    r = mjkin.solve(tree, G.Position("ee", T[:, :3, 3]), q0=Q)
    assert r.success.all()
    with pytest.raises(mjkin.InputError, match="q0 has shape"):
        mjkin.solve(tree, G.Position("ee", T[:, :3, 3]), q0=Q[:3])


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3), st.sampled_from(["lm", "dls", "pinv", "transpose"]),
       st.floats(0.5, 1.6))
def test_no_nan_for_any_valid_target(xyz, method, scale):
    """Targets anywhere, also far out of reach where the arm stretches (singular): finite, in limits."""
    tree = tree_of("arm7")
    target = np.array(xyz) * scale
    r = mjkin.solve(tree, [G.Position("ee", target), G.Orientation("ee", [0, 1, 0, 0], priority=1)],
                    method=method, max_iters=60)
    assert np.isfinite(r.q).all() and np.isfinite(r.error).all()
    np.testing.assert_allclose(tree.clip(r.q), r.q, atol=1e-12)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # numpy's overflow warnings, in SciPy's cost
@settings(max_examples=20, deadline=None)
@given(st.floats(1e150, 1e308), st.sampled_from(["auto", "lm", "dls", "pinv", "transpose", "ccd", "optimize"]))
def test_absurdly_far_targets_fail_cleanly(far, method):
    """A target beyond floating point's squares (found by a user: dls returned NaN q as "converged", pinv
    raised LinAlgError, optimize returned NaN marked converged): a finite q in the limits, and no success."""
    tree = tree_of("arm7")
    r = mjkin.solve(tree, G.Position("ee", [far, 0.0, 0.0]), method=method, max_iters=20)
    assert np.isfinite(r.q).all() and not r.success and r.status != "converged"
    np.testing.assert_allclose(tree.clip(r.q), r.q, atol=1e-12)
