"""Designed motion: minimum-jerk timing, rounded corners, and a walk whose planted feet do not slide."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import mjkin
from conftest import tree_of
from mjkin import motion
from mjkin.apps.cli import main

MM = 1e-3
SQUARE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])


@given(st.floats(0, 1))
def test_min_jerk_is_a_monotone_rest_to_rest_timing(u):
    assert 0 <= motion.min_jerk(u) <= 1
    assert motion.min_jerk(u) + motion.min_jerk(1 - u) == pytest.approx(1, abs=1e-12)  # symmetric
    h = 1e-4
    assert motion.min_jerk(min(u + h, 1.0)) >= motion.min_jerk(u)


def test_eased_path_starts_and_stops_at_rest_without_jumps():
    p = motion.waypoints(SQUARE, 200, corner=0.2, ease=True)
    speed = np.linalg.norm(np.diff(p, axis=0), axis=1)
    assert speed[0] < 0.02 * speed.max() and speed[-1] < 0.02 * speed.max()  # at rest at both ends
    assert np.abs(np.diff(speed)).max() < 0.05 * speed.max()  # speed changes smoothly
    np.testing.assert_allclose(p[[0, -1]], SQUARE[[0, -1]])
    plain = motion.waypoints(SQUARE, 200)
    np.testing.assert_allclose(np.linalg.norm(np.diff(plain[:60], axis=0), axis=1), 3 / 199, rtol=1e-9)  # as before


def test_rounded_corners_stay_near_the_waypoints_without_sharp_turns():
    r = 0.2
    p = motion.waypoints(SQUARE, 400, corner=r)
    d = np.diff(p, axis=0)
    turn = np.arccos(np.clip(np.sum(d[1:] * d[:-1], -1) / (np.linalg.norm(d[1:], axis=-1)
                                                               * np.linalg.norm(d[:-1], axis=-1)), -1, 1))
    sharp = np.arccos(0.0)
    assert turn.max() < 0.25 * sharp  # no 90° corner between two frames
    for corner in SQUARE[1:3]:  # the path passes within the arc's reach of each waypoint
        gap = np.linalg.norm(p - corner, axis=1).min()
        assert 0.05 < gap < r  # rounded: near, not through
    np.testing.assert_allclose(p[[0, -1]], SQUARE[[0, -1]])
    with pytest.raises(mjkin.InputError, match="not both"):
        motion.waypoints(SQUARE, 10, times=[0, 1, 2, 3], ease=True)
    with pytest.raises(mjkin.InputError, match="corner must be"):
        motion.waypoints(SQUARE, 10, corner=-1)


@pytest.fixture(scope="module")
def walk():
    tree = tree_of("primate")
    return tree, motion.walk_cycle(tree, steps=3, gait=motion.Gait(stride=0.3, frames_per_step=16))


def test_walk_feet_do_not_slide_heel_to_toe(walk):
    tree, w = walk
    n = 16
    assert w.success.all() and len(w.q) == 3 * n
    s = np.arange(1, n + 1) / n
    for k in range(3):
        planted, swing = ("left_foot", "right_foot")[k % 2], ("left_foot", "right_foot")[1 - k % 2]
        step = w.q[k * n:(k + 1) * n]
        P = tree.pose(step, planted, "body")[:, :3, 3]
        assert np.abs(P - P[0]).max() <= MM  # the planted foot does not slide
        T = tree.pose(step, swing, "body")
        toe, heel = motion.sole_points(tree, swing)
        toes, heels = T[:, :3, :3] @ toe + T[:, :3, 3], T[:, :3, :3] @ heel + T[:, :3, 3]
        rolling, landing = s <= motion.TOE_OFF, s >= motion.HEEL_STRIKE
        assert np.abs(toes[rolling] - toes[rolling][0]).max() <= MM  # rolls onto the toe in place
        assert np.abs(heels[landing] - heels[landing][-1]).max() <= MM  # lands on the heel in place
        pitch = np.arctan2(-T[:, 2, 0], T[:, 0, 0])  # toe down > 0
        assert pitch[rolling].max() > 0.2 and pitch[(s > motion.HEEL_STRIKE) & (s < 1)].min() < -0.05
        assert T[n // 2, 2, 3] > T[-1, 2, 3] + 0.03 and T[-1, 0, 3] > T[0, 0, 3] + 0.1  # lifted, forward


def test_walk_swings_arms_against_legs_and_sways_the_pelvis(walk):
    tree, w = walk
    n = 16
    for k in (1, 2):  # at the end of a full step the swing foot leads and its arm trails
        swing_side = ("left", "right")[1 - k % 2]
        other = ("left", "right")[k % 2]
        q = w.q[(k + 1) * n - 1]
        assert tree.pose(q, f"{swing_side}_foot", "body")[0, 3] > tree.pose(q, f"{other}_foot", "body")[0, 3]
        assert tree.pose(q, f"{swing_side}_hand")[0, 3] < tree.pose(q, f"{other}_hand")[0, 3] - 0.1
    P = tree.pose(w.q, "lower_torso", "body")
    pelvis, head = P[:, :3, 3], tree.pose(w.q, "head")[:, :3, 3]
    for k in range(3):  # mid-step: swayed over the planted foot, and highest
        planted_y = tree.pose(w.q[k * n], ("left_foot", "right_foot")[k % 2], "body")[1, 3]
        mid = k * n + n // 2 - 1
        assert np.sign(head[mid, 1]) == np.sign(planted_y) and abs(head[mid, 1]) > 0.03  # the body sways
        assert np.sign(P[mid, 2, 1]) == np.sign(planted_y)  # the pelvis drops on the free side (its y axis tilts)
        assert pelvis[mid, 2] > pelvis[k * n + n - 1, 2] + 0.01  # bob: high mid-stance, low at double support
    # forward; the pelvis goal yields a few mm to the feet at times (legs without ankle roll)
    assert np.diff(pelvis[:, 0]).min() > -6e-3 and pelvis[-1, 0] - pelvis[0, 0] > 0.3


def test_cli_walk(tmp_path, capsys):
    out = tmp_path / "walk.png"
    assert main(["walk", "--steps", "1", "--width", "160", "--height", "120", "-o", str(out)]) == 0
    assert out.stat().st_size > 1000 and "feet on target in 100%" in capsys.readouterr().out
    assert main(["walk", "--stride", "-1", "-o", str(tmp_path / "w.mp4")]) == 2
    assert "--stride: must be a finite number > 0" in capsys.readouterr().err


# ------------------------------------------------------------------ scripts
def write_script(tmp_path, name="s.json", **change):
    """A 4-frame arm7 script as JSON, with ``change`` applied to its keys (values written as given)."""
    tree = tree_of("arm7")
    doc = {"format": motion.FORMAT, "version": 1, "model": "arm7", "source": "arm7",
           "fingerprint": motion.fingerprint(tree), "site": "ee", "times": [0.0, 0.1, 0.2, 0.3],
           "qpos": np.repeat(tree.model.key_qpos[:1], 4, axis=0).tolist(), "targets": None, "success": None, "meta": {}}
    doc.update(change)
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize("change, error, text", [
    ({"qpos": [[10**400] + [0.0] * 6] * 4}, mjkin.InputError, "'qpos' must be a list of T configurations"),
    ({"times": [0, 1, 2, 10**400]}, mjkin.InputError, "'times' must be a list of T times"),
    ({"success": ["no", "no", "yes", "no"]}, mjkin.InputError, "'success' must be one true/false per frame"),
    ({"success": [None, True, True, True]}, mjkin.InputError, "'success' must be one true/false per frame"),
    ({"times": [0.0, 0.2, 0.1, 0.3]}, mjkin.InputError,
     "'times' must not decrease, but frame 2 is at 0.1 s after 0.2 s"),
    ({"times": [1.5] * 4}, mjkin.InputError, "'times' are all 1.5 s; they must increase over the 4 frames"),
])
def test_load_refuses_what_json_holds_but_a_script_cannot_mean(tmp_path, change, error, text):
    with pytest.raises(error) as e:
        motion.Trajectory.load(write_script(tmp_path, **change), tree_of("arm7"))
    assert text in str(e.value) and "\n" not in str(e.value)


def test_load_survives_json_nested_deeper_than_python_recurses(tmp_path):
    path = tmp_path / "deep.json"
    path.write_text('{"format": "mjkin-trajectory", "times": ' + "[" * 20_000 + "]" * 20_000 + "}")
    with pytest.raises(mjkin.MjkinIOError, match="its JSON is nested too deeply"):
        motion.Trajectory.load(path)


def test_times_may_repeat_and_one_frame_has_one_time(tmp_path):
    traj = motion.Trajectory.load(write_script(tmp_path, times=[0.0, 0.1, 0.1, 0.3], success=[True, False, True, True]))
    assert traj.success.tolist() == [True, False, True, True]  # booleans stay booleans
    one = write_script(tmp_path, "one.json", times=[7.0], qpos=[tree_of("arm7").qpos0.tolist()])
    assert len(motion.Trajectory.load(one, tree_of("arm7")).q) == 1


def test_a_script_keeps_where_its_model_came_from(tmp_path):
    tree = tree_of("arm7")
    traj = motion.Trajectory(times=np.arange(2) / 30, q=np.repeat(tree.qpos0[None], 2, 0),
                             fingerprint=motion.fingerprint(tree), model="arm7", source="/models/arm7.xml")
    assert motion.Trajectory.load(traj.save(tmp_path / "t.json")).source == "/models/arm7.xml"
    doc = json.loads((tmp_path / "t.json").read_text())
    del doc["source"]  # a script written before the key existed
    (tmp_path / "old.json").write_text(json.dumps(doc))
    assert motion.Trajectory.load(tmp_path / "old.json", tree).source == ""


def test_outside_limits_names_the_joint_and_the_frame():
    arm = tree_of("arm7")
    q = np.repeat(arm.model.key_qpos[:1], 4, axis=0)
    assert motion.outside_limits(arm, q) is None
    q[2:, 0] = 5.0
    assert motion.outside_limits(arm, q) == ("joint j1 = 5 is outside its range [-2.96, 2.96] at frame 2 "
                                             "(and 1 more frame)")
    assert motion.outside_limits(arm, q[2]) == "joint j1 = 5 is outside its range [-2.96, 2.96]"  # one q: no frame
    chain = tree_of("ball_chain")  # ball joints limited to a 1.0472 rad cone
    q = chain.qpos0.copy()
    a = chain.jnt_qadr[0]
    q[a:a + 4] = [np.cos(1.0), np.sin(1.0), 0.0, 0.0]  # turned 2 rad
    name = chain.names("joint")[0] or 0
    assert motion.outside_limits(chain, q) == f"joint {name} turns 2 rad, beyond its 1.047 rad cone"
    q[a:a + 4] = [-2.0, 0.0, 0.0, 0.0]  # not unit, and -q: no turn at all
    assert motion.outside_limits(chain, q) is None
