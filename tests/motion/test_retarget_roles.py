"""Retargeting roles found from a figure's tree and names: Menagerie-style humanoids written here (Booster T1,
Apptronik Apollo, Fourier N1 and Unitree H1 in their bodies, joints and proportions, mesh geoms left out), the G1
without a table, a missing arm, mapping files from --print-mapping, and the clip names of Mixamo/LAFAN1/AMASS."""

from __future__ import annotations

import json
from itertools import permutations
from pathlib import Path

import mujoco
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_retarget import G1, MOCAP, crouch_bvh

import mjkin
from mjkin.apps.cli import run
from mjkin.errors import InputError
from mjkin.motion import bvh
from mjkin.motion.retarget import report
from mjkin.motion.roles import (
    FIGURE_ROLES,
    figure_mapping,
    find_figure,
    pelvis_lean,
    read_mapping,
    role_offsets,
    source_mapping,
)

SIDE = {"left": {"side": "left", "Side": "Left", "s": "l", "Y": "", "N": "-"},
        "right": {"side": "right", "Side": "Right", "s": "r", "Y": "-", "N": ""}}
KEYPOINT_MEDIAN = 0.03  # m: the crouch's hands, feet and head relative to the pelvis, as the primate's shared clips


def both(template: str) -> str:
    """``template`` for the left and the right side: {side} left, {Side} Left, {s} l; {Y} '' or '-' and {N} '-'
    or '' mirror y."""
    return "".join(template.format(**SIDE[s]) for s in ("left", "right"))


def mjcf(name: str, body: str, geom: str = "", extra: str = "") -> str:
    return (f'<mujoco model="{name}"><compiler angle="radian" autolimits="true" boundmass="0.01" boundinertia="1e-5"/>'
            f'<default><joint range="-2.6 2.6"/><geom {geom}/></default><worldbody>{body}</worldbody>{extra}</mujoco>')


def load(xml: str) -> mjkin.Tree:
    return mjkin.load(mujoco.MjModel.from_xml_string(xml))


# Booster T1: the root is the trunk (torso) with the arms; the legs hang from a yawing Waist; arms in a T-pose named
# AL1..AL3 (their joints say Left_Shoulder_Pitch ...), Left_Elbow_Pitch twisting the upper arm, Left_Elbow_Yaw the
# elbow of left_hand_link (the last body: the wrist is its far end); the hip is pitch, roll, yaw in three bodies.
T1 = mjcf("t1_like", """
<body name="Trunk" pos="0 0 0.7"><freejoint/><geom type="box" size="0.075 0.1 0.15" pos="0.06 0 0.12"/>
 <body name="H1" pos="0.0625 0 0.243"><joint name="AAHead_yaw" axis="0 0 1"/><geom size="0.02"/>
  <body name="H2" pos="0 0 0.06185"><joint name="Head_pitch" axis="0 1 0"/><geom size="0.08" pos="0.01 0 0.11"/>
 </body></body>""" + both("""
 <body name="A{s}1" pos="0.0575 {Y}0.1063 0.219"><joint name="{Side}_Shoulder_Pitch" axis="0 1 0"/>
  <geom size="0.02"/>
  <body name="A{s}2" pos="0 {Y}0.047 0"><joint name="{Side}_Shoulder_Roll" axis="1 0 0"/><geom size="0.02"/>
   <body name="A{s}3" pos="0.00025 {Y}0.0605 0"><joint name="{Side}_Elbow_Pitch" axis="0 1 0"/>
    <geom type="cylinder" size="0.03 0.075" pos="0 {Y}0.05 0" quat="0.707105 0.707108 0 0"/>
    <body name="{side}_hand_link" pos="0 {Y}0.1471 0"><joint name="{Side}_Elbow_Yaw" axis="0 0 1"/>
     <inertial pos="0 {Y}0.109573 0" mass="0.33" diaginertia="0.008 0.008 0.0002"/>
     <geom type="cylinder" size="0.03 0.0875" pos="0 {Y}0.13 0" quat="0.707105 0.707108 0 0"/>
 </body></body></body></body>""") + """
 <body name="Waist" pos="0.0625 0 -0.1155"><joint name="Waist" axis="0 0 1"/><geom size="0.02"/>""" + both("""
  <body name="Hip_Pitch_{Side}" pos="0 {Y}0.106 0"><joint name="{Side}_Hip_Pitch" axis="0 1 0"/>
   <body name="Hip_Roll_{Side}" pos="0 0 -0.02"><joint name="{Side}_Hip_Roll" axis="1 0 0"/>
    <body name="Hip_Yaw_{Side}" pos="0 0 -0.081854"><joint name="{Side}_Hip_Yaw" axis="0 0 1"/>
     <geom type="cylinder" size="0.05 0.08"/>
     <body name="Shank_{Side}" pos="-0.014 0 -0.134"><joint name="{Side}_Knee_Pitch" axis="0 1 0" range="0 2.34"/>
      <geom type="cylinder" size="0.05 0.075" pos="0 0 -0.12"/>
      <body name="Ankle_Cross_{Side}" pos="0 0 -0.28"><joint name="{Side}_Ankle_Pitch" axis="0 1 0"/>
       <body name="{side}_foot_link" pos="0 {Y}0.00025 -0.012"><joint name="{Side}_Ankle_Roll" axis="1 0 0"/>
        <geom type="box" size="0.1115 0.05 0.015" pos="0.01 0 -0.015"/>
 </body></body></body></body></body></body>""") + "</body></body>")

# Apptronik Apollo: base_link is the pelvis; the torso yaws, rolls and pitches in three bodies; the head is a
# neck_yaw/roll/pitch chain; l_/r_ prefixes; hips ie/aa/fe in three bodies at one point; a wrist of three joints
# past a forearm that twists (l_wrist_roll); the sole on l_foot_link past l_ankle_ie_link.
APOLLO = mjcf("apollo_like", """
<body name="base_link" pos="0 0 1.0813"><freejoint name="floating_base"/>
 <geom type="capsule" size="0.1 0.09" pos="-0.06 0 -0.08" quat="0.707388 0.706825 0 0"/>
 <body name="torso_oak_d_pro_w_front_frame_link" pos="0.087 0 0.048"/>
 <body name="torso_roll_link" pos="0.03 0 0.03125"><joint name="torso_yaw" axis="0 0 -1" range="-0.83 0.83"/>
  <body name="torso_pitch_link"><joint name="torso_roll" axis="1 0 0" range="-0.21 0.21"/>
   <body name="torso_link"><joint name="torso_pitch" axis="0 1 0" range="-0.305 1.35"/>
    <geom type="capsule" size="0.16 0.05" pos="-0.045 0 0.2"/>
    <body name="neck_yaw_link" pos="-0.03 0 0.328"><joint name="neck_yaw" axis="0 0 1"/>
     <body name="neck_roll_link" pos="-0.025 0 0.2"><joint name="neck_roll" axis="1 0 0"/>
      <body name="neck_pitch_link"><joint name="neck_pitch" axis="0 1 0"/><geom size="0.1" pos="0.04 0 0"/>
    </body></body></body>""" + both("""
    <body name="{s}_shoulder_aa_link" pos="-0.05 {Y}0.2 0.32"><joint name="{s}_shoulder_aa" axis="1 0 0"/>
     <body name="{s}_shoulder_ie_link"><joint name="{s}_shoulder_ie" axis="0 0 1"/>
      <body name="{s}_shoulder_fe_link" pos="0.0105 {Y}0.039 0"><joint name="{s}_shoulder_fe" axis="0 1 0"/>
       <geom type="capsule" size="0.055 0.14" pos="-0.005 {Y}0.01 -0.16"/>
       <body name="{s}_elbow_fe_link" pos="0.025 0 -0.315"><joint name="{s}_elbow_fe" axis="0 1 0"/>
        <body name="{s}_wrist_roll_link" pos="-0.04 0 -0.06"><joint name="{s}_wrist_roll" axis="0 0 1"/>
         <geom type="capsule" size="0.0475 0.1076" pos="0 0 -0.1"/>
         <body name="{s}_wrist_yaw_link" pos="0.025 0 -0.2"><joint name="{s}_wrist_yaw" axis="1 0 0"/>
          <body name="{s}_wrist_pitch_link"><joint name="{s}_wrist_pitch" axis="0 1 0"/>
           <geom type="box" size="0.041 0.02 0.083" pos="0.0075 0 -0.112"/>
    </body></body></body></body></body></body></body>""") + "</body></body></body>" + both("""
 <body name="{s}_hip_ie_link" pos="-0.02 {Y}0.11 -0.16875"><joint name="{s}_hip_ie" axis="0 0 1"/>
  <body name="{s}_hip_aa_link"><joint name="{s}_hip_aa" axis="1 0 0"/>
   <body name="{s}_hip_fe_link"><joint name="{s}_hip_fe" axis="0 1 0"/>
    <geom type="capsule" size="0.105 0.1" pos="0 0 -0.215"/>
    <body name="{s}_knee_fe_link" pos="-0.05 0 -0.425"><joint name="{s}_knee_fe" axis="0 1 0" range="0 2.6"/>
     <geom type="capsule" size="0.071 0.15" pos="0.0476 0 -0.19"/>
     <body name="{s}_ankle_ie_link" pos="0.05 0 -0.425"><joint name="{s}_ankle_ie" axis="1 0 0"/>
      <body name="{s}_foot_link"><joint name="{s}_ankle_pd" axis="0 1 0"/>
       <geom type="box" size="0.1 0.0425 0.009" pos="0.0647 0 -0.0384"/>
 </body></body></body></body></body></body>""") + "</body>", geom='contype="0" conaffinity="0"')  # as Apollo's

# Fourier N1: thigh_pitch/roll/yaw bodies with hip_*_joint joints, shank_pitch, foot_roll then foot_pitch (the
# sole); the torso_link is welded on a yawing waist and carries a head sphere and a camera link, no head body; the
# hand_yaw_link twists (wrist_yaw_joint) before a welded end effector.
N1 = mjcf("n1_like", """
<body name="base_link" pos="0 0 0.7"><freejoint name="base_free_joint"/>
 <geom type="cylinder" size="0.065 0.0675" pos="0 0 -0.05" quat="0.707388 0.706825 0 0"/>""" + both("""
 <body name="{side}_thigh_pitch_link" pos="0 {Y}0.050453 -0.067365"><joint name="{side}_hip_pitch_joint" axis="0 1 0"/>
  <body name="{side}_thigh_roll_link" pos="0 {Y}0.072 0"><joint name="{side}_hip_roll_joint" axis="1 0 0"/>
   <geom type="cylinder" size="0.0415 0.06" quat="0.707388 0 0.706825 0"/>
   <body name="{side}_thigh_yaw_link" pos="0 0 -0.0815"><joint name="{side}_hip_yaw_joint" axis="0 0 1"/>
    <geom type="cylinder" size="0.06 0.095" pos="0 0 -0.08"/>
    <body name="{side}_shank_pitch_link" pos="0 0 -0.2075">
     <joint name="{side}_knee_pitch_joint" axis="0 1 0" range="-0.0872 2.356"/>
     <geom type="cylinder" size="0.04 0.1" pos="0 0 -0.12"/>
     <body name="{side}_foot_roll_link" pos="0 0 -0.28"><joint name="{side}_ankle_roll_joint" axis="1 0 0"/>
      <body name="{side}_foot_pitch_link"><joint name="{side}_ankle_pitch_joint" axis="0 1 0"/>
       <geom type="box" size="0.1 0.04 0.015" pos="0.03 0 -0.035"/>
 </body></body></body></body></body></body>""") + """
 <body name="imu_link" pos="0 0 -0.1472"><site name="imu_sensor"/></body>
 <body name="waist_yaw_link" pos="0 0 0.0256"><joint name="waist_yaw_joint" axis="0 0 1"/>
  <geom type="cylinder" size="0.06 0.0275" pos="0 0 0.04"/>
  <body name="torso_link" pos="0 0 0.2598">
   <geom type="cylinder" size="0.1 0.11" pos="0 0 -0.06"/><geom size="0.08" pos="0 0 0.19"/>
   <body name="camera_link" pos="0.071343 -0.0048077 0.17959"/>""" + both("""
   <body name="{side}_upper_arm_pitch_link" pos="0 {Y}0.09765 0">
    <joint name="{side}_shoulder_pitch_joint" axis="0 1 0"/>
    <body name="{side}_upper_arm_roll_link" pos="0 {Y}0.078 0"><joint name="{side}_shoulder_roll_joint" axis="1 0 0"/>
     <geom size="0.032"/>
     <body name="{side}_upper_arm_yaw_link" pos="0 0 -0.1005"><joint name="{side}_shoulder_yaw_joint" axis="0 0 1"/>
      <geom type="cylinder" size="0.032 0.06"/>
      <body name="{side}_lower_arm_pitch_link" pos="0 0 -0.1095"><joint name="{side}_elbow_pitch_joint" axis="0 1 0"/>
       <body name="{side}_hand_yaw_link" pos="0 0 -0.1005"><joint name="{side}_wrist_yaw_joint" axis="0 0 1"/>
        <geom type="cylinder" size="0.032 0.06"/>
        <body name="{side}_end_effector_link" pos="0 0 -0.1045"><geom size="0.02751"/>
   </body></body></body></body></body></body>""") + "</body></body></body>")


def h1(left_arm: bool = True) -> str:
    """Unitree H1 (its collision geoms): hips yaw, roll, pitch in three bodies; no wrist or head bodies, the head a
    torso geom; ``left_arm=False`` leaves only the left shoulder's first motor."""
    arm = """
   <body name="{side}_shoulder_pitch_link" pos="0.0055 {Y}0.15535 0.42999" quat="0.976296 {Y}0.216438 0 0">
    <joint name="{side}_shoulder_pitch" axis="0 1 0"/>"""
    rest = """
    <body name="{side}_shoulder_roll_link" pos="-0.0055 {Y}0.0565 -0.0165" quat="0.976296 {N}0.216438 0 0">
     <joint name="{side}_shoulder_roll" axis="1 0 0"/>
     <geom type="capsule" size="0.04" fromto="0 {Y}0.01 0.008 0 {N}0.07 -0.02"/>
     <body name="{side}_shoulder_yaw_link" pos="0 0 -0.1343"><joint name="{side}_shoulder_yaw" axis="0 0 1"/>
      <geom type="capsule" size="0.03" fromto="0 0 0.15 0 0 -0.2"/>
      <body name="{side}_elbow_link" pos="0.0185 0 -0.198"><joint name="{side}_elbow" axis="0 1 0"/>
       <inertial pos="0.15908 0 -0.015776" mass="0.669" diaginertia="0.006 0.006 0.0004"/>
       <geom type="capsule" size="0.025" fromto="0 0 0 0.28 0 -0.015"/><geom size="0.033" pos="0.28 0 -0.015"/>
    </body></body></body>"""
    arms = (arm + ("" if s == "left" and not left_arm else rest) + "</body>" for s in SIDE)
    return mjcf("h1_like" if left_arm else "h1_one_arm", """
<body name="pelvis" pos="0 0 1.06"><freejoint/><geom size="0.05"/>""" + both("""
 <body name="{side}_hip_yaw_link" pos="0 {Y}0.0875 -0.1742"><joint name="{side}_hip_yaw" axis="0 0 1"/>
  <geom type="cylinder" size="0.06 0.035" pos="-0.067 0 0" quat="0.707123 0 0.70709 0"/>
  <body name="{side}_hip_roll_link" pos="0.039468 0 0"><joint name="{side}_hip_roll" axis="1 0 0"/>
   <geom type="cylinder" size="0.05 0.03" quat="1 1 0 0" pos="0 {N}0.02 0"/>
   <body name="{side}_hip_pitch_link" pos="0 {Y}0.11536 0"><joint name="{side}_hip_pitch" axis="0 1 0"/>
    <geom type="capsule" size="0.03" fromto="0.02 0 -0.4 -0.02 0 0.02"/>
    <body name="{side}_knee_link" pos="0 0 -0.4"><joint name="{side}_knee" axis="0 1 0" range="-0.26 2.05"/>
     <geom type="capsule" size="0.025" fromto="0.02 0 -0.4 0.02 0 0"/><geom size="0.05" pos="0 0 -0.115"/>
     <body name="{side}_ankle_link" pos="0 0 -0.4"><joint name="{side}_ankle" axis="0 1 0" range="-0.87 0.52"/>
      <geom type="capsule" size="0.014" fromto="-0.035 0 -0.056 0.02 0 -0.045"/>
      <geom type="capsule" size="0.014" fromto="0.02 0 -0.045 0.115 0 -0.056"/>
      <geom type="capsule" size="0.014" fromto="0.14 -0.03 -0.056 0.14 0.03 -0.056"/>
 </body></body></body></body></body>""") + """
 <body name="torso_link"><joint name="torso" axis="0 0 1"/>
  <geom name="head" type="capsule" size="0.06" fromto="0.05 0 0.68 0.05 0 0.6"/>
  <geom name="helmet" size="0.073" pos="0.045 0 0.68"/>
  <geom name="torso" type="box" size="0.07 0.1 0.22" pos="0 0 0.25"/>
  """ + "".join(a.format(**SIDE[s]) for a, s in zip(arms, SIDE, strict=True)) + "</body></body>", extra="<contact>"
        + (both('<exclude body1="torso_link" body2="{side}_shoulder_roll_link"/>') if left_arm else "") + "</contact>")


def side_roles(**parts: str) -> dict[str, str]:
    """Both sides' roles from templates: hip="{s}_hip_aa_link" -> left_hip: l_hip_aa_link, right_hip: r_hip_..."""
    return {f"{s}_{p}": name.format(**SIDE[s]) for s in SIDE for p, name in parts.items()}


EXPECTED = {
    "t1": (T1, {"pelvis": "Waist", "torso": "Trunk", "head": "H2"} | side_roles(
        hip="Hip_Roll_{Side}", knee="Shank_{Side}", ankle="{side}_foot_link", shoulder="A{s}2",
        elbow="{side}_hand_link", wrist="{side}_hand_link")),
    "apollo": (APOLLO, {"pelvis": "base_link", "torso": "torso_link", "head": "neck_pitch_link"} | side_roles(
        hip="{s}_hip_ie_link", knee="{s}_knee_fe_link", ankle="{s}_foot_link", shoulder="{s}_shoulder_aa_link",
        elbow="{s}_elbow_fe_link", wrist="{s}_wrist_yaw_link")),
    "n1": (N1, {"pelvis": "base_link", "torso": "torso_link", "head": "torso_link"} | side_roles(
        hip="{side}_thigh_roll_link", knee="{side}_shank_pitch_link", ankle="{side}_foot_pitch_link",
        shoulder="{side}_upper_arm_roll_link", elbow="{side}_lower_arm_pitch_link", wrist="{side}_hand_yaw_link")),
    "h1": (h1(), {"pelvis": "pelvis", "torso": "torso_link", "head": "torso_link"} | side_roles(
        hip="{side}_hip_roll_link", knee="{side}_knee_link", ankle="{side}_ankle_link",
        shoulder="{side}_shoulder_roll_link", elbow="{side}_elbow_link", wrist="{side}_elbow_link")),
}


@pytest.fixture(scope="module", params=sorted(EXPECTED))
def robot(request: pytest.FixtureRequest) -> tuple[str, mjkin.Tree, dict[str, str]]:
    xml, roles = EXPECTED[request.param]
    return request.param, load(xml), roles


def test_roles_of_menagerie_style_humanoids(robot: tuple[str, mjkin.Tree, dict[str, str]]) -> None:
    name, tree, expected = robot
    found = find_figure(tree)
    assert found.missing == () and found.bodies == expected
    assert figure_mapping(tree) == expected


def test_points_lean_and_retarget_on_menagerie_style_humanoids(robot: tuple[str, mjkin.Tree, dict[str, str]]) -> None:
    name, tree, bodies = robot
    offsets = role_offsets(tree, bodies)
    T = {r: tree.pose(tree.qpos0, b, "body") for r, b in bodies.items()}
    point = {r: T[r][:3, :3] @ offsets[r] + T[r][:3, 3] for r in bodies}
    shoulders = 0.5 * (point["left_shoulder"] + point["right_shoulder"])
    assert point["head"][2] > shoulders[2] + 0.05  # a head above the shoulders, with or without a head body
    for s in ("left", "right"):  # hands past the elbows, feet below the knees below the hips
        assert np.linalg.norm(point[f"{s}_wrist"] - point[f"{s}_elbow"]) > 0.1
        assert point[f"{s}_ankle"][2] < point[f"{s}_knee"][2] - 0.15 < point[f"{s}_hip"][2] - 0.3
    if name == "h1":  # no head body: the helmet geom's centre; no wrist body: the forearm's far end
        np.testing.assert_allclose(offsets["head"], [0.045, 0, 0.68])
        assert 0.28 < offsets["left_wrist"][0] < 0.32
    assert pelvis_lean(tree, bodies) == (0.5 if name == "apollo" else 1.0)  # only Apollo's torso pitches
    clip = bvh.parse(crouch_bvh(12), "crouch.bvh")
    traj = mjkin.retarget(clip, tree, clearance=None)  # the roles' doing only: the H1's hands hang into its wide
    rep = report(tree, traj)  # thighs, which a clearance between its geoms keeps them off (tested with the clearance)
    assert np.isfinite(traj.q).all() and traj.meta["retarget"]["bodies"] == bodies
    assert rep["keypoint_error_median"] < KEYPOINT_MEDIAN and rep["limits"] is None
    assert rep["skate_per_contact_max"] < 5e-3 and rep["floor_min"] > -5e-3


# ------------------------------------------------------------------ generated humanoids (hypothesis)
AXIS = {"pitch": np.array([0.0, 1.0, 0.0]), "roll": np.array([1.0, 0.0, 0.0]), "yaw": np.array([0.0, 0.0, -1.0])}
STYLES = {  # how a robot names the body of a side's part ("hip_pitch"); None: numbered, sides only by geometry
    "snake": lambda side, part: f"{side}_{part}_link",
    "prefix": lambda side, part: f"{side[0]}_{part}",
    "suffix": lambda side, part: "_".join(w.title() for w in part.split("_")) + f"_{side.title()}",
    "camel": lambda side, part: side[0].upper() + "".join(w.title() for w in part.split("_")),
    "plain": None,
}


def xyz(v: np.ndarray) -> str:
    return " ".join(f"{x:.6g}" for x in v)


def generated(style: str, hip: tuple[str, ...], shoulder: tuple[str, ...], d: tuple[float, float],
              legs: tuple[float, float], arms: tuple[float, float], extras: bool) -> tuple[str, dict[str, str]]:
    """A humanoid whose hips and shoulders are three bodies turning about axes in the order ``hip`` (``shoulder``),
    the second ``d[0]`` along the first's axis, the third ``d[1]`` along its own: the three axes meet at the second
    body's origin, the joint centre. Thighs and shins ``legs``, upper arms and forearms ``arms`` long (m);
    ``extras``: a clavicle joint before each shoulder and, when named so, a toe joint past each foot.
    Also the roles it should get."""
    label, numbers = STYLES[style], iter(range(1000))

    def name(side: str, part: str) -> str:
        return f"b{next(numbers)}" if label is None else label(side, part)

    def limb(side: str, top: str, at: tuple[float, float, float], order: tuple[str, ...],
             parts: tuple[str, str], lengths: tuple[float, float], end: str) -> tuple[str, list[str]]:
        mirror = np.array([1.0, 1.0 if side == "left" else -1.0, 1.0])
        bodies = [name(side, f"{top}_{kind}") for kind in order] + [name(side, p) for p in parts]
        offsets = [np.array(at), d[0] * AXIS[order[0]] * mirror, d[1] * AXIS[order[2]] * mirror]
        xml = "".join(f'<body name="{b}" pos="{xyz(o)}"><joint name="{b}_j" axis="{xyz(AXIS[k])}"/>'
                      for b, o, k in zip(bodies, offsets, order, strict=False))
        knee = -offsets[2] - [0.0, 0.0, lengths[0]]  # from the third body: the joint centre, then down
        xml += (f'<geom type="capsule" size="0.03" fromto="{xyz(-offsets[2])} {xyz(knee)}"/>'
                f'<body name="{bodies[3]}" pos="{xyz(knee)}"><joint name="{bodies[3]}_j" axis="0 1 0"/>'
                f'<geom type="capsule" size="0.025" fromto="0 0 0 0 0 {-lengths[1]}"/>'
                f'<body name="{bodies[4]}" pos="0 0 {-lengths[1]}"><joint name="{bodies[4]}_j" axis="0 1 0"/>{end}')
        return xml + "</body>" * 5, bodies

    pelvis, torso, neck = ("b900", "b901", "b902") if label is None else ("pelvis", "torso_link", "neck_link")
    xml = f'<body name="{pelvis}" pos="0 0 1.2"><freejoint/><geom type="box" size="0.08 0.12 0.06"/>'
    roles = {"pelvis": pelvis, "torso": torso, "head": neck}
    for side in SIDE:
        foot = name(side, "ankle_roll")
        toe = (f'<body name="{name(side, "toe")}" pos="0.1 0 -0.04"><joint axis="0 1 0"/><geom type="box" '
               'size="0.03 0.04 0.015" pos="0.03 0 0"/></body>') if extras and label else ""
        leg, bodies = limb(side, "hip", (0.0, 0.09 if side == "left" else -0.09, -0.08), hip, ("knee", "ankle_pitch"),
                           legs, f'<body name="{foot}" pos="0 0 -0.02"><joint name="{foot}_j" axis="1 0 0"/>'
                           f'<geom type="box" size="0.07 0.04 0.015" pos="0 0 -0.04"/>{toe}</body>')
        xml += leg
        roles |= {f"{side}_hip": bodies[1], f"{side}_knee": bodies[3], f"{side}_ankle": foot}
    xml += (f'<body name="{torso}" pos="0 0 0.1"><joint name="{torso}_j" axis="0 0 1"/><geom type="box" '
            f'size="0.08 0.12 0.15" pos="0 0 0.15"/><body name="{neck}" pos="0 0 0.4"><joint name="{neck}_j" '
            'axis="0 0 1"/><geom size="0.09" pos="0 0 0.1"/></body>')
    for side in SIDE:
        y = 1.0 if side == "left" else -1.0
        arm, bodies = limb(side, "shoulder", (0.0, 0.11 * y, 0.02) if extras else (0.0, 0.17 * y, 0.35), shoulder,
                           ("elbow", "wrist"), arms, '<geom type="box" size="0.03 0.02 0.05" pos="0 0 -0.06"/>')
        clavicle = name(side, "clavicle")
        xml += (f'<body name="{clavicle}" pos="0 {0.06 * y} 0.33"><joint name="{clavicle}_j" axis="1 0 0"/>{arm}'
                '</body>') if extras else arm
        roles |= {f"{side}_shoulder": bodies[1], f"{side}_elbow": bodies[3], f"{side}_wrist": bodies[4]}
    return mjcf("generated", xml + "</body></body>"), roles


@given(style=st.sampled_from(sorted(STYLES)), hip=st.sampled_from(list(permutations(AXIS))),
       shoulder=st.sampled_from(list(permutations(AXIS))), d=st.tuples(*[st.floats(0.02, 0.08)] * 2),
       legs=st.tuples(*[st.floats(0.3, 0.45)] * 2), arms=st.tuples(*[st.floats(0.22, 0.32)] * 2), extras=st.booleans())
def test_hips_and_shoulders_map_to_the_joint_centre_whatever_the_order_and_names(
        style: str, hip: tuple[str, ...], shoulder: tuple[str, ...], d: tuple[float, float],
        legs: tuple[float, float], arms: tuple[float, float], extras: bool) -> None:
    xml, expected = generated(style, hip, shoulder, d, legs, arms, extras)
    found = find_figure(load(xml))
    assert found.missing == () and found.bodies == expected


# ------------------------------------------------------------------ the G1, a missing arm, mapping files, clip names
G1_ROLES = {"pelvis": "pelvis", "torso": "torso_link", "head": "torso_link"} | side_roles(
    hip="{side}_hip_roll_link", knee="{side}_knee_link", ankle="{side}_ankle_roll_link",
    shoulder="{side}_shoulder_roll_link", elbow="{side}_elbow_pitch_link", wrist="{side}_elbow_roll_link")
G1_TABLE = G1_ROLES | side_roles(wrist="{side}_zero_link")  # the G1's former table of body names (by model name)


@pytest.mark.skipif(not G1.is_file() or not MOCAP.is_dir(), reason="the shared G1 or clips are not here")
def test_the_g1_maps_by_its_tree_under_any_model_name() -> None:
    xml = G1.read_text().replace('<mujoco model="g1"', '<mujoco model="some_humanoid"')
    assert 'model="some_humanoid"' in xml
    tree = load(xml)
    assert find_figure(tree).bodies == G1_ROLES  # the hip at its joint centre: the middle of three bodies
    offsets = role_offsets(tree, G1_ROLES)
    assert 0.35 < offsets["head"][2] < 0.5  # no head body: above the torso in proportion to the shoulders
    assert 0.17 < offsets["left_wrist"][0] < 0.21  # the wrist body holds the fingers: where they attach
    assert pelvis_lean(tree, G1_ROLES) == 1.0  # the torso only yaws: the pelvis takes the whole lean
    found = report(tree, mjkin.retarget(MOCAP / "mixamo_freebvh.bvh", tree))
    table = report(tree, mjkin.retarget(MOCAP / "mixamo_freebvh.bvh", tree, {"figure": G1_TABLE}))
    assert found["keypoint_error_median"] <= table["keypoint_error_median"] and found["limits"] is None


def test_a_missing_arm_is_one_line_naming_roles_and_bodies(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    tree = load(h1(left_arm=False))
    found = find_figure(tree)
    assert found.missing == ("left_shoulder", "left_elbow", "left_wrist")
    assert found.candidates[0] == "left_shoulder_pitch_link"  # the missing side's first
    clip = bvh.parse(crouch_bvh(4), "crouch.bvh")
    with pytest.raises(InputError, match="cannot find the retargeting roles left_shoulder, left_elbow, left_wrist "
                                         r"of model 'h1_one_arm' \(bodies that might fit: left_shoulder_pitch_link\)"
                       ) as e:
        mjkin.retarget(clip, tree)
    assert "\n" not in str(e.value)
    (tmp_path / "one_arm.xml").write_text(h1(left_arm=False))
    (tmp_path / "crouch.bvh").write_text(crouch_bvh(4))
    args = ["retarget", str(tmp_path / "crouch.bvh"), "--model", str(tmp_path / "one_arm.xml")]
    assert run(args) == 2 and "left_shoulder, left_elbow, left_wrist" in capsys.readouterr().err
    assert run([*args, "--print-mapping", str(tmp_path / "map.json")]) == 0  # what was found, to fill in
    assert "figure: left_shoulder, figure: left_elbow, figure: left_wrist" in capsys.readouterr().err
    doc = read_mapping(tmp_path / "map.json")
    assert set(doc["figure"]) == set(FIGURE_ROLES) - {"left_shoulder", "left_elbow", "left_wrist"}
    doc["figure"] |= dict.fromkeys(("left_shoulder", "left_elbow", "left_wrist"), "left_shoulder_pitch_link")
    assert figure_mapping(tree, doc["figure"])["left_wrist"] == "left_shoulder_pitch_link"  # filled in: it maps


def test_print_mapping_writes_what_reproduces_the_retarget(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "n1.xml").write_text(N1)
    (tmp_path / "crouch.bvh").write_text(crouch_bvh(8))
    args = ["retarget", str(tmp_path / "crouch.bvh"), "--model", str(tmp_path / "n1.xml")]
    assert run([*args, "--print-mapping", str(tmp_path / "map.json"), "-o", str(tmp_path / "x.json")]) == 0
    assert not (tmp_path / "x.json").exists()  # nothing solved
    doc = read_mapping(tmp_path / "map.json")
    assert doc["figure"] == EXPECTED["n1"][1] and doc["source"]["left_knee"] == "LeftKnee"
    capsys.readouterr()
    assert run([*args, "--print-mapping"]) == 0 and json.loads(capsys.readouterr().out) == doc  # printed
    tree, clip = load(N1), bvh.parse(crouch_bvh(8), "crouch.bvh")
    found, given = mjkin.retarget(clip, tree), mjkin.retarget(clip, tree, tmp_path / "map.json")
    np.testing.assert_array_equal(given.q, found.q)
    doc["figure"]["head"] = "camera_link"  # the file is what counts: a role changed there changes the retarget
    (tmp_path / "map.json").write_text(json.dumps(doc))
    assert mjkin.retarget(clip, tree, tmp_path / "map.json").meta["retarget"]["bodies"]["head"] == "camera_link"
    doc["figure"]["elbow"] = "x"
    (tmp_path / "map.json").write_text(json.dumps(doc))
    assert run([*args, "--mapping", str(tmp_path / "map.json")]) == 2
    assert "unknown figure role 'elbow'" in capsys.readouterr().err


def lafan1_bvh() -> str:
    """One frame of a LAFAN1/AMASS-named rig: Spine..Spine2, a LeftShoulder collar above LeftArm, LeftToe."""
    def j(name: str, offset: str, inside: str = "") -> str:
        return f"JOINT {name}\n{{\nOFFSET {offset}\nCHANNELS 3 Zrotation Yrotation Xrotation\n{inside}}}\n"
    side = "".join(j(f"{S}UpLeg", f"{x} -5 0", j(f"{S}Leg", "0 -42 0", j(f"{S}Foot", "0 -42 0", j(
        f"{S}Toe", "0 -7 14")))) for S, x in (("Left", 9), ("Right", -9)))
    arms = "".join(j(f"{S}Shoulder", f"{x} 20 0", j(f"{S}Arm", f"{x} 0 0", j(f"{S}ForeArm", "0 -28 0", j(
        f"{S}Hand", "0 -26 0")))) for S, x in (("Left", 8), ("Right", -8)))
    spine = j("Spine", "0 8 0", j("Spine1", "0 10 0", j("Spine2", "0 10 0", arms + j("Neck", "0 12 0", j(
        "Head", "0 8 0")))))
    head = "HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition Zrotation " \
           "Yrotation Xrotation\n" + side + spine + "}\n"
    n = head.count("CHANNELS 3") * 3 + 6
    return head + "MOTION\nFrames: 1\nFrame Time: 0.0333333\n" + " ".join(["0"] * n) + "\n"


def test_lafan1_and_amass_joint_names_map() -> None:
    clip = bvh.parse(lafan1_bvh(), "lafan1.bvh")
    roles = {r: clip.names[i] for r, i in source_mapping(clip).items()}
    assert roles == {"pelvis": "Hips", "head": "Head", "neck": "Neck"} | {
        f"{s}_{p}": f"{S}{j}" for s, S in (("left", "Left"), ("right", "Right")) for p, j in (
            ("hip", "UpLeg"), ("knee", "Leg"), ("ankle", "Foot"), ("toe", "Toe"), ("shoulder", "Arm"),
            ("elbow", "ForeArm"), ("wrist", "Hand"))}


GMR_G1 = G1.parents[1] / "gmr_unitree_g1" / "g1_mocap_29dof.xml"


@pytest.mark.skipif(not GMR_G1.is_file(), reason="GMR's G1 (../shared/models/gmr_unitree_g1) is not here")
def test_a_long_hand_mesh_does_not_make_the_wrist_the_elbow() -> None:
    """GMR's G1: its hand mesh reaches 0.2 m past the wrist, which made the wrist pitch the arm's middle joint (the
    shoulder mapped to the elbow link, the elbow to the wrist)."""
    bodies = find_figure(mjkin.load(GMR_G1)).bodies
    for side in ("left", "right"):
        assert (bodies[f"{side}_shoulder"], bodies[f"{side}_elbow"], bodies[f"{side}_wrist"]) == (
            f"{side}_shoulder_roll_link", f"{side}_elbow_link", f"{side}_wrist_pitch_link")


def primate_spec(turn: np.ndarray | None = None, root_frame: np.ndarray | None = None,
                 short_sides: bool = False) -> mujoco.MjSpec:
    """The bundled primate, its world geometry as it is but: the whole figure turned by the quaternion ``turn``;
    its root body's frame turned by ``root_frame`` (its children, geoms and sites put back where they were, as CMU's
    humanoid has its root's y up); sides named by a bare first letter (``lthigh``/``rthigh``, as CMU's rig)."""
    text = Path(mjkin.kinematics.tree.bundled_models()["primate"]).read_text()
    if short_sides:
        text = text.replace('"left_', '"l').replace('"right_', '"r')
    spec = mujoco.MjSpec.from_string(text)
    root = spec.body("lower_torso")
    if root_frame is not None:
        back = mjkin.spatial.quat_conj(root_frame)
        for e in [*root.bodies, *root.geoms, *root.sites]:
            e.pos = mjkin.spatial.quat_rotate(back, e.pos)
            e.quat = mjkin.spatial.quat_mul(back, e.quat)
        root.quat = mjkin.spatial.quat_mul(root_frame, root.quat)
    if turn is not None:
        root.quat = mjkin.spatial.quat_mul(turn, root.quat)
        root.pos = mjkin.spatial.quat_rotate(turn, root.pos)
    return spec


def test_a_root_frame_with_y_up_and_one_letter_sides_keep_the_roles() -> None:
    """CMU's humanoid (dm_control's suite, 62 dofs) has its root's y up and its sides named by a first letter
    (``lfemur``, ``rfemur``): before, every body was taken for the left (sides from the root's y) and the right arm
    was not found. The primate made so keeps its roles, and retargets as the primate does."""
    spec = primate_spec(root_frame=mjkin.spatial.quat_from_axis_angle([1.0, 0.0, 0.0], np.pi / 2), short_sides=True)
    tree = mjkin.load(spec)
    primate = mjkin.load("primate")
    assert np.allclose(tree.fk(tree.qpos0)[1:, :3, 3], primate.fk(primate.qpos0)[1:, :3, 3])  # the same figure
    short = {r: b.replace("left_", "l").replace("right_", "r") for r, b in find_figure(primate).bodies.items()}
    assert find_figure(tree).bodies == short
    clip_ = bvh.parse(crouch_bvh(frames=12))
    a, b = mjkin.retarget(clip_, tree), mjkin.retarget(clip_, primate)
    assert np.allclose(a.meta["retarget"]["errors"], b.meta["retarget"]["errors"], atol=1e-3)


def test_a_figure_facing_another_way_moves_as_it_faces() -> None:
    """A figure built facing +y (the primate turned a quarter about z) gets the clip turned to face as it does: the
    same motion turned, key points as near. Before, the source faced +x whatever the figure did."""
    turn = mjkin.spatial.quat_from_axis_angle([0.0, 0.0, 1.0], np.pi / 2)
    tree = mjkin.load(primate_spec(turn=turn))
    primate = mjkin.load("primate")
    clip_ = bvh.parse(crouch_bvh(frames=12))
    a, b = mjkin.retarget(clip_, tree), mjkin.retarget(clip_, primate)
    assert np.allclose(a.meta["retarget"]["errors"], b.meta["retarget"]["errors"], atol=1e-3)
    pelvis = tree.id("lower_torso", "body")
    R = mjkin.spatial.quat_to_mat(turn)
    assert np.allclose(tree.fk(a.q)[:, pelvis, :3, 3], primate.fk(b.q)[:, pelvis, :3, 3] @ R.T, atol=1e-3)
