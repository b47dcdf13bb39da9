"""mjkin play: the pure drag → target → IK → q core, the HTTP API on a real server, and one browser test."""

from __future__ import annotations

import http.client
import json
import logging
import math
import os
import re
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from functools import cache
from pathlib import Path

import browser
import imageio.v3 as imageio
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mjkin
from conftest import tree_of
from mjkin import motion, render
from mjkin.apps.play import core, journal
from mjkin.apps.play import server as server_module
from mjkin.apps.play.server import BOUNDARY, PART, is_loopback, start_server, stop_server
from mjkin.apps.play.session import Playground, recordings_folder, view_camera
from mjkin.errors import InputError, MjkinIOError, UnknownNameError
from mjkin.kinematics import build
from mjkin.kinematics import tree as tree_module
from mjkin.runtime.files import strict_json as to_strict_json

IK_TOL = 1e-6
W, H = 320, 240
unit = st.floats(0.02, 0.98)


def arm() -> mjkin.Tree:
    return tree_of("arm7")


@cache
def arm_view() -> core.View:
    tree = arm()
    return core.View.of(view_camera(tree, core.initial_state(tree).q), tree.model, W, H)


@cache
def arm_home() -> core.Camera:
    tree = arm()
    return core.Camera.of(view_camera(tree, core.initial_state(tree).q))


def view_of(camera: core.Camera | dict) -> core.View:
    """The arm's view in a W x H image of a camera, or of the ``"camera"`` of a JSON state."""
    if isinstance(camera, dict):
        camera = core.Camera(tuple(camera["lookat"]), camera["distance"], camera["azimuth"], camera["elevation"])
    return core.View.of(camera, arm().model, W, H)


def angle_gap(a: float, b: float) -> float:
    """``a - b`` in degrees, wrapped to [-180, 180)."""
    return (a - b + 180.0) % 360.0 - 180.0


def off_ray(view: core.View, point: np.ndarray, uv) -> float:
    """How far (m) ``point`` is from the ray through image point ``uv``."""
    return float(np.linalg.norm(np.cross(np.asarray(point) - view.pos, view.ray(uv))))


def in_limits(tree: mjkin.Tree, q: np.ndarray) -> bool:
    return bool(np.allclose(tree.clip(q), q, atol=1e-12) and np.isfinite(q).all())


# ------------------------------------------------------------------ camera (pure)
@settings(deadline=None)
@given(u=unit, v=unit, depth=st.floats(0.1, 10.0))
def test_project_inverts_ray(u, v, depth):
    view = arm_view()
    point = view.pos + depth * view.ray([u, v])
    np.testing.assert_allclose(view.project(point), [u, v], atol=1e-9)


@settings(deadline=None)
@given(u=unit, v=unit, x=st.floats(-0.6, 0.6), y=st.floats(-0.6, 0.6), z=st.floats(0.1, 1.2))
def test_drag_stays_on_the_plane_facing_the_camera_and_lands_under_the_pointer(u, v, x, y, z):
    view, target = arm_view(), np.array([x, y, z])
    moved = core.drag(view, target, [u, v])
    assert abs((moved - target) @ view.forward) < 1e-9  # same depth along the view axis
    np.testing.assert_allclose(view.project(moved), [u, v], atol=1e-9)


@settings(deadline=None)
@given(amount=st.floats(-0.3, 0.3))
def test_push_moves_along_the_line_of_sight(amount):
    view, target = arm_view(), np.array([0.3, 0.1, 0.6])
    moved = core.push(view, target, amount)
    np.testing.assert_allclose(view.project(moved), view.project(target), atol=1e-9)
    assert np.linalg.norm(moved - view.pos) == pytest.approx(np.linalg.norm(target - view.pos) + amount, abs=1e-12)


@pytest.mark.parametrize("moves", [(), (core.Orbit(-70.0, 25.0), core.Zoom(0.8))], ids=["home", "orbited"])
def test_view_matches_what_mujoco_draws(moves):
    """A marker drawn by the renderer appears where View.project says (within 2 px), also after an orbit."""
    tree = arm()
    q = core.initial_state(tree).q
    camera = arm_home()
    for move in moves:
        camera = core.look(arm_home(), camera, move)
    cam = camera.mjv(tree.model)
    view = core.View.of(cam, tree.model, W, H)
    overlay = render.Overlay(point_size=0.03, point_rgba=(0.0, 1.0, 0.0, 1.0))
    with render.Painter(tree, W, H) as painter:
        for point in ([0.5, -0.4, 0.3], [-0.3, 0.5, 0.9], [0.6, 0.6, 0.1]):
            image = painter.draw(q, cam, [point], overlay=overlay).astype(int)
            green = (image[..., 1] > 100) & (image[..., 0] < 90) & (image[..., 2] < 90)  # lit and shaded sides
            assert green.sum() > 5
            rows, cols = np.nonzero(green)
            seen = np.array([cols.mean() + 0.5, rows.mean() + 0.5]) / [W, H]
            np.testing.assert_allclose(seen * [W, H], view.project(point) * [W, H], atol=2.0)


def test_camera_round_trips_through_mujoco_and_gives_the_same_view():
    tree = arm()
    cam = view_camera(tree, core.initial_state(tree).q)
    home = core.Camera.of(cam)
    assert core.Camera.of(home.mjv(tree.model)) == home
    a, b = core.View.of(cam, tree.model, W, H), core.View.of(home, tree.model, W, H)
    for x, y in ((a.pos, b.pos), (a.forward, b.forward), (a.up, b.up)):
        np.testing.assert_allclose(x, y, atol=1e-12)
    assert -core.ELEVATION_LIMIT < home.elevation < core.ELEVATION_LIMIT
    cam.elevation = -90.0  # a planar chain is framed from straight above: its home stops at the orbit's limit
    assert core.Camera.of(cam).elevation == -core.ELEVATION_LIMIT


def test_orbit_turns_about_the_look_at_point_and_stops_short_of_the_poles():
    home = arm_home()
    cam = core.look(home, home, core.Orbit(30.0, 10.0))
    assert angle_gap(cam.azimuth, home.azimuth) == pytest.approx(30.0)
    assert cam.elevation == pytest.approx(home.elevation + 10.0)
    assert cam.lookat == home.lookat and cam.distance == home.distance
    before, after = view_of(home), view_of(cam)
    assert np.linalg.norm(after.pos - home.lookat) == pytest.approx(home.distance)
    np.testing.assert_allclose(after.project(home.lookat), [0.5, 0.5], atol=1e-12)  # still the image's middle
    cos = (before.pos - home.lookat) @ (after.pos - home.lookat) / home.distance**2
    assert 10.0 < np.degrees(np.arccos(cos)) < 40.0  # the camera moved on its sphere
    assert core.look(home, home, core.Orbit(0.0, 500.0)).elevation == core.ELEVATION_LIMIT
    assert core.look(home, home, core.Orbit(0.0, -500.0)).elevation == -core.ELEVATION_LIMIT
    around = core.look(home, home, core.Orbit(730.0, 0.0))
    assert angle_gap(around.azimuth, home.azimuth) == pytest.approx(10.0) and -180 <= around.azimuth <= 180


def test_zoom_moves_the_camera_along_its_line_of_sight_within_range():
    home = arm_home()
    lo, hi = core.distance_range(home)
    assert lo < home.distance < hi
    near = core.look(home, home, core.Zoom(0.6))
    assert near.distance == pytest.approx(0.6 * home.distance)
    assert (near.lookat, near.azimuth, near.elevation) == (home.lookat, home.azimuth, home.elevation)
    before, after = view_of(home), view_of(near)
    np.testing.assert_allclose(after.forward, before.forward, atol=1e-12)
    np.testing.assert_allclose(after.pos, before.pos + 0.4 * home.distance * before.forward, atol=1e-12)
    assert core.look(home, near, core.Zoom(1e-9)).distance == pytest.approx(lo)
    assert core.look(home, near, core.Zoom(1e9)).distance == pytest.approx(hi)


def test_at_the_nearest_zoom_what_the_arm_reaches_stays_in_front_of_the_camera():
    tree, home = arm(), arm_home()
    points = np.array([tree.pose(q, "ee")[:3, 3] for q in tree.random_q(np.random.default_rng(0), 500)])
    nearest = core.distance_range(home)[0]
    for azimuth in range(-180, 180, 30):
        for elevation in (-89, -60, -30, 0, 30, 60, 89):
            view = view_of(core.Camera(home.lookat, nearest, azimuth, elevation))
            assert ((points - view.pos) @ view.forward).min() > 0.02 * home.distance, (azimuth, elevation)


view_events = st.one_of(
    st.builds(core.Orbit, st.floats(allow_nan=False, allow_infinity=False),
              st.floats(allow_nan=False, allow_infinity=False)),
    st.builds(core.Orbit, st.floats(-200, 200), st.floats(-200, 200)),
    st.builds(core.Zoom, st.floats(min_value=0.0, exclude_min=True, allow_infinity=False)),
    st.builds(core.Zoom, st.floats(0.2, 5.0)),
    st.just(core.ResetView()),
)


@settings(deadline=None)
@given(events=st.lists(view_events, max_size=25))
def test_any_orbits_and_zooms_keep_a_valid_camera_and_reset_goes_home(events):
    home = arm_home()
    lo, hi = core.distance_range(home)
    cam = home
    for event in events:
        cam = core.look(home, cam, event)
        assert cam.lookat == home.lookat
        assert np.isfinite([cam.distance, cam.azimuth, cam.elevation]).all()
        assert -core.ELEVATION_LIMIT <= cam.elevation <= core.ELEVATION_LIMIT
        assert -180.0 <= cam.azimuth <= 180.0 and lo * (1 - 1e-12) <= cam.distance <= hi * (1 + 1e-12)
        view = view_of(cam)
        frame = np.stack([view.forward, view.up, view.right])
        np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(view.project(home.lookat), [0.5, 0.5], atol=1e-9)
    assert core.look(home, cam, core.ResetView()) == home


@settings(max_examples=50, deadline=None)
@given(d_az=st.floats(-180, 180), d_el=st.floats(-120, 120), factor=st.floats(0.6, 2.5),
       du=st.floats(-0.1, 0.1), dv=st.floats(-0.1, 0.1))
def test_a_drag_after_an_orbit_lands_on_the_ray_under_the_pointer(d_az, d_el, factor, du, dv):
    tree, home = arm(), arm_home()
    cam = core.look(home, core.look(home, home, core.Orbit(d_az, d_el)), core.Zoom(factor))
    view = view_of(cam)
    state = core.initial_state(tree)
    target = state.targets["ee"][:3]
    uv = view.project(target) + [du, dv]
    moved = core.move(tree, view, state, core.Drag("ee", (float(uv[0]), float(uv[1])))).targets["ee"][:3]
    assert off_ray(view, moved, uv) < 1e-9
    assert (moved - view.pos) @ view.ray(uv) > 0  # in front of the camera
    assert abs((moved - target) @ view.forward) < 1e-9  # on the plane facing the new camera
    np.testing.assert_allclose(view.project(moved), uv, atol=1e-9)


@pytest.mark.parametrize(("event", "needle"), [
    (core.Orbit(float("nan"), 0.0), "finite angles"),
    (core.Orbit(0.0, float("inf")), "finite angles"),
    (core.Zoom(0.0), "factor > 0"),
    (core.Zoom(-2.0), "factor > 0"),
    (core.Zoom(float("nan")), "factor > 0"),
    (core.Zoom(float("inf")), "factor > 0"),
])
def test_bad_view_events_are_input_errors(event, needle):
    with pytest.raises(InputError, match=needle):
        core.look(arm_home(), arm_home(), event)


# -------------------------------------------------------------- state and IK (pure)
def test_place_puts_the_effector_on_a_reachable_target_within_limits():
    tree, view = arm(), arm_view()
    state = core.initial_state(tree)
    target = (0.4, 0.2, 0.5)
    out = core.apply(tree, view, state, core.Place("ee", target))
    assert out.success and out.error[0] < IK_TOL and out.status == "converged"
    np.testing.assert_allclose(tree.pose(out.q, "ee")[:3, 3], target, atol=IK_TOL)
    assert in_limits(tree, out.q)
    assert out.manipulability == pytest.approx(np.prod(out.singular)) and out.manipulability > 0
    assert state.q is not out.q and np.allclose(state.targets["ee"][:3], tree.pose(state.q, "ee")[:3, 3])


@settings(max_examples=30, deadline=None)
@given(du=st.floats(-0.08, 0.08), dv=st.floats(-0.08, 0.08))
def test_drag_event_moves_the_effector_under_the_pointer(du, dv):
    """The core as one pure function: (state, drag) → target → IK → q; the effector lands where the pointer is."""
    tree, view = arm(), arm_view()
    state = core.apply(tree, view, core.initial_state(tree), core.Place("ee", (0.4, 0.0, 0.6)))  # mid-workspace
    uv = view.project(state.targets["ee"][:3]) + [du, dv]
    out = core.apply(tree, view, state, core.Drag("ee", (float(uv[0]), float(uv[1]))))
    ee = tree.pose(out.q, "ee")[:3, 3]
    assert out.success, out.status
    np.testing.assert_allclose(view.project(ee), uv, atol=1e-5)
    assert abs((ee - state.targets["ee"][:3]) @ view.forward) < 1e-5
    assert in_limits(tree, out.q)


def test_follow_is_warm_started_small_drags_give_small_joint_steps():
    tree, view = arm(), arm_view()
    state = core.initial_state(tree)
    uv0 = view.project(state.targets["ee"][:3])
    steps = []
    for k in range(1, 21):
        nxt = core.apply(tree, view, state, core.Drag("ee", (float(uv0[0] + 0.004 * k), float(uv0[1]))))
        assert nxt.success
        steps.append(np.abs(nxt.q - state.q).max())
        state = nxt
    assert max(steps) < 0.1  # no jump to another IK branch while following


def test_unreachable_target_shows_the_closest_pose_and_says_so():
    tree, view = arm(), arm_view()
    out = core.apply(tree, view, core.initial_state(tree), core.Place("ee", (3.0, 0.0, 0.5)))
    assert not out.success and out.status in ("unreachable", "limits", "max_iterations")
    assert in_limits(tree, out.q)
    ee = tree.pose(out.q, "ee")[:3, 3]
    reach = 1.2  # the arm is ~1.1 m long from its base at the origin
    assert out.error[0] == pytest.approx(np.linalg.norm(ee - [3.0, 0.0, 0.5]), rel=1e-6)
    assert out.error[0] > 3.0 - reach


def test_step_mode_advances_one_iteration_per_call_until_converged():
    tree, view = arm(), arm_view()
    state = core.with_method(replace_step(core.initial_state(tree)), "dls")
    moved = core.apply(tree, view, state, core.Place("ee", (0.4, 0.3, 0.6)))
    assert np.array_equal(moved.q, state.q) and core.needs_step(moved)  # step mode: the target moves, q waits
    errors = []
    while core.needs_step(moved) and len(errors) < 500:
        moved = core.solve_state(tree, moved, max_iters=1)
        errors.append(moved.error[0])
        assert moved.iterations == len(errors)
    assert moved.success and errors[-1] < IK_TOL and errors[0] > 1e-2
    assert errors[-1] < errors[len(errors) // 2] < errors[0]


def replace_step(state: core.State) -> core.State:
    from dataclasses import replace

    return replace(state, step=True)


@pytest.mark.parametrize("method", core.panel_methods())
def test_every_panel_method_follows_a_small_drag(method):
    tree, view = arm(), arm_view()
    state = core.with_method(core.initial_state(tree), method)
    target = state.targets["ee"][:3] + [0.03, -0.02, 0.02]
    if method == "reach":  # the thesis's recursive reach: planar and ball-joint chains; this 3-D hinge arm is refused
        with pytest.raises(mjkin.GoalError, match="planar chains"):
            core.apply(tree, view, state, core.Place("ee", tuple(target)))
        return
    out = core.apply(tree, view, state, core.Place("ee", tuple(target)))
    assert in_limits(tree, out.q)
    assert out.error[0] < 1e-3, (method, out.status)


@settings(deadline=None)
@given(angle=st.floats(-3.0, 3.0))
def test_turn_rotates_the_target_about_the_line_of_sight(angle):
    tree, view = arm(), arm_view()
    state = core.initial_state(tree)
    out = core.move(tree, view, state, core.Turn("ee", angle))
    np.testing.assert_array_equal(out.targets["ee"][:3], state.targets["ee"][:3])
    R0 = mjkin.spatial.quat_to_mat(state.targets["ee"][3:])
    R1 = mjkin.spatial.quat_to_mat(out.targets["ee"][3:])
    np.testing.assert_allclose(R1 @ R0.T @ view.forward, view.forward, atol=1e-9)  # the view axis is the axis
    np.testing.assert_allclose(mjkin.spatial.quat_distance(out.targets["ee"][3:], state.targets["ee"][3:]),
                               abs(angle), atol=1e-9)
    turned_right = (R1 @ R0.T @ view.right) @ view.up
    assert np.sign(turned_right) == np.sign(angle) or abs(angle) < 1e-9  # counter-clockwise as seen


def test_pose_and_aim_goals():
    tree, view = arm(), arm_view()
    state = core.with_goal(core.initial_state(tree), "pose")
    turned = mjkin.spatial.quat_from_axis_angle([1.0, 0.0, 0.0], 0.4)
    target = state.targets["ee"][:3] + [0.05, 0.05, -0.05]
    out = core.apply(tree, view, state, core.Place("ee", tuple(target), tuple(turned)))
    assert out.success and out.error[1] < 1e-5
    T = tree.pose(out.q, "ee")
    assert mjkin.spatial.quat_distance(mjkin.spatial.mat_to_quat(T[:3, :3]), turned) < 1e-5
    aim = core.apply(tree, view, core.with_goal(state, "aim"), core.Place("ee", (0.6, 0.4, 0.2)))
    T = tree.pose(aim.q, "ee")
    direction = (np.array([0.6, 0.4, 0.2]) - T[:3, 3]) / np.linalg.norm([0.6, 0.4, 0.2] - T[:3, 3])
    assert T[:3, 2] @ direction == pytest.approx(1.0, abs=1e-6)  # the frame's z axis points at the target


def test_primate_moves_one_hand_and_keeps_the_other_effectors_and_its_root():
    tree = tree_of("primate")
    state = core.initial_state(tree)
    assert {"left_hand", "right_hand", "left_foot", "right_foot"} <= set(state.targets)
    view = core.View.of(view_camera(tree, state.q), tree.model, W, H)
    goal = state.targets["left_hand"][:3] + [0.15, 0.05, 0.1]
    out = core.apply(tree, view, state, core.Place("left_hand", tuple(goal)))
    assert out.success, out.status
    for frame, t in out.targets.items():
        np.testing.assert_allclose(tree.pose(out.q, frame)[:3, 3], t[:3], atol=IK_TOL)
    free = tree.layout.free_q.ravel()
    np.testing.assert_array_equal(out.q[free], state.q[free])  # the figure stands where it stood


def test_joint_slider_is_forward_kinematics_and_targets_follow():
    tree = arm()
    state = core.initial_state(tree)
    out = core.with_joint(tree, state, "j2", 0.9)
    assert out.q[tree.jnt_qadr[tree.id("j2", "joint")]] == 0.9
    np.testing.assert_allclose(out.targets["ee"][:3], tree.pose(out.q, "ee")[:3, 3])
    clipped = core.with_joint(tree, state, "j2", 50.0)
    assert clipped.q[1] == pytest.approx(2.09)
    with pytest.raises(UnknownNameError, match="'j7'"):
        core.with_joint(tree, state, "elbow", 0.1)
    with pytest.raises(InputError, match="ball or free"):
        core.with_joint(tree_of("primate"), core.initial_state(tree_of("primate")), "left_hip", 0.1)
    names = [s["name"] for s in core.joint_sliders(tree)]
    assert names == [f"j{k}" for k in range(1, 8)]


@settings(deadline=None)
@given(bad=st.sampled_from([float("nan"), float("inf"), -float("inf")]))
def test_bad_events_are_input_errors(bad):
    tree, view = arm(), arm_view()
    state = core.initial_state(tree)
    for event in (core.Drag("ee", (bad, 0.5)), core.Push("ee", bad), core.Place("ee", (0.1, bad, 0.2)),
                  core.Place("ee", (0.1, 0.1, 0.2), (bad, 0.0, 0.0, 1.0))):
        with pytest.raises(InputError):
            core.move(tree, view, state, event)
    with pytest.raises(InputError, match="not all zero"):
        core.move(tree, view, state, core.Place("ee", (0.1, 0.1, 0.2), (0.0, 0.0, 0.0, 0.0)))
    with pytest.raises(InputError, match="choose one of: auto"):
        core.with_method(state, "magic")
    with pytest.raises(InputError, match="position, pose, aim"):
        core.with_goal(state, "hug")
    with pytest.raises(InputError, match="at least one"):
        core.with_frames(tree, state, [])


def test_targets_beyond_far_are_refused_and_nearer_ones_solve_to_finite_numbers():
    """1e308 m away the position error overflowed to inf (sent as Infinity); the solvers are finite up to FAR."""
    tree, view = arm(), arm_view()
    state = core.initial_state(tree)
    centre, reach = tree.model.stat.center, tree_module.FAR * tree.model.stat.extent
    for event in (core.Place("ee", (1e308, 0.1, 0.4)), core.Place("ee", tuple(centre + [0, 0, 1.001 * reach])),
                  core.Push("ee", 1e308), core.Push("ee", -2 * reach), core.Drag("ee", (0.5, 1e6))):
        with pytest.raises(InputError, match=r"more than 1000 model extents \(1\.43e\+03 m\) from the model"):
            core.move(tree, view, state, event)
    for method in ("auto", "dls", "pinv", "transpose", "optimize"):
        for goal in ("position", "pose"):
            far = core.with_goal(core.with_method(state, method), goal)
            solved = core.apply(tree, view, far, core.Place("ee", tuple(centre + 0.999 * reach * np.ones(3) / 3**0.5)))
            assert np.isfinite([*solved.q, *solved.error, *solved.singular, solved.manipulability]).all()
            assert not solved.success
    slider = mjkin.load(build.dh_chain([[0, 0, 0.1, 0], [0.3, 0, 0, 0]], "PR"))  # an unlimited slide
    assert not slider.jnt_limited[0]
    state = core.initial_state(slider, ["ee"])
    assert core.with_joint(slider, state, slider.names("joint")[0], 5.0).targets["ee"][2] == pytest.approx(5.1)
    with pytest.raises(InputError, match="the target of 'ee' would be at \\[0.3, 0, 1e\\+308\\], more than"):
        core.with_joint(slider, state, slider.names("joint")[0], 1e308)


@settings(deadline=None, max_examples=40)
@given(pos=st.lists(st.floats(allow_nan=False, allow_infinity=False) | st.floats(-2000, 2000), min_size=3, max_size=3))
def test_a_placed_target_anywhere_is_refused_or_solved_to_finite_numbers(pos):
    tree = arm()
    try:
        solved = core.apply(tree, arm_view(), core.initial_state(tree), core.Place("ee", tuple(pos)))
    except InputError as e:
        assert "model extents" in str(e) and "\n" not in str(e)
        assert math.hypot(*(np.array(pos) - tree.model.stat.center)) > tree_module.FAR * tree.model.stat.extent
        return
    assert np.isfinite([*solved.q, *solved.error, *solved.singular]).all()


def test_a_target_level_with_the_camera_projects_to_non_finite_numbers_that_go_out_as_null():
    view = arm_view()
    point = view.project(view.pos)
    assert not np.isfinite(point).any()
    doc = to_strict_json({"screen": {"ee": point.tolist()}, "error": (float("inf"), 0.5), "n": 3, "ok": True})
    assert json.loads(doc) == {"screen": {"ee": [None, None]}, "error": [None, 0.5], "n": 3, "ok": True}


# ------------------------------------------------------------------- HTTP (real server)
def strict_json(payload: bytes) -> object:
    """Parse JSON as browsers do: ``Infinity`` and ``NaN`` (which Python's json writes by default) are errors."""
    def refuse(word: str) -> None:
        raise ValueError(f"not JSON: {word}")
    return json.loads(payload, parse_constant=refuse)


class Client:
    """Requests as the page makes them: its client id, the server's token, JSON bodies; ``headers`` change that."""

    def __init__(self, port: int, token: str | None, name: str = "test") -> None:
        self.port, self.token, self.name = port, token, name

    @classmethod
    def of(cls, server, name: str = "test") -> Client:
        return cls(server.server_address[1], server.token, name)

    def request(self, method: str, path: str, body: object = None, raw: bytes | None = None,
                headers: dict | None = None):
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=60)
        data = raw if raw is not None else (None if body is None else json.dumps(body).encode())
        sent = {"X-Mjkin-Client": self.name, "Content-Type": "application/json"}
        if self.token is not None:
            sent["X-Mjkin-Token"] = self.token
        sent = {k: v for k, v in {**sent, **(headers or {})}.items() if v is not None}  # None: leave the header out
        if "Host" in sent:
            conn.putrequest(method, path, skip_host=True)  # http.client would send its own Host as well
            for k, v in sent.items():
                conn.putheader(k, v)
            conn.putheader("Content-Length", str(len(data or b"")))
            conn.endheaders(data)
        else:
            conn.request(method, path, data, sent)
        resp = conn.getresponse()
        payload = resp.read()
        conn.close()
        kind = resp.getheader("Content-Type") or ""
        return resp.status, strict_json(payload) if kind.startswith("application/json") else payload

    def get(self, path: str, headers: dict | None = None):
        return self.request("GET", path, headers=headers)

    def post(self, path: str, body: object = None, raw: bytes | None = None, headers: dict | None = None):
        return self.request("POST", path, {} if body is None and raw is None else body, raw, headers)


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    out = tmp_path_factory.mktemp("recordings")
    pg = Playground(arm(), W, H, lease=0.5, out_dir=out).start()
    server, thread = start_server(pg)
    yield server, out
    stop_server(server, thread)
    assert not [t for t in threading.enumerate() if t.name.startswith("mjkin-play")]


@pytest.fixture
def api(served):
    server, _ = served
    client = Client.of(server)
    deadline = time.monotonic() + 10
    while client.post("/reset")[0] == 409 and time.monotonic() < deadline:
        time.sleep(0.1)  # another test's client holds control until its lease (0.5 s here) runs out
    client.post("/view", {"reset": True})
    client.post("/frames", {"frames": ["ee"]})
    client.post("/method", {"method": "auto"})
    client.post("/goal", {"goal": "position"})
    return client


def test_state_has_the_documented_shape(api):
    status, state = api.get("/state")
    assert status == 200
    assert {"model", "q", "targets", "error", "iterations", "method"} <= set(state)
    assert state["model"] == "arm7" and len(state["q"]) == 7 and len(state["error"]) == 2
    assert list(state["targets"]) == ["ee"] and len(state["targets"]["ee"]) == 7
    target = np.array(state["targets"]["ee"])
    x_tip = target[:3] + 0.08 * mjkin.spatial.quat_to_mat(target[3:])[:, 0]  # the drawn x axis ends there
    np.testing.assert_allclose(state["screen_axes"]["ee"][0], arm_view().project(x_tip), atol=1e-9)


def test_post_target_solves_and_returns_the_new_state(api):
    status, state = api.post("/target", {"frame": "ee", "pos": [0.4, 0.2, 0.5]})
    assert status == 200 and state["error"][0] < IK_TOL and state["success"]
    np.testing.assert_allclose(arm().pose(np.array(state["q"]), "ee")[:3, 3], [0.4, 0.2, 0.5], atol=IK_TOL)
    assert api.get("/state")[1]["q"] == state["q"]


def test_drag_route_moves_the_effector_under_the_pointer(api):
    _, state = api.get("/state")
    u, v = state["screen"]["ee"]
    status, moved = api.post("/drag", {"frame": "ee", "uv": [u + 0.05, v - 0.03]})
    assert status == 200 and moved["success"]
    np.testing.assert_allclose(moved["screen"]["ee"], [u + 0.05, v - 0.03], atol=1e-6)
    _, pushed = api.post("/drag", {"frame": "ee", "depth": 0.05})
    np.testing.assert_allclose(pushed["screen"]["ee"], moved["screen"]["ee"], atol=1e-6)
    _, turned = api.post("/drag", {"frame": "ee", "turn": 0.3})
    assert turned["targets"]["ee"][:3] == pushed["targets"]["ee"][:3]
    assert turned["targets"]["ee"][3:] != pushed["targets"]["ee"][3:]
    assert "\"turn\": radians" in api.post("/drag", {"frame": "ee"})[1]["error"]


@pytest.mark.parametrize(("body", "needle"), [
    ({"frame": "hand", "pos": [0.4, 0.2, 0.5]}, "sites: 'ee'; bodies: 'world', 'link1'"),
    ({"frame": "ee"}, "pos must be a list of 3 numbers"),
    ({"frame": "ee", "pos": [0.4, 0.2]}, "pos must be a list of 3 numbers"),
    ({"frame": "ee", "pos": [0.4, "x", 0.5]}, "pos must be a number"),
    ({"frame": "ee", "pos": [0.4, 0.2, 0.5], "quat": [0, 0, 0, 0]}, "not all zero"),
    ({"pos": [0.4, 0.2, 0.5]}, "\"frame\""),
    ([1, 2], "JSON object"),
])
def test_bad_target_is_a_400_with_one_line(api, body, needle):
    status, doc = api.post("/target", body)
    assert status == 400 and set(doc) == {"error"} and "\n" not in doc["error"]
    assert needle in doc["error"]


def test_info_lists_what_the_panel_offers(api):
    status, info = api.get("/info")
    assert status == 200 and info["methods"] == list(core.panel_methods())
    assert info["goals"] == ["position", "pose", "aim"]
    assert info["sites"] == ["ee"] and "link7" in info["bodies"] and (info["width"], info["height"]) == (W, H)
    assert [j["name"] for j in info["joints"]] == [f"j{k}" for k in range(1, 8)]
    status, page = api.get("/")
    assert status == 200 and b"/stream.mjpg" in page and b"/drag" in page and b"/view" in page


def test_bad_json_unknown_route_and_bad_method(api):
    status, doc = api.post("/target", raw=b"{not json")
    assert status == 400 and "must be JSON" in doc["error"]
    status, doc = api.post("/method", {"method": "magic"})
    assert status == 400 and f"choose one of: {', '.join(core.panel_methods())}" in doc["error"]
    assert api.post("/nowhere")[0] == 404 and api.get("/nowhere")[0] == 404
    status, doc = api.post("/method", {"method": "dls"})
    assert status == 200 and doc["method"] == "dls"
    status, doc = api.post("/method", {"method": "reach"})  # the 3-D hinge arm: refused, and nothing changes
    assert status == 400 and "planar chains" in doc["error"] and "\n" not in doc["error"]
    assert api.get("/state")[1]["method"] == "dls"


def test_frame_jpg_shows_the_current_state(api):
    status, before = api.get("/frame.jpg")
    assert status == 200 and before[:2] == b"\xff\xd8"
    assert imageio.imread(before).shape == (H, W, 3)
    api.post("/target", {"frame": "ee", "pos": [0.3, -0.4, 0.3]})
    _, after = api.get("/frame.jpg")
    diff = np.abs(imageio.imread(after).astype(int) - imageio.imread(before).astype(int))
    assert diff.mean() > 0.5  # the arm moved in the picture


class Stream:
    """A reader of ``/stream.mjpg``: :meth:`next` is the next JPEG the server streams."""

    def __init__(self, server) -> None:
        self.conn = http.client.HTTPConnection("127.0.0.1", server.server_address[1], timeout=30)
        self.conn.request("GET", f"/stream.mjpg?token={server.token}")  # as the page's <img> asks
        self.resp = self.conn.getresponse()
        self.data = b""
        while len(self.data) < len(PART) - 2:
            self.data += self.resp.read1(1 << 16)
        assert self.data.startswith(PART[2:])
        self.data = self.data[len(PART) - 2:]

    def next(self) -> np.ndarray:
        while PART not in self.data:
            self.data += self.resp.read1(1 << 16)
        jpeg, self.data = self.data.split(PART, 1)
        return imageio.imread(jpeg).astype(int)

    def close(self) -> None:
        self.resp.close()
        self.conn.close()


def test_view_route_orbits_zooms_and_resets_what_is_streamed(api, served):
    server, _ = served
    _, state = api.get("/state")
    home = state["camera"]
    assert api.get("/frame.jpg")[0] == 200  # the current state is drawn: the stream starts with it
    stream = Stream(server)
    try:
        first = stream.next()
        status, turned = api.post("/view", {"orbit": [50, -20]})
        assert status == 200
        cam = turned["camera"]
        assert angle_gap(cam["azimuth"], home["azimuth"]) == pytest.approx(50.0)
        assert cam["elevation"] == pytest.approx(home["elevation"] - 20.0)
        assert cam["lookat"] == home["lookat"] and cam["distance"] == home["distance"]
        assert turned["q"] == state["q"] and turned["targets"] == state["targets"]  # the figure stays put
        np.testing.assert_allclose(turned["screen"]["ee"], view_of(cam).project(state["targets"]["ee"][:3]))
        assert not np.allclose(turned["screen"]["ee"], state["screen"]["ee"], atol=0.01)  # seen from elsewhere
        orbited = stream.next()
        assert np.abs(orbited - first).mean() > 2.0
        assert api.post("/reset")[1]["camera"] == cam  # "reset pose" keeps the view
        assert np.abs(stream.next() - orbited).mean() < 0.5  # the pose was home already: the same picture
        status, zoomed = api.post("/view", {"zoom": 0.6})
        assert status == 200 and zoomed["camera"]["distance"] == pytest.approx(0.6 * home["distance"])
        closer = stream.next()
        assert np.abs(closer - orbited).mean() > 2.0
        status, back = api.post("/view", {"reset": True})
        assert status == 200 and back["camera"] == home
        np.testing.assert_allclose(back["screen"]["ee"], state["screen"]["ee"], atol=1e-12)
        again = stream.next()
        assert np.abs(again - first).mean() < 0.5  # the first frame again, within JPEG noise
    finally:
        stream.close()


def test_a_drag_after_an_orbit_moves_the_effector_under_the_pointer_in_the_new_view(api):
    status, turned = api.post("/view", {"orbit": [-70, 25]})
    assert status == 200
    view = view_of(turned["camera"])
    u, v = turned["screen"]["ee"]
    uv = [u + 0.04, v + 0.03]
    status, moved = api.post("/drag", {"frame": "ee", "uv": uv})
    assert status == 200 and moved["success"]
    target = np.array(moved["targets"]["ee"][:3])
    assert off_ray(view, target, uv) < 1e-9
    assert off_ray(arm_view(), target, uv) > 0.01  # the initial view's ray is elsewhere: the drag used the new one
    np.testing.assert_allclose(moved["screen"]["ee"], uv, atol=1e-9)
    np.testing.assert_allclose(arm().pose(np.array(moved["q"]), "ee")[:3, 3], target, atol=IK_TOL)


@pytest.mark.parametrize(("body", "needle"), [
    ({}, "exactly one of \"orbit\": [d_azimuth, d_elevation] (degrees)"),
    ({"orbit": [10, 0], "zoom": 2}, "got keys [\"orbit\", \"zoom\"]"),
    ({"orbit": [10]}, "orbit must be a list of 2 numbers"),
    ({"orbit": [10, "up"]}, "orbit must be a number"),
    ({"zoom": 0}, "factor > 0"),
    ({"zoom": -1.5}, "factor > 0"),
    ({"zoom": "in"}, "zoom must be a number"),
    ({"reset": "yes"}, "\"reset\" must be true"),
    (b'{"orbit": [NaN, 0]}', "finite angles"),
])
def test_bad_view_change_is_a_400_with_one_line_and_changes_nothing(api, body, needle):
    _, before = api.get("/state")
    status, doc = api.post("/view", raw=body) if isinstance(body, bytes) else api.post("/view", body)
    assert status == 400 and set(doc) == {"error"} and "\n" not in doc["error"]
    assert needle in doc["error"]
    assert api.get("/state")[1]["camera"] == before["camera"]


def test_stream_sends_frames_and_a_client_leaving_mid_stream_costs_nothing(api, served):
    server, _ = served
    for _ in range(3):
        conn = http.client.HTTPConnection("127.0.0.1", server.server_address[1], timeout=30)
        conn.request("GET", f"/stream.mjpg?token={server.token}")
        resp = conn.getresponse()
        assert resp.getheader("Content-Type") == f"multipart/x-mixed-replace; boundary={BOUNDARY}"
        data = b""
        while data.count(PART) < 1:
            data += resp.read1(1 << 16)
        assert data.startswith(PART[2:])  # the stream opens with the first part's headers
        image = data[len(PART) - 2:].split(PART)[0]
        resp.close()  # leave mid-stream (the response holds the socket open until it is closed too)
        conn.close()
    assert image[:2] == b"\xff\xd8"
    status, state = api.post("/target", {"frame": "ee", "pos": [0.35, 0.25, 0.55]})
    assert status == 200 and api.get("/frame.jpg")[0] == 200
    deadline = time.monotonic() + 10
    while server.routes.streams and time.monotonic() < deadline:
        time.sleep(0.05)  # the server hears of the closed socket and ends the stream
    assert server.routes.streams == 0


def test_one_client_controls_others_watch(served):
    server, _ = served
    a, b = Client.of(server, "a"), Client.of(server, "b")
    time.sleep(0.6)  # any earlier lease (0.5 s in this fixture) has run out
    assert a.post("/target", {"frame": "ee", "pos": [0.4, 0.1, 0.5]})[0] == 200
    status, doc = b.post("/target", {"frame": "ee", "pos": [0.4, -0.1, 0.5]})
    assert status == 409 and "another client controls" in doc["error"]
    assert b.get("/state")[0] == 200  # watching is always allowed
    time.sleep(0.6)
    assert b.post("/target", {"frame": "ee", "pos": [0.4, -0.1, 0.5]})[0] == 200


def finished(client: Client, timeout: float = 300.0) -> tuple[dict, list[float]]:
    """The last take's save as ``/state`` reports it once finished (written or failed); the progress seen before."""
    seen, deadline = [], time.monotonic() + timeout
    while time.monotonic() < deadline:
        save = client.get("/state")[1]["save"]
        if save["done"] or save["error"]:
            return save, seen
        seen.append(save["progress"])
        time.sleep(0.02)
    pytest.fail(f"the save did not finish within {timeout} s: {save}")


def test_record_and_stop_write_a_script_and_a_video(api, served):
    _, out = served
    assert api.post("/stop")[0] == 400  # not recording
    assert api.post("/record")[1]["recording"]
    assert api.post("/record")[0] == 400
    for k in range(6):
        api.post("/target", {"frame": "ee", "pos": [0.4, 0.2 - 0.05 * k, 0.5]})
        time.sleep(0.05)
    status, started = api.post("/stop")
    assert status == 200 and started["frames"] >= 2 and not started["done"]  # the reply does not wait for the save
    saved, _ = finished(api)
    assert saved == {**started, "progress": 1.0, "done": True}, saved
    traj = motion.Trajectory.load(saved["path"], arm())  # the existing format, on this model
    np.testing.assert_allclose(arm().pose(traj.q[-1], "ee")[:3, 3], [0.4, -0.05, 0.5], atol=IK_TOL)
    assert traj.targets is not None and traj.targets.shape == (len(traj.q), 1, 3)
    frames = imageio.imread(saved["video"], index=None)
    assert frames.ndim == 4 and frames.shape[1:] == (H, W, 3)
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary files left


def test_absurd_numbers_get_one_line_400s_and_every_reply_is_strict_json(api):
    """A target 1e308 m away was a 200 with Infinity in it, and /state kept it: the page's r.json() failed."""
    refused = [("/target", {"frame": "ee", "pos": [1e308, 0.1, 0.4]}), ("/drag", {"frame": "ee", "depth": 1e308}),
               ("/drag", {"frame": "ee", "uv": [0.5, 1e6]})]
    for path, body in refused:
        status, doc = api.post(path, body)  # the client parses strictly: Infinity or NaN would raise
        assert status == 400 and "model extents" in doc["error"] and "\n" not in doc["error"], (path, doc)
    for path in ("/state", "/info"):
        assert api.get(path)[0] == 200
    accepted = [("/view", {"orbit": [1e308, -1e308]}), ("/view", {"zoom": 1e308}),
                ("/joint", {"joint": "j1", "value": 1e308}), ("/method", {"method": "dls"}),
                ("/goal", {"goal": "pose"}),
                ("/target", {"frame": "ee", "pos": [0.4, 0.1, 0.4], "quat": [1e308, 0, 0, 1e308]}),
                ("/frames", {"frames": ["ee", "link4"]}), ("/step", {"on": False}), ("/reset", {}),
                ("/view", {"reset": True})]
    for path, body in accepted:
        status, doc = api.post(path, body)
        assert status == 200, (path, doc)
        if path == "/target":  # the huge quaternion, made unit without overflowing to zeros
            np.testing.assert_allclose(doc["targets"]["ee"][3:], [0.5**0.5, 0, 0, 0.5**0.5], atol=1e-12)
    assert api.get("/state")[0] == 200


def test_a_target_level_with_the_camera_has_null_image_points(api):
    _, state = api.get("/state")
    eye = view_of(state["camera"]).pos
    status, doc = api.post("/target", {"frame": "ee", "pos": eye.tolist()})
    assert status == 200 and doc["screen"]["ee"] == [None, None]
    assert api.get("/state")[1]["screen"]["ee"] == [None, None]
    assert all(np.isfinite(doc["q"])) and np.isfinite(doc["error"]).all()


def test_a_recording_that_cannot_be_written_is_kept_and_a_retry_writes_it(api, served, monkeypatch):
    """The folder went away: /stop was a 500 and the recording was gone. Now the error says it is kept."""
    _, out = served
    before = set(out.iterdir())
    assert api.post("/record")[0] == 200
    for k in range(3):
        api.post("/target", {"frame": "ee", "pos": [0.4, 0.1 * k, 0.5]})
        time.sleep(0.05)
    away = out.with_name(out.name + "-away")
    out.rename(away)
    try:
        assert api.post("/stop")[0] == 200  # the save starts, and fails in the background
        doc, _ = finished(api)
    finally:
        away.rename(out)
    assert not doc["done"] and "does not exist" in doc["error"] and "\n" not in doc["error"]
    assert "the recording is kept" in doc["error"] and "POST /stop" in doc["error"]
    _, state = api.get("/state")
    assert state["unsaved"] and not state["recording"]
    status, doc = api.post("/record")  # a new recording would hide the unsaved one
    assert status == 400 and "not written yet" in doc["error"]
    saved_script = motion.Trajectory.save

    def fail_once(self, path):  # the video is written, then the script fails (disk full, say)
        monkeypatch.setattr(motion.Trajectory, "save", saved_script)
        raise MjkinIOError(f"cannot write {str(path)!r}: [Errno 28] No space left on device")

    monkeypatch.setattr(motion.Trajectory, "save", fail_once)
    assert api.post("/stop")[0] == 200
    doc, _ = finished(api)
    assert "No space left" in doc["error"] and "the recording is kept" in doc["error"]
    kept = set(out.glob("*.journal.jsonl"))  # the take's journal stays until the take is written
    assert len(kept) == 1 and set(out.iterdir()) == before | kept  # no video without its script, no temporary file
    assert api.post("/stop")[0] == 200  # the retry
    saved, _ = finished(api)
    assert saved["done"] and saved["frames"] >= 2
    traj = motion.Trajectory.load(saved["path"], arm())
    np.testing.assert_allclose(arm().pose(traj.q[-1], "ee")[:3, 3], [0.4, 0.2, 0.5], atol=IK_TOL)
    assert imageio.imread(saved["video"], index=None).shape[1:] == (H, W, 3)
    assert not api.get("/state")[1]["unsaved"] and set(out.iterdir()) == before | {Path(saved["path"]),
                                                                                    Path(saved["video"])}
    assert api.post("/stop")[0] == 400  # written: nothing left to stop


def unwritable(tmp_path) -> str:
    """A folder made read-only; skips when this user writes there anyway (root ignores permission bits)."""
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        (folder / "probe").write_text("")
    except PermissionError:
        return str(folder)
    pytest.skip("this user (root?) writes into a read-only folder: chmod cannot make one unwritable here")


@pytest.mark.parametrize(("out", "needle"), [
    ("{tmp}/missing", "does not exist"),
    ("/proc", "folder '/proc' is not writable"),  # not even root writes there
    ("read-only", "is not writable (Permission denied)"),
])
def test_an_unwritable_recordings_folder_is_refused_at_the_start(tmp_path, out, needle):
    out = unwritable(tmp_path) if out == "read-only" else out.format(tmp=tmp_path)
    with pytest.raises(MjkinIOError, match="--out") as e:
        recordings_folder(out, "arm7")
    assert needle in str(e.value) and "\n" not in str(e.value)
    proc = subprocess.run([sys.executable, "-m", "mjkin.apps.cli", "play", "arm7", "--port", "0", "--no-browser",
                           "--out", out], capture_output=True, text=True, timeout=300)  # serves forever if accepted
    assert proc.returncode == 2 and proc.stdout == "" and proc.stderr.strip().count("\n") == 0
    assert needle in proc.stderr and "Traceback" not in proc.stderr


def test_frames_and_step_routes(api):
    status, doc = api.post("/frames", {"frames": ["ee", "link4"]})
    assert status == 200 and list(doc["targets"]) == ["ee", "link4"]
    assert api.post("/frames", {"frames": "ee"})[0] == 400
    status, doc = api.post("/target", {"frame": "link7", "pos": [0.3, 0.2, 0.6]})  # a body becomes an effector
    assert status == 200 and list(doc["targets"]) == ["ee", "link4", "link7"]
    api.post("/frames", {"frames": ["ee"]})
    status, doc = api.post("/step", {"on": True})
    assert doc["step"]
    _, doc = api.post("/target", {"frame": "ee", "pos": [0.3, 0.3, 0.7]})
    assert doc["iterations"] == 0 and doc["stepping"]
    deadline = time.monotonic() + 30
    while doc["stepping"] and time.monotonic() < deadline:  # the render thread steps, frame by frame
        time.sleep(0.1)
        doc = api.get("/state")[1]
    assert doc["success"] and doc["iterations"] > 1
    assert api.post("/step", {"on": "yes"})[0] == 400
    api.post("/step", {"on": False})


def test_loopback_detection():
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.4")


# ------------------------------------------------------------ the door (token, Host, Origin, Content-Type)
def still(api) -> tuple:
    """What a refused request must leave as it was: the pose, the targets, the recording."""
    _, state = api.get("/state")
    return state["q"], state["targets"], state["recording"]


def test_the_url_carries_a_secret_token_and_every_route_needs_it(api, served):
    server, out = served
    port, token = server.server_address[1], server.token
    assert server.url == f"http://127.0.0.1:{port}/?token={token}" and len(token) >= 32
    anonymous, wrong = Client(port, None), Client(port, token[:-1] + ("A" if token[-1] != "A" else "B"))
    before, files = still(api), set(out.iterdir())
    for client in (anonymous, wrong):
        for path in ("/state", "/info", "/frame.jpg", "/stream.mjpg?token=nope"):
            status, doc = client.get(path)
            assert status == 403 and set(doc) == {"error"} and "\n" not in doc["error"], (path, doc)
            assert "token" in doc["error"]
        for path in ("/record", "/stop", "/target"):
            body = {"frame": "ee", "pos": [0.3, 0.3, 0.3]} if path == "/target" else {}
            assert client.post(path, body)[0] == 403
    assert still(api) == before and set(out.iterdir()) == files  # nothing recorded, nothing written
    status, page = anonymous.get("/")  # the page, too, as Jupyter does
    assert status == 403 and page.count(b"\n") == 1 and b"mjkin play printed" in page and b"?token=" in page
    assert anonymous.get(f"/?token={token}")[0] == 200
    assert anonymous.get("/state", headers={"Authorization": f"token {token}"})[0] == 200
    assert anonymous.get(f"/state?token={token}")[0] == 200
    assert anonymous.get("/state", headers={"Authorization": f"Bearer {token}"})[0] == 403


def test_a_foreign_host_is_refused_and_the_arm_does_not_move(api, served):
    """DNS rebinding: a page of evil.example whose name now points here sends its own name as Host."""
    server, _ = served
    port = server.server_address[1]
    before = still(api)
    for host in (f"evil.example:{port}", "evil.example", f"127.0.0.1:{port + 1}", "localhost", ""):
        status, doc = api.post("/target", {"frame": "ee", "pos": [0.3, 0.3, 0.3]}, headers={"Host": host})
        assert status == 421 and "\n" not in doc["error"] and "Host" in doc["error"], (host, doc)
        assert api.get("/state", headers={"Host": host})[0] == 421
    assert still(api) == before
    for host in (f"localhost:{port}", f"LOCALHOST:{port}", f"[::1]:{port}", f"127.0.0.1:{port}"):
        assert api.get("/state", headers={"Host": host})[0] == 200, host


def test_cross_origin_and_non_json_posts_are_refused_and_change_nothing(api, served):
    server, _ = served
    port = server.server_address[1]
    evil = "http://evil.example"
    move = json.dumps({"frame": "ee", "pos": [0.3, 0.3, 0.3]}).encode()
    before = still(api)
    form = Client(port, None).post("/target", raw=move, headers={"Origin": evil, "Content-Type": "text/plain"})
    assert form[0] == 403  # what a form or a simple fetch of another page sends
    status, doc = api.post("/target", raw=move, headers={"Origin": evil})
    assert status == 403 and "another origin" in doc["error"]
    assert api.post("/record", headers={"Origin": "null"})[0] == 403  # a sandboxed frame or a file:// page
    for kind in ("text/plain", "application/x-www-form-urlencoded", "multipart/form-data; boundary=x", None):
        status, doc = api.post("/target", raw=move, headers={"Content-Type": kind})
        assert status == 415 and "application/json" in doc["error"], (kind, doc)
    status, doc = api.request("OPTIONS", "/target", headers={"Origin": evil, "Access-Control-Request-Method": "POST",
                                                           "Access-Control-Request-Headers": "content-type"})
    assert status == 403 and "Access-Control-Allow-Origin" not in str(doc)  # no preflight passes
    assert still(api) == before
    status, doc = api.post("/target", raw=move, headers={"Origin": f"http://127.0.0.1:{port}",
                                                         "Content-Type": "application/json; charset=utf-8"})
    assert status == 200 and doc["targets"]["ee"][:3] == [0.3, 0.3, 0.3]  # the page's own origin


def test_the_door_holds_for_any_host_address():
    """--host other than loopback keeps the token and the Host rule (its warning is printed by serve)."""
    hosts = server_module.host_names("192.168.1.4", 8765, "192.168.1.4")
    assert {"192.168.1.4:8765", "localhost:8765", "127.0.0.1:8765", "[::1]:8765"} <= hosts
    assert "192.168.1.5:8765" not in hosts and "192.168.1.4" not in hosts
    assert "[fe80::1]:8765" in server_module.host_names("fe80::1", 8765, "fe80::1")
    scope = {"type": "http", "method": "GET", "path": "/state", "query_string": b"",
             "headers": [(b"host", b"192.168.1.4:8765")]}
    with pytest.raises(server_module.Refused, match="token") as e:
        server_module.check_request(scope, "secret", hosts)
    assert e.value.status == 403
    server_module.check_request({**scope, "query_string": b"token=secret"}, "secret", hosts)


# ------------------------------------------------------------ framing and connections (uvicorn, h11)
def exchange(port: int, data: bytes, timeout: float = 60.0) -> bytes:
    """Send raw bytes on a new connection; everything the server answers until it closes the connection."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as sock:
        sock.sendall(data)
        answer = b""
        while chunk := sock.recv(1 << 16):
            answer += chunk
    return answer


def raw_post(server, path: str, extra: bytes, body: bytes = b"") -> bytes:
    """A POST's bytes as the ``api`` client's, the framing headers in ``extra``."""
    port = server.server_address[1]
    return (f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nX-Mjkin-Token: {server.token}\r\n"
            "X-Mjkin-Client: test\r\nContent-Type: application/json\r\n").encode() + extra + b"\r\n" + body


def test_a_huge_integer_or_deep_nesting_is_a_one_line_400_and_the_server_goes_on(api):
    before = still(api)
    huge = b"1" + b"0" * 400
    for path, raw in [("/target", b'{"frame": "ee", "pos": [' + huge + b", 0, 0.5]}"),
                      ("/joint", b'{"joint": "j1", "value": ' + huge + b"}"),
                      ("/view", b'{"zoom": -' + huge + b"}"), ("/drag", b'{"frame": "ee", "depth": ' + huge + b"}"),
                      ("/target", b"[" * 20_000 + b"]" * 20_000), ("/view", b'{"a":' * 10_000 + b"1" + b"}" * 10_000)]:
        status, doc = api.post(path, raw=raw)
        assert status == 400 and set(doc) == {"error"} and "\n" not in doc["error"], (path, doc)
        assert "401 digits" in doc["error"] or "nested too deeply" in doc["error"], doc
    assert still(api) == before and api.get("/state")[0] == 200


def test_bad_framing_is_a_400_or_411_and_leftover_bytes_are_never_a_request(api, served):
    server, _ = served
    port = server.server_address[1]
    _, placed = api.post("/target", {"frame": "ee", "pos": [0.4, 0.1, 0.5]})
    for length in (b"-1", b"abc", b"2, 3"):
        answer = exchange(port, raw_post(server, "/reset", b"Content-Length: " + length + b"\r\n", b"{}"))
        assert answer.startswith(b"HTTP/1.1 400 "), (length, answer)
    sneaked = raw_post(server, "/target", b"Content-Length: 41\r\n", b'{"frame": "ee", "pos": [0.3, -0.3, 0.6]}\n')
    answer = exchange(port, raw_post(server, "/target", b"", sneaked))  # no length: the rest is not its body
    assert answer.startswith(b"HTTP/1.1 411 ") and answer.count(b"HTTP/1.1 ") == 1, answer
    assert b"Content-Length" in answer.split(b"\r\n\r\n", 1)[1] and b"connection: close" in answer.lower()
    assert api.get("/state")[1]["targets"] == placed["targets"]  # the request hidden in the leftovers did not run
    body = b'{"frame": "ee", "pos": [0.35, 0.15, 0.55]}'
    chunked = b"".join(b"%x\r\n%s\r\n" % (len(part), part) for part in (body[:10], body[10:])) + b"0\r\n\r\n"
    framing = b"Transfer-Encoding: chunked\r\nConnection: close\r\n"
    answer = exchange(port, raw_post(server, "/target", framing, chunked))
    assert answer.startswith(b"HTTP/1.1 200 "), answer
    assert json.loads(answer.split(b"\r\n\r\n", 1)[1])["targets"]["ee"][:3] == [0.35, 0.15, 0.55]  # decoded
    big = b"Content-Length: %d\r\n" % (server_module.MAX_BODY + 1)
    answer = exchange(port, raw_post(server, "/target", big, b"{"))
    assert answer.startswith(b"HTTP/1.1 413 ") and b"at most 65536" in answer


def test_the_listen_queue_holds_300_connections_before_any_is_accepted():
    """The backlog was 5: with the server busy, the 7th connect waited for SYN retries (58 of 300 timed out)."""
    pg = Playground(arm(), W, H)
    server = server_module.bind(pg, "127.0.0.1", 0)  # listening, not yet serving: nothing accepts
    socks = []
    try:
        for _ in range(300):
            socks.append(socket.create_connection(("127.0.0.1", server.server_address[1]), timeout=30))
    finally:
        for sock in socks:
            sock.close()
        server.close()
        pg.close()
    assert len(socks) == 300


def test_a_client_leaving_mid_body_or_mid_stream_costs_nothing(api, served, caplog):
    server, _ = served
    port = server.server_address[1]
    with socket.create_connection(("127.0.0.1", port), timeout=60) as sock:
        sock.sendall(raw_post(server, "/target", b"Content-Length: 100\r\n", b'{"fra'))
    with socket.create_connection(("127.0.0.1", port), timeout=60) as sock:
        sock.sendall(f"GET /stream.mjpg?token={server.token} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
        assert sock.recv(100).startswith(b"HTTP/1.1 200 ")
    deadline = time.monotonic() + 30
    while (server.routes.streams or server.server.server_state.tasks) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not server.routes.streams and not server.server.server_state.tasks
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR], caplog.text  # no traceback
    assert api.get("/state")[0] == 200


def test_300_simultaneous_connections_all_get_an_answer(api, served):
    """The listen backlog was 5: 58 of 300 connects timed out. Now each gets a 200 or, past the cap, a 503."""
    server, _ = served
    port = server.server_address[1]
    request = (f"GET /info HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nX-Mjkin-Token: {server.token}\r\n"
               "Connection: close\r\n\r\n").encode()
    socks = [socket.create_connection(("127.0.0.1", port), timeout=60) for _ in range(300)]
    statuses = []
    try:
        for sock in socks:
            sock.sendall(request)
        for sock in socks:
            answer = b""
            while chunk := sock.recv(1 << 16):
                answer += chunk
            statuses.append(int(answer.split(b" ", 2)[1]))
    finally:
        for sock in socks:
            sock.close()
    assert len(statuses) == 300 and set(statuses) <= {200, 503}, statuses  # 503: over the cap while all 300 are open
    assert api.get("/state")[0] == 200


def test_past_the_connection_cap_a_request_is_a_503(api, served):
    """The cap counts connections that have shown the token; past it a request with the token is a one-line 503."""
    server, _ = served
    port = server.server_address[1]
    request = f"GET /info HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nX-Mjkin-Token: {server.token}\r\n\r\n".encode()
    held = [socket.create_connection(("127.0.0.1", port), timeout=60) for _ in range(server_module.MAX_CONNECTIONS)]
    try:
        for sock in held:  # each shows the token once and stays open (keep-alive)
            sock.sendall(request)
            assert sock.recv(1 << 16).startswith(b"HTTP/1.1 200 ")
        answer = exchange(port, request.replace(b"\r\n\r\n", b"\r\nConnection: close\r\n\r\n"))
        assert answer.startswith(b"HTTP/1.1 503 ") and b"at most 64 connections" in answer, answer
        assert api.get("/info", {"X-Mjkin-Token": "wrong"})[0] == 403  # refused by the door, not counted
    finally:
        for sock in held:
            sock.close()
    deadline = time.monotonic() + 30
    while api.get("/info")[0] == 503 and time.monotonic() < deadline:
        time.sleep(0.05)  # the server hears of the closed sockets
    assert api.get("/info")[0] == 200


def test_a_new_connection_must_complete_its_first_request_head_within_the_head_timeout(served):
    """Before it shows the token a connection waits 1 s (HEAD_TIMEOUT) for its request head, not the idle 5 s."""
    server, _ = served
    port = server.server_address[1]
    for sent in (b"", f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n".encode()):
        with socket.create_connection(("127.0.0.1", port), timeout=server_module.IDLE_TIMEOUT - 1) as sock:
            sock.sendall(sent)
            assert sock.recv(1 << 16) == b"", sent  # the server closed it (a socket timeout here fails the test)


class Siege:
    """What anyone on the machine can do without the token: ``n`` raw sockets held open (half say nothing, half send
    part of a request), each opened again as soon as the server closes it, or ``every`` seconds after it opened."""

    def __init__(self, port: int, n: int = 70, every: float = 4.0) -> None:
        self.port, self.n, self.every = port, n, every
        self.opened = 0  # sockets opened so far
        self.ending = threading.Event()
        self.thread = threading.Thread(target=self.hold, name="siege")

    def __enter__(self) -> Siege:
        self.thread.start()
        deadline = time.monotonic() + 30
        while self.opened < self.n and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.2)  # the server has accepted them
        return self

    def __exit__(self, *exc: object) -> None:
        self.ending.set()
        self.thread.join()

    def open(self, k: int) -> tuple[socket.socket, float]:
        sock = socket.create_connection(("127.0.0.1", self.port), timeout=60)
        if k % 2:
            sock.sendall(f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{self.port}\r\n".encode())  # no token, no end
        self.opened += 1
        return sock, time.monotonic()

    def hold(self) -> None:
        held = [self.open(k) for k in range(self.n)]
        try:
            while not self.ending.is_set():
                closed = select.select([sock for sock, _ in held], [], [], 0.05)[0]  # readable: the server closed it
                now = time.monotonic()
                for k, (sock, since) in enumerate(held):
                    if sock in closed or now - since >= self.every:
                        sock.close()
                        held[k] = self.open(k)
        finally:
            for sock, _ in held:
                sock.close()


def test_idle_sockets_without_the_token_do_not_lock_out_the_page(api, served):
    """70 idle sockets without the token, opened again every 4 s, filled the 64-connection cap: 40 of 40 page
    requests were 503s. Only connections that have shown the token count against the cap now."""
    server, _ = served
    statuses = []
    with Siege(server.server_address[1]) as siege:
        for _ in range(40):
            statuses.append(api.get("/")[0])
            time.sleep(0.1)
        opened = siege.opened
    assert opened > siege.n  # the siege went on: the server closed sockets and they came back
    assert statuses.count(200) >= 36, statuses  # >= 90 %


def test_replies_do_not_wait_for_the_clients_acks(served):
    """With Nagle's algorithm on, a reply's body waited for the delayed ACK of its headers: 40 ms a request."""
    server, _ = served
    with socket.create_connection(("127.0.0.1", server.server_address[1]), timeout=60) as sock:
        sock.sendall(f"GET /info HTTP/1.1\r\nHost: 127.0.0.1:{server.server_address[1]}\r\n"
                     f"X-Mjkin-Token: {server.token}\r\n\r\n".encode())
        assert sock.recv(1 << 16).startswith(b"HTTP/1.1 200 ")  # answered, and kept open for the next request
        held = [c.transport.get_extra_info("socket") for c in list(server.server.server_state.connections)]
        assert held and all(s.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) for s in held)


def test_idle_connections_are_closed_after_the_timeout():
    """A socket held open without a request (or half of one, or after its answer) held a thread for ever."""
    server, thread = start_server(Playground(arm(), W, H).start(), idle_timeout=1)
    try:
        port, token = server.server_address[1], server.token
        request = f"GET /info HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nX-Mjkin-Token: {token}\r\n\r\n".encode()
        for sent in (b"", request[:20], request):
            with socket.create_connection(("127.0.0.1", port), timeout=60) as sock:
                sock.sendall(sent)
                answer = b""
                while chunk := sock.recv(1 << 16):  # until the server closes it (a timeout here fails the test)
                    answer += chunk
            assert answer.startswith(b"HTTP/1.1 200 ") if sent == request else answer == b"", (sent, answer)
        assert not server.server.server_state.connections
    finally:
        stop_server(server, thread)


# ------------------------------------------------------------ the journal of a recording
def test_recording_journals_its_samples_and_a_normal_stop_removes_the_journal(api, served):
    _, out = served
    before = set(out.iterdir())
    assert api.post("/record")[0] == 200
    api.post("/target", {"frame": "ee", "pos": [0.4, 0.2, 0.5]})
    path, lines = journal_lines(out, least_t=0.2)  # on disk while the take goes on
    assert journal.leftovers(out) == []  # held by this process: not a take cut short
    assert api.post("/stop")[0] == 200
    saved, _ = finished(api)
    assert saved["done"] and not path.exists()
    assert set(out.iterdir()) == before | {Path(saved["path"]), Path(saved["video"])}
    assert Path(saved["path"]).name == path.name.replace(".journal.jsonl", ".json")  # one name per take
    assert lines[0]["frames"] == ["ee"] and len(lines) >= 2


def test_a_take_is_saved_in_the_background_its_progress_rises_to_1_and_the_page_goes_on(tmp_path):
    """Stop & save took 3.5 s per second of take, the request waiting throughout; now it returns at once."""
    pg = Playground(arm(), W, H, out_dir=tmp_path).start()
    server, thread = start_server(pg)
    try:
        client = Client.of(server)
        assert client.post("/record")[0] == 200
        journal_lines(tmp_path, least_t=2.0)  # two seconds of samples: 61 frames to render
        status, started = client.post("/stop")
        assert status == 200 and not started["done"] and started["progress"] == 0.0
        assert client.post("/record")[1]["error"].startswith("the last recording is being saved (")
        assert client.post("/target", {"frame": "ee", "pos": [0.4, 0.1, 0.5]})[0] == 200  # the page goes on
        saved, seen = finished(client)
        written = sorted(tmp_path.iterdir())
        assert client.post("/record")[0] == 200  # a new take may start as soon as the last one is written
    finally:
        stop_server(server, thread)
    assert seen and seen == sorted(seen) and set(seen) - {0.0}, seen  # it rose while the client watched
    assert saved["done"] and saved["progress"] == 1.0 and saved["error"] is None
    assert written == sorted(Path(saved[k]) for k in ("path", "video"))  # no journal, no temporary file
    video = imageio.imread(saved["video"], index=None)
    traj = motion.Trajectory.load(saved["path"], arm())
    assert video.shape == (int(traj.times[-1] * 30 + 1e-9) + 1, H, W, 3)  # one frame per 1/30 s of the take


def test_a_take_stopped_before_its_first_sample_is_a_still_a_script_can_hold(tmp_path):
    """It was written as two frames at 0 s, which scripts refuse now (times must increase)."""
    pg = Playground(arm(), W, H, out_dir=tmp_path, source="arm7")  # not started: no render thread takes samples
    try:
        pg.record("a")
        saved = pg.stop("a")
    finally:
        pg.close()
    traj = motion.Trajectory.load(saved["path"], arm())
    np.testing.assert_allclose(traj.times, [0.0, 1.0 / pg.fps])
    np.testing.assert_array_equal(traj.q, [pg.state.q, pg.state.q])
    assert traj.source == "arm7" and not list(tmp_path.glob("*.journal.jsonl"))


def test_a_take_whose_journal_cannot_be_made_does_not_start(api, served):
    _, out = served
    away = out.with_name(out.name + "-away")
    out.rename(away)
    try:
        status, doc = api.post("/record")
    finally:
        away.rename(out)
    assert status == 500 and "cannot start the recording's journal" in doc["error"] and "\n" not in doc["error"]
    assert not api.get("/state")[1]["recording"]


def test_a_journal_is_read_as_a_script_even_cut_off_mid_line(tmp_path):
    tree = arm()
    take = journal.Journal(tmp_path / "mjkin-play-arm7-x", {"model": "arm7", "source": "arm7",
                                                            "fingerprint": motion.fingerprint(tree), "frames": ["ee"],
                                                            "method": "dls", "goal": "position"})
    qs = tree.random_q(np.random.default_rng(1), 5)
    for k, q in enumerate(qs):
        take.add((0.25 + 0.1 * k, q, tree.pose(q, "ee")[None, :3, 3]))
    deadline = time.monotonic() + 30
    while take.path.read_text().count("\n") < 6 and time.monotonic() < deadline:
        time.sleep(0.05)  # the writer flushes on its own, without close
    assert take.path.read_text().count("\n") == 6
    assert journal.leftovers(tmp_path) == []  # still held
    take.close()
    assert journal.leftovers(tmp_path) == [take.path]
    with take.path.open("a") as f:
        f.write('{"t": 0.9, "q": [0.1, 0.')  # the line being written at the crash
    traj = motion.Trajectory.load(take.path, tree)
    np.testing.assert_allclose(traj.q, qs)
    np.testing.assert_allclose(traj.times, 0.1 * np.arange(5), atol=1e-12)
    assert traj.model == "arm7" and traj.frame == "ee" and traj.targets.shape == (5, 1, 3)
    assert traj.meta["play"]["method"] == "dls"
    lines = take.path.read_text().splitlines()
    take.path.write_text("\n".join([lines[0], "{oops", *lines[1:3]]) + "\n")
    with pytest.raises(mjkin.MjkinError, match="line 2 is not JSON") as e:
        motion.Trajectory.load(take.path)
    assert "\n" not in str(e.value)
    take.path.write_text(lines[0] + "\n")
    assert journal.recover(take.path) is None and not take.path.exists()  # cut short before its first sample


URL_LINE = re.compile(r"mjkin play: http://127\.0\.0\.1:(\d+)/\?token=([\w-]{32,})  \(Ctrl-C stops\)\n")


def play_process(out) -> tuple[subprocess.Popen, Client]:
    """A real ``mjkin play --port 0 --no-browser --out OUT`` and a client with the token from the URL it printed."""
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    proc = subprocess.Popen([sys.executable, "-m", "mjkin.apps.cli", "play", "arm7", "--port", "0", "--no-browser",
                             "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, text=True)
    line = proc.stdout.readline()
    found = URL_LINE.fullmatch(line)
    if found is None:
        proc.kill()
        pytest.fail(f"mjkin play printed {line!r}, not its URL with a token; stderr: {proc.communicate()[1]}")
    return proc, Client(int(found[1]), found[2])


def stop_process(proc: subprocess.Popen, sig: int = signal.SIGINT) -> str:
    """Ctrl-C (or another signal ``sig``); its stderr, once it stopped cleanly (status 0, the line "stopped")."""
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0 and "Traceback" not in err and "mjkin play: stopped\n" in err, err
    return err


def journal_lines(folder, least_t: float = 0.0, timeout: float = 60.0) -> tuple[object, list[dict]]:
    """The one journal in ``folder`` and its lines, once a sample at least ``least_t`` s into the take is on disk."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = list(folder.glob("*.journal.jsonl"))
        if found:
            lines = [json.loads(x) for x in found[0].read_text().splitlines()]
            if len(lines) > 1 and lines[-1]["t"] >= least_t:
                return found[0], lines
        time.sleep(0.1)
    pytest.fail(f"no journal with a sample {least_t} s into the take in {folder}: {list(folder.iterdir())}")


def test_cli_serves_and_stops_cleanly_on_ctrl_c_saving_the_recording_that_was_on(tmp_path):
    proc, client = play_process(tmp_path)
    try:
        assert client.post("/record")[0] == 200
        path, lines = journal_lines(tmp_path)  # samples are on disk while recording
    finally:
        err = stop_process(proc)
    script = tmp_path / path.name.replace(".journal.jsonl", ".json")
    assert f"mjkin play: the recording that was on is saved as {str(script)!r} from its journal" in err
    assert list(tmp_path.iterdir()) == [script]  # the journal is gone, no temporary file is left
    traj = motion.Trajectory.load(script, arm())
    assert len(traj.q) >= len(lines) - 1 and traj.meta["play"]["frames"] == ["ee"]
    # a first run's compilation says so itself (mjkin.runtime.progress); a start with the kernels cached says
    # nothing of it
    assert "mjkin play: loading arm7...\n" in err and "first run compiles" not in err


def test_sigterm_saves_the_take_prints_stopped_and_exits_0(tmp_path):
    """``kill``, ``docker stop``, ``systemctl stop``: SIGTERM stops the playground just as Ctrl-C does."""
    proc, client = play_process(tmp_path)
    try:
        assert client.post("/record")[0] == 200
        path, lines = journal_lines(tmp_path)  # a take is being recorded
    finally:
        err = stop_process(proc, signal.SIGTERM)  # status 0 and "mjkin play: stopped", not killed (-15)
    script = tmp_path / path.name.replace(".journal.jsonl", ".json")
    assert f"mjkin play: the recording that was on is saved as {str(script)!r} from its journal" in err
    assert list(tmp_path.iterdir()) == [script]  # saved now, not left to a later mjkin play to recover
    traj = motion.Trajectory.load(script, arm())
    assert len(traj.q) >= len(lines) - 1 and traj.meta["play"]["frames"] == ["ee"]


def test_sigterm_while_a_take_is_saved_finishes_the_save(tmp_path):
    proc, client = play_process(tmp_path)
    try:
        assert client.post("/record")[0] == 200
        journal_lines(tmp_path, least_t=3.0)
        status, started = client.post("/stop")
        assert status == 200 and not started["done"]
    finally:
        err = stop_process(proc, signal.SIGTERM)
    assert "mjkin play: finishing the recording being written...\n" in err and "journal" not in err, err
    assert sorted(tmp_path.iterdir()) == sorted(Path(started[k]) for k in ("path", "video"))  # nothing else left
    traj = motion.Trajectory.load(started["path"], arm())
    assert len(imageio.imread(started["video"], index=None)) == int(traj.times[-1] * 30 + 1e-9) + 1  # complete


def test_a_take_survives_kill_9_the_next_start_recovers_it_and_replay_reads_its_journal(tmp_path):
    proc, client = play_process(tmp_path)
    try:
        assert client.post("/record")[0] == 200
        client.post("/target", {"frame": "ee", "pos": [0.4, 0.2, 0.5]})
        path, seen = journal_lines(tmp_path, least_t=1.5)  # 1.5 s into the take, on disk
        proc.kill()  # kill -9: nothing runs after it
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    header, samples = lines[0], lines[1:]
    assert lines[:len(seen)] == seen  # every sample on disk before the kill is there
    assert header["format"] == "mjkin-play-journal" and header["model"] == "arm7" and header["frames"] == ["ee"]
    assert header["fingerprint"] == motion.fingerprint(arm()) and header["source"] == "arm7"  # a bundled name
    times = [x["t"] for x in samples]
    assert times == sorted(times) and times[-1] >= 1.5 and all(len(x["q"]) == 7 for x in samples)
    np.testing.assert_allclose(arm().pose(np.array(samples[-1]["q"]), "ee")[:3, 3], [0.4, 0.2, 0.5], atol=IK_TOL)

    video = tmp_path / "replayed.mp4"
    replay = subprocess.run([sys.executable, "-m", "mjkin.apps.cli", "replay", str(path), "-o", str(video),
                             "--width", "160", "--height", "120"], capture_output=True, text=True, timeout=300)
    assert replay.returncode == 0, replay.stderr
    assert imageio.imread(video, index=None).shape == (len(samples), 120, 160, 3)
    video.unlink()

    proc, client = play_process(tmp_path)
    try:
        assert not client.get("/state")[1]["recording"]
    finally:
        err = stop_process(proc)
    script = tmp_path / path.name.replace(".journal.jsonl", ".json")
    said = [x for x in err.splitlines() if "cut short" in x]
    assert said == [f"mjkin play: a recording cut short is saved as {str(script)!r} from its journal (no video: "
                    f"mjkin replay {script} -o take.mp4 makes one)"]
    assert list(tmp_path.iterdir()) == [script]
    traj = motion.Trajectory.load(script, arm())
    np.testing.assert_allclose(traj.q, [x["q"] for x in samples])
    np.testing.assert_allclose(traj.times, np.array(times) - times[0])
    np.testing.assert_allclose(traj.targets, [x["targets"] for x in samples])


def test_cli_bad_port_is_one_line():
    proc = subprocess.run([sys.executable, "-m", "mjkin.apps.cli", "play", "arm7", "--port", "70000", "--no-browser"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0 and "--port" in proc.stderr


# ------------------------------------------------------------------------- browser
def browser_client(served) -> tuple:
    """For a browser test: the server, a watcher client, and the state after a reset of pose and view.

    Skips (and says why) where Chromium or playwright is missing.
    """
    reason = browser.missing()
    if reason:
        print(f"browser test skipped: {reason}")
        pytest.skip(reason)
    server, _ = served
    client = Client.of(server, "watcher")
    time.sleep(0.6)  # the other tests' lease has run out
    client.post("/reset")
    _, state = client.post("/view", {"reset": True})
    return server, client, state


def test_browser_drags_the_target_and_the_figure_follows(served):
    server, client, _ = browser_client(served)  # skips before the import where playwright is missing
    from playwright.sync_api import sync_playwright

    time.sleep(0.6)
    _, before = client.get("/state")
    _, frame_before = client.get("/frame.jpg")
    with sync_playwright() as p:
        chromium = browser.launch(p)
        try:
            page = browser.open_page(chromium, server.url)
            shot_before = page.locator("#view").screenshot()
            browser.drag_target(page, "ee", 60, 40)
            page.wait_for_function(f"{browser.STATE}.then(s => s.version > {before['version']})")
            page.wait_for_timeout(500)
            shot_after = page.locator("#view").screenshot()
            assert page.locator("#perr").inner_text().endswith(" m")
        finally:
            chromium.close()
    _, after = client.get("/state")
    assert after["q"] != before["q"] and after["success"]
    u, v = before["screen"]["ee"]
    moved = np.array(after["screen"]["ee"]) - [u, v]
    assert moved[0] * W > 20 and moved[1] * H > 10  # dragged right and down, as the mouse went
    np.testing.assert_allclose(arm().pose(np.array(after["q"]), "ee")[:3, 3], after["targets"]["ee"][:3],
                               atol=IK_TOL)
    _, frame_after = client.get("/frame.jpg")
    assert frame_after != frame_before
    assert shot_after != shot_before  # the page's own view changed


def test_browser_panel_puts_each_constraint_control_on_a_line_of_its_own(served):
    """The max joint speed field wrapped into the balance label: each label is one line, below the last."""
    server, _, _ = browser_client(served)
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        chromium = browser.launch(p)
        try:
            page = browser.open_page(chromium, server.url)
            boxes = [page.locator(f"aside > label:has(#{name})").bounding_box() for name in
                     ("step", "clearance", "balance", "speed")]
        finally:
            chromium.close()
    line = min(b["height"] for b in boxes)
    assert all(b["height"] < 1.5 * line for b in boxes)  # none wrapped onto a second line
    assert all(low["y"] >= high["y"] + high["height"] - 1 for high, low in zip(boxes, boxes[1:], strict=False))


def test_browser_right_drag_turns_the_view_and_a_later_drag_still_moves_the_target(served):
    server, client, _ = browser_client(served)  # skips before the import where playwright is missing
    from playwright.sync_api import sync_playwright

    time.sleep(0.6)
    _, before = client.get("/state")
    settled = "!inFlight && !pending && !orbitBy && !zoomBy"  # the page has sent every move it had
    with sync_playwright() as p:
        chromium = browser.launch(p)
        try:
            page = browser.open_page(chromium, server.url)
            help_line = page.locator("#help").inner_text()
            assert "Right-drag (or Alt + drag) turns the view" in help_line and "Ctrl + wheel" in help_line
            shot_before = page.locator("#view").screenshot()
            box = page.locator("#view").bounding_box()
            browser.turn_view(page, 120, -40)
            page.wait_for_function(settled)
            _, turned = client.get("/state")
            page.wait_for_timeout(500)  # the stream shows the turned view
            shot_turned = page.locator("#view").screenshot()
            browser.drag_target(page, "ee", 50, 30)
            page.wait_for_function(settled)
            _, after = client.get("/state")
            page.keyboard.down("Alt")  # trackpads: Alt + drag turns the view too
            browser.mouse_drag(page, box["x"] + 20, box["y"] + 20, -60, 0)
            page.keyboard.up("Alt")
            page.keyboard.down("Control")  # Ctrl + wheel (a pinch) zooms; the plain wheel moves a target in depth
            page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
            page.mouse.wheel(0, 100)
            page.keyboard.up("Control")
            page.wait_for_function(settled)
            _, alt = client.get("/state")
            page.click("#resetview")
            page.wait_for_function(settled)
        finally:
            chromium.close()
    # a drag across the view's height is 180 degrees, the scene following the mouse (MuJoCo's viewer)
    cam, home = turned["camera"], before["camera"]
    assert angle_gap(cam["azimuth"], home["azimuth"]) == pytest.approx(-120 / box["height"] * 180, abs=1e-6)
    assert cam["elevation"] == pytest.approx(home["elevation"] + 40 / box["height"] * 180, abs=1e-6)
    assert turned["targets"] == before["targets"]  # the right button turned the view, it did not grab the target
    assert shot_turned != shot_before
    # the later left-drag: the target went where the mouse went, in the turned view
    assert after["camera"] == cam and after["success"]
    expected = np.array(turned["screen"]["ee"]) + [50 / box["width"], 30 / box["height"]]
    np.testing.assert_allclose(after["screen"]["ee"], expected, atol=2 / box["height"])
    assert off_ray(view_of(cam), np.array(after["targets"]["ee"][:3]), after["screen"]["ee"]) < 1e-9
    np.testing.assert_allclose(arm().pose(np.array(after["q"]), "ee")[:3, 3], after["targets"]["ee"][:3],
                               atol=IK_TOL)
    assert angle_gap(alt["camera"]["azimuth"], cam["azimuth"]) == pytest.approx(60 / box["height"] * 180, abs=1e-6)
    assert alt["camera"]["distance"] == pytest.approx(cam["distance"] * np.exp(100 * 0.0025), rel=1e-9)
    assert alt["targets"] == after["targets"]  # neither grabbed the target
    assert client.get("/state")[1]["camera"] == home  # the "Reset view" button


def test_browser_shows_numbers_the_server_sends_as_null_as_dashes(served):
    """The page reads strict JSON (null for a number that is not finite) and keeps working."""
    server, client, state = browser_client(served)  # skips before the import where playwright is missing
    from playwright.sync_api import sync_playwright

    eye = view_of(state["camera"]).pos
    assert client.post("/target", {"frame": "ee", "pos": eye.tolist()})[1]["screen"]["ee"] == [None, None]
    with sync_playwright() as p:
        chromium = browser.launch(p)
        try:
            page = browser.open_page(chromium, server.url)
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.wait_for_function("state && state.screen.ee[0] === null")  # the page parsed it, no marker drawn
            shown = page.evaluate("""() => {
                show({...state, goal: "pose", error: [null, null], manipulability: null, singular_values: [null, 1],
                      q: state.q.map(() => null), screen_axes: {ee: [null, [0.5, null], [0.2, 0.3]]},
                      recording: false, unsaved: true});
                return ["perr", "rerr", "manip", "smin"].map(id => $(id).textContent).concat(
                    [document.querySelector("#sliders .v").textContent, $("record").disabled, $("stop").disabled]);
            }""")
            page.wait_for_timeout(700)  # a few polls of /state, with its null image point
        finally:
            chromium.close()
    client.post("/reset")
    assert shown == ["-", "-", "-", "-", "-", True, False]  # an unsaved recording: Stop & save writes it again
    assert errors == []


# ------------------------------------------------------------------ solutions
def test_solutions_of_a_two_link_target_are_its_two_elbows_and_next_alternates_them():
    tree = tree_of("planar_2link")
    pg = Playground(tree, W, H)  # not started: no frames needed
    target = np.array([1.2, 0.5, 0.0])
    pg.apply("t", core.Place("tip", tuple(target)))  # type: ignore[arg-type]
    found = pg.find_solutions("t")
    assert found["count"] == 2 and found["index"] == 0 and found["solutions"] == {"count": 2, "index": 0}
    shown = [np.array(found["q"])]
    for i in (1, 0, 1):
        doc = pg.show_solution("t")
        assert doc["index"] == i and doc["success"]
        shown.append(np.array(doc["q"]))
    for q in shown:
        np.testing.assert_allclose(tree.pose(q, "tip")[:3, 3], target, atol=1e-5)
    np.testing.assert_allclose(shown[2], shown[0], atol=1e-9)
    np.testing.assert_allclose(shown[3], shown[1], atol=1e-9)
    elbows = [np.arctan2(np.sin(q[1]), np.cos(q[1])) for q in shown[:2]]
    assert elbows[0] * elbows[1] < 0 and abs(elbows[0] + elbows[1]) < 1e-4  # elbow up and elbow down
    assert pg.show_solution("t", -1)["index"] == 1
    pg.apply("t", core.Place("tip", (1.0, 0.6, 0.0)))  # a new target drops the list
    assert "solutions" not in pg.snapshot()
    with pytest.raises(InputError, match="POST /solutions"):
        pg.show_solution("t")
    pg.set_frames("t", ["tip", "link1"])
    with pytest.raises(InputError, match="solutions take one frame"):
        pg.find_solutions("t")


def test_solutions_routes_find_cycle_and_refuse_bad_requests(api):
    status, doc = api.post("/solutions")
    assert status == 200 and doc["count"] >= 2 and doc["index"] == 0, doc
    tree, target = arm(), np.array(doc["targets"]["ee"])[:3]
    first = np.array(doc["q"])
    status, doc = api.post("/solutions", {"next": True})
    assert status == 200 and doc["index"] == 1 and doc["solutions"] == {"count": doc["count"], "index": 1}
    assert np.abs(np.array(doc["q"]) - first).max() > 1e-3
    for q in (first, np.array(doc["q"])):
        np.testing.assert_allclose(tree.pose(q, "ee")[:3, 3], target, atol=1e-5)
    assert api.post("/solutions", {"index": doc["count"]})[1]["index"] == 0  # cyclic
    assert api.get("/state")[1]["solutions"]["index"] == 0
    for bad in ({"next": 1}, {"index": 1.5}, {"index": True}, {"next": True, "index": 0}, {"other": 1}):
        status, err = api.post("/solutions", bad)
        assert status == 400 and "\n" not in err["error"] and "solutions take" in err["error"], (bad, err)
    assert api.post("/drag", {"frame": "ee", "depth": 0.01})[0] == 200  # a drag drops the list
    assert "solutions" not in api.get("/state")[1]
    status, err = api.post("/solutions", {"next": True})
    assert status == 400 and "POST /solutions {}" in err["error"]
    api.post("/frames", {"frames": ["ee", "link4"]})
    status, err = api.post("/solutions")
    assert status == 400 and err["error"].startswith("solutions take one frame") and "\n" not in err["error"]
