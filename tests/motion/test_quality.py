"""The one score of a retargeted motion, whichever tool made it (mjkin.motion.quality, issue 55): constructed
trajectories with a known penetration, float, slide, acceleration, self-contact and key-point error."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import mujoco
import numpy as np
import pytest

import mjkin
from mjkin import spatial
from mjkin.apps.bench.report import shared_models_dir
from mjkin.apps.bench.retarget import mocap_dir
from mjkin.errors import InputError
from mjkin.motion import bvh
from mjkin.motion.quality import FLOAT, KEYPOINTS, foot_gaps, keypoint_errors, score
from mjkin.motion.retarget import plan, report
from mjkin.motion.roles import figure_mapping, role_offsets
from mjkin.motion.terrain import Terrain

MOCAP = mocap_dir() or Path("../shared/mocap")
WALK = MOCAP / "mixamo_freebvh.bvh"
G1 = (shared_models_dir() or Path("../shared/models")) / "gmr_unitree_g1" / "g1_mocap_29dof.xml"
pytestmark = [pytest.mark.skipif(not WALK.is_file(), reason=f"the shared clips are not here ({MOCAP})"),
              pytest.mark.skipif(not G1.is_file(), reason=f"GMR's G1 is not here ({G1})")]


@cache
def g1() -> mjkin.Tree:
    return mjkin.load(G1)


@cache
def clip() -> bvh.Clip:
    return bvh.read(WALK)


def standing() -> np.ndarray:
    """The G1 at ``qpos0`` with its lowest foot point on the ground, every frame of the walk ``(F, nq)``."""
    tree = g1()
    q = tree.qpos0.copy()
    bodies = figure_mapping(tree)
    q[2] -= foot_gaps(tree, q[None], bodies, Terrain.flat()).min()
    return np.tile(q, (clip().frames, 1))


def dof(tree: mjkin.Tree, joint: str) -> int:
    return int(tree.model.jnt_qposadr[tree.id(joint, "joint")])


def test_standing_still_scores_nothing_but_the_pose() -> None:
    m = score(g1(), standing(), clip())
    assert m["frames"] == clip().frames and m["contact_frames"] > 0
    assert m["foot_penetration"] == pytest.approx(0.0, abs=1e-9) and m["float_share"] == 0.0
    assert m["slide_speed_mean"] == pytest.approx(0.0, abs=1e-9) and m["joint_accel_mean"] == 0.0
    assert m["self_contact_frames"] == 0 and m["self_contact_deepest"] == 0.0 and m["limits"] is None
    assert 0.0 < m["keypoint_mean"] <= m["keypoint_p95"]  # a walk is not a still pose


def test_penetration_float_and_slide_are_measured_as_constructed() -> None:
    q, dt = standing(), clip().frame_time
    F = len(q)
    q[: F // 3, 2] -= 0.007  # a third of the clip 7 mm into the ground
    q[F // 3: 2 * F // 3, 2] += FLOAT + 0.02  # the next third in the air, both feet 5 cm up
    v = 0.4  # m/s: the whole figure slides forward in every frame
    q[:, 0] += v * dt * np.arange(F)
    m = score(g1(), q, clip())
    assert m["foot_penetration"] == pytest.approx(0.007, abs=1e-9)
    assert m["float_share"] == pytest.approx((2 * F // 3 - F // 3) / F)
    assert m["slide_speed_mean"] == pytest.approx(v, rel=1e-9)  # every planted sole, at the figure's speed
    assert m["joint_accel_mean"] == 0.0  # the root moved, no joint
    assert m["self_contact_frames"] == 0  # the floor's contacts are not self-contacts


def test_joint_acceleration_is_the_second_difference_of_the_hinges() -> None:
    tree, q, dt = g1(), standing(), clip().frame_time
    a = 2.0  # rad/s²: one hinge at constant acceleration, at rest mid-clip
    t = dt * np.arange(len(q))
    q[:, dof(tree, "left_elbow_joint")] += 0.5 * a * (t - t.mean()) ** 2  # within its range (up to 1.3 rad)
    hinges = int(np.sum(np.isin(tree.jnt_type, (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE))))
    m = score(tree, q, clip())
    assert m["joint_accel_mean"] == pytest.approx(a / hinges, rel=1e-6) and m["limits"] is None
    m = score(tree, q, clip(), frame_time=2 * dt)  # the same poses at half the rate: a quarter
    assert m["joint_accel_mean"] == pytest.approx(a / hinges / 4, rel=1e-6)


def test_self_contact_counts_frames_deeper_than_a_millimetre_by_mujoco() -> None:
    tree, q = g1(), standing()
    deep, shallow = slice(10, 20), slice(30, 35)
    q[deep, dof(tree, "left_shoulder_roll_joint")] = -0.6  # the upper arm into the torso
    m = mujoco.MjModel.from_xml_path(str(G1))
    d = mujoco.MjData(m)
    d.qpos[:] = q[10]
    mujoco.mj_kinematics(m, d)
    mujoco.mj_collision(m, d)
    body = m.geom_bodyid[d.contact.geom]
    mine = d.contact.dist[(body != 0).all(axis=1)]
    assert mine.min() < -1e-3
    # just touching: the roll where MuJoCo's deepest contact is half a millimetre
    lo, hi = -0.6, 0.11
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        d.qpos[dof(tree, "left_shoulder_roll_joint")] = mid
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        body = m.geom_bodyid[d.contact.geom]
        dist = d.contact.dist[(body != 0).all(axis=1)]
        lo, hi = (mid, hi) if dist.size and dist.min() < -5e-4 else (lo, mid)
    q[shallow, dof(tree, "left_shoulder_roll_joint")] = hi
    got = score(tree, q, clip())
    assert got["self_contact_frames"] == 10  # the 5 frames 0.5 mm deep do not count
    assert got["self_contact_deepest"] == pytest.approx(float(mine.min()), abs=1e-12)


def test_keypoints_are_relative_to_the_pelvis_and_blind_to_the_heading() -> None:
    tree, q, c = g1(), standing(), clip()
    F = len(q)
    q[:, dof(tree, "left_elbow_joint")] = np.linspace(0.0, 1.2, F)
    bodies = figure_mapping(tree)
    offsets = role_offsets(tree, bodies)
    roles = {"pelvis": 0, **{r: k + 1 for k, r in enumerate(KEYPOINTS)}}

    def point(qs: np.ndarray, r: str) -> np.ndarray:
        T = tree.pose(qs, bodies[r], "body")
        return T[..., :3, :3] @ offsets[r] + T[..., :3, 3]

    source = np.stack([point(q, r) for r in roles], axis=1)  # the figure's own points: no error
    assert keypoint_errors(tree, q, source, roles, bodies, offsets).max() < 1e-12
    moved = source.copy()
    moved[:, roles["head"]] += [0.0, 0.0, 0.05]  # the source's head 5 cm higher
    moved[:, roles["right_ankle"]] -= [0.0, 0.0, 0.05]  # its right foot 5 cm lower (height leaves the yaw fit be)
    err = keypoint_errors(tree, q, moved, roles, bodies, offsets)
    np.testing.assert_allclose(err, np.array([0.05, 0.0, 0.0, 0.0, 0.05])[None].repeat(F, 0), atol=1e-9)
    # the figure turned 70 degrees about the vertical, shifted and raised: the same errors, as a peer that keeps
    # the clip's heading and places its root its own way is measured
    R = spatial.axis_angle_to_mat(np.array([0.0, 0.0, 1.0]), np.deg2rad(70.0))
    turned = q.copy()
    turned[:, :3] = q[:, :3] @ R.T + [1.5, -2.0, 0.3]
    turned[:, 3:7] = spatial.mat_to_quat(R @ spatial.quat_to_mat(q[:, 3:7]))
    np.testing.assert_allclose(keypoint_errors(tree, turned, moved, roles, bodies, offsets), err, atol=1e-9)
    a, b = score(tree, q, c), score(tree, turned, c)
    assert a["keypoint_mean"] == pytest.approx(b["keypoint_mean"], abs=1e-9)
    assert a["keypoint_p95"] == pytest.approx(b["keypoint_p95"], abs=1e-9)


def test_keypoints_are_against_the_source_scaled_as_mjkin_plans_it() -> None:
    tree, c = g1(), clip()
    p = plan(c, tree)
    assert p.source.shape == (c.frames, len(c.names), 3) and 0.5 < p.root_ratio < 1.0  # the G1 is smaller
    q = standing()
    q[:, dof(tree, "left_shoulder_pitch_joint")] = -1.2  # an arm up and forward: further from the walk's
    assert score(tree, q, c)["keypoint_mean"] > score(tree, standing(), c)["keypoint_mean"]


def test_a_trajectory_of_another_length_is_refused() -> None:
    with pytest.raises(InputError, match="one pose a frame"):
        score(g1(), standing()[:-1], clip())


def test_the_score_agrees_with_mjkins_own_report_where_they_measure_the_same() -> None:
    """The ground, slide and self-contact measures are report()'s, per frame: on mjkin's own output they agree."""
    tree = mjkin.load("primate")
    traj = mjkin.retarget(WALK, tree)
    rep, got = report(tree, traj), score(tree, traj.q, clip())
    assert got["foot_penetration"] == pytest.approx(rep["terrain_penetration"], abs=1e-12)
    assert got["self_contact_deepest"] == pytest.approx(rep["self_contact_deepest"], abs=1e-12)
    assert got["contact_frames"] == rep["contact_frames"]
    assert got["slide_speed_mean"] == pytest.approx(rep["skate_per_frame_mean"] / clip().frame_time, rel=1e-9)
    assert got["limits"] == rep["limits"]
