"""mjkin play's constraint toggles: clearance (the closest pair) and balance (the support), pure and over HTTP."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from test_play import Client

import mjkin
from conftest import tree_of
from mjkin.apps.play import core
from mjkin.apps.play.server import start_server, stop_server
from mjkin.apps.play.session import Playground
from mjkin.errors import InputError
from mjkin.kinematics.geoms import contact_pairs

BALL = np.array([0.35, 0.0, 0.55])  # an obstacle in arm7's reach


def cluttered() -> mjkin.Tree:
    """arm7 with a ball of 8 cm at :data:`BALL`."""
    if "cluttered" not in _TREES:
        spec = mujoco.MjSpec.from_file(str(mjkin.kinematics.tree.bundled_models()["arm7"]))
        spec.worldbody.add_geom(name="ball", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.08, 0, 0], pos=BALL)
        _TREES["cluttered"] = mjkin.load(spec)
    return _TREES["cluttered"]


_TREES: dict[str, mjkin.Tree] = {}


def mujoco_clearance(tree: mjkin.Tree, q: np.ndarray) -> tuple[float, tuple[int, int]]:
    """The least ``mj_geomDistance`` over MuJoCo's contact pairs at ``q`` (MuJoCo's own kinematics), and the pair."""
    m, d = tree.model, mujoco.MjData(tree.model)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    best = (np.inf, (-1, -1))
    for a, b in contact_pairs(tree):
        dist = mujoco.mj_geomDistance(m, d, int(a), int(b), 10.0, None)
        best = min(best, (dist, (int(a), int(b))))
    return best


def test_closest_pair_is_mujoco_s_with_its_witness_points():
    tree = cluttered()
    for q in tree.random_q(np.random.default_rng(4), 12):
        c = core.closest_pair(tree, q)
        dist, pair = mujoco_clearance(tree, q)
        assert c is not None and c.distance == pytest.approx(dist, abs=1e-6)
        assert set(c.geoms) == {tree.model.geom(g).name or f"#{g}" for g in pair}
        assert np.linalg.norm(c.b - c.a) == pytest.approx(abs(c.distance), abs=1e-6)


def test_clearance_toggle_keeps_the_arm_off_the_ball_the_plain_solve_goes_through():
    tree = cluttered()
    state = core.initial_state(tree, ["ee"])
    event = core.Place("ee", tuple(BALL))  # the target is the ball's centre
    plain = core.apply(tree, core.View.of(mujoco.MjvCamera(), tree.model, 64, 48), state, event)
    assert mujoco_clearance(tree, plain.q)[0] < -0.01  # through the ball
    clear = core.with_constraints(tree, state, clearance=True)
    clear = core.apply(tree, core.View.of(mujoco.MjvCamera(), tree.model, 64, 48), clear, event)
    assert not clear.success and mujoco_clearance(tree, clear.q)[0] >= -1e-6
    assert np.linalg.norm(tree.pose(clear.q, "ee")[:3, 3] - BALL) < 0.2  # as close as the ball lets it
    report = core.constraint_report(tree, clear)
    assert report["clearance"] and not report["balance"] and report["support"] is None
    assert report["closest"]["distance"] >= -1e-6
    (line, rgba), = core.constraint_lines(tree, clear)
    np.testing.assert_allclose(line, [report["closest"]["a"], report["closest"]["b"]])


def test_balance_needs_feet_and_the_support_is_the_soles_hull():
    with pytest.raises(InputError, match="feet"):
        core.with_constraints(tree_of("arm7"), core.initial_state(tree_of("arm7")), balance=True)
    tree = tree_of("primate")
    assert core.support_frames(tree) == ["left_foot", "right_foot"]
    q = core.initial_state(tree).q
    s = core.support(tree, q)
    d = mujoco.MjData(tree.model)
    d.qpos[:] = q
    mujoco.mj_kinematics(tree.model, d)
    feet = (tree.model.geom("left_foot").id, tree.model.geom("right_foot").id)
    soles = [d.geom_xpos[g] + d.geom_xmat[g].reshape(3, 3) @ (tree.model.geom_size[g] * [x, y, -1])
             for g in feet for x in (-1, 1) for y in (-1, 1)]
    outer = {tuple(np.round(p[:2], 9)) for p in soles if abs(p[1]) > 0.1}  # the inner edges' corners lie inside
    assert {tuple(np.round(p[:2], 9)) for p in s.polygon} == outer
    assert s.inside
    np.testing.assert_allclose(s.com[:2], tree.com(q)[:2], atol=1e-12)
    assert s.com[2] == pytest.approx(min(p[2] for p in soles))


def test_balance_toggle_holds_at_the_home_pose_and_after_a_reach():
    tree = tree_of("primate")
    state = core.with_constraints(tree, core.initial_state(tree), balance=True)
    home = core.solve_state(tree, state)
    assert home.success and home.status == "converged"
    np.testing.assert_allclose(home.q, state.q, atol=1e-9)  # the home pose already balances: nothing moves
    view = core.View.of(mujoco.MjvCamera(), tree.model, 64, 48)
    reach = core.apply(tree, view, home, core.Place("left_hand", (0.3, 0.45, 1.1)))
    assert reach.success and core.support(tree, reach.q).inside


@settings(deadline=None, max_examples=50)
@given(st.lists(st.tuples(st.floats(-1, 1), st.floats(-1, 1)), min_size=3, max_size=20),
       st.tuples(st.floats(-1, 1), st.floats(-1, 1)))
# found by CI: a sliver whose corner at (1, 0) turns by a cross product of 6e-220, which rounds to zero from its edges
@example([(0.0, -1.0), (1.0, 0.0), (6.081216636022552e-220, -1.0)], (0.0, 0.0))
def test_convex_hull_holds_every_point_counter_clockwise(points, probe):
    pts = np.array(points)
    hull = core.convex_hull(pts)
    if len(hull) < 3:  # all on a line
        return
    edges = np.roll(hull, -1, 0) - hull
    assert np.all(core.cross2(edges, np.roll(edges, -1, 0)) > 0)  # strictly convex, counter-clockwise
    for p in pts:
        assert np.all(core.cross2(edges, p - hull) >= -1e-9)
    assert all(any(np.allclose(h, p) for p in pts) for h in hull)


# ------------------------------------------------------------------ HTTP
@pytest.fixture(scope="module")
def served_cluttered(tmp_path_factory):
    pg = Playground(cluttered(), 160, 120, lease=0.5, out_dir=tmp_path_factory.mktemp("rec")).start()
    server, thread = start_server(pg)
    yield server
    stop_server(server, thread)


def test_constraints_route_switches_clearance_and_state_reports_it(served_cluttered):
    api = Client.of(served_cluttered)
    status, state = api.get("/state")
    assert status == 200 and state["clearance"] is False and state["closest"] is None
    status, state = api.post("/constraints", {"clearance": True})
    assert status == 200 and state["clearance"] is True and state["balance"] is False
    status, state = api.post("/target", {"frame": "ee", "pos": BALL.tolist()})
    assert status == 200 and not state["success"]
    dist, _ = mujoco_clearance(cluttered(), np.array(state["q"]))
    assert dist >= -1e-6 and state["closest"]["distance"] == pytest.approx(dist, abs=1e-6)
    assert "ball" in state["closest"]["geoms"]
    status, frame = api.get("/frame.jpg")
    assert status == 200 and frame[:2] == b"\xff\xd8"
    status, info = api.get("/info")
    assert info["balance"] is False and info["support"] == []
    for body, needle in (({"balance": True}, "feet"), ({"clearance": 1}, "true or false"), ({}, "clearance"),
                         ({"clearance": True, "speed": 2}, "clearance")):
        status, reply = api.post("/constraints", body)
        assert status == 400 and needle in reply["error"] and "\n" not in reply["error"]
    status, state = api.post("/constraints", {"clearance": False})
    assert status == 200 and state["clearance"] is False and state["closest"] is None
    assert mujoco_clearance(cluttered(), np.array(state["q"]))[0] < -0.01  # free again: it goes through


def test_a_speed_limit_moves_no_joint_more_than_its_step_per_frame_and_still_arrives():
    tree = tree_of("arm7")
    state = core.with_max_step(core.initial_state(tree, ["ee"]), 0.05)
    target = (0.4, 0.2, 0.5)
    view = core.View.of(mujoco.MjvCamera(), tree.model, 64, 48)
    prev, state = state.q, core.apply(tree, view, state, core.Place("ee", target))
    frames = 1
    while core.needs_step(state) and frames < 400:
        assert np.abs(tree.difference(state.q, prev)).max() <= 0.05 + 1e-6
        prev, state = state.q, core.advance(tree, state)
        frames += 1
    assert np.abs(tree.difference(state.q, prev)).max() <= 0.05 + 1e-6
    assert state.success and frames > 5  # far enough to need several frames
    np.testing.assert_allclose(tree.pose(state.q, "ee")[:3, 3], target, atol=1e-4)
    with pytest.raises(InputError, match="positive"):
        core.with_max_step(state, -1.0)


def test_max_joint_speed_over_http(served_cluttered):
    api = Client.of(served_cluttered)
    status, state = api.post("/constraints", {"clearance": False, "max_joint_speed": 3.0})
    assert status == 200 and state["max_joint_speed"] == pytest.approx(3.0)
    q0, v0 = np.array(state["q"]), state["version"]
    status, state = api.post("/target", {"frame": "ee", "pos": [0.0, 0.45, 0.6]})
    # each change of the state, the target's and any frame the render loop stepped meanwhile (a loaded host),
    # moves no joint more than 3/30
    frames = state["version"] - v0
    assert status == 200 and frames >= 1
    assert np.abs(cluttered().difference(np.array(state["q"]), q0)).max() <= 0.1 * frames + 1e-6
    status, reply = api.post("/constraints", {"max_joint_speed": "fast"})
    assert status == 400 and "max_joint_speed" in reply["error"]
    status, state = api.post("/constraints", {"max_joint_speed": None})
    assert status == 200 and state["max_joint_speed"] is None
