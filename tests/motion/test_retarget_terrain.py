"""Retargeting onto a scene (issue 39): the ground by ray casts, feet placed by their geoms' lowest points, a walk
recorded on flat ground taken up an 8 degree ramp onto a 12 cm step, checked against MuJoCo's own distances."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import mjkin
from mjkin import render, spatial
from mjkin.apps.bench.report import shared_models_dir
from mjkin.apps.bench.retarget import mocap_dir
from mjkin.apps.cli import run
from mjkin.errors import InputError, MjkinIOError, ModelError
from mjkin.kinematics.tree import bundled_models
from mjkin.motion import bvh
from mjkin.motion.retarget import plan, report
from mjkin.motion.terrain import Terrain, foot_points, lowest, sole_corners

MOCAP = mocap_dir() or Path("../shared/mocap")
WALK = MOCAP / "mixamo_freebvh.bvh"
G1 = (shared_models_dir() or Path("../shared/models")) / "unitree_g1" / "g1.xml"
need_walk = pytest.mark.skipif(not WALK.is_file(), reason=f"the shared walk is not here ({WALK})")
need_g1 = pytest.mark.skipif(not (WALK.is_file() and G1.is_file()), reason="the shared walk or G1 is not here")

ANGLE = np.radians(8.0)
RAMP = (0.25, 0.95)  # m: where the ramp's top rises from the floor, and where it ends (along x)
STEP = (1.0, 0.12)  # m: where the step begins, its height
PENETRATION, FLOAT = 5e-3, 15e-3  # m: the bounds


def ground_geoms() -> str:
    """A ramp (a box turned 8 degrees, rising along +x) and a 12 cm step along the primate's walk, as MJCF geoms."""
    half, thick = 0.5, 0.05
    up = np.array([np.cos(ANGLE), 0.0, np.sin(ANGLE)])  # the box's x axis
    top_end = np.array([RAMP[1], 0.0, (RAMP[1] - RAMP[0]) * np.tan(ANGLE)])
    centre = top_end - half * up - thick * np.array([-np.sin(ANGLE), 0.0, np.cos(ANGLE)])
    quat = (np.cos(-ANGLE / 2), 0.0, np.sin(-ANGLE / 2), 0.0)  # about y by -8 degrees: x tips up
    return (f'<geom name="ramp" type="box" size="{half} 0.5 {thick}" pos="{centre[0]:.9f} 0 {centre[2]:.9f}" '
            f'quat="{quat[0]:.12f} 0 {quat[2]:.12f} 0" rgba="0.75 0.5 0.3 1"/>'
            f'<geom name="step" type="box" size="0.4 0.5 {STEP[1] / 2}" pos="{STEP[0] + 0.4} 0 {STEP[1] / 2}" '
            'rgba="0.35 0.5 0.75 1"/>')


SCENE = ('<mujoco model="ramp and step"><worldbody><light pos="0 0 3" dir="0 0 -1"/>'
         '<geom name="floor" type="plane" size="0 0 1" rgba="0.8 0.8 0.8 1"/>' + ground_geoms()
         + "</worldbody></mujoco>")


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("scene") / "ramp_step.xml"
    path.write_text(SCENE)
    return path


@pytest.fixture(scope="module")
def primate() -> mjkin.Tree:
    return mjkin.load("primate")


def ramp_height(x: np.ndarray) -> np.ndarray:
    return (x - RAMP[0]) * np.tan(ANGLE)


# ------------------------------------------------------------------------------------------------ the ground
@given(st.floats(RAMP[0] + 0.02, RAMP[1] - 0.02), st.floats(-0.45, 0.45), st.floats(0.0, 0.4))
def test_rays_find_the_ramp_its_slope_and_the_floor(x: float, y: float, above: float) -> None:
    ground = Terrain.load(SCENE)
    h, n = ground.under(np.array([[x, y, ramp_height(np.array(x)) + above], [x, 2.0, above]]))
    np.testing.assert_allclose(h, [ramp_height(np.array(x)), 0.0], atol=1e-9)  # beside the ramp: the floor
    np.testing.assert_allclose(n, [[-np.sin(ANGLE), 0, np.cos(ANGLE)], [0, 0, 1]], atol=1e-9)
    assert np.all(ground.ceiling(np.array([[x, y]]), np.array([[x, y]])) >= h[0])  # the broad phase bounds it


def test_the_step_and_no_ground(scene_file: Path) -> None:
    ground = Terrain.load(scene_file)
    h, _ = ground.under(np.array([[STEP[0] + 0.1, 0.0, 0.05], [0.0, 0.0, 0.3]]))  # a point inside the step: its top
    np.testing.assert_allclose(h, [STEP[1], 0.0], atol=1e-12)
    islet = Terrain.load('<mujoco><worldbody><geom type="box" size="0.1 0.1 0.1"/></worldbody></mujoco>')
    assert islet.floor is None and np.isneginf(islet.under(np.array([[1.0, 0.0, 0.0]]))[0]).all()
    lift = islet.lift(np.array([[[0.0, 0.0, 0.05], [0.05, 0.0, 0.15]], [[2.0, 0.0, -1.0], [0.0, 0.0, 0.3]]]))
    np.testing.assert_allclose(lift, [0.05, 0.0])  # under the box top: up to it; nothing under, or above: stays


def test_a_menagerie_style_scene_keeps_the_world_and_drops_the_robot(tmp_path: Path) -> None:
    (tmp_path / "robot.xml").write_text(
        '<mujoco><actuator><motor joint="hinge"/></actuator><worldbody><body name="base" pos="0 0 0.5"><freejoint/>'
        '<geom size="0.2"/><body><joint name="hinge"/><geom size="0.1" pos="0.3 0 0"/></body></body>'
        '</worldbody><sensor><jointpos joint="hinge"/></sensor><keyframe><key qpos="0 0 1 1 0 0 0 0"/></keyframe>'
        '</mujoco>')
    (tmp_path / "scene.xml").write_text(
        '<mujoco><include file="robot.xml"/><worldbody><geom name="floor" type="plane" size="0 0 0.05"/>'
        '<body name="crate" pos="2 0 0.1"><geom type="box" size="0.1 0.1 0.1"/></body>'
        '<geom name="decal" type="box" size="1 1 0.2" pos="-3 0 0" contype="0" conaffinity="0"/></worldbody></mujoco>')
    ground = Terrain.load(tmp_path / "scene.xml")
    assert ground.model.nq == 0 and ground.model.nu == 0 and ground.model.nbody == 2  # the world and the crate
    h, _ = ground.under(np.array([[0.0, 0.0, 0.1], [2.0, 0.0, 0.1], [-3.0, 0.0, 0.1]]))
    np.testing.assert_allclose(h, [0.0, 0.2, 0.0])  # not the robot's ball; the crate; not the decal (no collision)


@pytest.mark.parametrize(("text", "error", "words"), [
    (None, MjkinIOError, "scene file not found"),
    ("<mujoco><worldbody><geom type='box' size='1'/>", ModelError, "cannot read scene"),
    ("<mujoco><worldbody><geom type='plane' size='1 1 1' contype='0' conaffinity='0'/></worldbody></mujoco>",
     InputError, "has no ground"),
])
def test_bad_scenes_are_one_line(tmp_path: Path, text: str | None, error: type[Exception], words: str) -> None:
    path = tmp_path / "scene.xml"
    if text is not None:
        path.write_text(text)
    with pytest.raises(error, match=words) as e:
        Terrain.load(path)
    assert "\n" not in str(e.value)


# ------------------------------------------------------------------------------------------------ the feet
@given(st.floats(-np.pi, np.pi), st.floats(0.0, 1.0), st.floats(-np.pi, np.pi))
def test_a_foots_lowest_ball_is_its_geoms_lowest_point(primate: mjkin.Tree, yaw: float, tilt: float,
                                                         towards: float) -> None:
    axis = np.array([np.cos(towards), np.sin(towards), 0.0])  # tilted up to 1 rad about a level axis
    R = spatial.quat_to_mat(spatial.quat_mul(spatial.quat_from_axis_angle(axis, tilt),
                                             spatial.quat_from_axis_angle([0.0, 0.0, 1.0], yaw)))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, (0.3, -0.2, 0.5)
    m = primate.model
    box = m.geom("left_foot")
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * box.size + box.pos
    pts, radius = foot_points(primate, "left_foot")
    assert lowest(T, pts, radius)[:, 2].min() == pytest.approx((corners @ R.T + T[:3, 3])[:, 2].min(), abs=1e-12)


@need_g1
def test_the_g1s_sole_corners_are_its_four_foot_spheres() -> None:
    tree = mjkin.load(G1)
    corners, radius = sole_corners(*foot_points(tree, "left_ankle_roll_link"))
    np.testing.assert_allclose(np.sort(corners[:, 0]), [-0.06, -0.06, 0.13, 0.13])
    np.testing.assert_allclose(radius, 0.001)


def foot_geoms(model: mujoco.MjModel, bodies: tuple[str, ...]) -> list[int]:
    ids = [model.body(b).id for b in bodies]
    return [g for g in range(model.ngeom) if model.geom_bodyid[g] in ids and model.geom_contype[g]]


def gaps(model: mujoco.MjModel, q: np.ndarray, feet: list[int], ground: list[int]) -> np.ndarray:
    """MuJoCo's own signed distance ``(F, len(feet))`` of each foot geom to the nearest ground geom, every frame."""
    data = mujoco.MjData(model)
    out = np.empty((len(q), len(feet)))
    for f, qf in enumerate(q):
        data.qpos[:] = qf
        mujoco.mj_kinematics(model, data)
        out[f] = [min(mujoco.mj_geomDistance(model, data, a, b, 1.0, None) for b in ground) for a in feet]
    return out


@need_g1
def test_the_g1s_sole_spheres_stay_out_of_the_flat_floor() -> None:
    # the issue: placed by their sole points, the G1's sole geoms went 8.3 mm below the floor on the shared walk
    tree = mjkin.load(G1)
    traj = mjkin.retarget(WALK, tree)
    rep = report(tree, traj)
    assert rep["terrain_penetration"] <= PENETRATION and rep["floor_min"] >= -PENETRATION
    feet = foot_geoms(tree.model, ("left_ankle_roll_link", "right_ankle_roll_link"))
    low = np.empty((len(traj.q), len(feet)))
    data = mujoco.MjData(tree.model)
    for f, q in enumerate(traj.q):  # MuJoCo's own poses of the spheres
        data.qpos[:] = q
        mujoco.mj_kinematics(tree.model, data)
        low[f] = data.geom_xpos[feet, 2] - tree.model.geom_size[feet, 0]
    assert low.min() >= -PENETRATION
    assert rep["floor_min"] == pytest.approx(low.min(), abs=1e-6)  # the report measures what MuJoCo places
    contact = np.array(traj.meta["retarget"]["contact"])
    planted = np.concatenate([low[contact[i], 4 * i:4 * i + 4].min(axis=1) for i in range(2)])
    assert planted.max() <= FLOAT and rep["planted_float_max"] <= FLOAT


# ------------------------------------------------------------------------------------------------ a walk on it
@pytest.fixture(scope="module")
def on_the_ramp(primate: mjkin.Tree, scene_file: Path) -> tuple[mjkin.motion.Trajectory, mjkin.motion.Trajectory]:
    return mjkin.retarget(WALK, primate, scene=scene_file), mjkin.retarget(WALK, primate)


@need_walk
def test_a_flat_walk_goes_up_the_ramp_onto_the_step(primate: mjkin.Tree, on_the_ramp: tuple) -> None:
    traj, flat = on_the_ramp
    path = bundled_models()["primate"]
    merged = mujoco.MjModel.from_xml_string(path.read_text().replace("<worldbody>", "<worldbody>" + ground_geoms(),
                                                                      1))
    ground = [merged.geom(n).id for n in ("floor", "ramp", "step")]
    gap = gaps(merged, traj.q, foot_geoms(merged, ("left_foot", "right_foot")), ground)  # MuJoCo's distances
    contact = np.array(traj.meta["retarget"]["contact"]).T  # (F, 2)
    assert gap.min() >= -PENETRATION  # no foot goes more than 5 mm into the floor, the ramp or the step
    assert gap[contact].max() <= FLOAT  # nor floats more than 15 mm above it while planted
    rep = report(primate, traj)
    assert rep["terrain_penetration"] <= PENETRATION and rep["planted_float_max"] <= FLOAT
    assert rep["terrain_penetration"] == pytest.approx(max(0.0, -gap.min()), abs=2e-3)
    assert rep["keypoint_error_median"] <= 0.03 and rep["skate_per_contact_max"] <= 0.01
    # the feet stood on all three: the right on the step, the left on the ramp
    right = primate.pose(traj.q, "right_foot", "body")[:, :3, 3]
    left = primate.pose(traj.q, "left_foot", "body")[:, :3, 3]
    assert (right[contact[:, 1], 0] > STEP[0]).any() and (left[contact[:, 0], 0] > RAMP[0] + 0.2).any()
    # the pelvis rose with the ground under the feet, and came down again
    rise = primate.pose(traj.q, "lower_torso", "body")[:, 2, 3] - primate.pose(flat.q, "lower_torso", "body")[:, 2, 3]
    both_up = contact[:, 1] & (right[:, 0] > STEP[0]) & contact[:, 0] & (left[:, 0] > RAMP[0] + 0.2)
    assert both_up.sum() >= 5 and rise[both_up].min() > 0.06 and abs(rise[-1]) < 0.03


@need_walk
def test_a_planted_foot_lies_on_the_slope(primate: mjkin.Tree, scene_file: Path) -> None:
    targets = plan(bvh.read(WALK), primate, terrain=Terrain.load(scene_file))
    feet, contact, heel = targets.feet[0], targets.contact[0], targets.heel[0]
    on_ramp = contact & heel & (feet[:, 0, 3] > RAMP[0] + 0.2) & (feet[:, 0, 3] < RAMP[1] - 0.2)
    assert on_ramp.sum() >= 5
    toes = feet[on_ramp, :3, 0]  # the foot's x axis lies in the ramp's plane, whichever way the foot points
    np.testing.assert_allclose(toes @ [-np.sin(ANGLE), 0.0, np.cos(ANGLE)], 0.0, atol=1e-9)
    assert np.abs(toes[:, 2]).min() > np.sin(np.radians(3.0))  # so it is pitched, not level
    flat = plan(bvh.read(WALK), primate)
    assert np.abs(flat.feet[0][flat.contact[0] & flat.heel[0], 2, 0]).max() < 1e-9  # on the floor: level


@need_walk
def test_a_scene_given_as_text_is_measured_when_given_again(primate: mjkin.Tree) -> None:
    clip = bvh.read(WALK)
    traj = mjkin.retarget(replace(clip, values=clip.values[:12]), primate, scene=Terrain.load(SCENE))
    with pytest.raises(InputError, match="as XML text"):
        report(primate, traj)
    assert report(primate, traj, terrain=Terrain.load(SCENE))["terrain_penetration"] <= PENETRATION


def test_no_ground_under_a_planted_foot_is_one_line(primate: mjkin.Tree) -> None:
    from test_retarget import crouch_bvh

    far = '<mujoco><worldbody><geom type="box" size="0.5 0.5 0.1" pos="5 5 0"/></worldbody></mujoco>'
    with pytest.raises(InputError, match="no ground under the left foot at frame 0") as e:
        mjkin.retarget(bvh.parse(crouch_bvh(4)), primate, scene=Terrain.load(far))
    assert "\n" not in str(e.value)


# ------------------------------------------------------------------------------------------------ drawn on it
def test_the_painter_draws_the_scene_instead_of_the_models_floor(primate: mjkin.Tree, scene_file: Path) -> None:
    ground = Terrain.load(scene_file)
    drawn = render.terrain_geoms(ground)
    assert sorted(np.round(g[1][2], 3) for g in drawn) == [0.05, 0.06]  # the ramp and the step; the floor: checker
    q = primate.qpos0
    with render.Painter(primate, 160, 120, terrain=ground) as painter:
        cam = painter.camera(None, q[None])
        image = painter.draw(q, cam)
        geoms = [painter.renderer.scene.geoms[i] for i in range(painter.renderer.scene.ngeom)]
        floor = primate.model.geom("floor").id
        assert not any(g.objtype == mujoco.mjtObj.mjOBJ_GEOM and g.objid == floor for g in geoms)
        assert sum(g.category == mujoco.mjtCatBit.mjCAT_STATIC for g in geoms) == 2
        assert painter.floor is not None and painter.floor.z == 0.0
    with render.Painter(primate, 160, 120) as plain:
        assert np.abs(plain.draw(q, cam).astype(int) - image).sum() > 0


@need_walk
def test_command_line_scene(tmp_path: Path, scene_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "ramp.png"
    assert run(["retarget", str(WALK), "--model", "primate", "--scene", str(scene_file), "-o", str(out), "--frame",
                "30", "--width", "160", "--height", "90", "--report"]) == 0
    assert out.stat().st_size > 0 and '"terrain_penetration"' in capsys.readouterr().out
    assert run(["retarget", str(WALK), "--model", "primate", "--scene", str(tmp_path / "none.xml")]) == 2
    err = capsys.readouterr().err.strip()
    assert "scene file not found" in err and "\n" not in err
