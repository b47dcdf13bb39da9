"""CenterOfMass (issues 22, 38): a soft target for the whole figure's CoM and hard balance over the feet's soles."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import ConvexHull

import mjkin
from conftest import assert_goal_jacobian, mujoco_state, tree_of
from mjkin import goals as G
from mjkin.apps.bench.report import shared_models_dir
from mjkin.errors import GoalError, UnknownNameError
from mjkin.ik import evaluate
from mjkin.ik.kernel import HARD_TOL
from mjkin.kinematics.qspace import FREE

FEET = ("left_foot", "right_foot")
CORNERS = [(f, (x, y, 0.0)) for f in FEET for x in (0.1, -0.1) for y in (0.05, -0.05)]  # a sole's corners
ORIGINS = [(f, (0.0, 0.0, 0.0)) for f in FEET]  # the feet sites themselves: a segment
README = G.CenterOfMass(support=list(FEET), margin=0.01)  # the README's example
G1 = (shared_models_dir() or Path("../shared/models")) / "unitree_g1" / "g1.xml"


def points(tree, q, support):
    """World positions ``(S, 3)`` of ``(frame, offset)`` support points, from ``tree.pose`` (not the goal's code)."""
    out = []
    for name, offset in support:
        T = tree.pose(q, name)
        out.append(T[:3, 3] + T[:3, :3] @ np.asarray(offset))
    return np.array(out)


def box_soles(tree, q, geoms=FEET):
    """MuJoCo's world corners ``(4 G, 3)`` of the bottom faces of the box geoms named ``geoms`` at ``q``."""
    d = mujoco_state(tree.model, q)
    out = []
    for name in geoms:
        g = tree.model.geom(name).id
        out += [d.geom_xpos[g] + d.geom_xmat[g].reshape(3, 3) @ (tree.model.geom_size[g] * [x, y, -1])
                for x in (-1, 1) for y in (-1, 1)]
    return np.array(out)


def sphere_centres(tree, q, bodies):
    """MuJoCo's world centres ``(K, 3)`` of the geoms on ``bodies`` at ``q``."""
    d = mujoco_state(tree.model, q)
    ids = [tree.model.body(b).id for b in bodies]
    return np.array([d.geom_xpos[g] for g in range(tree.model.ngeom) if tree.model.geom_bodyid[g] in ids])


def inside(tree, q, support=CORNERS):
    """The CoM's signed distance inside the hull of ``support`` (points ``(S, 3)`` or ``(frame, offset)``) on the
    floor (gravity is -z here): > 0 inside."""  # noqa: D205, D209
    pts = support if isinstance(support, np.ndarray) else points(tree, q, support)
    hull = ConvexHull(pts[:, :2])
    return float(np.min(-(hull.equations[:, :2] @ tree.com(q)[:2] + hull.equations[:, 2])))


def fixed_root(tree):
    """Every joint but the free one: the figure stands where it is (as the playground solves)."""
    return [n for n, t in zip(tree.names("joint"), tree.jnt_type, strict=True) if t != FREE]


@pytest.mark.parametrize("goal", [G.CenterOfMass([0.1, -0.2, 0.8]), G.CenterOfMass(support=CORNERS, margin=0.01),
                                  README, G.CenterOfMass(support=ORIGINS, margin=-0.05)],
                         ids=["target", "corners", "soles", "segment"])
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
    g, _, _ = evaluate(tree, G.CenterOfMass(support=ORIGINS), tree.qpos0)  # a segment: its sides, then its ends
    off = points(tree, tree.qpos0, ORIGINS)[0, 0] - tree.com(tree.qpos0)[0]  # the feet stand 5 cm ahead of the CoM
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
    ({"support": ORIGINS, "margin": 0.01}, "2 distinct points, no area"),
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


def test_box_feet_stand_on_their_bottom_corners(rng):
    tree = tree_of("primate")
    for q in [tree.qpos0, *tree.random_q(rng, 4)]:
        np.testing.assert_allclose(README.points(tree, q), box_soles(tree, q), atol=1e-12)
        g, _, _ = evaluate(tree, README, q)
        assert g[0].min() == pytest.approx(inside(tree, q, box_soles(tree, q)) - 0.01, abs=1e-12)


def test_readme_example_holds_alone_and_beside_a_hand_target():
    tree = tree_of("primate")
    alone = mjkin.solve(tree, README)
    assert alone.success and alone.status == "converged"
    hands = [[0.3, 0.4, 1.2], [0.4, -0.3, 0.9], [0.2, 0.6, 1.0]]
    res = mjkin.solve(tree, [README, G.Position("left_hand", hands)], q0=tree.qpos0)
    assert np.all(res.success)
    for q in res.q:
        assert inside(tree, q, box_soles(tree, q)) >= 0.01 - HARD_TOL


@pytest.mark.skipif(not G1.is_file(), reason=f"the G1 is not here ({G1})")
def test_g1_balances_on_both_feet(rng):
    g1 = tree_of(G1)
    feet = ("left_ankle_roll_link", "right_ankle_roll_link")
    balance = G.CenterOfMass(support=list(FEET), margin=0.01)  # the sites on those bodies: their four contact spheres
    np.testing.assert_allclose(balance.points(g1, g1.qpos0), sphere_centres(g1, g1.qpos0, feet), atol=1e-12)
    assert mjkin.solve(g1, balance).success
    q0 = g1.qpos0
    plant = [G.Position(f, g1.pose(q0, f)[:3, 3]) for f in FEET]
    reach = G.Position("left_zero_link", [[0.35, 0.3, 0.9], [0.3, 0.1, 0.6], [0.25, 0.45, 1.0]])
    res = mjkin.solve(g1, [balance, reach, *plant], q0=q0)
    assert np.all(res.success)
    for q in res.q:
        assert inside(g1, q, sphere_centres(g1, q, feet)) >= 0.01 - HARD_TOL
    for q in g1.random_q(rng, 2):
        assert_goal_jacobian(g1, balance, q)


def test_a_frame_whose_body_has_no_geoms_stands_on_its_origin():
    tree = mjkin.load("""<mujoco><worldbody><body name="base" pos="0 0 1"><freejoint/><geom size=".1" pos="0 0 -0.05"/>
        <body name="a" pos="0.1 0.2 -1"><site name="a" pos="0.01 0 0"/></body><body name="b" pos="0.1 -0.2 -1"/>
        </body></worldbody></mujoco>""")
    a, b, base = (tree.model.body(n).id for n in ("a", "b", "base"))
    np.testing.assert_array_equal(G.Balance(["a", "b"]).support_points(tree), [[a, 0.01, 0, 0], [b, 0, 0, 0]])
    np.testing.assert_array_equal(G.Balance(["base", "b"]).support_points(tree), [[base, 0, 0, -0.05], [b, 0, 0, 0]])
    with pytest.raises(GoalError, match="no area") as info:
        mjkin.solve(tree, G.CenterOfMass(support=["a", "b"], margin=0.01))
    assert "\n" not in str(info.value)


def test_a_com_target_outside_every_reachable_support_is_proven_out_of_balance():
    tree = tree_of("primate")
    far, near = [2.0, 0.0, 0.9], [0.05, 0.0, 0.9]
    goals = G.CenterOfMass([far, near], support=list(FEET), margin=0.01)
    res = mjkin.solve(tree, goals, joints=fixed_root(tree))
    assert not res.success[0] and res.reason[0] == "balance"  # proven, whichever way the run ended
    assert isinstance(res.goals[res.binding[0]], G.Balance)
    assert res.reason[1] != "balance"  # the feet could stand under it: nothing proven
    free = mjkin.solve(tree, G.CenterOfMass(far), joints=fixed_root(tree))
    assert not free.success and free.reason == "not_found"  # without balance the same target is not proven
