"""Fuzzing the public entry points: bad or extreme input either gives a clean result or raises a MjkinError.

Each property feeds one entry point (``mjkin.solve``, ``Problem.solve``, ``solutions``, ``reachability``,
``place_base``, ``bvh.parse``, ``retarget``, the gymnasium envs) arbitrary arguments: NaN, inf, huge and tiny
numbers, odd shapes and dtypes, strings, dropped or changed BVH lines. The call must either return a clean result
(finite ``q`` inside the joint limits, boolean success, the documented shapes) or raise a :class:`mjkin.MjkinError`
subclass; any other exception type (ValueError, TypeError, LinAlgError, MemoryError, StopIteration, ...) fails.
Sizes and budgets are small so every example is fast, and a watchdog turns a hang into a failure.

Inputs that failed once are pinned below as explicit cases, so each bug found stays fixed.
"""

from __future__ import annotations

import dataclasses
import math
import re
import signal
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import mujoco
import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from test_bvh import small
from test_retarget import crouch_bvh

import mjkin
from mjkin import goals as G
from mjkin import motion, render
from mjkin.goals.program import compile_goals
from mjkin.ik.by_name import METHODS
from mjkin.motion import bvh
from mjkin.motion.bvh import _is_number

T = TypeVar("T")
NAN, INF = float("nan"), float("inf")
BIG = 1.7976931348623157e308
EXTREME = [0.0, -0.0, 5e-324, 1e-300, -1e-300, 1e300, -1e300, BIG, -BIG, NAN, INF, -INF, 1.0, -1.0, 0.3, 1e9]
# wall-clock limit of one call (s): generous, numba may compile on the first call of a fresh process
HANG = 120.0

finite_small = st.floats(-2.0, 2.0, allow_nan=False, allow_infinity=False)
extreme = st.sampled_from(EXTREME) | st.floats(allow_nan=True, allow_infinity=True) | finite_small
junk = st.sampled_from([None, "abc", "1", b"xy", [1, [2, 3]], {"a": 1}, object(), 1j, True, [], ()])


class Hang(AssertionError):
    """A call ran past the watchdog."""


@contextmanager
def watchdog(seconds: float = HANG) -> Iterator[None]:
    """Fail (with :class:`Hang`) when the block runs longer than ``seconds`` (the main thread's SIGALRM)."""
    if not hasattr(signal, "SIGALRM"):  # pragma: no cover - Windows
        yield
        return

    def ring(signum: int, frame: Any) -> None:
        raise Hang(f"no answer within {seconds} s")

    old = signal.signal(signal.SIGALRM, ring)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def outcome(call: Callable[[], T]) -> T | None:
    """``call()``'s value, or None when it raised a MjkinError; any other exception propagates (the test fails)."""
    with watchdog(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numpy's overflow warnings on extreme input are not the property
        try:
            return call()
        except mjkin.MjkinError:
            return None


_TREES: dict[str, mjkin.Tree] = {}


def tree(name: str) -> mjkin.Tree:
    if name not in _TREES:
        _TREES[name] = mjkin.load(name)
    return _TREES[name]


FRAMES = {"arm7": "ee", "planar_3link": "tip"}


def assert_in_limits(t: mjkin.Tree, q: np.ndarray) -> None:
    assert np.all(np.isfinite(q)), q
    np.testing.assert_allclose(t.clip(q), q, rtol=0, atol=1e-9)
    for j in range(t.njnt):
        if t.jnt_limited[j] and int(t.jnt_type[j]) in (2, 3):  # limited slide, hinge
            x = q[..., t.jnt_qadr[j]]
            lo, hi = t.jnt_range[j]
            assert np.all((x >= lo - 1e-9) & (x <= hi + 1e-9)), (j, x, lo, hi)


def assert_clean_result(t: mjkin.Tree, r: mjkin.Result, batch: tuple[int, ...] | None = None) -> None:
    success = np.asarray(r.success)
    b = success.shape if batch is None else batch
    assert success.dtype == np.bool_ and success.shape == b
    assert np.shape(r.q) == b + (t.nq,)
    assert np.shape(r.error) == b + (2,)
    assert np.shape(r.iterations) == b and np.shape(r.status) == b
    assert_in_limits(t, np.asarray(r.q))


def batch_of(target: Any, core: int) -> tuple[int, ...] | None:
    """The batch shape a well-formed target of ``core`` axes gives, None when it is not an array of numbers."""
    try:
        a = np.asarray(target, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    return a.shape[: a.ndim - core] if a.ndim > core else ()


# ----------------------------------------------------------------------------------------------- solve / Problem
def target_arrays(core: tuple[int, ...]) -> st.SearchStrategy[Any]:
    shapes = st.sampled_from([core, (1,) + core, (2,) + core, (0,) + core, (), (2,), (4,), (3, 3), (2, 2) + core])
    return shapes.flatmap(lambda s: hnp.arrays(np.float64, s, elements=extreme)) | junk


def goal_of(kind: str, frame: str, target: Any) -> G.Goal:
    if kind == "position":
        return G.Position(frame, target)
    if kind == "orientation":
        return G.Orientation(frame, target)
    return G.Pose(frame, target)


CORE = {"position": (3,), "orientation": (3, 3), "pose": (4, 4)}
goal_kinds = st.sampled_from(sorted(CORE))


@st.composite
def goal_cases(draw: st.DrawFn) -> tuple[str, str, Any]:
    kind = draw(goal_kinds)
    return kind, draw(st.sampled_from(sorted(FRAMES))), draw(target_arrays(CORE[kind]))


def q_starts(nq: int) -> st.SearchStrategy[Any]:
    shapes = st.sampled_from([(nq,), (1, nq), (2, nq), (nq + 1,), (), (0, nq)])
    return st.none() | shapes.flatmap(lambda s: hnp.arrays(np.float64, s, elements=extreme)) | junk


numbers = st.sampled_from([1e-6, 1e-3, 0.0, -1.0, NAN, INF, 1e300, 5e-324, "x", None])


@settings(max_examples=80, deadline=None)
@given(case=goal_cases(), method=st.sampled_from(list(METHODS)), data=st.data())
def test_solve_is_clean_or_raises_mjkin_error(case: tuple[str, str, Any], method: str, data: st.DataObject) -> None:
    kind, model, target = case
    t = tree(model)
    q0 = data.draw(q_starts(t.nq), "q0")
    tol = data.draw(st.sampled_from([1e-6, 1e-3]) | numbers, "tol")
    r = outcome(lambda: mjkin.solve(t, goal_of(kind, FRAMES[model], target), q0, method=method, tol=tol,
                                    timeout=0.5))
    if r is not None:
        assert_clean_result(t, r)
        b = batch_of(target, len(CORE[kind]))
        if b:  # a batched target gives its batch
            assert np.shape(r.success) == b


@settings(max_examples=40, deadline=None)
@given(method=st.sampled_from(list(METHODS)), option=st.sampled_from(["max_iters", "restarts", "damping", "seed",
                                                                     "timeout", "rot_tol", "history", "bogus"]),
       value=extreme | junk | st.sampled_from([0, 1, -1, 2**70, 3.5]))
@example(method="dls", option="damping", value=2.225073858507203e-309)  # its square underflowed: 0 / 0 in the step
def test_solve_options_are_checked(method: str, option: str, value: Any) -> None:
    t = tree("arm7")
    if option == "restarts":
        assume(not (isinstance(value, (int, float)) and not isinstance(value, bool) and value > 4))  # time, not a bug
    if option == "max_iters":
        assume(not (isinstance(value, (int, float)) and not isinstance(value, bool) and value > 1000))
    kw = {"timeout": 0.5, option: value}
    r = outcome(lambda: mjkin.solve(t, G.Position("ee", (0.3, 0.2, 0.5)), method=method, **kw))
    if r is not None:
        assert_clean_result(t, r, ())


POSITION = G.Position("ee", (0.3, 0.2, 0.5))


def test_solve_pinned_orientation_of_a_string() -> None:
    outcome(lambda: mjkin.solve(tree("arm7"), G.Orientation("ee", "abc")))


@pytest.mark.parametrize(("option", "value"), [
    pytest.param("timeout", 2**70, id="timeout-2**70"),  # a numba TypingError (int too large): now no limit
    pytest.param("timeout", 1e300, id="timeout-1e300"),  # OverflowError (inf to int): now no limit
    pytest.param("max_iters", 2**70, id="max_iters-2**70"),  # a numba TypingError: now past MAX_ITERS
    pytest.param("damping", [1, [2, 3]], id="damping-ragged"),  # ValueError (inhomogeneous shape) from np.ndim
    pytest.param("tol", [1, [2, 3]], id="tol-ragged"),
    pytest.param("timeout", 1e6, id="timeout-1e6"),
    pytest.param("max_iters", 2**40, id="max_iters-2**40"),
])
def test_solve_option_pinned(option: str, value: Any) -> None:
    kw = {"timeout": 0.5, option: value}
    if option == "max_iters":
        kw["timeout"] = 0.2
    r = outcome(lambda: mjkin.solve(tree("arm7"), POSITION, **kw))
    if r is not None:
        assert_clean_result(tree("arm7"), r, ())


@settings(max_examples=50, deadline=None)
@given(model=st.sampled_from(sorted(FRAMES)), data=st.data())
def test_problem_solve_is_clean_or_raises_mjkin_error(model: str, data: st.DataObject) -> None:
    t = tree(model)
    frame = FRAMES[model]
    problem = outcome(lambda: mjkin.Problem(t, G.Position(frame, (0.1, 0.1, 0.1)), timeout=0.5))
    assert problem is not None
    target = data.draw(target_arrays((3,)), "target")
    q0 = data.draw(q_starts(t.nq), "q0")
    other = data.draw(st.booleans(), "other structure")
    goal = G.Position(frame, target, weight=2.0) if other else G.Position(frame, target)
    r = outcome(lambda: problem.solve(q0, goal))
    if r is not None:
        assert_clean_result(t, r)


# every goal kind, made well on its model: one field at a time is then given any value
GOALS: dict[str, tuple[str, Callable[[], G.Goal]]] = {
    "position": ("arm7", lambda: G.Position("ee", (0.3, 0.2, 0.5))),
    "pose": ("arm7", lambda: G.Pose("ee", T=np.eye(4))),
    "orientation": ("arm7", lambda: G.Orientation("ee", np.eye(3))),
    "aim": ("arm7", lambda: G.Aim("ee", point=(0.5, 0.5, 0.5))),
    "line": ("arm7", lambda: G.Line("ee", point=(0.3, 0.0, 0.5), direction=(0.0, 0.0, 1.0))),
    "plane": ("arm7", lambda: G.Plane("ee", point=(0.0, 0.0, 0.5), normal=(0.0, 0.0, 1.0))),
    "halfspace": ("arm7", lambda: G.HalfSpace("ee", point=(0.0, 0.0, 0.5), normal=(0.0, 0.0, 1.0))),
    "rest": ("arm7", lambda: G.Rest(np.zeros(7))),
    "coupling": ("arm7", lambda: G.Coupling({"j1": 1.0, "j2": -1.0})),
    "steplimit": ("arm7", lambda: G.StepLimit(np.zeros(7), 0.1)),
    "clearance": ("arm7", lambda: G.Clearance(0.01)),
    "com": ("primate", lambda: G.CenterOfMass(xyz=(0.0, 0.0, 0.5))),
    "balance": ("primate", lambda: G.CenterOfMass(support=["left_foot", "right_foot"])),
}
GROUPED = {"clearance", "com", "balance"}  # the kinds that are not common (mjkin.ik.loop.other_goal)
FIELD_VALUES = (extreme | junk | st.sampled_from([0, 2, -1, 2**70, 1.5, "site", "body", "world", (0.0, 0.1, 0.0),
                                                  {"j1": "x"}, [("a", 1)], [(0, 1)], "xz"])
                | hnp.arrays(np.float64, st.sampled_from([(), (2,), (3,), (1, 3), (0,), (7,), (3, 3)]),
                             elements=extreme))


@settings(max_examples=80, deadline=None)
@given(kind=st.sampled_from(sorted(GOALS)), data=st.data())
def test_a_goal_field_of_any_value_is_clean_or_raises_mjkin_error(kind: str, data: st.DataObject) -> None:
    """Any one field of any goal kind, whatever its value, gives a clean solve or a MjkinError (GoalError
    when the goal is made, for a value that is no number, name or shape the field takes).

    The grouped kinds are made and encoded, not solved: their loop takes minutes to compile on a cold cache,
    past the watchdog when the warmup compiles it beside the suite.
    """
    model, make = GOALS[kind]
    goal = make()
    field = data.draw(st.sampled_from(sorted(f.name for f in dataclasses.fields(goal))), "field")
    value = data.draw(FIELD_VALUES, "value")
    t = tree(model)
    if kind in GROUPED:  # their loop may still be compiling (warmup): made and encoded, as a solve does first
        outcome(lambda: compile_goals(t, dataclasses.replace(goal, **{field: value})))
        return
    r = outcome(lambda: mjkin.solve(t, dataclasses.replace(goal, **{field: value}), timeout=0.1))
    if r is not None:
        assert_clean_result(t, r, np.shape(r.success))


@pytest.mark.parametrize(("kind", "field", "value", "text"), [
    pytest.param("position", "weight", "abc", "weight", id="weight-str"),  # ValueError from float()
    pytest.param("position", "weight", "1", "weight", id="weight-numeric-str"),  # passed float(), failed at "1" > 0
    pytest.param("position", "weight", None, "weight", id="weight-None"),  # TypeError from float()
    pytest.param("position", "kind", np.array([1.0, 2.0]), "kind", id="kind-array"),  # an array's truth in `not in`
    pytest.param("position", "offset", "abc", "offset", id="offset-str"),  # ValueError in the goal's key
    pytest.param("position", "offset", [1, [2, 3]], "offset", id="offset-ragged"),
    pytest.param("position", "offset", 1j, "offset", id="offset-complex"),  # TypeError
    pytest.param("position", "offset", (0.0, 0.1), "offset", id="offset-two"),
    pytest.param("orientation", "axes", [1, [2, 3]], "axes", id="axes-ragged"),  # unhashable list in set()
    pytest.param("orientation", "axes", np.zeros(3), "axes", id="axes-array"),  # an array's truth
    pytest.param("rest", "q_rest", "abc", "q_rest", id="rest-str"),  # ValueError in batch()
    pytest.param("rest", "stiffness", {"a": 1}, "stiffness", id="stiffness-dict"),  # TypeError in key()
    pytest.param("coupling", "coefficients", None, "coefficients", id="coupling-None"),  # AttributeError: .items
    pytest.param("coupling", "coefficients", {"j1": "x"}, "coefficient of 'j1'", id="coupling-str-coefficient"),
    pytest.param("coupling", "value", "x", "value", id="coupling-value-str"),  # TypeError from np.isfinite
    pytest.param("steplimit", "q_prev", b"xy", "q_prev", id="steplimit-bytes"),
    pytest.param("steplimit", "max_step", object(), "max_step", id="steplimit-object"),  # TypeError in key()
    pytest.param("clearance", "pairs", [1, [2, 3]], "pairs", id="clearance-pairs-ragged"),  # TypeError in key()
])
def test_a_goal_field_pinned(kind: str, field: str, value: Any, text: str) -> None:
    with pytest.raises(mjkin.GoalError, match=re.escape(text)):
        dataclasses.replace(GOALS[kind][1](), **{field: value})


@pytest.mark.parametrize("kind", ["clearance", "balance"])
def test_a_margin_past_int64_is_a_number(kind: str) -> None:
    """``np.isfinite(2**70)`` raised TypeError (no int64 holds it); it is a (silly) finite margin, encoded."""
    model, make = GOALS[kind]
    prog = compile_goals(tree(model), dataclasses.replace(make(), margin=2**70))
    assert prog.data[0, 0, 0] == 2.0**70


TREE_CALLS: dict[str, Callable[[mjkin.Tree, Any], Any]] = {
    "fk": lambda t, v: t.fk(v),
    "pose": lambda t, v: t.pose(v, "ee"),
    "pose kind": lambda t, v: t.pose(t.qpos0, "ee", kind=v),
    "jacobian": lambda t, v: t.jacobian(v, "ee"),
    "jacobian offset": lambda t, v: t.jacobian(t.qpos0, "ee", offset=v),
    "clip": lambda t, v: t.clip(v),
    "integrate v": lambda t, v: t.integrate(t.qpos0, v),
    "difference": lambda t, v: t.difference(t.qpos0, v),
    "random_q rng": lambda t, v: t.random_q(v, 2),
    "random_q n": lambda t, v: t.random_q(0, v),
    "frame": lambda t, v: t.frame(v),
}


@settings(max_examples=80, deadline=None)
@given(call=st.sampled_from(sorted(TREE_CALLS)), value=FIELD_VALUES | q_starts(7))
def test_tree_methods_are_clean_or_raise_mjkin_error(call: str, value: Any) -> None:
    """A Tree's kinematics and q-space methods given any one argument: an answer, or a MjkinError."""
    t = tree("arm7")
    out = outcome(lambda: TREE_CALLS[call](t, value))
    if out is not None and call.startswith("random_q"):
        assert_in_limits(t, out)


@pytest.mark.parametrize(("call", "value", "text"), [
    pytest.param("fk", [1, [2, 3]], "q", id="fk-ragged"),  # ValueError from np.ndim of a ragged list
    pytest.param("jacobian offset", "abc", "offset", id="offset-str"),  # ValueError from np.asarray
    pytest.param("jacobian offset", {"a": 1}, "offset", id="offset-dict"),  # TypeError
    pytest.param("integrate v", "abc", "v", id="integrate-str"),
    pytest.param("random_q rng", "abc", "rng", id="rng-str"),  # TypeError from SeedSequence
    pytest.param("random_q rng", -1, "rng", id="rng-negative"),  # ValueError from SeedSequence
    pytest.param("random_q n", 2**70, "n = ", id="n-2**70"),  # ValueError: maximum allowed dimension exceeded
])
def test_tree_method_pinned(call: str, value: Any, text: str) -> None:
    with pytest.raises(mjkin.InputError, match=re.escape(text)):
        TREE_CALLS[call](tree("arm7"), value)


PATH = np.array([[0.5, 0.2, 0.0], [0.4, 0.3, 0.0]])
MOTION_CALLS: dict[str, Callable[[Any], Any]] = {
    "interpolate times": lambda v: motion.interpolate(tree("planar_3link"), v, np.zeros((2, 3)), [0.5]),
    "interpolate t": lambda v: motion.interpolate(tree("planar_3link"), [0.0, 1.0], np.zeros((2, 3)), v),
    "line n": lambda v: motion.line((0, 0, 0), (1, 0, 0), v),
    "line start": lambda v: motion.line(v, (1, 0, 0), 3),
    "circle radius": lambda v: motion.circle((0, 0, 0), v, 4),
    "circle normal": lambda v: motion.circle((0, 0, 0), 1.0, 4, normal=v),
    "circle turns": lambda v: motion.circle((0, 0, 0), 1.0, 4, turns=v),
    "min_jerk": lambda v: motion.min_jerk(v),
    "waypoints": lambda v: motion.waypoints(v, 5),
    "waypoints times": lambda v: motion.waypoints(PATH, 5, times=v),
    "waypoints corner": lambda v: motion.waypoints(PATH, 5, corner=v),
    "follow targets": lambda v: motion.follow(tree("planar_3link"), "tip", v, timeout=0.1),
    "follow fps": lambda v: motion.follow(tree("planar_3link"), "tip", PATH, fps=v, timeout=0.1),
    "follow smooth": lambda v: motion.follow(tree("planar_3link"), "tip", PATH, smooth=v, timeout=0.1),
    "follow q0": lambda v: motion.follow(tree("planar_3link"), "tip", PATH, q0=v, timeout=0.1),
    "follow extra": lambda v: motion.follow(tree("planar_3link"), "tip", PATH, extra=v, timeout=0.1),
    "walk_cycle fps": lambda v: motion.walk_cycle(tree("primate"), steps=1, fps=v),
    "workspace n": lambda v: mjkin.workspace(tree("planar_3link"), "tip", n=v if not isinstance(v, int) or v < 5
                                             else 50),
    "workspace seed": lambda v: mjkin.workspace(tree("planar_3link"), "tip", n=50, seed=v),
    "Problem joints": lambda v: mjkin.Problem(tree("arm7"), POSITION, joints=v),
}


@settings(max_examples=80, deadline=None)
@given(call=st.sampled_from(sorted(MOTION_CALLS)), value=FIELD_VALUES)
@example(call="Problem joints", value=np.array(0.0))  # iterable to isinstance, TypeError to list()
def test_motion_and_workspace_helpers_are_clean_or_raise_mjkin_error(call: str, value: Any) -> None:
    """The paths, keyframes, follow, walk and workspace helpers given any one argument: an answer or a MjkinError."""
    outcome(lambda: MOTION_CALLS[call](value))


@pytest.mark.parametrize(("call", "value", "text"), [
    pytest.param("interpolate times", None, "times", id="interpolate-None"),  # TypeError from np.diff
    pytest.param("line n", "abc", "frame count", id="line-n-str"),  # ValueError from int()
    pytest.param("line n", 2**70, "frame count", id="line-n-2**70"),  # OverflowError in linspace
    pytest.param("circle normal", 1.0, "normal", id="circle-normal-scalar"),  # IndexError: nrm[0]
    pytest.param("circle radius", "abc", "radius", id="circle-radius-str"),  # TypeError from np.isfinite
    pytest.param("waypoints corner", None, "corner", id="corner-None"),  # TypeError from np.isfinite
    pytest.param("follow fps", None, "fps", id="follow-fps-None"),  # TypeError: int / None
    pytest.param("follow smooth", np.zeros(3), "smooth", id="follow-smooth-array"),  # an array's truth
    pytest.param("follow q0", np.zeros((2, 3)), "q0", id="follow-q0-batch"),  # a batch of starts: an array's truth
    pytest.param("follow extra", None, "goal", id="follow-extra-None"),  # TypeError: *None
    pytest.param("workspace n", "abc", "n", id="workspace-n-str"),  # ValueError from int()
    pytest.param("workspace seed", -1, "seed", id="workspace-seed-negative"),  # ValueError from SeedSequence
    pytest.param("Problem joints", 1j, "joints", id="problem-joints-complex"),  # TypeError: not iterable
])
def test_motion_helper_pinned(call: str, value: Any, text: str) -> None:
    with pytest.raises(mjkin.MjkinError, match=re.escape(text)):
        MOTION_CALLS[call](value)


def test_walk_cycle_refuses_steps_no_memory_holds() -> None:
    """2**70 steps ran (a loop that would not end): now an InputError at once."""
    with pytest.raises(mjkin.InputError, match="steps"):
        motion.walk_cycle(tree("primate"), steps=2**70)


QS = np.zeros((2, 3))
IMAGE = np.zeros((16, 16, 3), np.uint8)
# text given as a path is taken inside the test's folder: the fuzz writes nothing where the suite runs
FILE_CALLS: dict[str, Callable[[Any, Path], Any]] = {
    "frames qs": lambda v, d: list(render.frames(tree("planar_3link"), v, 32, 24)),
    "frames width": lambda v, d: list(render.frames(tree("planar_3link"), QS, v if not isinstance(v, int) else 24, 24)),
    "frames camera": lambda v, d: list(render.frames(tree("planar_3link"), QS, 32, 24, camera=v)),
    "write_video fps": lambda v, d: render.write_video([IMAGE, IMAGE], d / "a.mp4", fps=v),
    "write_video images": lambda v, d: render.write_video(v, d / "b.mp4"),
    "write_video path": lambda v, d: render.write_video([IMAGE], d / v if isinstance(v, str) else v),
    "write_image": lambda v, d: render.write_image(v, d / "c.png"),
    "trajectory times": lambda v, d: motion.Trajectory(v, QS, "x").save(d / "t.json"),
    "trajectory q": lambda v, d: motion.Trajectory(np.arange(2.0), v, "x").save(d / "t.json"),
    "trajectory save": lambda v, d: motion.Trajectory(np.arange(2.0), QS, "x").save(d / v if isinstance(v, str) else v),
    "trajectory load": lambda v, d: motion.Trajectory.load(d / v if isinstance(v, str) else v),
}


@settings(max_examples=60, deadline=None)
@given(call=st.sampled_from(sorted(FILE_CALLS)), value=FIELD_VALUES)
def test_render_and_file_helpers_are_clean_or_raise_mjkin_error(call: str, value: Any, tmp_path_factory:
                                                                 pytest.TempPathFactory) -> None:
    """Frames, videos, images and trajectory files given any one argument: an answer or a MjkinError."""
    folder = tmp_path_factory.mktemp("files")
    outcome(lambda: FILE_CALLS[call](value, folder))
    assert not [p for p in folder.iterdir() if p.name.startswith(".")]  # no temporary file left behind


@pytest.mark.parametrize(("call", "value", "text"), [
    pytest.param("frames width", None, "width", id="width-None"),  # TypeError: None <= 0
    pytest.param("frames camera", b"xy", "camera", id="camera-bytes"),  # TypeError inside MuJoCo
    pytest.param("frames camera", 1.5, "camera", id="camera-float"),  # ValueError: camera id out of range
    pytest.param("frames camera", 5, "camera id 5", id="camera-id-out-of-range"),  # MuJoCo's ValueError
    pytest.param("write_video fps", None, "fps", id="fps-None"),  # TypeError from float()
    pytest.param("write_video fps", float("inf"), "fps", id="fps-inf"),  # OverflowError in imageio
    pytest.param("write_video images", None, "images", id="images-None"),  # TypeError: not iterable
    pytest.param("write_video path", None, "path", id="video-path-None"),  # TypeError from Path()
    pytest.param("write_image", "abc", "image", id="image-str"),  # imageio's ValueError
    pytest.param("trajectory times", None, "times", id="trajectory-times-None"),  # AttributeError at save
    pytest.param("trajectory load", b"xy", "path", id="trajectory-load-bytes"),  # TypeError from Path()
])
def test_render_and_file_helper_pinned(call: str, value: Any, text: str, tmp_path: Path) -> None:
    with pytest.raises(mjkin.MjkinError, match=re.escape(text)):
        FILE_CALLS[call](value, tmp_path)


DH = np.array([[0.0, 0.3, 0.0, 0.0], [0.0, 0.2, 0.0, 0.0]])
BUILD_CALLS: dict[str, Callable[[Any], Any]] = {
    "planar_chain lengths": lambda v: mjkin.build.planar_chain(v),
    "planar_chain ranges": lambda v: mjkin.build.planar_chain([0.5, 0.4], ranges=v),
    "dh_chain rows": lambda v: mjkin.build.dh_chain(v),
    "dh_chain joints": lambda v: mjkin.build.dh_chain(DH, joints=v),
    "dh_chain convention": lambda v: mjkin.build.dh_chain(DH, convention=v),
    "dh_fk q": lambda v: mjkin.build.dh_fk(DH, v),
    "links_mjcf": lambda v: mjkin.build.links_mjcf(v),
    **{f"Link {name}": (lambda v, name=name: mjkin.load(mjkin.build.links_mjcf(
        [mjkin.build.Link("a"), mjkin.build.Link(**{"name": "b", "parent": "a", name: v})])))
       for name in ("name", "parent", "joint", "axis", "length", "direction", "at", "range", "radius")},
}


@settings(max_examples=80, deadline=None)
@given(call=st.sampled_from(sorted(BUILD_CALLS)), value=FIELD_VALUES)
def test_model_builders_are_clean_or_raise_mjkin_error(call: str, value: Any) -> None:
    """The chain builders (planar, DH, links) given any one argument or link field: MJCF text or a MjkinError."""
    outcome(lambda: BUILD_CALLS[call](value))


@pytest.mark.parametrize(("call", "value", "text"), [
    pytest.param("planar_chain lengths", None, "lengths", id="planar-None"),  # TypeError: len(None)
    pytest.param("planar_chain ranges", 1j, "ranges", id="planar-ranges-complex"),  # TypeError: len(1j)
    pytest.param("dh_chain joints", np.zeros(2), "joints", id="dh-joints-array"),  # an array's truth
    pytest.param("dh_chain convention", np.zeros(2), "convention", id="dh-convention-array"),
    pytest.param("dh_fk q", None, "q", id="dh-fk-None"),  # IndexError: 0-d q
    pytest.param("links_mjcf", "abc", "links", id="links-str"),  # AttributeError: str.length
    pytest.param("Link name", None, "name", id="link-name-None"),  # TypeError from ElementTree
    pytest.param("Link length", None, "length", id="link-length-None"),  # TypeError: abs(None)
])
def test_model_builder_pinned(call: str, value: Any, text: str) -> None:
    with pytest.raises(mjkin.MjkinError, match=re.escape(text)):
        BUILD_CALLS[call](value)


@pytest.mark.parametrize(("kwargs", "text"), [
    pytest.param({"sources": None}, "sources", id="sources-None"),  # TypeError: not iterable
    pytest.param({"sources": [b"xy"]}, "source", id="sources-bytes"),  # TypeError from Path()
    pytest.param({"out": None}, "out", id="out-None"),  # TypeError from Path()
])
def test_retarget_many_arguments_pinned(kwargs: dict[str, Any], text: str, tmp_path: Path) -> None:
    args = {"sources": [], "out": tmp_path / "out", **kwargs}
    with pytest.raises(mjkin.InputError, match=re.escape(text)):
        mjkin.retarget_many(args["sources"], "primate", args["out"])


TREE_ENTRIES: dict[str, Callable[[Any], Any]] = {
    "Problem": lambda t: mjkin.Problem(t, G.Position("tip", (0.5, 0.2, 0.0))),
    "solve": lambda t: mjkin.solve(t, G.Position("tip", (0.5, 0.2, 0.0))),
    "reachability": lambda t: mjkin.reachability(t, "tip"),
    "workspace": lambda t: mjkin.workspace(t, "tip", n=10),
    "follow": lambda t: motion.follow(t, "tip", PATH),
    "walk_cycle": lambda t: motion.walk_cycle(t),
    "interpolate": lambda t: motion.interpolate(t, [0.0, 1.0], np.zeros((2, 3)), [0.5]),
    "frames": lambda t: list(render.frames(t, np.zeros((1, 3)))),
    "singular_values": lambda t: mjkin.singular_values(t, G.Position("tip", (0.5, 0.2, 0.0)), np.zeros(3)),
}


@pytest.mark.parametrize("entry", sorted(TREE_ENTRIES))
@pytest.mark.parametrize("given", [None, "planar_3link", mujoco.MjModel.from_xml_string("<mujoco/>")],
                         ids=["None", "a-name", "an-MjModel"])
def test_an_entry_given_something_else_than_a_tree_says_so(entry: str, given: Any) -> None:
    """Each raised AttributeError ('NoneType' object has no attribute 'nv', 'str' ... 'check_q')."""
    with pytest.raises(mjkin.InputError, match=r"^tree must be a mjkin\.Tree \(mjkin\.load\(name or path\)\), got "):
        TREE_ENTRIES[entry](given)


# ------------------------------------------------------------------------------------------------------ solutions
@settings(max_examples=30, deadline=None)
@given(model=st.sampled_from(sorted(FRAMES)), xyz=target_arrays((3,)),
       starts=st.sampled_from([1, 2, 4, 0, -1, 2.5, NAN, "4", None]),
       rounds=st.sampled_from([1, 2, 0, -3, 1.5, INF]),
       merge=st.sampled_from([1e-3, 0.1, 0.0, -1.0, NAN, INF, 1e300]),
       max_solutions=st.sampled_from([None, 1, 3, 0, -1, 2.5, 10**30]),
       seed=st.sampled_from([0, 1, -1, 2**70, 1.5, None, "s"]))
def test_solutions_are_clean_or_raise_mjkin_error(model: str, xyz: Any, starts: Any, rounds: Any, merge: Any,
                                                  max_solutions: Any, seed: Any) -> None:
    t = tree(model)
    r = outcome(lambda: mjkin.solutions(t, G.Position(FRAMES[model], xyz), starts=starts, rounds=rounds,
                                        merge=merge, max_solutions=max_solutions, seed=seed, timeout=0.5))
    if r is not None:
        k = np.shape(r.q)[0]
        assert_clean_result(t, r, (k,))
        assert np.all(r.success)
        if isinstance(max_solutions, int):
            assert k <= max_solutions


# ----------------------------------------------------------------------------------------- reachability / place
def mostly(valid: list[Any], bad: list[Any]) -> st.SearchStrategy[Any]:
    """One of ``valid`` three times in four, else one of ``bad`` (so most examples get past the checks)."""
    return st.sampled_from(valid * 3 * max(1, len(bad) // max(1, len(valid))) + bad)


@settings(max_examples=30, deadline=None)
@given(resolution=mostly([0.5, 0.8, 2.0], [1e300, 0.0, -0.5, NAN, INF, "0.5", None]),
       orientations=mostly([1, 2], [0, -1, True, 2.5, NAN, "2", None]) | hnp.arrays(
           np.float64, st.sampled_from([(1, 4), (2, 4), (0, 4), (2, 3), (4,)]), elements=extreme),
       samples=mostly([2, 4], [1, 0, -5, 3.5, NAN, None]),
       seed=mostly([0, 7], [-1, 2**70, 1.5, None]),
       restarts=mostly([0, 1], [-1, 1.5, NAN, "x"]),
       tol=mostly([1e-3], [0.0, -1.0, NAN, INF]))
def test_reachability_is_clean_or_raises_mjkin_error(resolution: Any, orientations: Any, samples: Any, seed: Any,
                                                     restarts: Any, tol: Any) -> None:
    t = tree("arm7")
    m = outcome(lambda: mjkin.reachability(t, "ee", resolution=resolution, orientations=orientations,
                                           samples=samples, seed=seed, restarts=restarts, tol=tol, timeout=0.5))
    if m is not None:
        assert m.reached.dtype == np.bool_ and m.reached.ndim == 4
        assert m.reached.shape[3] == len(m.orientations)
        assert np.all(np.isfinite(m.origin)) and np.isfinite(m.resolution) and m.resolution > 0


_CAPABILITY: list[Any] = []


def capability() -> Any:
    """A coarse map of arm7's ee (built once)."""
    if not _CAPABILITY:
        _CAPABILITY.append(mjkin.reachability(tree("arm7"), "ee", resolution=0.5, orientations=2, samples=8,
                                              restarts=0))
    return _CAPABILITY[0]


@settings(max_examples=40, deadline=None)
@given(poses=st.sampled_from([(1, 7), (2, 7), (1, 4, 4), (7,), (0, 7), (1, 3), (4, 4)]).flatmap(
           lambda s: hnp.arrays(np.float64, s, elements=extreme)) | junk
       | st.just([[0.3, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0]]),
       region=hnp.arrays(np.float64, st.sampled_from([(4,), (2,), (2, 2)]), elements=extreme) | junk
       | st.just((-0.5, -0.5, 0.5, 0.5)),
       step=mostly([None, 0.5], [1.0, 1e-9, 0.0, -1.0, NAN, INF, 1e300]),
       yaws=mostly([1, 2], [0, -1, 10**12, 2.5]),
       verify=mostly([1, 2], [0, -1, 10**12, 1.5]))
def test_place_base_is_clean_or_raises_mjkin_error(poses: Any, region: Any, step: Any, yaws: Any,
                                                   verify: Any) -> None:
    t = tree("arm7")
    cap = capability()
    p = outcome(lambda: mjkin.place_base(t, "ee", poses, region, step=step, yaws=yaws, verify=verify,
                                         capability=cap, timeout=0.5))
    if p is not None:
        c = len(p.xy)
        assert p.xy.shape == (c, 2) and p.yaw.shape == (c,) and np.all(np.isfinite(p.xy))
        assert p.reached.dtype == np.bool_ and p.reached.shape[0] == c
        assert p.q.shape[:1] == (c,) and p.q.shape[-1] == t.nq
        assert_in_limits(t, p.q)
        assert np.all(np.isfinite(p.manipulability))


@pytest.mark.parametrize(("poses", "region"), [
    pytest.param("abc", (-0.5, -0.5, 0.5, 0.5), id="poses-string"),
    pytest.param([[0.3, 0, 0.5, 1, 0, 0, 0]], "abc", id="region-string"),
    pytest.param([[0.3, 0, 0.5, 1, 0, 0, 0]], {"a": 1}, id="region-dict"),
    pytest.param([[0.3, 0, 0.5, 1e300, 1e300, 0, 0]], (-0.5, -0.5, 0.5, 0.5), id="quaternion-1e300"),
])
def test_place_base_pinned(poses: Any, region: Any) -> None:
    p = outcome(lambda: mjkin.place_base(tree("arm7"), "ee", poses, region, yaws=1, verify=1, capability=capability(),
                                         timeout=0.5))
    if p is not None:
        assert_in_limits(tree("arm7"), p.q)


@pytest.mark.parametrize("kwargs", [
    pytest.param({"resolution": 1e-5}, id="resolution-1e-5"),
    pytest.param({"resolution": 1e-9}, id="resolution-1e-9"),
    pytest.param({"resolution": 5e-324}, id="resolution-5e-324"),
    pytest.param({"resolution": 1e300, "tol": INF}, id="resolution-1e300-tol-inf"),
    pytest.param({"seed": -1}, id="seed-negative"),
    pytest.param({"seed": 1.5}, id="seed-float"),
    pytest.param({"restarts": NAN}, id="restarts-nan"),
    pytest.param({"restarts": "x"}, id="restarts-string"),
])
def test_reachability_pinned(kwargs: dict[str, Any]) -> None:
    """Billions of voxels must be a MjkinError at once (not MemoryError, not a solve of every voxel); bad seeds too."""
    kw = {"resolution": 0.5, "orientations": 1, "samples": 2, "restarts": 0, "timeout": 0.1, **kwargs}
    m = outcome(lambda: mjkin.reachability(tree("arm7"), "ee", **kw))
    if m is not None:
        assert m.reached.dtype == np.bool_


# ----------------------------------------------------------------------------------------------------------- BVH
SMALL_BVH = small(order="Zrotation Xrotation Yrotation")  # test_bvh's two-joint clip

EXTREME_TOKENS = ["1e308", "-1e308", "1e309", "nan", "inf", "-inf", "1e-320", "9" * 400, "0", "-0", "0x10", "1_0",
                  "7.", "1e99999", "-1", "6", "7", "2.5", "999999999999", "1e18", "", "{", "}", "End", "JOINT", "ROOT",
                  "MOTION", "Frames:", "CHANNELS", "Site", "OFFSET", "Xrotation", "xposition", "Wrotation"]


@st.composite
def mutated_bvh(draw: st.DrawFn, base: str = SMALL_BVH) -> str:
    """``base`` with a few edits: a token replaced (numbers by extreme values), a line dropped, doubled, cut."""
    lines = base.splitlines()
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["token", "number", "drop", "double", "cut", "case"]))
        i = draw(st.integers(0, len(lines) - 1))
        words = lines[i].split()
        if op in ("token", "number") and words:
            numeric = [k for k, w in enumerate(words) if _is_number(w)]
            pool = numeric if op == "number" and numeric else range(len(words))
            k = draw(st.sampled_from(list(pool)))
            words[k] = draw(st.sampled_from(EXTREME_TOKENS) | st.text(max_size=6))
            lines[i] = " ".join(words)
        elif op == "drop":
            del lines[i]
        elif op == "double":
            lines.insert(i, lines[i])
        elif op == "cut":
            lines = lines[:i]
        elif op == "case":
            lines[i] = lines[i].lower() if draw(st.booleans()) else lines[i].upper()
        if not lines:
            break
    return "\n".join(lines) + "\n"


def check_clip(clip: bvh.Clip) -> None:
    J, F = len(clip.names), clip.frames
    assert F >= 1 and J >= 1
    assert clip.parents.shape == (J,) and clip.offsets.shape == (J, 3) and clip.ends.shape == (J,)
    assert clip.values.shape[0] == F and np.all(np.isfinite(clip.values)) and np.all(np.isfinite(clip.offsets))
    assert np.isfinite(clip.frame_time) and clip.frame_time > 0
    if F * J <= 10_000:
        assert clip.positions().shape == (F, J, 3)


NO_CHANNELS_HUGE_FRAMES = SMALL_BVH.replace("CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation",
                                            "CHANNELS 0").replace("CHANNELS 3 Zrotation Xrotation Yrotation",
                                                                  "CHANNELS 0").replace("Frames: 2", "Frames: 1e300")


@settings(max_examples=300, deadline=None)
@given(text=mutated_bvh())
def test_bvh_parse_is_clean_or_raises_bvh_error(text: str) -> None:
    clip = outcome(lambda: bvh.parse(text, "fuzz.bvh"))
    if clip is not None:
        check_clip(clip)


@pytest.mark.parametrize("text", [
    pytest.param(NO_CHANNELS_HUGE_FRAMES, id="no-channels-frames-1e300"),
    pytest.param(SMALL_BVH.replace("Frames: 2", "Frames: 1e300"), id="frames-1e300"),
    pytest.param(SMALL_BVH.replace("OFFSET 0 10 0", "OFFSET 0 1e308 0"), id="offset-1e308"),
])
def test_bvh_parse_pinned(text: str) -> None:
    clip = outcome(lambda: bvh.parse(text, "pinned.bvh"))
    if clip is not None:
        check_clip(clip)


def test_bvh_parse_junk_types() -> None:
    for text in ("", "\x00", "HIERARCHY", "HIERARCHY\nROOT", "\n" * 10, "HIERARCHY\n" + "ROOT a\n{\n" * 3000):
        clip = outcome(lambda text=text: bvh.parse(text))
        if clip is not None:
            check_clip(clip)


# ------------------------------------------------------------------------------------------------------ retarget
CROUCH = crouch_bvh(3)


@st.composite
def motion_mutations(draw: st.DrawFn) -> str:
    """The crouch with a few channel values (after MOTION) or offsets replaced by extreme numbers."""
    head, motion = CROUCH.split("MOTION\n")
    lines = motion.splitlines()
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(2, len(lines) - 1))
        words = lines[i].split()
        k = draw(st.integers(0, len(words) - 1))
        words[k] = draw(st.sampled_from(["1e308", "-1e308", "1e30", "-1e30", "1e-320", "1e6", "-36000", "720"]))
        lines[i] = " ".join(words)
    if draw(st.booleans()):
        hl = head.splitlines()
        offs = [k for k, ln in enumerate(hl) if ln.startswith("OFFSET")]
        k = draw(st.sampled_from(offs))
        hl[k] = "OFFSET " + " ".join(draw(st.lists(st.sampled_from(["0", "1e30", "-1e30", "1e-300", "42"]),
                                                   min_size=3, max_size=3)))
        head = "\n".join(hl) + "\n"
    return head + "MOTION\n" + "\n".join(lines) + "\n"


def check_trajectory(t: mjkin.Tree, traj: Any, frames: int) -> None:
    assert np.shape(traj.q) == (frames, t.nq) and np.shape(traj.times) == (frames,)
    assert np.all(np.isfinite(traj.q)) and np.all(np.isfinite(traj.times))
    assert_in_limits(t, np.asarray(traj.q))


@settings(max_examples=15, deadline=None)
@given(text=motion_mutations() | mutated_bvh(CROUCH),
       scale=st.sampled_from([None, 0.01, 0.0, -1.0, NAN, INF, 1e300]),
       max_speed=st.sampled_from([10.0, 0.0, -1.0, NAN, INF, 1e300]),
       tol=st.sampled_from([1e-4, 0.0, -1.0, NAN, INF]))
def test_retarget_is_clean_or_raises_mjkin_error(text: str, scale: Any, max_speed: Any, tol: Any) -> None:
    t = tree("primate")
    clip = outcome(lambda: bvh.parse(text, "fuzz.bvh"))
    if clip is None or clip.frames * len(clip.names) > 2000:
        return
    traj = outcome(lambda: mjkin.retarget(clip, t, scale=scale, max_speed=max_speed, tol=tol))
    if traj is not None:
        check_trajectory(t, traj, clip.frames)


@pytest.mark.parametrize("kwargs", [
    pytest.param({"scale": 1e-300}, id="scale-1e-300"),
    pytest.param({"max_speed": "x"}, id="max_speed-string"),
    pytest.param({"max_speed": (1.0, 2.0)}, id="max_speed-2-values"),
    pytest.param({"scale": 0.01}, id="scale-cm"),
])
def test_retarget_pinned(kwargs: dict[str, Any]) -> None:
    clip = bvh.parse(CROUCH)
    traj = outcome(lambda: mjkin.retarget(clip, tree("primate"), **kwargs))
    if traj is not None:
        check_trajectory(tree("primate"), traj, clip.frames)


def test_retarget_needs_a_free_root() -> None:
    assert outcome(lambda: mjkin.retarget(bvh.parse(CROUCH), tree("arm7"))) is None


# ---------------------------------------------------------------------------------------------------- gym envs
gym = pytest.importorskip("gymnasium")
import mjkin.envs  # noqa: E402,F401  (registers the ids)

ENV_KWARGS: dict[str, list[Any]] = {
    "action_type": ["joint", "cartesian", "bad", None, 3],
    "goal_type": ["position", "pose", "x"],
    "goal_conditioned": [False, True, "yes", 2],
    "step_size": [None, 0.1, 0.0, -1.0, NAN, INF, 1e300, "a"],
    "rot_step": [0.1, 0.0, NAN, 1e300],
    "success_tol": [None, 0.02, 0.0, NAN, 1e300, -1.0],
    "rot_tol": [0.1, 0.0, INF],
    "success_bonus": [1.0, NAN, 1e300, -INF],
    "sparse": [False, True, "no"],
    "collision_penalty": [0.0, 1.0, NAN, -1.0],
    "obstacles": [None, [], [((0.5, 0.0, 0.5), 0.1)], [((NAN, 0, 0), 0.1)], [((0, 0, 0), -1.0)], [((0, 0), 0.1)],
                  [((1e300, 0, 0), 1e300)], "ball", [1, 2]],
    "table": [None, -10.0, 0.0, 1e300, NAN, -1e300],
    "target_region": [None, ((-1, -1, -1), (1, 1, 1)), ((1, 1, 1), (-1, -1, -1)), ((NAN, 0, 0), (1, 1, 1)),
                      ((-1e300,) * 3, (1e300,) * 3), ((0, 0), (1, 1)), "box"],
    "start_noise": [0.0, 0.1, math.pi, 4.0, -1.0, NAN],
    "width": [480, 1, 0, -1, 2.5],
    "max_joint_speed": [None, 1.0, 0.0, -1.0, NAN, (1.0,) * 7, (1.0,) * 3],
}


@st.composite
def env_kwargs(draw: st.DrawFn) -> dict[str, Any]:
    keys = draw(st.lists(st.sampled_from(sorted(ENV_KWARGS)), max_size=3, unique=True))
    return {k: draw(st.sampled_from(ENV_KWARGS[k])) for k in keys}


def flat_obs(obs: Any) -> np.ndarray:
    if isinstance(obs, dict):
        return np.concatenate([np.ravel(v) for v in obs.values()])
    return np.ravel(obs)


def check_transition(env: Any, obs: Any, reward: float | None = None, terminated: Any = False) -> None:
    u = env.unwrapped
    assert np.all(np.isfinite(flat_obs(obs)))
    shape = env.observation_space.shape
    if shape is not None and not isinstance(obs, dict):
        assert np.shape(obs) == shape
    assert_in_limits(u.tree, np.asarray(u.q))
    if reward is not None:
        assert isinstance(reward, float) and math.isfinite(reward), reward
    assert isinstance(terminated, (bool, np.bool_))


actions = (hnp.arrays(st.sampled_from([np.float32, np.float64, np.int64, np.int8, np.bool_, np.float16]),
                      st.sampled_from([(7,), (3,), (6,), (), (1, 7), (0,)]), elements=None)
           | hnp.arrays(np.float64, st.sampled_from([(7,), (3,), (6,)]), elements=extreme) | junk)


@settings(max_examples=40, deadline=None)
# found in a README test run: the distance's squares overflowed, the reward was -inf
@example(env_id="mjkin/Reach-v0", kwargs={}, target=np.full(3, 1e300), q=None, acts=[np.zeros(7, np.float32)])
# found in a README test run: MuJoCo's collision of a 1e300 m obstacle 1e300 m away raised its FatalError
@example(env_id="mjkin/Reach-v0", kwargs={"obstacles": [((1e300, 0, 0), 1e300)]}, target=None, q=None, acts=[None])
@given(env_id=st.sampled_from(["mjkin/Reach-v0", "mjkin/PlanarReach-v0"]), kwargs=env_kwargs(),
       target=st.none() | hnp.arrays(np.float64, st.sampled_from([(3,), (7,), (2,)]), elements=extreme) | junk,
       q=st.none() | hnp.arrays(np.float64, st.sampled_from([(7,), (3,), (1, 7)]), elements=extreme) | junk,
       acts=st.lists(actions, min_size=1, max_size=3))
def test_env_reset_step_are_clean_or_raise_mjkin_error(env_id: str, kwargs: dict[str, Any], target: Any, q: Any,
                                                       acts: list[Any]) -> None:
    env = outcome(lambda: gym.make(env_id, disable_env_checker=True, **kwargs))
    if env is None:
        return
    try:
        got = outcome(lambda: env.reset(seed=0, options={"target": target, "q": q}))
        if got is None:
            got = outcome(lambda: env.reset(seed=0))
            assert got is not None  # a plain reset of an env that was made works
        check_transition(env, got[0])
        for a in acts:
            step = outcome(lambda a=a: env.step(a))
            if step is not None:
                obs, reward, terminated, truncated, info = step
                check_transition(env, obs, reward, terminated)
                assert isinstance(truncated, (bool, np.bool_)) and isinstance(info["is_success"], bool)
    finally:
        env.close()
