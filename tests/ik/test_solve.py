"""The solve front door: time limits, what restarts may move, threads, pickling, one compiled layout."""

from __future__ import annotations

import importlib
import os
import pickle
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mjkin
from conftest import GYM_ASSETS, tree_of
from mjkin import goals as G
from mjkin.errors import GoalError
from mjkin.goals.program import compile_goals
from mjkin.ik import kernel
from mjkin.ik.lm import AUTO_RESTARTS
from mjkin.ik.loop import solve_packed


def pose_targets(tree, site, rng, n):
    return tree.pose(tree.random_q(rng, n), site)


# ------------------------------------------------------------------- stalls
def test_progress_is_an_unmet_counted_goal_falling_by_the_fraction():
    tol, rot_tol = 1e-3, 1e-2
    counted = np.array([True, True, False])
    ref = np.array([50.0, 0.5, 80.0])  # errors in tolerances at the last progress: unmet, met, not counted
    err = np.array([[0.046, 0.0], [1e-4, 1e-3], [0.01, 0.0]])  # 8 % down; the met one and the uncounted fell a lot
    assert not kernel.progressed(err, counted, tol, rot_tol, ref, 0.9)
    assert ref.tolist() == [50.0, 0.5, 80.0]  # unchanged without progress
    err[0] = [0.0, 0.44]  # 12 % down, now on its rotation
    assert kernel.progressed(err, counted, tol, rot_tol, ref, 0.9)
    np.testing.assert_allclose(ref, [44.0, 0.1, 10.0])  # the next window starts from here


def test_lm_follows_a_slowly_converging_run():
    """Five position goals on the primate converge linearly for ~100 iterations in one run: no window of
    LM_PATIENCE iterations passes without some goal's error falling by LM_PROGRESS, so the run goes on."""
    tree = tree_of("primate")
    targets = {f: tree.pose(tree.qpos0, f, "body")[:3, 3] for f in ("left_foot", "right_foot", "head", "right_hand")}
    targets["left_hand"] = tree.pose(tree.qpos0, "left_hand", "body")[:3, 3] + [0.15, 0.05, 0.1]
    goals = [G.Position(f, xyz, kind="body") for f, xyz in targets.items()]
    free = [n for n, t in zip(tree.names("joint"), tree.jnt_type, strict=True) if t != mjkin.kinematics.qspace.FREE]
    res = mjkin.solve(tree, goals, tree.qpos0, max_iters=200, restarts=0, joints=free)
    assert res.success and res.iterations > 40, (res.status, res.iterations)


def test_result_summary_takes_the_worst_counted_goal_and_keeps_nan():
    err = np.array([[[1e-7, 2e-6], [5.0, 5.0]], [[np.nan, 0.0], [0.0, 0.0]], [[2e-6, 0.0], [0.0, 0.0]]])
    worst, success = np.empty((3, 2)), np.empty(3, dtype=bool)
    none = np.array([False, False])  # no hard constraints
    kernel.summarise(err, np.array([True, False]), none, 1e-6, 1e-5, worst, success)
    np.testing.assert_array_equal(worst, [[1e-7, 2e-6], [np.nan, 0.0], [2e-6, 0.0]])  # goal 1 is not counted
    assert success.tolist() == [True, False, False]
    kernel.summarise(err, none, none, 1e-6, 1e-5, worst, success)
    assert (worst == 0).all() and success.all()  # nothing counted: nothing missed
    kernel.summarise(err, none, np.array([False, True]), 1e-6, 1e-5, worst, success)  # goal 1 hard: its violation
    assert (worst == 0).all() and success.tolist() == [False, True, True]


# ------------------------------------------------------------------ timeout
def test_timeout_stops_each_target_and_says_so(rng):
    tree = tree_of("arm7")
    T = pose_targets(tree, "ee", rng, 80)  # 80 targets: the threaded path
    far = tree.qpos0
    res = mjkin.solve(tree, G.Pose("ee", T=T), far, tol=1e-12, rot_tol=1e-12, timeout=1e-9)
    assert set(res.status) == {"timeout"}
    assert not res.success.any()
    assert np.all(res.iterations <= 1)  # one pass at most before the clock is read
    np.testing.assert_allclose(tree.clip(res.q), res.q, atol=1e-12)


def test_generous_timeout_changes_nothing(rng):
    tree = tree_of("arm7")
    T = pose_targets(tree, "ee", rng, 20)
    a = mjkin.solve(tree, G.Pose("ee", T=T), tol=1e-5, rot_tol=1e-5)
    b = mjkin.solve(tree, G.Pose("ee", T=T), tol=1e-5, rot_tol=1e-5, timeout=60.0)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.status, b.status)


@pytest.mark.parametrize("method", ["auto", "dls", "pinv", "transpose", "ccd", "reach", "optimize", "analytic2"])
def test_timeout_works_with_every_method_and_inf_is_no_limit(method):
    tree = tree_of("planar_2link")
    goal, q0 = G.Position("tip", (1.2, 0.5, 0.0)), [0.3, 0.5]
    a = mjkin.solve(tree, goal, q0, method=method)
    b = mjkin.solve(tree, goal, q0, method=method, timeout=float("inf"))
    np.testing.assert_array_equal(a.q, b.q)
    assert b.success
    if method == "auto":  # no limit: the usual restarts, not the 1000 a time limit allows
        far = mjkin.solve(tree, G.Position("tip", (5.0, 0.0, 0.0)), q0, timeout=float("inf"))
        assert far.restarts == AUTO_RESTARTS
    late = mjkin.solve(tree, goal, q0, method=method, timeout=1e-9)  # was refused for ccd, reach, optimize, analytic2
    assert late.status == ("converged" if method == "analytic2" else "timeout")  # the closed form takes no time
    np.testing.assert_allclose(tree.clip(late.q), late.q, atol=1e-12)


# found by a probe: SciPy's SLSQP on the primate with a half-space and a plane goal and a planted upper arm runs
# to its iteration limit in every level and re-centring pass (2042 iterations, 30-140 s here, up to 489 s there)
PRIMATE_WALLS = [G.HalfSpace("right_hand", point=[-0.223, -0.339, 1.47], normal=[-0.378, 2.043, 0.647]),
                 G.Plane("head", point=[0.016, -0.384, 1.123], normal=[0.663, -0.514, -1.648])]


@pytest.mark.parametrize("timeout", [0.5, None])
def test_optimize_stops_on_time_with_the_best_so_far(timeout, monkeypatch):
    front = importlib.import_module("mjkin.ik.optimize")
    assert 0 < front.OPTIMIZE_TIMEOUT <= 10  # a default bound of a few seconds per target
    monkeypatch.setattr(front, "OPTIMIZE_TIMEOUT", 0.5)  # the default's path, without waiting for it
    tree = tree_of("primate")
    start = mjkin.solve(tree, PRIMATE_WALLS, method="optimize", root="left_upper_arm", max_iters=0)
    res = mjkin.solve(tree, PRIMATE_WALLS, method="optimize", root="left_upper_arm", timeout=timeout)
    assert res.status == "timeout" and not res.success
    np.testing.assert_allclose(tree.clip(res.q), res.q, atol=1e-12)
    # an SLSQP iterate cut short can be far worse than where it began (2 m off the planted arm): never kept
    assert np.all(np.isfinite(res.goal_errors)) and res.error[0] <= start.error[0] + 1e-12


# options: (name, what a good value must be) -> the checks solve makes
POSITIVE = ("tol", "rot_tol", "damping", "alpha")
POSITIVE_OR_INF = ("timeout", "max_step", "goal_step")
COUNTS = ("max_iters", "restarts", "seed")  # whole numbers >= 0
bad_number = st.one_of(st.floats(max_value=0.0), st.just(float("nan")), st.just("1e-3"), st.just(True),
                       st.just(None).map(lambda _: [1.0]))


@settings(max_examples=60, deadline=None)
@given(name=st.sampled_from(POSITIVE + POSITIVE_OR_INF + COUNTS + ("patience",)), value=bad_number)
def test_every_numeric_option_refuses_bad_values_in_one_line(name, value):
    if name in COUNTS and isinstance(value, float) and value == 0.0:
        return  # zero is a fine count
    tree = tree_of("planar_3link")
    with pytest.raises(mjkin.InputError, match=name) as info:
        mjkin.solve(tree, G.Position("tip", (10.0, 5.0, 0.0)), **{name: value})
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("kwargs, text", [
    ({"damping": float("nan")}, "damping must be a finite number > 0"),  # gave NaN q with status "converged"
    ({"method": "dls", "damping": 0.0}, "damping must be a finite number > 0"),  # ZeroDivisionError
    ({"damping": -1.0}, "damping must be a finite number > 0"),  # accepted, then 692 iterations to nowhere
    ({"max_iters": 1.5}, "max_iters must be a whole number from 0 to 1,000,000,000"),  # truncated silently
    ({"tol": "1e-3"}, "tol must be a finite number > 0"),  # TypeError
    ({"seed": -1}, "seed must be a whole number >= 0"),  # numpy's ValueError
    ({"halving": -1}, "halving must be True or False"),
    ({"patience": 0}, "patience must be a whole number from 1 to 1,000,000,000"),
])
def test_bad_options_found_by_a_new_user(kwargs, text):
    tree = tree_of("planar_3link")
    with pytest.raises(mjkin.InputError, match=text):
        mjkin.solve(tree, G.Position("tip", (10.0, 5.0, 0.0)), **kwargs)


@pytest.mark.parametrize("make, text", [
    (lambda: mjkin.ik.LM(foo=1), "method 'lm' takes no option 'foo'; its options: damping, goal_step, halving, "),
    (lambda: mjkin.ik.CCD(*range(9)), "method 'ccd' takes at most 4 options, 9 given by position; its options: "),
    (lambda: mjkin.solve(tree_of("planar_3link"), G.Position("tip", (1.0, 0.0, 0.0)), method="lm", foo=1),
     "method 'lm' takes no option 'foo'; its options: damping, goal_step, halving, "),
])
def test_a_method_object_with_an_unknown_option_gives_the_line_its_name_gives(make, text):
    """``mjkin.ik.LM(foo=1)`` was a bare TypeError from the dataclass; now the same one line as ``method="lm"``."""
    with pytest.raises(mjkin.InputError, match=text.replace("(", r"\(")):
        make()


def test_goals_that_are_not_goals_are_a_goal_error():
    with pytest.raises(mjkin.GoalError, match="goals must be a mjkin.goals goal or a list of them, got NoneType"):
        mjkin.solve(tree_of("planar_3link"), None)


def test_large_seeds_are_taken_exactly():
    from mjkin.runtime.checks import check_count

    assert check_count(2**64 + 1, "seed", 0) == 2**64 + 1  # not through a float, where it would be 2**64
    assert check_count(np.uint64(2**63 + 7), "seed", 0) == 2**63 + 7
    assert check_count(3.0, "seed", 0, whole_floats=True) == 3
    with pytest.raises(mjkin.InputError, match="seed must be a whole number >= 0, got 3.0"):
        check_count(3.0, "seed", 0)  # a float only where whole floats are taken


# ------------------------------------------------ restarts move only what helps
def test_restarts_leave_joints_that_cannot_help():
    """pusher.xml: the object and goal slide joints are no ancestors of the arm's tip."""
    tree = tree_of(GYM_ASSETS / "pusher.xml")
    arm = {tree.names("joint")[j] for j in range(tree.njnt) if tree.names("joint")[j].startswith(("r_",))}
    others = [j for j in range(tree.njnt) if tree.names("joint")[j] not in arm]
    assert others, "pusher has object/goal joints"
    q0 = tree.qpos0.copy()
    res = mjkin.solve(tree, G.Position("tips_arm", kind="body", xyz=(5.0, 5.0, 5.0)), q0, restarts=6)
    assert res.restarts == 6  # unreachable: every restart ran
    for j in others:
        a = tree.jnt_qadr[j]
        assert res.q[a] == q0[a], tree.names("joint")[j]


def test_restarts_keep_the_other_branches_of_a_tree():
    tree = tree_of("primate")
    q0 = tree.clip(tree.random_q(np.random.default_rng(3)))  # as solve starts: quaternions renormalised
    left = tree.pose(q0, "left_hand")[:3, 3]
    res = mjkin.solve(tree, [G.Position("left_hand", left + (0.0, 0.0, 5.0))], q0, restarts=4,
                      joints=None, base="upper_torso")
    moved = np.flatnonzero(res.q != q0)
    hand_dofs = set(tree.body_dofs[tree.id("left_hand", "body")].tolist())
    torso_dofs = set(tree.body_dofs[tree.id("upper_torso", "body")].tolist())
    allowed_q = set()
    for j in range(tree.njnt):
        d = int(tree.jnt_dofadr[j])
        if d in hand_dofs and d not in torso_dofs:
            n = {0: 7, 1: 4}.get(int(tree.jnt_type[j]), 1)
            allowed_q |= set(range(tree.jnt_qadr[j], tree.jnt_qadr[j] + n))
    assert set(moved.tolist()) <= allowed_q


def test_restarts_respect_joints_and_two_effectors(rng):
    tree = tree_of("primate")
    q0 = tree.qpos0.copy()
    joints = ["left_shoulder", "left_elbow"]
    far = tree.pose(q0, "left_hand")[:3, 3] + (0.0, 3.0, 0.0)
    res = mjkin.solve(tree, [G.Position("left_hand", far), G.Position("right_hand", (0.0, -3.0, 0.0))], q0,
                      joints=joints, restarts=3)
    keep = np.ones(tree.nq, dtype=bool)
    for name in joints:
        j = tree.id(name, "joint")
        n = {0: 7, 1: 4}.get(int(tree.jnt_type[j]), 1)
        keep[tree.jnt_qadr[j]:tree.jnt_qadr[j] + n] = False
    np.testing.assert_array_equal(res.q[keep], q0[keep])


def test_root_keeps_its_pose_through_restarts_and_collision_retries():
    tree = tree_of("primate")
    q0 = tree.qpos0.copy()
    foot = tree.pose(q0, "left_foot", kind="body")
    hand = tree.pose(q0, "right_hand")[:3, 3] + (0.1, 0.0, 0.1)
    for extra in ({"restarts": 4}, {"avoid_collisions": True}):
        res = mjkin.solve(tree, G.Position("right_hand", hand), q0, root="left_foot", **extra)
        np.testing.assert_allclose(tree.pose(res.q, "left_foot", kind="body"), foot, atol=1e-5)


def test_collision_retries_move_only_what_helps():
    tree = tree_of(GYM_ASSETS / "pusher.xml")
    q0 = tree.qpos0.copy()
    arm = [j for j in range(tree.njnt) if tree.names("joint")[j].startswith("r_")]
    others = [int(tree.jnt_qadr[j]) for j in range(tree.njnt) if j not in arm]
    tip = tree.pose(q0, "tips_arm", kind="body")[:3, 3]
    res = mjkin.solve(tree, G.Position("tips_arm", kind="body", xyz=tip + (0.05, 0.0, -0.05)), q0,
                      avoid_collisions=True)
    np.testing.assert_array_equal(res.q[others], q0[others])


# ------------------------------------------------------------------- analytic2
@pytest.mark.parametrize("kwargs", [{"joints": ["shoulder"]}, {"restarts": 3}, {"max_iters": 5}, {"root": "link1"},
                                    {"history": True}])
def test_analytic2_rejects_options_it_cannot_honour(kwargs):
    tree = tree_of("planar_2link")
    with pytest.raises(mjkin.InputError, match="analytic2"):
        mjkin.solve(tree, G.Position("tip", (1.0, 0.5, 0.0)), method="analytic2", **kwargs)


# -------------------------------------------------------------- batch == loop
def test_threaded_batch_equals_loop_of_single_solves(rng):
    tree = tree_of("arm7")
    T = pose_targets(tree, "ee", rng, 96)  # >= 64: split over threads
    batch = mjkin.solve(tree, G.Pose("ee", T=T), tol=1e-5, rot_tol=1e-4)
    for b in range(len(T)):
        one = mjkin.solve(tree, G.Pose("ee", T=T[b]), tol=1e-5, rot_tol=1e-4)
        np.testing.assert_array_equal(batch.q[b], one.q)
        assert batch.status[b] == one.status and batch.iterations[b] == one.iterations


def test_halving_reaches_goals_the_plain_step_overshoots():
    """Goal halving (the Finnish thesis): a full pinv step from near-singular overshoots; halving lands."""
    tree = tree_of("planar_3link")
    q0 = np.array([0.0, 1e-3, 1e-3])
    goal = G.Position("tip", (20.0, 12.0, 0.0))
    plain = mjkin.solve(tree, goal, q0, method="pinv", max_iters=40, history=True)
    halved = mjkin.solve(tree, goal, q0, method="pinv", max_iters=40, halving=True, history=True)
    assert halved.success
    err = halved.history.error[:, 0]
    err = err[np.isfinite(err)]
    assert np.all(np.diff(err) <= 1e-12)  # halving only accepts steps that lower the error
    assert halved.iterations <= plain.iterations or not plain.success


# ------------------------------------------------------- pickling and slicing
def test_result_pickles_without_its_tree(rng):
    tree = tree_of("arm7")
    res = mjkin.solve(tree, G.Pose("ee", T=pose_targets(tree, "ee", rng, 3)))
    data = pickle.dumps(res)
    assert len(data) < 20_000  # the MjModel alone is over a megabyte
    back = pickle.loads(data)
    assert back.tree is None
    np.testing.assert_array_equal(back.q, res.q)
    with pytest.raises(mjkin.InputError, match="with_tree"):
        back.singular_values()
    np.testing.assert_allclose(back.with_tree(tree).singular_values(), res.singular_values())
    np.testing.assert_allclose(back.with_tree(mjkin.load("arm7")).q, res.q)  # the same model, loaded again
    for result in (back, res):  # after pickling and before
        with pytest.raises(mjkin.InputError, match="solved on another model .* not on 'panda'"):
            result.with_tree(tree_of("panda"))


def test_goal_take_slices_targets(rng):
    tree = tree_of("arm7")
    T = pose_targets(tree, "ee", rng, 10)
    R = T[:, :3, :3]
    goals = [G.Pose("ee", T=T), G.Orientation("ee", quat=R), G.Rest(tree.qpos0, weight=0.1, priority=1)]
    full = mjkin.solve(tree, goals)
    part = mjkin.solve(tree, [g.take(3, 7) for g in goals])
    np.testing.assert_array_equal(part.q, full.q[3:7])
    assert goals[2].take(3, 7) is goals[2]  # unbatched: as it is


@settings(max_examples=30, deadline=None)
@given(cuts=st.lists(st.integers(0, 9), max_size=4))
def test_goal_concatenate_undoes_take(cuts):
    rng = np.random.default_rng(len(cuts))
    T = np.tile(np.eye(4), (9, 1, 1))
    T[:, :3, 3] = rng.normal(size=(9, 3))
    goals = [G.Pose("ee", T=T), G.Position("ee", rng.normal(size=(9, 3)), offset=(0.0, 0.0, 0.1)),
             G.Orientation("ee", quat=np.tile([1.0, 0.0, 0.0, 0.0], (9, 1)), weight=0.5),
             G.Aim("ee", point=rng.normal(size=(9, 3))), G.Rest(np.zeros(7), priority=1)]
    edges = [0, *sorted(cuts), 9]
    for g in goals:
        back = G.concatenate([g.take(lo, hi) for lo, hi in zip(edges[:-1], edges[1:], strict=True)])
        assert type(back) is type(g) and back.batch() == g.batch()
        for name in g._batched:
            np.testing.assert_array_equal(np.asarray(getattr(back, name)), np.asarray(getattr(g, name)))
        assert (back.weight, back.priority) == (g.weight, g.priority)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 5))
def test_goal_unbatch_gives_each_target_as_built_alone(seed, n):
    """Each piece of unbatch() encodes as the goal built with that target alone (quaternions and matrices alike)."""
    tree = tree_of("arm7")
    rng = np.random.default_rng(seed)
    T = pose_targets(tree, "ee", rng, n)
    quat = rng.normal(size=(n, 4))
    goals = [(G.Pose("ee", T=T), "T"), (G.Position("ee", T[:, :3, 3], offset=(0.0, 0.0, 0.1), weight=2.0), "xyz"),
             (G.Orientation("ee", quat=quat, axes="z"), "quat"), (G.Orientation("ee", quat=T[:, :3, :3]), "quat"),
             (G.Aim("ee", point=rng.normal(size=(n, 3))), "point"),
             (G.Rest(tree.random_q(rng, n), priority=1), "q_rest")]
    for g, field in goals:
        pieces = g.unbatch()
        assert len(pieces) == n
        for b, piece in enumerate(pieces):
            alone = replace(g, **{field: np.asarray(getattr(g, field))[b]})
            assert piece.batch() == () and piece.key() == alone.key()
            np.testing.assert_array_equal(compile_goals(tree, piece).data, compile_goals(tree, alone).data)
            np.testing.assert_array_equal(compile_goals(tree, piece).rest_q, compile_goals(tree, alone).rest_q)
    one = G.Position("ee", (0.1, 0.2, 0.3))
    assert one.unbatch() == [one]


def test_goal_concatenate_rejects_pieces_of_different_goals():
    a = G.Position("ee", np.zeros((2, 3)))
    with pytest.raises(mjkin.GoalError, match="at least one"):
        G.concatenate([])
    with pytest.raises(mjkin.GoalError, match="pieces of one goal"):
        G.concatenate([a, G.Pose("ee", T=np.tile(np.eye(4), (2, 1, 1)))])
    with pytest.raises(mjkin.GoalError, match="pieces of one goal"):
        G.concatenate([a, G.Position("ee", np.zeros(3))])


# ---------------------------------------------------------------- threads
def test_thread_setting(monkeypatch):
    from mjkin.runtime import parallel

    monkeypatch.setattr(parallel, "_threads", None)  # whatever an earlier test set
    monkeypatch.delenv("MJKIN_NUM_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert mjkin.threads() == 3
    monkeypatch.setenv("MJKIN_NUM_THREADS", "1")
    assert mjkin.threads() == 1
    mjkin.set_threads(5)
    try:
        assert mjkin.threads() == 5
    finally:
        mjkin.set_threads(None)
    monkeypatch.setenv("MJKIN_NUM_THREADS", "zero")
    with pytest.raises(mjkin.InputError, match="MJKIN_NUM_THREADS"):
        mjkin.threads()
    with pytest.raises(mjkin.InputError, match="positive integer"):
        mjkin.set_threads(0)


@pytest.mark.parametrize("omp, expected", [("4,2", 4), (" 3 ", 3), ("0", None), ("auto", None), ("", None)])
def test_omp_num_threads_is_another_librarys_and_never_an_error(monkeypatch, omp, expected):
    from mjkin.runtime import parallel

    monkeypatch.setattr(parallel, "_threads", None)
    monkeypatch.delenv("MJKIN_NUM_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", omp)
    default = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    assert mjkin.threads() == (default if expected is None else expected)  # "4,2": OpenMP's nested levels


def test_one_thread_runs_the_batch_in_the_caller(monkeypatch):
    import threading

    from mjkin.runtime import parallel

    seen = set()
    monkeypatch.setattr(parallel, "_threads", None)
    monkeypatch.setenv("MJKIN_NUM_THREADS", "1")
    parallel.parallel_chunks(lambda lo, hi: seen.add(threading.get_ident()), 1000)
    assert seen == {threading.get_ident()}


def test_threads_are_kept_between_calls_and_renewed_when_the_count_changes():
    import threading
    import time

    from mjkin.runtime import parallel

    def idents(n_threads):
        seen = set()
        with parallel.threads_set(n_threads):
            for _ in range(3):
                parallel.parallel_chunks(lambda lo, hi: (seen.add(threading.current_thread()), time.sleep(0.01)), 256)
        return seen

    two = idents(2)
    assert len(two) == 2 and threading.current_thread() not in two
    assert idents(2) == two  # the same two threads, not two new ones per call
    three = idents(3)
    assert len(three) == 3 and not three & two  # (thread objects: an ended thread's ident may be reused)


def test_a_chunk_that_splits_again_runs_in_its_thread_and_covers_its_range():
    import threading

    from mjkin.runtime import parallel

    hits = np.zeros(4096, int)
    where: dict[int, set] = {}

    def inner(lo, hi):
        hits[lo:hi] += 1
        where.setdefault(lo // 1024, set()).add(threading.get_ident())

    def outer(lo, hi):
        for a in range(lo, hi):
            parallel.parallel_chunks(lambda x, y, a=a: inner(a * 1024 + x, a * 1024 + y), 1024)

    with parallel.threads_set(2):
        parallel.parallel_chunks(outer, 4, min_chunk=1)  # four outer chunks on two kept threads: no deadlock
    assert (hits == 1).all()
    assert all(len(threads) == 1 for threads in where.values())  # each outer chunk's inner calls in its own thread


def test_an_error_in_one_chunk_is_raised_after_every_chunk_is_done():
    import time

    from mjkin.runtime import parallel

    done = []

    def run(lo, hi):
        if lo == 0:
            raise ValueError("first chunk")
        time.sleep(0.05)
        done.append(lo)

    with parallel.threads_set(2), pytest.raises(ValueError, match="first chunk"):
        parallel.parallel_chunks(run, 1000)
    assert sorted(done) == parallel.chunk_edges(1000, 2, 32)[1:-1]  # nothing still running when it was raised


def test_a_forked_child_starts_threads_of_its_own():
    from mjkin.runtime import parallel

    with parallel.threads_set(2):
        parallel.parallel_chunks(lambda lo, hi: None, 256)  # the parent's pool exists
        pid = os.fork()
        if pid == 0:  # the child: the parent's threads are not here; a call must still finish
            code = 1
            try:  # whatever happens, the child ends here and never goes back into pytest
                hits = np.zeros(256, int)
                parallel.parallel_chunks(lambda lo, hi: hits.__setitem__(slice(lo, hi), hits[lo:hi] + 1), 256)
                code = 0 if (hits == 1).all() else 1
            finally:
                os._exit(code)
    import time

    deadline = time.monotonic() + 60
    while (done := os.waitpid(pid, os.WNOHANG))[0] == 0 and time.monotonic() < deadline:
        time.sleep(0.02)
    if done[0] == 0:  # waiting on the parent's threads, which the child does not have
        os.kill(pid, 9)
        os.waitpid(pid, 0)
        pytest.fail("the forked child's call never finished")
    assert os.waitstatus_to_exitcode(done[1]) == 0


def test_a_loop_is_checked_for_compiled_once_per_process_not_per_solve(rng, monkeypatch):
    """The check types the 18 packed fields (~1 ms): a new problem of the same kinds does not repeat it."""
    from mjkin.ik import lm

    tree = tree_of("arm7")
    T = pose_targets(tree, "ee", rng, 80)
    mjkin.solve(tree, G.Pose("ee", T=T))
    calls, checked = [], lm.packed_kernels
    monkeypatch.setattr(lm, "packed_kernels", lambda *a: calls.append(a) or checked(*a))
    for goal in (G.Pose("ee", T=T), G.Pose("ee", T=T[:70]), G.Pose("ee", T=T[0])):
        assert mjkin.solve(tree, goal).success.all()
    assert calls == []
    monkeypatch.setenv("MJKIN_COMPILE", "interpret")  # the mode still decides: interpreted, as asked
    from mjkin.runtime import tier

    interpreted = []
    real = tier.interpreted_call
    monkeypatch.setattr(tier, "interpreted_call", lambda *a: interpreted.append(a[0]) or real(*a))
    assert mjkin.solve(tree, G.Pose("ee", T=T[:3]), restarts=0).success.all()
    assert interpreted


def test_the_loop_loaded_for_common_kinds_is_checked_again_for_the_others(rng, monkeypatch):
    """One solve_packed serves both: loaded for a Pose problem, it is not taken as loaded for a Clearance problem,
    whose goal arrays (with the geoms) are another compiled version, to be loaded or compiled through the tier."""
    from mjkin.ik import lm

    tree = tree_of("arm7")
    T = pose_targets(tree, "ee", rng, 2)
    monkeypatch.setattr(lm, "_LOADED", set())  # as in a new process: nothing loaded yet
    mjkin.solve(tree, G.Pose("ee", T=T[0]))
    calls, checked = [], lm.packed_kernels
    monkeypatch.setattr(lm, "packed_kernels", lambda *a: calls.append(a) or checked(*a))
    mjkin.solve(tree, G.Pose("ee", T=T[1]), avoid_collisions=True)
    assert len(calls) == 1 and calls[0][1][1].geoms is tree.geoms


@given(st.integers(0, 100_000), st.integers(1, 64), st.integers(1, 256))
def test_chunks_cover_the_batch_once_and_shrink(n, workers, min_chunk):
    from mjkin.runtime.parallel import chunk_edges

    edges = np.array(chunk_edges(n, workers, min_chunk))
    sizes = np.diff(edges)
    assert edges[0] == 0 and edges[-1] == n and (sizes > 0).all()
    assert (sizes >= min(n, min_chunk)).all()  # no sliver: a rest smaller than min_chunk joins the last chunk
    assert (sizes[:-1] >= sizes[1:] - min_chunk).all()  # large first, small last (the last may take a rest)
    if n >= 4 * workers * min_chunk:  # plenty of work: the first chunk leaves the others most of it
        assert sizes[0] == -(-n // (2 * workers)) and len(sizes) >= 2 * workers


# -------------------------------------------------- one compiled specialisation
def test_batch_sizes_share_one_compiled_kernel(rng):
    tree = tree_of("arm7")
    T = pose_targets(tree, "ee", rng, 70)
    mjkin.solve(tree, G.Pose("ee", T=T))
    before = len(solve_packed.signatures)
    assert before >= 1
    for goal in (G.Pose("ee", T=T[0]), G.Pose("ee", T=T[:1]), G.Pose("ee", T=T[:5])):
        mjkin.solve(tree, goal)
    mjkin.solve(tree, G.Pose("ee", T=T[0]), restarts=0)
    assert len(solve_packed.signatures) == before


def test_a_problem_solves_new_targets_of_its_structure_as_solve_does(rng):
    tree = tree_of("arm7")
    T = pose_targets(tree, "ee", rng, 3)
    problem = mjkin.Problem(tree, G.Pose("ee", T=T[0]), restarts=2)
    for t in T:
        got, want = problem.solve(goals=[G.Pose("ee", T=t)]), mjkin.solve(tree, G.Pose("ee", T=t), restarts=2)
        for field in ("q", "success", "error", "iterations", "status", "goal_errors", "restarts"):
            np.testing.assert_array_equal(getattr(got, field), getattr(want, field))
    with pytest.raises(mjkin.GoalError, match="differ from the problem's"):
        problem.solve(goals=[G.Pose("ee", T=T[1], weight=2.0)])
    with pytest.raises(mjkin.GoalError, match="differ from the problem's"):
        problem.solve(goals=[G.Position("ee", T[1, :3, 3])])


def test_spread_restart_starts_stratify_every_joint():
    """Sobol starts put exactly one of 64 draws in each 1/64th of every joint's range (uniform draws do not)."""
    from mjkin.kinematics import qspace

    tree = tree_of("arm7")
    q = qspace.random(tree, 0, 64, spread=True)
    np.testing.assert_allclose(tree.clip(q), q, atol=0)
    lay = tree.layout
    u = (q[:, lay.scalar_q] - lay.scalar_lo) / (lay.scalar_hi - lay.scalar_lo)
    for column in u.T:
        assert sorted(np.floor(column * 64).astype(int)) == list(range(64))
    plain = qspace.random(tree, 0, 64)
    v = (plain[:, lay.scalar_q] - lay.scalar_lo) / (lay.scalar_hi - lay.scalar_lo)
    assert any(len(set(np.floor(c * 64).astype(int))) < 64 for c in v.T)


def test_a_seeds_restart_starts_are_drawn_once_per_tree_and_each_problem_owns_a_copy():
    """Drawing them (scipy's Sobol set-up) cost more than ten easy solves on every ``mjkin.solve``."""
    import gc
    import weakref

    from mjkin.ik.problem import SEEDED_STARTS
    from mjkin.kinematics import qspace

    tree = mjkin.load("arm7")
    goal = G.Position("ee", (0.3, 0.1, 0.4))
    a, b = mjkin.Problem(tree, goal, seed=3), mjkin.Problem(tree, goal, seed=3)
    np.testing.assert_array_equal(a.starts, qspace.random(tree, np.random.default_rng(3), AUTO_RESTARTS, spread=True))
    np.testing.assert_array_equal(a.starts, b.starts)
    a.starts[:] = 0.0  # one problem's copy, not the shared draw
    assert not np.array_equal(b.starts, a.starts)
    np.testing.assert_array_equal(mjkin.Problem(tree, goal, seed=3).starts, b.starts)
    assert not np.array_equal(mjkin.Problem(tree, goal, seed=4).starts, b.starts)
    assert set(SEEDED_STARTS[tree]) == {(3, AUTO_RESTARTS), (4, AUTO_RESTARTS)}
    mjkin.Problem(tree, goal, seed=None).solve()  # new starts each solve, none kept
    assert set(SEEDED_STARTS[tree]) == {(3, AUTO_RESTARTS), (4, AUTO_RESTARTS)}
    alive = weakref.ref(tree)
    del a, b, tree
    gc.collect()
    assert alive() is None  # the draws do not keep their tree alive: they go with it


@pytest.mark.parametrize("method", ["auto", "dls", "pinv", "transpose", "ccd", "optimize", "reach", "analytic2"])
def test_every_method_returns_its_tree(method):
    tree = tree_of("planar_2link")
    res = mjkin.solve(tree, G.Position("tip", (1.2, 0.5, 0.0)), method=method)
    assert res.tree is tree and res.singular_values().shape[-1] >= 1


def test_threads_set_restores_the_setting_not_the_number(monkeypatch):
    from mjkin.runtime import parallel

    monkeypatch.setattr(parallel, "_threads", None)
    monkeypatch.setenv("MJKIN_NUM_THREADS", "2")
    with parallel.threads_set(1):
        assert mjkin.threads() == 1
    monkeypatch.setenv("MJKIN_NUM_THREADS", "3")
    assert mjkin.threads() == 3  # the environment applies again


# ------------------------------------------------------------- nothing may move
EVERY_METHOD = ["auto", "lm", "dls", "pinv", "transpose", "ccd", "analytic2", "optimize", "reach"]
ZERO_DOF = """<mujoco><worldbody><body name="b" pos="0 0 1"><geom size=".1"/><site name="s" pos="0.1 0 0"/>
</body></worldbody></mujoco>"""


@pytest.mark.parametrize("method", EVERY_METHOD)
def test_a_model_without_joints_gives_its_pose_with_every_method(method):
    """0 DoF: every method raised IndexError; now the start comes back, met or not, after no iteration."""
    tree = mjkin.load(ZERO_DOF)
    there = mjkin.solve(tree, G.Position("s", (0.1, 0.0, 1.0)), method=method)
    assert there.success and there.status == "converged" and there.q.shape == (0,) and there.iterations == 0
    away = mjkin.solve(tree, G.Position("s", np.array([[0.1, 0.0, 1.0], [1.0, 0.0, 0.0]])), method=method)
    assert away.success.tolist() == [True, False] and away.status.tolist() == ["converged", "unreachable"]
    np.testing.assert_allclose(away.error[1, 0], np.sqrt(0.9 ** 2 + 1.0), atol=1e-12)


@pytest.mark.parametrize("method", [m for m in EVERY_METHOD if m != "analytic2"])  # it takes no joints= or base=
@pytest.mark.parametrize("limit", [{"joints": []}, {"base": "link3"}])
def test_no_movable_dof_is_the_same_answer_with_every_method(method, limit):
    """joints=[] or base= the goal's own body: optimize raised SciPy's 'not enough values to unpack'."""
    tree = tree_of("planar_3link")
    q0 = np.array([0.3, 0.4, 0.5])
    tip = tree.pose(q0, "tip")[:3, 3]
    res = mjkin.solve(tree, G.Position("tip", np.stack([tip, tip + (1.0, 0.0, 0.0)])), q0, method=method, **limit)
    np.testing.assert_array_equal(res.q, [q0, q0])
    assert res.status.tolist() == ["converged", "unreachable"] and res.iterations.tolist() == [0, 0]


# ------------------------------------------------------------- unlimited hinges
@pytest.mark.parametrize("method", EVERY_METHOD)
def test_unlimited_hinges_come_back_in_minus_pi_to_pi(method):
    """The seeds' arm has unlimited hinges: from a start near π, answers came back as e.g. -3.28 or 4.5 rad."""
    tree = tree_of("planar_2link" if method == "analytic2" else "planar_3link")
    goal = G.Position("tip", (-1.2, -0.5, 0.0) if method == "analytic2" else (-20.0, -5.0, 0.0))
    for q0 in (np.full(tree.nq, 3.0), np.full(tree.nq, -9.0), np.full(tree.nq, 1e308)):
        res = mjkin.solve(tree, goal, q0, method=method)
        assert res.success, (q0, res.status)
        assert np.all((res.q > -np.pi) & (res.q <= np.pi)), res.q  # qpos0 = 0 on these arms
        np.testing.assert_allclose(tree.pose(res.q, "tip")[:3, 3], goal.xyz, atol=1e-5)


LIMITED_WIDE = """<mujoco><compiler angle="radian"/><worldbody><body name="a">
<joint name="j1" axis="0 0 1" range="-5 5"/><geom size=".1"/>
<body name="b" pos="1 0 0"><joint name="j2" axis="0 0 1"/><geom size=".1"/>
<site name="tip" pos="1 0 0"/></body></body></worldbody></mujoco>"""


def test_limited_and_coupled_hinges_are_never_wrapped():
    tree = mjkin.load(LIMITED_WIDE)
    q0 = np.array([4.0, 0.3])  # j1 limited to ±5 rad: 4.0 is a value of its own, not 4.0 - 2π
    res = mjkin.solve(tree, G.Position("tip", tree.pose([4.1, 0.2], "tip")[:3, 3]), q0)
    assert res.success and res.q[0] > np.pi
    coupled = mjkin.solve(tree, [G.Position("tip", tree.pose([1.0, 4.0], "tip")[:3, 3]),
                                 G.Coupling(coefficients={"j2": 1.0}, value=4.0)], [1.0, 4.0])
    assert coupled.success and coupled.q[1] == pytest.approx(4.0)  # its equation is in the value itself


# ------------------------------------------------------------- extreme starts
extreme = st.one_of(st.floats(allow_nan=False, allow_infinity=False), st.sampled_from([1e308, -1e308, 0.0, 1e-300]))


@settings(max_examples=60, deadline=None)
@given(model=st.sampled_from(["ball_chain", "planar_3link", "planar_2link"]), method=st.sampled_from(EVERY_METHOD),
       values=st.lists(extreme, min_size=20, max_size=20))
def test_any_finite_start_gives_an_answer_inside_the_limits(model, method, values):
    """A ball joint's q0 component of -1e308 was clipped to [0, -0, 0, 0] and every method raised ZeroDivisionError."""
    tree = tree_of(model)
    q0 = np.array(values[:tree.nq])
    goal = G.Position("tip", tree.pose(tree.random_q(1), "tip")[:3, 3])
    try:
        res = mjkin.solve(tree, goal, q0, method=method, timeout=2.0)
    except mjkin.InputError as e:  # a zero quaternion, or a method that does not fit the chain: one line
        assert "\n" not in str(e)
        return
    assert np.all(np.isfinite(res.q)) and np.all(np.isfinite(res.error))
    np.testing.assert_allclose(tree.clip(res.q), res.q, atol=1e-12)
    hinges = tree.layout.unlimited_hinge_q
    assert np.all((res.q[hinges] > -np.pi) & (res.q[hinges] <= np.pi))


def test_a_huge_quaternion_is_normalised_without_overflow():
    tree = tree_of("ball_chain")
    q0 = tree.qpos0.copy()
    q0[0] = -1e308  # the probe's start: it came out of the clip as [0, -0, 0, 0]
    np.testing.assert_array_equal(np.abs(tree.clip(q0)[:4]), [1.0, 0.0, 0.0, 0.0])
    q0[:4] = [1e308, 1e308, 0.0, 0.0]
    np.testing.assert_allclose(tree.fk(q0), tree.fk(np.r_[1.0, 1.0, 0.0, 0.0, q0[4:]]), atol=1e-15)
    res = mjkin.solve(tree, G.Position("tip", tree.pose(tree.random_q(2), "tip")[:3, 3]), q0)
    assert res.success


@pytest.mark.parametrize("make", [lambda: mjkin.ik.LM(restarts=10**7), lambda: mjkin.ik.Auto(restarts=10_001)])
def test_restarts_past_their_bound_are_one_line_not_minutes(make):
    """restarts=10**7 drew 10**7 starts and ran for minutes; the bound is documented (MAX_RESTARTS)."""
    from mjkin.ik.method import MAX_RESTARTS

    with pytest.raises(mjkin.InputError, match=f"restarts must be a whole number from 0 to {MAX_RESTARTS:,}, got"):
        make()
    assert mjkin.ik.LM(restarts=MAX_RESTARTS).restarts == MAX_RESTARTS


@pytest.mark.parametrize("options", [{"method": "lm", "max_iters": 10**9, "patience": 10**9},
                                     {"method": "lm", "restarts": 10_000, "max_iters": 1001},
                                     {"method": "dls", "max_iters": 10**8}])
def test_untimed_work_past_its_bound_is_one_line_and_a_timeout_lifts_it(options):
    """max_iters=1e9 with no timeout ran 76 s: without a time limit a target's iterations are bounded, in one line."""
    tree = mjkin.load("arm7")
    goal = mjkin.goals.Position("ee", (0.3, 0.2, 0.5))
    with pytest.raises(mjkin.InputError, match=r"^max_iters x \(restarts \+ 1\) is [\d,]+ iterations a target, more "
                                               r"than 10,000,000 without a time limit: give a timeout") as e:
        mjkin.solve(tree, goal, **options)
    assert "\n" not in str(e.value)
    assert mjkin.solve(tree, goal, timeout=0.5, **options).status in ("converged", "timeout")


@pytest.mark.parametrize("method", ["pinv", "dls", "lm", "auto", "transpose"])
@pytest.mark.parametrize("xyz", [(1e308, 0.2, 0.5), (-1e308, 1e308, 0.5), (1e300, 0.0, 0.0)])
def test_a_target_at_1e308_is_unreachable_not_a_linalg_error(method, xyz):
    """method="pinv" with 1e308 in a target raised numpy's LinAlgError (SVD did not converge)."""
    tree = mjkin.load("arm7")
    res = mjkin.solve(tree, mjkin.goals.Position("ee", xyz), method=method, timeout=0.5)
    assert not res.success and str(res.reason) == "out_of_reach"
    assert np.all(np.isfinite(res.q)) and np.array_equal(tree.clip(res.q), res.q)


# ------------------------------------------------------------------ absurd targets
FAR_GOALS = {  # a goal with a point at a given world position (m); Position stays "unreachable" (the test above)
    "Line": lambda p: G.Line("left_foot", point=p, direction=(-0.45, 0.08, -0.53)),
    "Plane": lambda p: G.Plane("left_foot", point=p, normal=(0.0, 1.0, 0.0)),
    "Aim": lambda p: G.Aim("left_foot", point=p),
    "CenterOfMass": lambda p: G.CenterOfMass(p),
}


@pytest.mark.parametrize("kind", list(FAR_GOALS))
def test_a_target_point_past_1e10_m_is_a_one_line_goal_error(kind: str) -> None:
    """``Line(point=[0.45, -1e308, -0.56])`` reached the solver and raised numpy's LinAlgError (inf in the
    Jacobian); Plane the same."""
    primate = mjkin.load("primate")
    with pytest.raises(GoalError) as e:
        mjkin.solve(primate, FAR_GOALS[kind]([0.45, -1e308, -0.56]), method="pinv")
    assert "\n" not in str(e.value) and "within 1e+10 m of the world origin" in str(e.value), str(e.value)


@given(st.floats(1e10, 1e308, exclude_min=True), st.integers(0, 2), st.sampled_from([1.0, -1.0]),
       st.sampled_from(sorted(FAR_GOALS)))
def test_any_coordinate_past_1e10_m_is_refused(x: float, axis: int, sign: float, kind: str) -> None:
    p = [0.1, 0.2, 0.3]
    p[axis] = sign * x
    with pytest.raises(GoalError, match="within 1e\\+10 m"):
        FAR_GOALS[kind](p).targets()  # checked there, before any solve
    FAR_GOALS[kind]([0.1, 0.2, 1e9]).targets()  # far, yet a target


# ------------------------------------------- mjkin.solve keeps its problems
RESULT_FIELDS = ("q", "success", "error", "iterations", "status", "goal_errors", "restarts", "reason", "binding")


def assert_same_result(got, want):
    """Two results equal bit for bit: every field, the history, the goals' structure as solved."""
    for name in RESULT_FIELDS:
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    assert got.method == want.method and got.tree is want.tree
    assert [g.key() for g in got.goals] == [g.key() for g in want.goals]
    assert (got.history is None) == (want.history is None)
    if got.history is not None:
        np.testing.assert_array_equal(got.history.q, want.history.q)
        np.testing.assert_array_equal(got.history.error, want.history.error)


ARM_GOALS = {  # (kind, frame) -> a goal of it at a configuration q, with a weight and a priority
    ("pose", "ee"): lambda t, q, w, p: G.Pose("ee", T=t.pose(q, "ee"), weight=w, priority=p),
    ("position", "ee"): lambda t, q, w, p: G.Position("ee", t.pose(q, "ee")[:3, 3], weight=w, priority=p),
    ("position", "link5"): lambda t, q, w, p: G.Position("link5", t.pose(q, "link5", "body")[:3, 3], kind="body",
                                                         weight=w, priority=p),
    ("orientation", "ee"): lambda t, q, w, p: G.Orientation("ee", mjkin.spatial.mat_to_quat(t.pose(q, "ee")[:3, :3]),
                                                            weight=w, priority=p),
    ("rest", None): lambda t, q, w, p: G.Rest(q, weight=w, priority=p),
}
weights = st.sampled_from([1.0, 0.5, 2.0, 0.0])


@st.composite
def solve_cases(draw):
    """A goal structure on arm7, options for it, and three target configurations."""
    method = draw(st.sampled_from(["auto", "lm", "dls", "pinv", "transpose", "ccd"]))
    if method == "ccd":  # one position goal
        specs = [(("position", "ee"), draw(weights.filter(bool)), 0)]
    else:
        specs = draw(st.lists(st.tuples(st.sampled_from(list(ARM_GOALS)), weights, st.integers(0, 2)),
                              min_size=1, max_size=3))
    options = {"method": method, "seed": draw(st.integers(0, 3)), "restarts": draw(st.sampled_from([0, 2])),
               "max_iters": draw(st.sampled_from([5, 30])), "tol": draw(st.sampled_from([1e-6, 1e-4])),
               "history": draw(st.booleans())}
    limit = draw(st.sampled_from([{}, {"joints": ["j2", "j3", "j4", "j5", "j6", "j7"]}, {"base": "link2"}]))
    seeds = draw(st.lists(st.integers(0, 2**32 - 1), min_size=4, max_size=4))
    return specs, {**options, **limit}, seeds


@settings(max_examples=25, deadline=None)
@given(case=solve_cases())
def test_solve_keeps_a_problem_per_structure_and_answers_as_a_new_problem_bit_for_bit(case):
    """A loop of mjkin.solve calls paid a new Problem each call (4-6x a problem's solve): each tree keeps them by
    structure and options; a kept one answers new targets and starts exactly as a new problem of those goals does."""
    specs, options, seeds = case
    tree = tree_of("arm7")
    tree.problems.clear()

    def goals_at(seed, specs=specs):
        q = tree.random_q(np.random.default_rng(seed))
        return [ARM_GOALS[spec](tree, q, w, p) for spec, w, p in specs]

    def both(goals, seed):
        q0 = tree.random_q(np.random.default_rng(seed + 1))
        assert_same_result(mjkin.solve(tree, goals, q0, **options), mjkin.Problem(tree, goals, **options).solve(q0))

    both(goals_at(seeds[0]), seeds[0])
    assert len(tree.problems) == 1
    kept = list(tree.problems.values())
    both(goals_at(seeds[1]), seeds[1])  # the same structure, new targets and start: the kept problem
    both(goals_at(seeds[1]), seeds[2])  # the same targets again from another start
    assert list(tree.problems.values()) == kept
    (spec, w, p), *rest = specs  # another weight, or another frame: another problem
    other = [((("position", "link5") if spec == ("position", "ee") else ("position", "ee")), w or 1.0, p), *rest]
    changed = [(spec, 3.0, p), *rest] if spec != ("rest", None) and options["method"] != "ccd" \
        else other
    both(goals_at(seeds[3], changed), seeds[3])
    assert len(tree.problems) == 2 and list(tree.problems.values())[0] is kept[0]
    both(goals_at(seeds[0]), seeds[3])  # the first structure is still kept
    assert len(tree.problems) == 2


def test_a_changed_model_or_another_tree_never_reuses_a_kept_problem():
    tree = mjkin.load("arm7")
    goal = G.Position("ee", (0.3, 0.2, 0.5))
    q0 = np.full(tree.nq, 0.3)
    options = {"method": "dls", "max_iters": 30}
    before = mjkin.solve(tree, goal, q0, **options)
    tree.model.stat.extent *= 3.0  # dls's damping scales with the model's extent
    after = mjkin.solve(tree, goal, q0, **options)
    assert_same_result(after, mjkin.Problem(tree, goal, **options).solve(q0))
    assert not np.array_equal(after.q, before.q) and len(tree.problems) == 2
    twin = mjkin.load("arm7")  # the same file, another tree: its own problems
    on_twin = mjkin.solve(twin, goal, q0, **options)
    assert on_twin.tree is twin and len(twin.problems) == 1 and len(tree.problems) == 2
    assert_same_result(on_twin, mjkin.Problem(twin, goal, **options).solve(q0))
    model = mjkin.load("arm7").model  # the same names, a longer forearm
    model.body_pos[tree.id("link5", "body"), 2] += 0.1
    longer = mjkin.load(model)
    res = mjkin.solve(longer, goal, q0, **options)
    assert_same_result(res, mjkin.Problem(longer, goal, **options).solve(q0))
    assert not np.array_equal(res.q, on_twin.q)


def test_options_are_told_apart_by_type_and_bad_values_are_still_refused():
    """``tol=True`` equals ``1.0`` as a dict key: a kept problem must not let it through."""
    tree = mjkin.load("arm7")
    goal = G.Position("ee", (0.3, 0.2, 0.5))
    mjkin.solve(tree, goal, tol=1.0, history=True)
    with pytest.raises(mjkin.InputError, match="tol must be a finite number > 0"):
        mjkin.solve(tree, goal, tol=True, history=True)
    with pytest.raises(mjkin.InputError, match="history must be True or False"):
        mjkin.solve(tree, goal, tol=1.0, history=1)
    assert len(tree.problems) == 1
    mjkin.solve(tree, goal, joints=["j1", "j2"])  # a list option: kept by its items
    mjkin.solve(tree, goal, joints=["j1", "j2"])
    mjkin.solve(tree, goal, method=mjkin.ik.LM(restarts=1))  # a method object: by its options
    mjkin.solve(tree, goal, method=mjkin.ik.LM(restarts=1))
    assert len(tree.problems) == 3


def test_kept_problems_are_bounded_and_go_with_their_tree():
    import gc
    import weakref

    from mjkin.ik.solve import KEPT

    tree = mjkin.load("arm7")
    for k in range(KEPT + 4):
        mjkin.solve(tree, G.Position("ee", (0.3, 0.2, 0.5), weight=1.0 + k), max_iters=1)
    assert len(tree.problems) == KEPT
    assert {p.goals[0].weight for p in tree.problems.values()} == {1.0 + k for k in range(4, KEPT + 4)}
    assert pickle.loads(pickle.dumps(tree)).problems == {}
    alive = weakref.ref(tree)
    del tree
    gc.collect()
    assert alive() is None


@pytest.mark.parametrize("extra", [{"root": "link2"}, {"avoid_collisions": True}])
def test_problems_made_from_more_than_the_structure_are_not_kept(extra):
    tree = mjkin.load("arm7")
    goal = G.Position("ee", (0.3, 0.2, 0.5))
    q0 = np.full(tree.nq, 0.2)
    assert_same_result(mjkin.solve(tree, goal, q0, **extra), mjkin.Problem(tree, goal, **extra).solve(q0))
    assert tree.problems == {}


@pytest.mark.parametrize("goal", ["position", "pose"])
def test_a_figure_target_at_1e308_with_pinv_is_unmet_not_a_linalg_error(goal: str) -> None:
    """The primate's foot at 1e308 m with method="pinv": its rows overflowed and numba's SVD raised LinAlgError."""
    primate = mjkin.load("primate")
    T = np.eye(4)
    T[:3, 3] = [0.45, -1e308, -0.56]
    made = G.Position("left_foot", T[:3, 3]) if goal == "position" else G.Pose("left_foot", T=T)
    res = mjkin.solve(primate, made, method="pinv", timeout=0.5)
    assert not res.success and np.all(np.isfinite(res.q)) and np.array_equal(primate.clip(res.q), res.q)
