"""Retargeting onto the robots the field uses, meshes and all (issue 55): GMR's Unitree G1 (collision meshes), GMR's
Booster T1, the mesh-free G1 and the bundled primate, each shared clip with default options.

Every figure: hands, feet and head near the source's, no self-contact deeper than 1 mm, no foot geom more than
5 mm under the ground and both feet off it by more than 3 cm in at most 5 % of frames, planted soles slow, joints
not shaking. A few dozen frames of each clip (the walk's start, the crouch's way down) keep the time small.
"""

from __future__ import annotations

from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np
import pytest

import mjkin
from mjkin.apps.bench.report import shared_models_dir
from mjkin.apps.bench.retarget import mocap_dir
from mjkin.goals import HalfSpace
from mjkin.motion import Trajectory, bvh
from mjkin.motion.quality import score
from mjkin.motion.retarget import KEYS, SIDES, report, self_pairs
from mjkin.motion.roles import role_offsets
from mjkin.motion.terrain import foot_points, lowest

MOCAP = mocap_dir() or Path("../shared/mocap")
MODELS = shared_models_dir() or Path("../shared/models")
GMR_G1 = MODELS / "gmr_unitree_g1" / "g1_mocap_29dof.xml"
GMR_T1 = MODELS / "gmr_booster_t1" / "t1_mocap.xml"
G1 = MODELS / "unitree_g1" / "g1.xml"
# the clips' frames used: the walk's first 40 (frame 4 is where GMR's G1 froze), the crouch's way down
CLIPS = {"mixamo_freebvh": slice(0, 40), "mocapbank_19joint": slice(100, 150)}
# hands/feet/head off their targets (m, relative to the pelvis as report() measures them): GMR's own on its G1,
# mean over the frames (6.9 cm on the walk, 26.6 cm on the crouch); any figure's at the 95th percentile
GMR_MEAN = {"mixamo_freebvh": 0.069, "mocapbank_19joint": 0.266}
P95 = 0.20
DEPTH = 1e-3  # m: the deepest self-contact allowed
SINK = 5e-3  # m: the deepest a foot geom may go into the ground
AIRBORNE, AIRBORNE_SHARE = 0.03, 0.05  # both feet above the ground by more than this in at most this share of frames
SLIDE = 0.05  # m/s: a planted sole's mean slide
ACCELERATION = 45.0  # rad/s²: GMR's mean joint acceleration on a walk


def need(path: Path) -> pytest.MarkDecorator:
    return pytest.mark.skipif(not path.is_file(), reason=f"{path.name} is not here ({path})")


need_mocap = pytest.mark.skipif(not MOCAP.is_dir(), reason=f"the shared clips are not here ({MOCAP})")


@cache
def figure(name: str) -> mjkin.Tree:
    return mjkin.load(name)


@cache
def clip(name: str) -> bvh.Clip:
    c = bvh.read(MOCAP / f"{name}.bvh")
    return replace(c, values=c.values[CLIPS[name]])


@cache
def retargeted(model: str, name: str) -> Trajectory:
    return mjkin.retarget(clip(name), figure(model))


def keypoint_errors(tree: mjkin.Tree, traj: Trajectory) -> np.ndarray:
    """Hands, feet and head against their targets, relative to the pelvis (as :func:`report`): ``(F, 5)`` m."""
    bodies = traj.meta["retarget"]["bodies"]
    offsets = role_offsets(tree, bodies)
    got = []
    for r in KEYS:
        T = tree.pose(traj.q, bodies[r], "body")
        got.append(T[..., :3, :3] @ offsets[r] + T[..., :3, 3])
    got = np.stack(got, 1)
    return np.linalg.norm((got[:, 1:] - got[:, :1]) - (traj.targets[:, 1:] - traj.targets[:, :1]), axis=-1)


def feet_heights(tree: mjkin.Tree, traj: Trajectory) -> np.ndarray:
    """Each foot's lowest point above the plane z = 0 in every frame: ``(2, F)`` m."""
    bodies = traj.meta["retarget"]["bodies"]
    out = []
    for s in SIDES:
        body = bodies[f"{s}_ankle"]
        out.append(lowest(tree.pose(traj.q, body, "body"), *foot_points(tree, body))[..., 2].min(axis=1))
    return np.array(out)


def mean_acceleration(tree: mjkin.Tree, traj: Trajectory) -> float:
    """Mean |second difference| of the joints' values over the frames (rad/s², m/s²), the root's left out."""
    dt = float(np.diff(traj.times).mean())
    v = tree.difference(traj.q[1:], traj.q[:-1]) / dt
    joints = np.ones(tree.nv, bool)
    for j in np.flatnonzero(tree.model.jnt_type == 0):  # free joints: the root's path is the source's
        joints[tree.model.jnt_dofadr[j]:tree.model.jnt_dofadr[j] + 6] = False
    return float(np.abs(np.diff(v, axis=0)[:, joints]).mean() / dt)


def check_figure(model: str, name: str, mean_bound: float | None) -> dict:
    tree, traj = figure(model), retargeted(model, name)
    rep = report(tree, traj)
    err = keypoint_errors(tree, traj)
    got = {"mean": float(err.mean()), "p95": float(np.percentile(err, 95)), **rep}
    assert not traj.meta["retarget"]["constraint_unmet"], got
    if mean_bound is not None:
        assert got["mean"] <= mean_bound, got
    assert got["p95"] <= P95, got
    assert rep["self_contact_deepest"] >= -DEPTH, got
    assert rep["floor_min"] >= -SINK, got
    heights = feet_heights(tree, traj)
    assert np.mean(heights.min(axis=0) > AIRBORNE) <= AIRBORNE_SHARE, got
    fps = 1.0 / float(np.diff(traj.times).mean())
    assert rep["skate_per_frame_mean"] * fps <= SLIDE, got
    assert mean_acceleration(tree, traj) <= ACCELERATION, got
    return got


@need_mocap
@need(GMR_G1)
@pytest.mark.parametrize("name", list(CLIPS))
def test_gmr_g1_follows_each_clip_without_touching_itself(name: str) -> None:
    """Goals 2 and 3: default options on GMR's G1 (STL meshes) track the source at least as well as GMR does.
    Before issue 55 the clearance measured the meshes as bounding spheres, which overlapped: the figure froze
    from the walk's frame 4, 55 cm off."""
    check_figure(str(GMR_G1), name, GMR_MEAN[name])


@need_mocap
@pytest.mark.parametrize("model", [pytest.param(str(GMR_T1), marks=need(GMR_T1), id="gmr_t1"),
                                   pytest.param(str(G1), marks=need(G1), id="g1"),
                                   pytest.param("primate", id="primate")])
@pytest.mark.parametrize("name", list(CLIPS))
def test_other_figures_hold_the_same_limits(model: str, name: str) -> None:
    """Goal 4: the same limits on other figures, with and without meshes, key points within 20 cm (95th pct)."""
    check_figure(model, name, None)


def test_pairs_touching_at_rest_do_not_hold_the_figure() -> None:
    """A pair of geoms nearer than the clearance in the rest pose touches by design: left out of the clearance
    (kept, the figure could never meet it, and would not move)."""
    tree = mjkin.load("""<mujoco><worldbody><body name="pelvis"><freejoint/>
        <geom name="hip" type="sphere" size=".1"/>
        <body name="thigh" pos="0 0 -.25"><joint type="hinge" axis="0 1 0"/>
          <geom name="thigh" type="capsule" size=".05" fromto="0 0 0 0 0 -.2"/>
          <body name="shin" pos="0 0 -.3"><joint type="hinge" axis="0 1 0"/>
            <geom name="shin" type="capsule" size=".05" fromto="0 .06 .45 0 .06 -.2"/></body></body>
        <body name="arm" pos="0 .3 0"><joint type="hinge" axis="1 0 0"/>
          <geom name="arm" type="capsule" size=".04" fromto="0 0 0 0 0 -.3"/></body>
        </body></worldbody></mujoco>""")
    ids = {tree.model.geom(g).name: g for g in range(tree.model.ngeom)}
    every = self_pairs(tree)
    assert (ids["hip"], ids["shin"]) in every  # they overlap at rest (the shin's geom reaches up past the thigh)
    assert tree.distances(tree.qpos0, np.array([[ids["hip"], ids["shin"]]]))[0] < 0
    kept = self_pairs(tree, 0.002)
    assert kept == [p for p in every if p != (ids["hip"], ids["shin"])] and (ids["thigh"], ids["arm"]) in kept
    assert all(d >= 0.002 for d in tree.distances(tree.qpos0, np.array(kept)))


def test_frames_whose_constraints_cannot_be_met_are_counted() -> None:
    """Hard goals no pose meets (the pelvis above 10 m and below 9 m) leave every frame unmet: each keeps the
    pose the solver found nearest to meeting them, is listed in the result and counted by the report."""
    from test_retarget import crouch_bvh

    primate = figure("primate")
    clip_ = bvh.parse(crouch_bvh(frames=6))
    apart = [HalfSpace("lower_torso", point=(0.0, 0.0, 10.0), normal=(0.0, 0.0, 1.0), kind="body", priority=1),
             HalfSpace("lower_torso", point=(0.0, 0.0, 9.0), normal=(0.0, 0.0, -1.0), kind="body", priority=1)]
    traj = mjkin.retarget(clip_, primate, extra_goals=apart)
    assert traj.meta["retarget"]["constraint_unmet"] == list(range(6))
    assert report(primate, traj)["constraint_unmet_frames"] == 6 and np.isfinite(traj.q).all()
    free = mjkin.retarget(clip_, primate)
    assert free.meta["retarget"]["constraint_unmet"] == [] and report(primate, free)["constraint_unmet_frames"] == 0


# ------------------------------------------------------------------ goal 3: joints as smooth as GMR's, whole clips
# GMR's own on its G1, scored by mjkin.motion.quality.score (`mjkin bench retarget --models gmr_unitree_g1`, GMR
# beside): key points mean and 95th percentile (m), mean joint acceleration (rad/s²), rounded down
GMR_SCORE = {"mixamo_freebvh": {"keypoint_mean": 0.07628, "keypoint_p95": 0.1022, "joint_accel_mean": 10.12},
             "mocapbank_19joint": {"keypoint_mean": 0.2586, "keypoint_p95": 0.4315, "joint_accel_mean": 2.123}}


def gmr_score_params() -> list:
    # the walk is goal 3's open item: 13.3 rad/s² against GMR's 10.1 (branch accel-wip meets it, 9.99, but changes
    # the weights three other tests of tests/motion depend on)
    gap = pytest.mark.xfail(strict=True, reason="goal 3 open: the walk's joints accelerate 13.3 rad/s², GMR's 10.1")
    return [pytest.param(n, marks=[gap] if n == "mixamo_freebvh" else [], id=n) for n in GMR_SCORE]


@need_mocap
@need(GMR_G1)
@pytest.mark.parametrize("name", gmr_score_params())
def test_gmr_g1_joints_accelerate_no_more_than_gmrs(name: str) -> None:
    """Goal 3's smoothness on whole clips: mean joint acceleration at most GMR's, the key points no further from the
    source than GMR's (mean; 95th percentile within 2 cm), the feet planted and nothing through itself. The walk's
    joints accelerate 13.3 rad/s² (GMR 10.1): a planted foot's pitch switches on in one frame once the source's
    heel is 6 cm up, and the hips and waist shake with it (where a foot lands or lifts)."""
    path = MOCAP / f"{name}.bvh"
    tree = figure(str(GMR_G1))
    traj = mjkin.retarget(path, tree)
    got = score(tree, traj.q, path)
    gmr = GMR_SCORE[name]
    assert got["joint_accel_mean"] <= gmr["joint_accel_mean"], got
    assert got["keypoint_mean"] <= gmr["keypoint_mean"] and got["keypoint_p95"] <= gmr["keypoint_p95"] + 0.02, got
    assert got["self_contact_frames"] == 0 and got["foot_penetration"] <= SINK, got
    assert got["float_share"] <= AIRBORNE_SHARE and got["slide_speed_mean"] <= SLIDE, got
    assert not traj.meta["retarget"]["constraint_unmet"], got
