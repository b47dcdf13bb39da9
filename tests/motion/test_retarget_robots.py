"""Retargeting onto the robots the field uses, meshes and all (issue 55): GMR's Unitree G1 (collision meshes), GMR's
Booster T1, the mesh-free G1 and the bundled primate, each shared clip with default options.

Every figure: hands, feet and head near the source's, no self-contact deeper than 1 mm, no foot geom more than
5 mm under the ground and both feet off it by more than 3 cm in at most 5 % of frames, planted soles slow, joints
not shaking. A few dozen frames of each clip (the walk's start, the crouch's way down) keep the time small.
"""

from __future__ import annotations

import importlib.util
from dataclasses import replace
from functools import cache
from pathlib import Path

import mujoco
import numpy as np
import pytest

import mjkin
from mjkin.apps.bench.report import shared_models_dir
from mjkin.apps.bench.retarget import mocap_dir
from mjkin.goals import HalfSpace
from mjkin.motion import Trajectory, bvh
from mjkin.motion.quality import score
from mjkin.motion.retarget import KEYS, SIDES, Retarget, frame_goals, plan, report, self_pairs
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
    return check_trajectory(figure(model), retargeted(model, name), mean_bound)


def check_trajectory(tree: mjkin.Tree, traj: Trajectory, mean_bound: float | None, p95: float = P95) -> dict:
    rep = report(tree, traj)
    err = keypoint_errors(tree, traj)
    got = {"mean": float(err.mean()), "p95": float(np.percentile(err, 95)), **rep}
    assert not traj.meta["retarget"]["constraint_unmet"], got
    if mean_bound is not None:
        assert got["mean"] <= mean_bound, got
    assert got["p95"] <= p95, got
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


# ------------------------------------------------------------------ goal 4: humanoids mjkin was not tuned on
GYM_HUMANOID = Path(importlib.util.find_spec("gymnasium").origin).parent / "envs" / "mujoco" / "assets" / \
    "humanoid.xml" if importlib.util.find_spec("gymnasium") else Path("gymnasium-is-not-installed/humanoid.xml")


def scaled(source: str | Path, k: float) -> mjkin.Tree:
    """The figure of ``source`` (an MJCF path or "primate") made ``k`` times as large: every body, joint, geom and
    site place and size, slide ranges and mesh scales (its masses as they are: kinematics does not see them)."""
    path = mjkin.kinematics.tree.bundled_models()["primate"] if source == "primate" else source
    spec = mujoco.MjSpec.from_file(str(path))
    for b in spec.bodies:
        b.pos = np.asarray(b.pos) * k
    for g in spec.geoms:
        g.pos, g.size = np.asarray(g.pos) * k, np.asarray(g.size) * k
        if not np.isnan(g.fromto[0]):
            g.fromto = np.asarray(g.fromto) * k
    for s in spec.sites:
        s.pos, s.size = np.asarray(s.pos) * k, np.asarray(s.size) * k
    for j in spec.joints:
        j.pos = np.asarray(j.pos) * k
        if j.type == mujoco.mjtJoint.mjJNT_SLIDE:
            j.range = np.asarray(j.range) * k
    for m in spec.meshes:
        m.scale = np.asarray(m.scale) * k
    return mjkin.load(spec)


# name -> (the model file or "primate", scale): gymnasium's humanoid (capsules, 23 dofs: a torso-head, hands on the
# forearms, no ankles), small and large copies of it, of GMR's G1 (meshes, 35 dofs) and of the Booster T1, a large
# primate; the mesh-free G1 with its hands (43 dofs) is in test_other_figures_hold_the_same_limits
UNSEEN = {"gym_humanoid": (GYM_HUMANOID, 1.0), "gym_humanoid_x0.5": (GYM_HUMANOID, 0.5),
          "gym_humanoid_x1.3": (GYM_HUMANOID, 1.3), "gym_humanoid_x1.5": (GYM_HUMANOID, 1.5),
          "gmr_g1_x0.5": (GMR_G1, 0.5), "gmr_g1_x1.3": (GMR_G1, 1.3), "gmr_g1_x1.5": (GMR_G1, 1.5),
          "gmr_t1_x0.6": (GMR_T1, 0.6), "gmr_t1_x1.5": (GMR_T1, 1.5), "primate_x1.5": ("primate", 1.5)}


# The crouch's way down folds further at the hips than these figures reach: the nearest pose they can take with the
# feet where they stand leaves the pelvis 15-18 cm (at their own size) above its target (see
# test_the_crouch_is_out_of_these_figures_reach and, for the primate's 1.8 rad hips,
# test_the_primates_crouch_fails_the_bound_only_by_its_hips_reach). The miss is a share of the figure's size (the
# gym humanoid's 17.4, 22.5 and 26.3 cm at 1, 1.3 and 1.5 times; the T1's 11.3, 18.4 and 27.7 cm at 0.6, 1 and 1.5),
# so at 1.3-1.5 times it passes 20 cm.
OUT_OF_REACH = {("gym_humanoid_x1.3", "mocapbank_19joint"), ("gym_humanoid_x1.5", "mocapbank_19joint"),
                ("gmr_t1_x1.5", "mocapbank_19joint"), ("primate_x1.5", "mocapbank_19joint")}


def unseen_params() -> list:
    out = []
    for robot, (f, _) in UNSEEN.items():
        for name in CLIPS:
            marks = [need(Path(f))] if f != "primate" else []
            if (robot, name) in OUT_OF_REACH:
                marks.append(pytest.mark.xfail(strict=True, reason="the crouch folds deeper than the large figure's "
                                                                   "hips reach: key points over 20 cm off"))
            out.append(pytest.param(robot, name, marks=marks, id=f"{name}-{robot}"))
    return out


@need_mocap
@pytest.mark.parametrize(("robot", "name"), unseen_params())
def test_humanoids_not_tuned_on_hold_the_limits(robot: str, name: str) -> None:
    """Goal 4 on figures no constant was tuned on, small and large, with and without collision meshes, 23-35 dofs:
    default options, no mapping file; the same limits as above, key points within 20 cm (95th percentile)."""
    tree = unseen(robot)
    check_trajectory(tree, mjkin.retarget(clip(name), tree), None)


@cache
def unseen(robot: str) -> mjkin.Tree:
    source, k = UNSEEN[robot]
    return scaled(source, k)


def nearest_frame(tree: mjkin.Tree, plan_: Retarget, f: int) -> np.ndarray:
    """Frame ``f``'s key-point errors ``(5,)`` (m, as :func:`keypoint_errors`) at the best pose its own goals
    (feet held, sole corners above the ground, pelvis, turns, limbs, head: :func:`frame_goals`) reach when searched
    from 24 random starts, with no previous frame to stay near and no speed limit."""
    goals = list(frame_goals(tree, plan_).frames[f])
    q = tree.qpos0.copy()
    q[tree.layout.free_q[0][:3]] += plan_.points["pelvis"][f] - tree.pose(q, plan_.bodies["pelvis"], "body")[:3, 3]
    q = mjkin.Problem(tree, goals, tol=1e-6, max_iters=300, restarts=24, timeout=np.inf).solve(q).q
    b, got = plan_.bodies, []
    for r in KEYS:
        T = tree.pose(q, b[r], "body")
        got.append(T[:3, :3] @ plan_.offsets[r] + T[:3, 3])
    feet = {f"{s}_ankle": plan_.feet[i, f, :3, :3] @ plan_.offsets[f"{s}_ankle"] + plan_.feet[i, f, :3, 3]
            for i, s in enumerate(SIDES)}
    target = np.array([feet.get(r, plan_.points[r][f]) for r in KEYS])
    return np.linalg.norm((np.array(got[1:]) - got[0]) - (target[1:] - target[0]), axis=-1)


@need_mocap
@pytest.mark.parametrize("robot", [pytest.param("gym_humanoid_x1.5", marks=need(GYM_HUMANOID)),
                                   pytest.param("gmr_t1_x1.5", marks=need(GMR_T1))])
def test_the_crouch_is_out_of_these_figures_reach(robot: str) -> None:
    """The large copies miss the crouch (OUT_OF_REACH) only where the figure cannot go: in the clip's worst frame
    the best pose that frame's own goals reach, searched from 24 random starts with no previous frame or speed limit,
    misses by more than the bound too, and the retargeted frame by no more than it (within 3 cm). The gym
    humanoid's hips flex 110 degrees and it has no ankles (a flat foot holds the shin upright); the T1's hips pitch
    1.8 rad while its waist only yaws, so its pelvis leans with the trunk (59 degrees here) and the thighs would
    fold 150 degrees from it."""
    tree = unseen(robot)
    name = "mocapbank_19joint"
    traj = mjkin.retarget(clip(name), tree)
    got = check_trajectory(tree, traj, None, p95=np.inf)  # every other limit holds
    assert got["p95"] > P95, got
    err = keypoint_errors(tree, traj)
    f = int(np.argmax(err.max(axis=1)))
    best = nearest_frame(tree, plan(clip(name), tree), f)
    assert best.max() > P95 and err[f].max() <= best.max() + 0.03, (f, err[f], best)
