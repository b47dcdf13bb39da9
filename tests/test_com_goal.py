"""CenterOfMass (issue 22): a soft target for the whole figure's CoM and hard balance over support frames."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull

import mjkin
from conftest import assert_goal_jacobian, tree_of
from mjkin import goals as G
from mjkin.errors import GoalError, UnknownNameError
from mjkin.ik import evaluate
from mjkin.ik.kernel import HARD_TOL

FEET = ("left_foot", "right_foot")
CORNERS = [(f, (x, y, 0.0)) for f in FEET for x in (0.1, -0.1) for y in (0.05, -0.05)]  # a sole's corners


def points(tree, q, support):
    """World positions ``(S, 3)`` of the support points, from ``tree.pose`` (independently of the goal)."""
    out = []
    for s in support:
        name, offset = (s, np.zeros(3)) if isinstance(s, str) else s
        T = tree.pose(q, name)
        out.append(T[:3, 3] + T[:3, :3] @ np.asarray(offset))
    return np.array(out)


def inside(tree, q, support=CORNERS):
    """The CoM's signed distance inside the support polygon on the floor (gravity is -z here): > 0 inside."""
    hull = ConvexHull(points(tree, q, support)[:, :2])
    return float(np.min(-(hull.equations[:, :2] @ tree.com(q)[:2] + hull.equations[:, 2])))


@pytest.mark.parametrize("goal", [G.CenterOfMass([0.1, -0.2, 0.8]), G.CenterOfMass(support=CORNERS, margin=0.01),
                                  G.CenterOfMass(support=list(FEET), margin=-0.05)], ids=["target", "soles", "feet"])
def test_rows_match_finite_differences(goal, rng):
    tree = tree_of("primate")
    for q in tree.random_q(rng, 3):
        assert_goal_jacobian(tree, goal, q)


def test_balance_rows_are_the_distances_inside_the_hull(rng):
    tree = tree_of("primate")
    for q in [tree.qpos0, *tree.random_q(rng, 4)]:
        g, _, err = evaluate(tree, G.CenterOfMass(support=CORNERS, margin=0.02), q)
        assert g[0].min() == pytest.approx(inside(tree, q) - 0.02, abs=1e-12)
        assert err[0, 0, 0] == pytest.approx(max(0.0, 0.02 - inside(tree, q)), abs=1e-12)
    g, _, _ = evaluate(tree, G.CenterOfMass(support=list(FEET)), tree.qpos0)  # a segment: its sides, then its ends
    off = points(tree, tree.qpos0, FEET)[0, 0] - tree.com(tree.qpos0)[0]  # the feet stand 5 cm ahead of the CoM
    np.testing.assert_allclose(g[0], [off, -off, 0.1, 0.1], atol=1e-12)


def test_balance_holds_on_every_success_and_without_it_the_com_leaves():
    tree = tree_of("primate")
    q0 = tree.qpos0
    plant = [G.Position(f, tree.pose(q0, f)[:3, 3]) for f in FEET]
    y, z = np.meshgrid([0.5, 0.7, 0.9], [0.6, 1.0, 1.4])
    left = np.column_stack([np.full(y.size, 0.1), y.ravel(), z.ravel()])  # both hands far to the left
    hands = [G.Position("left_hand", left), G.Position("right_hand", left - [0.0, 0.2, 0.0])]
    free = mjkin.solve(tree, plant + hands, q0=q0)
    held = mjkin.solve(tree, plant + hands + [G.CenterOfMass(support=CORNERS, margin=0.02)], q0=q0)
    assert sum(free.success) >= 6 and sum(inside(tree, q) < 0.0 for q in free.q[free.success]) >= 5
    assert sum(held.success) >= 6
    for q, ok in zip(held.q, held.success, strict=True):
        if ok:
            assert inside(tree, q) >= 0.02 - HARD_TOL


def test_soft_target_is_reached(rng):
    tree = tree_of("primate")
    targets = tree.com(tree.random_q(rng, 4))
    res = mjkin.solve(tree, G.CenterOfMass(targets), q0=tree.qpos0)
    assert np.all(res.success)
    np.testing.assert_allclose(tree.com(res.q), targets, atol=1e-4)


@pytest.mark.parametrize("kwargs,match", [
    ({}, "needs xyz"),
    ({"support": ["left_foot"]}, "at least 2"),
    ({"support": "left_foot"}, "at least 2"),
    ({"support": FEET, "margin": np.nan}, "margin"),
    ({"support": [("left_foot", (1, 2)), "right_foot"]}, "offset of left_foot"),
    ({"support": [3, "right_foot"]}, "frame names or"),
    ({"xyz": [1, 2]}, "xyz"),
])
def test_bad_input_fails_in_one_line(kwargs, match):
    tree = tree_of("primate")
    with pytest.raises(GoalError, match=match) as info:
        mjkin.solve(tree, [G.Position("left_hand", [0.3, 0, 0.5]), G.CenterOfMass(**kwargs)])
    assert "\n" not in str(info.value)
    with pytest.raises(UnknownNameError, match="left_foot"):
        mjkin.solve(tree, G.CenterOfMass(support=["left_foot", "nose"]))


def test_solve_equals_problem_solve_bit_for_bit():
    tree = tree_of("primate")
    q0 = tree.qpos0
    goals = [G.Position("left_hand", [0.1, 0.6, 1.0]),
             G.CenterOfMass(tree.com(q0) + [0.0, 0.05, 0.0], support=CORNERS, margin=0.01, weight=0.1)]
    a = mjkin.solve(tree, goals, q0=q0)
    b = mjkin.Problem(tree, goals).solve(q0)
    assert np.array_equal(a.q, b.q) and a.status == b.status and np.array_equal(a.binding, b.binding)
    assert [type(g).__name__ for g in a.goals] == ["Balance", "Position", "ComTarget"]
