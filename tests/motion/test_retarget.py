"""Retargeting BVH onto the primate (and the G1): role mapping by names, planted feet, floor, limits, speeds;
a crouch written here (feet fixed by construction), the shared clips, the command line."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from test_retarget_quality import resample

import mjkin
from mjkin.apps.bench.report import shared_models_dir
from mjkin.apps.bench.retarget import mocap_dir
from mjkin.apps.cli import run
from mjkin.errors import InputError
from mjkin.goals import HalfSpace
from mjkin.motion import Trajectory, bvh
from mjkin.motion.retarget import MAX_FRAMES, plan, report, source_mapping

MOCAP = mocap_dir() or Path("../shared/mocap")  # found as the benchmarks find them (also from a worktree)
G1 = (shared_models_dir() or Path("../shared/models")) / "unitree_g1" / "g1.xml"
need_mocap = pytest.mark.skipif(not MOCAP.is_dir(), reason=f"the shared clips are not here ({MOCAP})")

THIGH = SHIN = 42.0  # cm


def joint(name: str, offset: tuple[float, float, float], children: str = "", end: tuple | None = None,
          channels: str = "3 Zrotation Xrotation Yrotation") -> str:
    tail = f"End Site\n{{\nOFFSET {end[0]} {end[1]} {end[2]}\n}}\n" if end else ""
    return f"JOINT {name}\n{{\nOFFSET {offset[0]} {offset[1]} {offset[2]}\nCHANNELS {channels}\n{children}{tail}}}\n"


def crouch_bvh(frames: int = 24, names: dict[str, str] | None = None, prefix: str = "", collar: bool = False,
               tiptoe: float = 0.0) -> str:
    """A 19-joint-style rig (cm, y up, facing +z) bending its knees by up to 60 degrees, feet fixed by construction.

    ``names`` renames the limb joints ({S} = Left/Right), ``prefix`` goes before every name, ``collar`` adds a
    collarbone named {S}Shoulder above each arm (as Mixamo has), ``tiptoe`` turns the feet toes down by that many
    degrees (63.4 points the toes straight down).
    """
    n = {"hip": "{S}Hip", "knee": "{S}Knee", "ankle": "{S}Ankle", "sh": "{S}Shoulder", "el": "{S}Elbow",
         "wr": "{S}Wrist", **(names or {})}
    legs = arms = ""
    for side, x in (("Left", 9.0), ("Right", -9.0)):
        def nm(k: str, side: str = side) -> str:
            return prefix + n[k].replace("{S}", side)
        legs += joint(nm("hip"), (x, -5, 0), joint(nm("knee"), (0, -THIGH, 0), joint(
            nm("ankle"), (0, -SHIN, 0), end=(0, -7, 14))))
        arm = joint(nm("sh"), (2 * x, 25, 0), joint(nm("el"), (0, -28, 0), joint(nm("wr"), (0, -26, 0),
                                                                                     end=(0, -8, 0))))
        arms += joint(f"{prefix}{side}Shoulder", (0, 0, 0), arm) if collar else arm
    head = joint(prefix + "Neck", (0, 30, 0), joint(prefix + "Head", (0, 8, 0), end=(0, 18, 0)))
    chest = joint(prefix + "Chest", (0, 12, 0), arms + head)
    hierarchy = (f"HIERARCHY\nROOT {prefix}Hips\n{{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition "
                 f"Zrotation Xrotation Yrotation\n{chest}{legs}}}\n")
    rig = bvh.parse(hierarchy + "MOTION\nFrames: 1\nFrame Time: 1\n" + "0 " * 200)
    lines = []
    for f in range(frames):
        a = np.rad2deg(np.deg2rad(30.0) * np.sin(np.pi * f / (frames - 1)))  # thigh pitch; the knee bends 2a
        hips_y = 5 + 7 + (THIGH + SHIN) * np.cos(np.deg2rad(a))
        pitch = {n["hip"]: -a, n["knee"]: 2 * a, n["ankle"]: tiptoe - a}  # +X pitches a leg forward (toward +z)
        row = [0.0, hips_y, 0.0, 0.0, 0.0, 0.0]
        for name, chans in zip(rig.names[1:], rig.channels[1:], strict=True):
            generic = name[len(prefix):].replace("Left", "{S}").replace("Right", "{S}")
            row += [pitch.get(generic, 0.0) if c == "xrotation" else 0.0 for c in chans]
        lines.append(" ".join(f"{v:.9f}" for v in row))
    return hierarchy + f"MOTION\nFrames: {frames}\nFrame Time: 0.0333333\n" + "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def primate() -> mjkin.Tree:
    return mjkin.load("primate")


def test_crouch_keeps_the_feet_planted(primate: mjkin.Tree) -> None:
    clip = bvh.parse(crouch_bvh(), "crouch.bvh")
    p = clip.positions()
    assert np.ptp(p[:, clip.index("LeftAnkle")], axis=0).max() < 1e-4  # the source's feet stay (cm)
    traj = mjkin.retarget(clip, primate)
    assert traj.q.shape == (clip.frames, primate.nq) and np.allclose(np.diff(traj.times), clip.frame_time)
    contact = np.array(traj.meta["retarget"]["contact"])
    assert contact.all()  # both feet down throughout
    rep = report(primate, traj)
    assert rep["skate_per_contact_max"] < 2e-3 and rep["floor_min"] > -5e-3 and rep["limits"] is None
    assert rep["speed_limit_ratio"] <= 1 + 1e-9
    pelvis = primate.pose(traj.q, "lower_torso", "body")[:, 2, 3]
    assert pelvis[len(pelvis) // 2] < pelvis[0] - 0.05  # it crouches


def test_feet_keep_their_heading_when_the_toes_point_down_and_back(primate: mjkin.Tree) -> None:
    # toes 10 degrees past straight down (a Mixamo toe-off): a frame built across world up flipped the foot's
    # heading by 180 degrees (the hip's yaw jumped); across the shin it stays (the shin leans forward > 10 degrees)
    clip = bvh.parse(crouch_bvh(tiptoe=73.4))
    p = clip.positions()
    toe = p[:, clip.index("LeftAnkle_End")] - p[:, clip.index("LeftAnkle")]
    assert np.all(toe[:, 2] < 0) and np.all(toe[:, 1] < -0.95 * np.linalg.norm(toe, axis=-1))  # down and back
    shin = p[:, clip.index("LeftKnee")] - p[:, clip.index("LeftAnkle")]
    leaning = np.degrees(np.arctan2(shin[:, 2], shin[:, 1])) > 15
    R = plan(clip, primate).rotations["left_ankle"]
    assert leaning.sum() > 10 and np.all(R[leaning, 1, 1] > 0.9)  # the foot's y axis stays to the figure's left


def test_extra_goals_join_every_frame(primate: mjkin.Tree) -> None:
    clip = bvh.parse(crouch_bvh(12), "crouch.bvh")
    plain = mjkin.retarget(clip, primate)
    hand = primate.pose(plain.q, "left_hand", "site")[:, 2, 3]
    wall = hand.max() + 0.1  # the left hand kept above this height, hard (priority 0 outranks the body)
    traj = mjkin.retarget(clip, primate, extra_goals=[HalfSpace("left_hand", point=(0, 0, wall), normal=(0, 0, 1))])
    assert np.all(primate.pose(traj.q, "left_hand", "site")[:, 2, 3] > wall - 1e-3)
    rep = report(primate, traj)
    assert rep["skate_per_contact_max"] < 2e-3 and rep["floor_min"] > -5e-3 and rep["limits"] is None


def test_speed_limit_holds_inside_the_solve(primate: mjkin.Tree) -> None:
    clip = bvh.parse(crouch_bvh(20), "crouch.bvh")
    free = report(primate, mjkin.retarget(clip, primate))
    slow = free["speed_max"] / 2  # half the speed the clip asks for: the StepLimit binds
    traj = mjkin.retarget(clip, primate, max_speed=slow)
    rep = report(primate, traj)
    assert 0.99 < rep["speed_limit_ratio"] <= 1 + 1e-9
    assert rep["floor_min"] > -5e-3 and rep["limits"] is None


def test_clearance_keeps_the_figure_off_itself(primate: mjkin.Tree) -> None:
    clip = bvh.parse(crouch_bvh(12), "crouch.bvh")
    traj = mjkin.retarget(clip, primate, clearance=0.0)
    rep = report(primate, traj)
    assert rep["self_contact_frames"] == 0 and rep["limits"] is None and rep["skate_per_contact_max"] < 2e-3


def test_a_given_scale_sets_the_root_path_in_metres(primate: mjkin.Tree) -> None:
    # metres per BVH unit: the crouch's hips drop (cm) becomes the figure's pelvis drop in metres, scale times it;
    # without a scale the root path is fitted to the figure's legs (the units cancel)
    clip = bvh.parse(crouch_bvh(12), "crouch.bvh")
    hips = clip.positions()[:, clip.index("Hips"), 1]
    drop_cm = hips[0] - hips.min()
    drops = {}
    for scale in (0.01, 0.005):
        pelvis = plan(clip, primate, scale=scale).points["pelvis"]
        np.testing.assert_allclose(pelvis - pelvis[0], np.c_[0 * hips, 0 * hips, scale * (hips - hips[0])],
                                   atol=1e-12)
        traj = mjkin.retarget(clip, primate, scale=scale)
        rep = report(primate, traj)
        assert rep["metres_per_unit"] == scale and rep["root_ratio"] == 1.0
        z = primate.pose(traj.q, "lower_torso", "body")[:, 2, 3]
        drops[scale] = z[0] - z.min()
    assert drops[0.01] == pytest.approx(0.01 * drop_cm, abs=3e-3)  # the source's 11 cm
    assert 0.45 < drops[0.005] / drops[0.01] < 0.6  # half the pelvis target; the knees' bend pulls it a little lower
    fitted = report(primate, mjkin.retarget(clip, primate))
    assert fitted["metres_per_unit"] == 0.01 and fitted["root_ratio"] != 1.0  # centimetres, from the height


def test_roles_by_names_of_the_common_rigs() -> None:
    clip19 = bvh.parse(crouch_bvh(2))
    roles = source_mapping(clip19)
    assert clip19.names[roles["left_shoulder"]] == "LeftShoulder" and clip19.names[roles["left_hip"]] == "LeftHip"
    assert clip19.names[roles["left_toe"]] == "LeftAnkle_End"
    cmu = bvh.parse(crouch_bvh(2, {"hip": "{S}UpLeg", "knee": "{S}Leg", "ankle": "{S}Foot", "sh": "{S}Arm",
                                   "el": "{S}ForeArm", "wr": "{S}Hand"}))
    roles = source_mapping(cmu)
    assert cmu.names[roles["right_knee"]] == "RightLeg" and cmu.names[roles["left_shoulder"]] == "LeftArm"
    # Mixamo: the same names in a namespace, and LeftShoulder is the collarbone above LeftArm
    clip = bvh.parse(crouch_bvh(2, {"hip": "{S}UpLeg", "knee": "{S}Leg", "ankle": "{S}Foot", "sh": "{S}Arm",
                                    "el": "{S}ForeArm", "wr": "{S}Hand"}, prefix="mixamorig:", collar=True))
    roles = source_mapping(clip)
    assert clip.names[roles["left_shoulder"]] == "mixamorig:LeftArm" and clip.names[roles["pelvis"]] == "mixamorig:Hips"


def test_unmappable_rig_is_one_line(primate: mjkin.Tree) -> None:
    clip = bvh.parse(crouch_bvh(2, {"knee": "{S}Shin_Bone", "wr": "{S}Paw"}), "odd.bvh")
    with pytest.raises(InputError, match="cannot map left_knee, left_wrist, right_knee, right_wrist") as e:
        mjkin.retarget(clip, primate)
    assert "\n" not in str(e.value)
    mapping = {"source": {f"{s}_knee": f"{S}Shin_Bone" for s, S in (("left", "Left"), ("right", "Right"))}
               | {f"{s}_wrist": f"{S}Paw" for s, S in (("left", "Left"), ("right", "Right"))}}
    assert mjkin.retarget(clip, primate, mapping).q.shape == (2, primate.nq)


@need_mocap
@pytest.mark.parametrize("clip", ["mixamo_freebvh", "mocapbank_19joint"])
def test_shared_clips_on_the_primate(primate: mjkin.Tree, clip: str) -> None:
    traj = mjkin.retarget(MOCAP / f"{clip}.bvh", primate)
    rep = report(primate, traj)
    assert rep["contact_frames"] > 0
    assert rep["skate_per_frame_mean"] <= 2e-3 and rep["skate_per_contact_max"] <= 0.01
    assert rep["floor_min"] >= -5e-3 and rep["limits"] is None and rep["speed_limit_ratio"] <= 1 + 1e-9
    assert rep["keypoint_error_median"] <= 0.03


@need_mocap
def test_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "walk.json"
    assert run(["retarget", str(MOCAP / "mixamo_freebvh.bvh"), "--model", "primate", "-o", str(out), "--report",
                "--retime"]) == 0
    printed = capsys.readouterr().out
    assert "frames of" in printed and json.loads(printed[printed.index("{"):])["frames"] == 69
    traj = Trajectory.load(out, mjkin.load("primate"))
    assert traj.q.shape[0] == 69 and traj.meta["retime"]["duration"] > 0
    bad = tmp_path / "map.json"
    bad.write_text('{"source": {"elbow": "X"}}')
    assert run(["retarget", str(MOCAP / "mixamo_freebvh.bvh"), "--model", "primate", "--mapping", str(bad)]) == 2
    assert "unknown role 'elbow'" in capsys.readouterr().err


def test_a_clip_of_over_max_frames_is_refused_before_any_work(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """A 1e6-frame clip (13 MB of BVH) raised MemoryError while its targets were laid out."""
    hierarchy = crouch_bvh(2).split("MOTION")[0].replace("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 0")
    path = tmp_path / "long.bvh"
    frames = MAX_FRAMES + 1
    path.write_text(hierarchy + f"MOTION\nFrames: {frames}\nFrame Time: 0.0083333\n" + "0 96 0 0 0 0\n" * frames)
    monkeypatch.setattr("mjkin.motion.retarget.plan", lambda *a, **k: pytest.fail("planned before the check"))
    told = f"clip {str(path)!r} has {frames:,} frames; mjkin retargets at most {MAX_FRAMES:,} frames of a clip"
    with pytest.raises(InputError, match="^" + re.escape(told)):
        mjkin.retarget(path, mjkin.load("primate"))
    assert run(["retarget", str(path), "--model", "primate", "-o", str(tmp_path / "long.json")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"mjkin: error: {told}") and err.count("\n") == 1
    [row] = mjkin.retarget_many([path], "primate", tmp_path / "out")
    assert row["status"].startswith(told)


@need_mocap
def test_command_line_scale_moves_the_root_proportionally(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    travel, said = {}, {}
    for scale in ("0.01", "0.005"):
        out = tmp_path / f"walk{scale}.json"
        # at half the clip's metres per unit the key points miss by 58 cm at the 95th percentile: failed (exit 3),
        # the file still written
        assert run(["retarget", str(MOCAP / "mixamo_freebvh.bvh"), "--model", "primate", "-o", str(out), "--scale",
                    scale, "--report"]) == (0 if scale == "0.01" else 3)
        printed = capsys.readouterr().out
        said[scale] = json.loads(printed[printed.index("{"):])
        assert f"{scale} m per BVH unit" in printed
        travel[scale] = np.ptp(Trajectory.load(out, mjkin.load("primate")).q[:, 0])  # the root's x range, m
    assert said["0.01"]["metres_per_unit"] == 0.01 and said["0.005"]["metres_per_unit"] == 0.005
    assert said["0.01"]["root_ratio"] == said["0.005"]["root_ratio"] == 1.0
    assert 0.8 < travel["0.01"] < 1.1  # the clip's hips range over 94 cm forward
    assert travel["0.005"] / travel["0.01"] == pytest.approx(0.5, abs=0.03)


@need_mocap
@pytest.mark.skipif(not G1.is_file(), reason=f"the G1 is not here ({G1})")
def test_walk_on_the_g1() -> None:
    g1 = mjkin.load(G1)
    traj = mjkin.retarget(MOCAP / "mixamo_freebvh.bvh", g1)
    rep = report(g1, traj)
    assert rep["limits"] is None and rep["speed_limit_ratio"] <= 1 + 1e-9
    assert rep["skate_per_frame_mean"] <= 2e-3


@need_mocap
def test_a_lifted_foot_eases_in_over_the_same_seconds_at_120_hz(primate: mjkin.Tree) -> None:
    # the ease after a lift-off is EASE_S seconds at any rate: counted in frames (6) it took 0.05 s at 120 Hz, the
    # feet's targets then stood up to 14 cm from the 30 Hz ones at the same instants and the toes skated 3.5 mm
    clip = bvh.read(MOCAP / "mixamo_freebvh.bvh")
    fast = resample(clip, 4 * clip.fps)
    slow_feet, fast_feet = plan(clip, primate).feet[..., :3, 3], plan(fast, primate).feet[:, ::4, :3, 3]
    apart = np.linalg.norm(fast_feet - slow_feet, axis=-1)
    assert np.median(apart) < 1e-3 and apart.max() < 0.02  # measured: 0.46 mm and 8.4 mm (contacts one frame off)
    slow, quick = (report(primate, mjkin.retarget(c, primate)) for c in (clip, fast))
    assert quick["skate_per_contact_max"] <= slow["skate_per_contact_max"] + 2e-3  # measured: 1.35 mm against 0.05
