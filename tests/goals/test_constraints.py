"""Hard constraints (issue 22): inside the solver, and ``success=True`` a promise, checked independently."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mjkin
from conftest import assert_goal_jacobian, tree_of
from mjkin import goals as G
from mjkin.errors import GoalError, InputError
from mjkin.ik import evaluate
from mjkin.ik.kernel import HARD_TOL
from mjkin.kinematics.qspace import BALL, FREE, HINGE

WALL = {"point": [0.0, 0.0, 0.5], "normal": [0.0, 0.0, 1.0]}


def steps(tree, q, q_prev):
    """Each joint's step ``(njnt + nfree,)`` from ``q_prev`` to ``q``, as StepLimit measures it (independently)."""
    out = []
    for j in range(tree.njnt):
        t, a = int(tree.jnt_type[j]), int(tree.jnt_qadr[j])
        if t == FREE:
            out.append(np.linalg.norm(q[a:a + 3] - q_prev[a:a + 3]))
            out.append(mjkin.spatial.quat_distance(q[a + 3:a + 7], q_prev[a + 3:a + 7]))
        elif t == BALL:
            out.append(mjkin.spatial.quat_distance(q[a:a + 4], q_prev[a:a + 4]))
        else:
            d = q[a] - q_prev[a]
            if t == HINGE and not tree.jnt_limited[j]:
                d = (d + np.pi) % (2 * np.pi) - np.pi
            out.append(abs(d))
    return np.array(out)


def wall_distance(tree, q, frame="ee", point=WALL["point"], normal=WALL["normal"]):
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    return float((tree.pose(q, frame)[:3, 3] - point) @ n)


# ------------------------------------------------------------------ Jacobians
@pytest.mark.parametrize("model", ["arm7", "primate"])
def test_hard_rows_match_finite_differences(model, rng):
    tree = tree_of(model)
    frame = "ee" if model == "arm7" else "right_hand"
    q_prev = tree.random_q(rng)
    goals = [G.HalfSpace(frame, point=[0.1, 0.2, 0.3], normal=[1, 2, 3]), G.StepLimit(q_prev, 0.2)]
    for goal in goals:
        for q in tree.random_q(rng, 3):
            assert_goal_jacobian(tree, goal, q)


def test_step_limit_rows_are_the_margins_left():
    tree = tree_of("primate")
    rng = np.random.default_rng(3)
    q_prev, q = tree.random_q(rng, 2)
    g, _, err = evaluate(tree, G.StepLimit(q_prev, 0.25), q)
    np.testing.assert_allclose(g[0], 0.25 - steps(tree, q, q_prev), atol=1e-12)
    assert err[0, 0, 0] == pytest.approx(max(0.0, -g[0].min()))


# ------------------------------------------------------------------ HalfSpace
@pytest.mark.parametrize("method", ["lm", "auto", "dls", "pinv", "optimize"])
def test_half_space_holds_on_every_success_and_binds_the_rest(method):
    tree = tree_of("arm7")
    rng = np.random.default_rng(7)
    targets = tree.pose(tree.random_q(rng, 12), "ee")[:, :3, 3]
    wall = G.HalfSpace("ee", **WALL)
    for p in targets:
        res = mjkin.solve(tree, [G.Position("ee", p), wall], method=method)
        s = wall_distance(tree, res.q)
        assert np.all(np.isfinite(res.q)) and np.allclose(tree.clip(res.q), res.q, atol=1e-12)
        if res.success:
            assert s >= -HARD_TOL
        if p[2] < 0.5 - 1e-3:  # behind the wall: never met; the answer keeps the wall and names it
            assert not res.success
            if res.status == "constraint":
                assert s >= -HARD_TOL and res.goals[int(res.binding)] is wall
        elif method in ("lm", "auto", "optimize"):
            assert res.success


def test_a_wall_is_exact_for_targets_beyond_it():
    """Pulled toward targets past a wall, the default method stops on it: it ended up to HARD_TOL (9.97e-7 m) past."""
    tree = tree_of("arm7")
    wall = G.HalfSpace("ee", **WALL)
    P = tree.pose(tree.random_q(np.random.default_rng(5), 400), "ee")[:, :3, 3]
    P = P[P[:, 2] < WALL["point"][2]][:30]
    res = mjkin.solve(tree, [G.Position("ee", P), wall])
    depth = WALL["point"][2] - tree.pose(res.q, "ee")[:, 2, 3]
    assert len(P) == 30 and depth.max() <= 1e-9


def test_unreachable_with_a_wall_is_the_closest_pose_on_it():
    tree = tree_of("arm7")
    wall = G.HalfSpace("ee", **WALL)
    q = tree.random_q(np.random.default_rng(11), 40)
    below = tree.pose(q, "ee")[:, :3, 3]
    below = below[below[:, 2] < 0.4][:5]
    for p in below:
        res = mjkin.solve(tree, [G.Position("ee", p), wall], method="lm")
        assert res.status == "constraint" and not res.success
        assert res.goals[int(res.binding)] is wall and res.goal_errors[0, 0] <= HARD_TOL
        ee = tree.pose(res.q, "ee")[:3, 3]
        assert abs(ee[2] - 0.5) <= HARD_TOL
        np.testing.assert_allclose(ee[:2], p[:2], atol=1e-4)  # the foot of the target on the wall


def test_hard_goals_come_first_and_only_a_weight_switches_them():
    tree = tree_of("arm7")
    q0 = tree.model.key_qpos[0]
    wall = G.HalfSpace("ee", point=[0, 0, 2.0], normal=[0, 0, 1])  # out of reach: never holds
    target = tree.pose(q0 + 0.3, "ee")[:3, 3]
    res = mjkin.solve(tree, [G.Position("ee", target), wall], q0=q0, method="lm")
    assert res.goals[0] is wall and res.status == "constraint" and not res.success and res.binding == 0
    off = mjkin.solve(tree, [G.Position("ee", target), G.HalfSpace("ee", point=[0, 0, 2.0], weight=0)],
                      q0=q0, method="lm")
    assert off.success and off.binding == -1


def test_a_start_behind_the_wall_is_pushed_out():
    tree = tree_of("arm7")
    q0 = tree.model.key_qpos[0]
    wall = G.HalfSpace("ee", point=[0, 0, 1.2], normal=[0, 0, 1])
    assert wall_distance(tree, q0, point=[0, 0, 1.2]) < 0
    for method in ("lm", "dls", "transpose", "optimize"):
        res = mjkin.solve(tree, wall, q0=q0, method=method)
        assert res.success and wall_distance(tree, res.q, point=[0, 0, 1.2]) >= -HARD_TOL, method


# ------------------------------------------------------------------ StepLimit
@pytest.mark.parametrize("model,frame", [("arm7", "ee"), ("primate", "right_hand")])
def test_step_limit_holds_every_step(model, frame):
    tree = tree_of(model)
    rng = np.random.default_rng(5)
    q0 = tree.qpos0
    limit = np.full(tree.njnt, 0.1)
    limit[0] = 0.05
    for p in tree.pose(tree.random_q(rng, 6), frame)[:, :3, 3]:
        res = mjkin.solve(tree, [G.Position(frame, p), G.StepLimit(q0, limit)], q0=q0, method="lm")
        assert np.all(steps(tree, res.q, q0) <= np.repeat(limit, 1 + (tree.jnt_type == FREE)) + HARD_TOL)
        assert res.status in ("converged", "constraint")


def test_step_limit_is_exact_on_hinges():
    tree = tree_of("arm7")
    q0 = tree.model.key_qpos[0]
    far = tree.pose(tree.random_q(np.random.default_rng(2), 5), "ee")[:, :3, 3]
    for p in far:
        res = mjkin.solve(tree, [G.Position("ee", p), G.StepLimit(q0, 0.05)], q0=q0, method="lm")
        assert np.all(np.abs(res.q - q0) <= 0.05 + 1e-9)


def test_follow_keeps_max_joint_speed_over_a_trajectory():
    tree = tree_of("arm7")
    q0 = tree.model.key_qpos[0]
    start = tree.pose(q0, "ee")[:3, 3]
    path = start + np.linspace(0, 1, 40)[:, None] * np.array([-0.3, 0.4, -0.2])  # too fast for the limit
    speed, fps = 1.0, 30.0
    traj = mjkin.motion.follow(tree, "ee", path, q0=q0, fps=fps, max_joint_speed=speed)
    free = mjkin.motion.follow(tree, "ee", path, q0=q0, fps=fps)
    qs = np.vstack([q0, traj.q])
    worst = max(steps(tree, b, a).max() for a, b in zip(qs[:-1], qs[1:], strict=True))
    assert worst <= speed / fps + 1e-9
    fast = np.vstack([q0, free.q])
    assert max(steps(tree, b, a).max() for a, b in zip(fast[:-1], fast[1:], strict=True)) > speed / fps  # it binds
    final = tree.pose(traj.q[-1], "ee")[:3, 3]
    assert np.linalg.norm(final - path[-1]) < 0.05  # and the arm catches up once the path stops


def test_follow_refuses_bad_speeds():
    tree = tree_of("arm7")
    pts = tree.pose(tree.qpos0, "ee")[None, :3, 3]
    for bad in (0.0, -1.0, [1.0, 2.0], "fast"):
        with pytest.raises(InputError, match="max_joint_speed"):
            mjkin.motion.follow(tree, "ee", pts, max_joint_speed=bad)


# ------------------------------------------------------------------ input, equality, pickling
@pytest.mark.parametrize("goal,match", [
    (lambda t: G.StepLimit(t.qpos0, [0.1, 0.2]), "one per joint"),
    (lambda t: G.StepLimit(t.qpos0, -0.1), ">= 0"),
    (lambda t: G.StepLimit(t.qpos0, np.nan), ">= 0"),
    (lambda t: G.StepLimit(t.qpos0[:3], 0.1), "q_prev"),
    (lambda t: G.StepLimit([np.nan] * t.nq, 0.1), "q_prev"),
])
def test_bad_constraints_fail_in_one_line(goal, match):
    tree = tree_of("arm7")
    with pytest.raises(GoalError, match=match) as info:
        mjkin.solve(tree, [G.Position("ee", [0.3, 0, 0.5]), goal(tree)])
    assert "\n" not in str(info.value)


def test_solve_equals_problem_solve_bit_for_bit_and_results_pickle():
    tree = tree_of("primate")
    rng = np.random.default_rng(9)
    q_prev = tree.random_q(rng)
    goals = [G.Position("right_hand", tree.pose(tree.random_q(rng), "right_hand")[:3, 3]),
             G.HalfSpace("left_hand", point=[0, 0, 1.0], normal=[0, 0, 1]), G.StepLimit(q_prev, 0.3)]
    a = mjkin.solve(tree, goals, q0=q_prev)
    b = mjkin.Problem(tree, goals).solve(q_prev)
    assert np.array_equal(a.q, b.q) and a.status == b.status and np.array_equal(a.binding, b.binding)
    c = pickle.loads(pickle.dumps(a))
    assert np.array_equal(c.q, a.q) and c.binding == a.binding and c.status == a.status


def test_batched_results_carry_binding_per_target():
    tree = tree_of("arm7")
    p = np.array([[0.3, 0.0, 0.6], [0.3, 0.0, 0.2]])  # above, behind the wall
    res = mjkin.solve(tree, [G.Position("ee", p), G.HalfSpace("ee", **WALL)], method="lm")
    assert res.binding.shape == (2,) and list(res.success) == [True, False]
    assert list(res.binding) == [-1, 0] and list(res.status) == ["converged", "constraint"]


# ------------------------------------------------------------------ property
@settings(max_examples=25)
@given(seed=st.integers(0, 2**31 - 1), wall=st.booleans(), step=st.one_of(st.none(), st.floats(0.02, 1.0)),
       method=st.sampled_from(["lm", "dls", "optimize"]))
def test_success_means_every_hard_constraint_holds(seed, wall, step, method):
    tree = tree_of("arm7")
    rng = np.random.default_rng(seed)
    q_prev, q_goal = tree.random_q(rng, 2)
    target = tree.pose(q_goal, "ee")[:3, 3] + rng.normal(scale=0.05, size=3)
    normal, point = rng.normal(size=3), tree.pose(tree.random_q(rng), "ee")[:3, 3]
    goals: list[G.Goal] = [G.Position("ee", target)]
    if wall:
        goals.append(G.HalfSpace("ee", point=point, normal=normal))
    if step is not None:
        goals.append(G.StepLimit(q_prev, step))
    res = mjkin.solve(tree, goals, q0=q_prev, method=method, max_iters=60)
    assert np.all(np.isfinite(res.q)) and np.all(np.isfinite(res.goal_errors))
    np.testing.assert_allclose(tree.clip(res.q), res.q, atol=1e-12)
    if res.success:
        if wall:
            assert wall_distance(tree, res.q, point=point, normal=normal) >= -HARD_TOL
        if step is not None:
            assert np.all(steps(tree, res.q, q_prev) <= step + HARD_TOL)
    if step is not None and not wall and method != "optimize":  # the start keeps the limit, so every answer does
        assert np.all(steps(tree, res.q, q_prev) <= step + HARD_TOL)


def test_cartesian_env_keeps_max_joint_speed():
    import gymnasium as gym

    import mjkin.envs  # noqa: F401  (registers the ids)

    speed = 0.5
    env = gym.make("mjkin/Reach-v0", action_type="cartesian", max_joint_speed=speed)
    tree = env.unwrapped.tree
    env.reset(seed=0)
    prev, worst = env.unwrapped.q.copy(), 0.0
    for _ in range(20):
        env.step(np.ones(3, dtype=np.float32))
        now = env.unwrapped.q.copy()
        worst = max(worst, steps(tree, now, prev).max())
        prev = now
    assert 0 < worst <= speed / 30 + 1e-9


# ------------------------------------------------------------------ Clearance
OBSTACLES = ('<geom name="ob0" type="sphere" size="0.1" pos="0.35 0.2 0.6"/>'
             '<geom name="ob1" type="sphere" size="0.08" pos="0.3 -0.25 0.45"/>'
             '<geom name="ob2" type="sphere" size="0.1" pos="-0.3 0.3 0.7"/>'
             '<geom name="table" type="box" size="0.3 0.3 0.02" pos="0.55 0 0.25"/>')


def cluttered(name="arm7"):
    """A bundled arm among three spheres and a table (the flange, a cylinder, meets the box: bounded)."""
    xml = mjkin.bundled_models()[name].read_text().replace("<worldbody>", "<worldbody>" + OBSTACLES, 1)
    return tree_of(xml)


def mujoco_clearance(tree, q):
    """The least signed distance over MuJoCo's contact pairs by ``mujoco.mj_geomDistance`` (the oracle)."""
    from mjkin.kinematics.distance import fallback_distance
    from mjkin.kinematics.geoms import contact_pairs

    return min(fallback_distance(tree, q, int(a), int(b))[0] for a, b in contact_pairs(tree))


def test_clearance_rows_are_the_closest_pairs_with_their_gradients(rng):
    from test_geoms import distance_jacobians

    from mjkin.kinematics.geoms import contact_pairs, native_pairs

    tree = cluttered()
    pairs = contact_pairs(tree)
    measured = pairs[native_pairs(tree.geoms, pairs)]  # (the flange, a cylinder, against the table box is bounded)
    goal = G.Clearance(0.02, pairs=measured, closest=4)
    for q in tree.random_q(rng, 5):
        g, J, _ = evaluate(tree, goal, q)
        d, Jd = distance_jacobians(tree, q, measured)
        near = np.sort(d)[:4] - 0.02
        live = near < G.Clearance.REACH
        np.testing.assert_allclose(g[0][live], near[live], atol=1e-9)
        np.testing.assert_allclose(g[0][~live], G.Clearance.REACH)
        for r in np.flatnonzero(live):
            p = int(np.argmin(np.abs(d - 0.02 - g[0, r])))
            np.testing.assert_allclose(J[0, r], Jd[p], atol=1e-9)


def test_a_pair_mjkin_cannot_measure_is_kept_by_its_bounding_sphere(rng):
    tree = cluttered()
    flange, table = tree.model.geom("flange").id, tree.model.geom("table").id
    goal = G.Clearance(0.0, pairs=[("flange", "table")], closest=1)
    for q in tree.random_q(rng, 20):
        s = evaluate(tree, goal, q)[0][0, 0]
        assert s <= tree.distances(q, [[flange, table]])[0] + 1e-12  # a lower bound of MuJoCo's distance


@pytest.mark.parametrize("method", ["lm", "auto", "optimize"])
def test_clearance_holds_on_every_success_by_mujoco(method):
    tree = cluttered()
    rng = np.random.default_rng(4)
    qs = tree.random_q(rng, 60)
    qs = qs[tree.distances(qs).min(axis=1) >= 0.02][:8]  # targets that a clear pose reaches
    goal = G.Clearance(0.02)
    wins = 0
    for q in qs:
        res = mjkin.solve(tree, [G.Position("ee", tree.pose(q, "ee")[:3, 3]), goal], method=method)
        if res.success:
            wins += 1
            assert mujoco_clearance(tree, res.q) >= 0.02 - HARD_TOL
        elif res.status == "constraint":
            assert res.goals[int(res.binding)] is goal
    assert wins >= len(qs) - 2


def test_avoid_collisions_is_a_clearance_that_moves_only_what_it_may():
    tree = cluttered()
    q0 = tree.model.key_qpos[0]
    target = tree.pose(tree.random_q(np.random.default_rng(8)), "ee")[:3, 3]
    res = mjkin.solve(tree, G.Position("ee", target), q0=q0, avoid_collisions=True, joints=["j2", "j3", "j4"])
    assert isinstance(res.goals[0], G.Clearance)  # hard goals come first
    moved = np.flatnonzero(np.abs(res.q - q0) > 0)
    assert set(moved) <= {int(tree.jnt_qadr[tree.id(j, "joint")]) for j in ("j2", "j3", "j4")}
    if res.success:
        assert not mjkin.scene.Scene(tree).in_collision(res.q)


@pytest.mark.parametrize("kwargs,error,match", [
    ({"margin": float("nan")}, GoalError, "margin"),
    ({"margin": "1"}, GoalError, "margin"),
    ({"pairs": [("ob0",)]}, GoalError, "pairs"),
    ({"pairs": [("ob0", "nothing")]}, mjkin.UnknownNameError, "nothing"),
    ({"pairs": [(0, 99)]}, GoalError, "99"),
])
def test_bad_clearance_fails_in_one_line(kwargs, error, match):
    tree = cluttered()
    with pytest.raises(error, match=match) as info:
        mjkin.solve(tree, [G.Position("ee", [0.3, 0, 0.5]), G.Clearance(**kwargs)])
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("arm", ["arm7", "panda"])
def test_clearance_answers_nearly_every_answerable_target_among_obstacles(arm):
    """Issue 38: 150 pose targets of configurations MuJoCo finds clear of three spheres and a table by the margin
    plus 1 mm (an answer exists for each). The default method answered 137 of 150; the goal is 99 %, and no
    answer it calls a success may be closer than the margin by MuJoCo's ``mj_geomDistance``."""
    from mjkin.apps.bench.constraints import ARMS, MARGIN, ROT_TOL, TOL, Judge, obstacle_scene

    tree, frame = obstacle_scene(arm), ARMS[arm]
    judge = Judge(tree, MARGIN)
    qs = [q for q in tree.random_q(np.random.default_rng(11), 1500) if judge.clearance(q) >= MARGIN + 1e-3][:150]
    assert len(qs) == 150
    T = tree.pose(np.array(qs), frame)
    q0 = np.broadcast_to(tree.model.key_qpos[0], (150, tree.nq)).copy()
    res = mjkin.solve(tree, [G.Pose(frame, T=T), G.Clearance(MARGIN)], q0=q0, tol=TOL, rot_tol=ROT_TOL)
    clear = np.array([judge.clear(q) for q in res.q])
    assert not (res.success & ~clear).any()
    assert (res.success & clear).sum() >= 149, set(res.status[~res.success])


def sphere_scene(model: str, seed: int, margin: float, k: int = 3):
    """The bundled ``model`` among ``k`` spheres of radius 4-12 cm, each centred near a body of the arm in a random
    configuration (in its workspace), redrawn until the keyframe keeps ``margin`` + 1 mm: tree, judge, keyframe."""
    import mujoco

    from mjkin.apps.bench.constraints import Judge

    rng = np.random.default_rng(seed)
    arm = mjkin.load(model)
    home = arm.model.key_qpos[0]
    while True:
        spec = mujoco.MjSpec.from_file(str(mjkin.bundled_models()[model]))
        for i in range(k):
            body = arm.model.body(int(rng.integers(2, arm.model.nbody))).name
            centre = arm.pose(arm.random_q(rng), body, "body")[:3, 3] + rng.normal(0.0, 0.05, 3)
            spec.worldbody.add_geom(name=f"ball{i}", type=mujoco.mjtGeom.mjGEOM_SPHERE, pos=centre,
                                    size=(rng.uniform(0.04, 0.12), 0, 0), contype=1, conaffinity=1)
        tree = mjkin.load(spec)
        judge = Judge(tree, margin)
        if judge.clearance(home) >= margin + 1e-3:
            return tree, judge, home


# the Panda's link0-link1 stand 8 mm apart: 5 mm; it misses ~1 in 200 (joint limits, iterations: 597 of 600 over
# four scenes), so one scene of 150 may miss 2
@pytest.mark.parametrize("arm,margin,least", [("arm7", 0.01, 149), ("panda", 0.005, 148)])
@settings(max_examples=2)
@given(seed=st.integers(0, 2**32 - 1))
def test_clearance_answers_nearly_every_answerable_target_in_scenes_never_seen(arm, margin, least, seed):
    """Issue 55: scenes no test or tuning saw (drawn anew on each local run, fixed in CI): 150 pose targets of
    configurations MuJoCo finds clear by the margin + 1 mm, one default solve each from the keyframe: >= 99 %
    answered, none MuJoCo finds inside the margin."""
    from mjkin.apps.bench.constraints import ARMS

    tree, judge, home = sphere_scene(arm, seed, margin)
    rng = np.random.default_rng(seed)
    qs: list = []
    while len(qs) < 150:
        qs += [q for q in tree.random_q(rng, 600) if judge.clearance(q) >= margin + 1e-3][:150 - len(qs)]
    T = tree.pose(np.array(qs), ARMS[arm])
    goals = [G.Pose(ARMS[arm], T=T[0]), G.Clearance(margin)]
    problem = mjkin.Problem(tree, goals)
    ok, missed = 0, []
    for k in range(150):
        res = problem.solve(home, [G.Pose(ARMS[arm], T=T[k]), G.Clearance(margin)])
        clear = judge.clear(res.q)
        assert clear or not res.success, (seed, k)
        ok += bool(res.success)
        if not res.success:
            missed.append((k, str(res.status)))
    assert ok >= least, (seed, missed)


def test_judge_sees_every_pair_within_the_margin_among_world_geoms():
    """MuJoCo's mid-phase, built when the model compiled without the judge's margin, hid the Panda's link0-link1
    (8 mm apart) once three spheres stood in the world body: the judge called 5 mm clear where it is not."""
    import mujoco

    from mjkin.apps.bench.constraints import Judge

    spec = mujoco.MjSpec.from_file(str(mjkin.bundled_models()["panda"]))
    for pos, r in (((-0.297, 0.595, 0.075), 0.091), ((-0.502, 0.032, 0.82), 0.109), ((-0.272, -0.165, 0.973), 0.092)):
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, pos=pos, size=(r, 0, 0))
    tree = mjkin.load(spec)
    judge = Judge(tree, 0.01)
    for q in [tree.model.key_qpos[0], *tree.random_q(np.random.default_rng(0), 20)]:
        assert judge.clearance(q) == pytest.approx(min(tree.distances(q).min(), 0.02), abs=1e-9)
