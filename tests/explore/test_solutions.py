"""mjkin.solutions against closed forms, and Result.reason: proofs never claimed for a reachable target."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mjkin
from mjkin import goals as G
from mjkin.apps.bench.arms import ARMS, CLOSED_FORMS, mjcf
from mjkin.explore.solutions import joint_distance
from mjkin.ik.reasons import reach_bound
from mjkin.kinematics.build import Link, dh_chain, dh_fk, links_mjcf

MATCH = 1e-4  # rad: a returned solution is the closed form's
ARM_TOL = 1e-9  # FK of a returned solution against the target (solutions are polished to 1e-3 of tol = 1e-6)


@pytest.fixture(scope="module")
def arms() -> dict[str, mjkin.Tree]:
    return {name: mjkin.load(mjcf(name)) for name in ARMS}


def test_closed_forms_are_right():
    """The references: each closed-form answer reproduces the pose, and they are distinct (8 for these poses)."""
    rng = np.random.default_rng(0)
    for name, table in ARMS.items():
        for q in rng.uniform(-np.pi, np.pi, (20, 6)):
            T = dh_fk(table, q)
            ref = CLOSED_FORMS[name](T)
            np.testing.assert_allclose(dh_fk(table, ref), np.broadcast_to(T, (len(ref), 4, 4)), atol=1e-9)
            d = np.abs(np.angle(np.exp(1j * (ref[:, None] - ref[None])))).max(-1)
            assert np.all(d[~np.eye(len(ref), dtype=bool)] > 1e-6)
            assert np.abs(np.angle(np.exp(1j * (ref - q)))).max(-1).min() < 1e-6  # the pose's own q is among them


def axes_and_offsets(tree: mjkin.Tree, intersecting: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IK-Geo's description of a 6-axis chain at q = 0: axes ``H (6, 3)``, offsets ``P (7, 3)``, the tool's rotation.

    Anchors of axes ``i`` and ``i + 1`` (``i`` in ``intersecting``) are moved along them to their common point.
    """
    T0 = tree.fk(tree.qpos0)
    H = np.array([T0[tree.jnt_body[j]][:3, :3] @ tree.jnt_axis[j] for j in range(6)])
    A = np.array([T0[tree.jnt_body[j]][:3, :3] @ tree.jnt_pos[j] + T0[tree.jnt_body[j]][:3, 3] for j in range(6)])
    for i in intersecting:
        s, *_ = np.linalg.lstsq(np.stack([H[i], -H[i + 1]], 1), A[i + 1] - A[i], rcond=None)
        A[i] = A[i + 1] = A[i] + s[0] * H[i]
    E = tree.pose(tree.qpos0, "ee")
    return H, np.vstack([A[0], np.diff(A, axis=0), E[:3, 3] - A[5]]), E[:3, :3]


@pytest.mark.parametrize("name, kind, intersecting", [("ur", "three_parallel_two_intersecting", [4]),
                                                      ("spherical", "spherical_two_parallel", [3, 4])])
def test_closed_forms_agree_with_ik_geo(arms, name, kind, intersecting):
    """The closed forms give IK-Geo's solutions (its Python binding takes and gives rotations transposed)."""
    ik_geo = pytest.importorskip("ik_geo", reason="ik-geo (PyPI) is an optional check of the closed forms")
    tree = arms[name]
    H, P, R0 = axes_and_offsets(tree, intersecting)
    robot = getattr(ik_geo.Robot, kind)(H.tolist(), P.tolist())
    for q in tree.random_q(np.random.default_rng(5), 20):
        T = tree.pose(q, "ee")
        theirs = np.array([s for s, least_squares in robot.get_ik((T[:3, :3] @ R0.T).T.tolist(), T[:3, 3].tolist())
                           if not least_squares]).reshape(-1, 6)
        ours = CLOSED_FORMS[name](dh_fk(ARMS[name], q))
        assert len(theirs) == len(ours)
        assert joint_distance(tree, theirs[:, None], ours[None]).min(0).max() < 1e-6


@pytest.mark.parametrize("name", list(ARMS))
def test_every_analytic_solution_is_found(arms, name):
    tree, rng = arms[name], np.random.default_rng(1)
    for q in tree.random_q(rng, 6):
        T = tree.pose(q, "ee")
        ref = CLOSED_FORMS[name](dh_fk(ARMS[name], q))
        res = mjkin.solutions(tree, G.Pose("ee", T))
        d = joint_distance(tree, res.q[:, None], ref[None])
        assert d.min(0).max() < MATCH, "an analytic solution was missed"
        assert d.min(1).max() < MATCH, "a returned solution is not an analytic one"
        assert len(res.q) == len(ref)
        np.testing.assert_allclose(tree.pose(res.q, "ee"), np.broadcast_to(T, (len(ref), 4, 4)), atol=ARM_TOL)
        assert res.success.all() and set(res.status) == {"converged"} and res.q.shape == (len(ref), tree.nq)


def test_limits_keep_only_the_solutions_inside_and_wrap_merges_two_pi():
    """Limits of ±2.5 rad keep the analytic solutions inside them; limits of ±2π (a full turn each way) hold
    each solution twice or more in q (q and q ± 2π): they come back once, as the closed form's count."""
    rng = np.random.default_rng(2)
    for limit in (2.5, 2 * np.pi):
        tree = mjkin.load(dh_chain(ARMS["ur"], ranges=[(-limit, limit)] * 6))
        for _ in range(3):
            q = tree.random_q(rng) if limit < 4 else rng.uniform(-np.pi, np.pi, 6)
            T = tree.pose(q, "ee")
            ref = CLOSED_FORMS["ur"](T)
            if limit < 4:
                ref = ref[np.all(np.abs(ref) <= limit, axis=1)]
            res = mjkin.solutions(tree, G.Pose("ee", T))
            assert np.all(np.abs(res.q) <= limit)
            assert len(res.q) == len(ref)
            d = joint_distance(tree, res.q[:, None], ref[None])
            assert d.min(0).max() < MATCH
            np.testing.assert_allclose(tree.pose(res.q, "ee"), np.broadcast_to(T, (len(ref), 4, 4)), atol=ARM_TOL)


def test_solutions_are_distinct_and_a_seven_dof_arm_gives_a_spread():
    tree = mjkin.load("arm7")
    q = tree.random_q(np.random.default_rng(3))
    T = tree.pose(q, "ee")
    res = mjkin.solutions(tree, G.Pose("ee", T), starts=64)
    assert len(res.q) > 8  # a redundant arm: a family, not isolated solutions
    d = joint_distance(tree, res.q[:, None], res.q[None])
    assert np.all(d[~np.eye(len(res.q), dtype=bool)] > 1e-3)
    np.testing.assert_allclose(tree.pose(res.q, "ee"), np.broadcast_to(T, (len(res.q), 4, 4)), atol=1e-6)
    assert np.all(tree.clip(res.q) == res.q)
    few = mjkin.solutions(tree, G.Pose("ee", T), starts=64, max_solutions=5)
    assert len(few.q) == 5 and all(np.any(joint_distance(tree, res.q, x) < 1e-9) for x in few.q)
    back = pickle.loads(pickle.dumps(few))
    np.testing.assert_array_equal(back.q, few.q)
    assert str(back.reason) == ""


def test_no_solution_says_why():
    tree = mjkin.load(mjcf("ur"))
    res = mjkin.solutions(tree, G.Position("ee", (5.0, 0.0, 0.0)), starts=8)
    assert res.q.shape == (0, tree.nq) and str(res.reason) == "out_of_reach"


@pytest.mark.parametrize("bad, error", [
    ({"goal": G.Position("ee", np.zeros((2, 3)))}, mjkin.GoalError),
    ({"starts": 0}, mjkin.InputError),
    ({"max_solutions": -1}, mjkin.InputError),
    ({"merge": float("nan")}, mjkin.InputError),
    ({"root": "link1"}, mjkin.InputError),
])
def test_bad_input_is_one_line(bad, error):
    tree = mjkin.load("arm7")
    args = {"goal": G.Position("ee", (0.3, 0.0, 0.3)), **bad}
    with pytest.raises(error) as info:
        mjkin.solutions(tree, args.pop("goal"), **args)
    assert "\n" not in str(info.value)


# ------------------------------------------------------------------ certified reasons
@pytest.fixture(scope="module")
def arm7() -> mjkin.Tree:
    return mjkin.load("arm7")


FRAMES = {"arm7": "ee", "ball_chain": "tip", "planar_prismatic": "tip", "panda": "flange", "primate": "left_hand"}


@pytest.fixture(scope="module")
def models() -> dict[str, mjkin.Tree]:
    return {name: mjkin.load(name) for name in FRAMES}


@settings(max_examples=15)
@given(seed=st.integers(0, 2**32 - 1), model=st.sampled_from(sorted(FRAMES)))
def test_a_reachable_target_is_never_proven_unreachable(models, seed, model):
    """Sample q, FK: that target is reachable, so a solve that fails (no iteration) may say not_found, never prove."""
    tree, frame = models[model], FRAMES[model]
    rng = np.random.default_rng(seed)
    q = tree.random_q(rng, 8)
    T = tree.pose(q, frame)
    for goal in (G.Pose(frame, T), G.Position(frame, T[:, :3, 3])):
        res = mjkin.solve(tree, goal, method="lm", max_iters=0, restarts=0)
        assert set(res.reason[~res.success]) <= {"not_found"} and set(res.reason[res.success]) <= {""}
    body, T_site = tree.frame_body(frame)
    anchor, bound = reach_bound(tree, body, T_site[:3, 3], np.ones(tree.nv, bool), q)
    assert np.all(np.linalg.norm(T[:, :3, 3] - anchor, axis=-1) <= bound + 1e-12)


@settings(max_examples=25)
@given(value=st.floats(-0.5, 0.5), kind=st.sampled_from(["hinge", "slide"]))
def test_a_single_joint_target_inside_the_limits_is_never_proven_blocked(value, kind):
    tree = single_joint(kind)
    target = tree.pose(np.array([value]), "ee")[:3, 3]
    res = mjkin.solve(tree, G.Position("ee", target), method="lm", max_iters=0, restarts=0)
    assert str(res.reason) in ("", "not_found")


def test_far_targets_are_proven_out_of_reach(arm7):
    near = arm7.pose(arm7.random_q(np.random.default_rng(0)), "ee")[:3, 3]
    res = mjkin.solve(arm7, G.Position("ee", [[3.0, 0, 0], [0, 0, -4.0], near]))
    assert list(res.reason) == ["out_of_reach", "out_of_reach", ""]
    assert not res.success[:2].any() and "out_of_reach" not in set(res.status)  # the reason stands beside the status
    assert res.reason.shape == res.status.shape


def test_a_free_joint_carries_any_target_so_nothing_is_proven_out_of_reach():
    """A figure on a free joint reaches anywhere: its far targets are not_found, the bound never claimed."""
    tree = mjkin.load("primate")
    res = mjkin.solve(tree, [G.Position("head", [100.0, 0, 0], kind="body"), G.Position("left_hand", [0, -50.0, 0],
                                                                                         kind="body")],
                      method="lm", max_iters=0, restarts=0)
    assert not res.success and str(res.reason) == "not_found"
    body = tree.id("head", "body")
    assert np.isinf(reach_bound(tree, body, np.zeros(3), np.ones(tree.nv, bool), tree.qpos0[None])[1]).all()


def test_success_costs_nothing_and_reason_is_empty(arm7):
    res = mjkin.solve(arm7, G.Position("ee", arm7.pose(arm7.random_q(np.random.default_rng(1)), "ee")[:3, 3]))
    assert res.success and str(res.reason) == ""


def single_joint(kind: str) -> mjkin.Tree:
    link = Link("arm", joint=kind, axis=(0, 0, 1) if kind == "hinge" else (1, 0, 0), length=1.0,
                range=(-0.5, 0.5))
    return mjkin.load(links_mjcf([link]))


def test_limits_proven_for_a_single_hinge_and_slide():
    hinge = single_joint("hinge")
    angles = np.array([2.0, -1.5, 0.3, 0.6])
    targets = np.stack([np.cos(angles), np.sin(angles), np.zeros(4)], -1)
    targets = np.vstack([targets, [[0.5, 0.0, 0.0], [0.0, 0.0, 3.0]]])  # inside the circle; beyond the reach
    res = mjkin.solve(hinge, G.Position("ee", targets))
    assert list(res.reason) == ["limits", "limits", "", "limits", "not_found", "out_of_reach"]
    slide = single_joint("slide")  # the tip at x = 1 + s, s in [-0.5, 0.5]
    res = mjkin.solve(slide, G.Position("ee", [[2.0, 0, 0], [0.2, 0, 0], [1.3, 0, 0], [1.2, 0.5, 0]]))
    assert list(res.reason) == ["out_of_reach", "limits", "", "not_found"]  # past 1.5 m the bound proves it first


@pytest.mark.parametrize("options, text", [({"rounds": 10**6}, "rounds must be a whole number from 1 to 100,000"),
                                           ({"starts": 50_000, "rounds": 3}, "starts x rounds must be at most 100,000"),
                                           ({"starts": 1000, "rounds": 1000}, "at most 100,000, got 1000 x 1000"),
                                           ({"starts": 10**7}, "starts must be a whole number from 1 to 100,000")])
def test_work_past_the_documented_bound_is_refused_before_it_starts(options, text):
    """solutions(rounds=10**6) grew to 24 GB until the out-of-memory killer ended it."""
    tree = mjkin.load("arm7")
    with pytest.raises(mjkin.InputError, match=text):
        mjkin.solutions(tree, mjkin.goals.Position("ee", (0.3, 0.1, 0.4)), **options)
