"""AMASS / SMPL-H / SMPL-X input: a synthetic body model and clip written here, checked against a BVH of the same
motion (joint positions, retargeted q), the Euler channels, one-line errors; LAFAN1 names found by role."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tracemalloc
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

import mjkin
from conftest import no_hang
from mjkin import spatial
from mjkin.apps.cli import run
from mjkin.errors import InputError, MjkinIOError
from mjkin.motion import bvh, smpl
from mjkin.motion.clips import CLIP_SUFFIXES, read_clip
from mjkin.motion.retarget import Z_UP, source_mapping

ROUND_TRIP = 1e-12  # Euler channels against the rotation they came from
SAME = 1e-9  # joint positions of the .npz clip against the BVH of the same motion (m)

# rest joints (m, y up, facing +z, left on +x) of a human-sized body: the left side and the middle
BODY = {"Hips": (0.0, 0.93, 0.0), "LeftUpLeg": (0.09, 0.85, 0.0), "Spine": (0.0, 1.05, -0.01),
        "LeftLeg": (0.1, 0.48, 0.0), "Spine1": (0.0, 1.18, 0.0), "LeftFoot": (0.11, 0.08, -0.03),
        "Spine2": (0.0, 1.24, 0.02), "LeftToeBase": (0.12, 0.02, 0.1), "Neck": (0.0, 1.45, -0.01),
        "LeftShoulder": (0.07, 1.37, 0.0), "Head": (0.0, 1.55, 0.03), "LeftArm": (0.18, 1.4, -0.01),
        "LeftForeArm": (0.44, 1.39, -0.03), "LeftHand": (0.7, 1.39, -0.02), "LeftFingers": (0.79, 1.39, -0.02),
        "Jaw": (0.0, 1.52, 0.06), "LeftEye": (0.03, 1.62, 0.08)}
FINGERS = ("Index", "Middle", "Pinky", "Ring", "Thumb")


def rest_joint(name: str) -> tuple[float, float, float]:
    """Where joint ``name`` of :data:`smpl.SKELETONS` stands at rest in the synthetic body."""
    side = name.removeprefix("Left").removeprefix("Right")
    mirror = -1.0 if name.startswith("Right") else 1.0
    if side.startswith("Hand") and side[-1].isdigit():  # finger n, segment k: out along x from the wrist
        n, k = FINGERS.index(side[4:-1]), int(side[-1])
        x, y, z = BODY["LeftHand"][0] + 0.06 + 0.03 * k, BODY["LeftHand"][1], BODY["LeftHand"][2] + 0.02 * (n - 2)
    else:
        x, y, z = BODY[name if name in BODY else "Left" + side]
    return mirror * x, y, z


def write_body_model(path: Path, joints: int = 52, shapes: int = 16, seed: int = 0) -> Path:
    """An ``.npz`` in the SMPL file layout: 3 vertices a joint (and 5 more) regressed to the joints above."""
    rng = np.random.default_rng(seed)
    _, names, parents = smpl.SKELETONS[joints]
    want = np.array([rest_joint(n) for n in names])
    V = 3 * joints + 5
    regressor = np.zeros((joints, V))
    for j in range(joints):
        w = rng.uniform(0.2, 1.0, 3)
        regressor[j, 3 * j:3 * j + 3] = w / w.sum()
    template = rng.normal(scale=0.05, size=(V, 3))
    template[: 3 * joints] += np.repeat(want - regressor @ template, 3, axis=0)  # the regressed rest joints: want
    kintree = np.array([parents, range(joints)], dtype=np.int64).astype(np.uint32)  # the root's parent: 2**32 - 1
    np.savez(path, J_regressor=regressor, v_template=template, shapedirs=rng.normal(scale=0.01, size=(V, 3, shapes)),
             kintree_table=kintree, f=np.zeros((1, 3), dtype=np.uint32))
    return path


def shaped_rest(model: Path, betas: np.ndarray, used: int) -> np.ndarray:
    """Rest joints ``(J, 3)`` by SMPL's definition, with the first ``used`` betas."""
    m = np.load(model)
    return m["J_regressor"] @ (m["v_template"] + m["shapedirs"][:, :, :used] @ betas[:used])


def motion(joints: int, frames: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """BVH-side motion: intrinsic XYZ Euler angles ``(F, J, 3)`` in degrees, root positions ``(F, 3)`` (m, y up)."""
    rng = np.random.default_rng(seed)
    u = np.linspace(0.0, 1.0, frames)[:, None, None]
    angles = rng.uniform(-10.0, 10.0, (joints, 3)) + u * rng.uniform(-10.0, 10.0, (joints, 3))  # a smooth sway
    angles[:, 0, 1] += 20.0 * u[:, 0, 0]  # the root turns about the vertical as it goes
    root = np.stack([0.1 * u[:, 0, 0], 0.93 - 0.02 * u[:, 0, 0], 0.3 * u[:, 0, 0]], axis=1)
    return angles, root


def bvh_text(names: tuple[str, ...], parents: tuple[int, ...], offsets: np.ndarray, angles: np.ndarray,
             root: np.ndarray, frame_time: float, six: bool = False) -> str:
    """A BVH of the skeleton: every joint ``Xrotation Yrotation Zrotation``, the root also its position (with
    ``six`` every joint, its offset repeated in the frames, as LAFAN1 has it). Joints are listed depth first."""
    children: dict[int, list[int]] = {}
    for j, p in enumerate(parents):
        children.setdefault(p, []).append(j)
    order: list[int] = []

    def joint(j: int, depth: int) -> str:
        order.append(j)
        pad = "  " * depth
        chans = "6 Xposition Yposition Zposition" if j == 0 or six else "3"
        head = f"{pad}{'ROOT' if j == 0 else 'JOINT'} {names[j]}\n{pad}{{\n"
        body = f"{pad}  OFFSET {' '.join(f'{v:.17g}' for v in offsets[j])}\n"
        body += f"{pad}  CHANNELS {chans} Xrotation Yrotation Zrotation\n"
        return head + body + "".join(joint(c, depth + 1) for c in children.get(j, [])) + f"{pad}}}\n"

    hierarchy = joint(0, 0)
    F = len(root)
    moving = np.concatenate([np.broadcast_to(offsets, (F, len(names), 3)), angles], axis=2) if six else angles
    rows = [" ".join(f"{v:.17g}" for v in (*root[f], *angles[f, 0], *moving[f, order[1:]].ravel())) for f in range(F)]
    return (f"HIERARCHY\n{hierarchy}MOTION\nFrames: {len(root)}\nFrame Time: {frame_time!r}\n"
            + "\n".join(rows) + "\n")


def write_clip(path: Path, angles: np.ndarray, root: np.ndarray, rest: np.ndarray) -> Path:
    """The AMASS ``.npz`` (30 fps) of the BVH motion ``angles``, ``root``: the same turns, in AMASS's z-up world."""
    F, J, _ = angles.shape
    R = Rotation.from_euler("XYZ", angles.reshape(-1, 3), degrees=True).as_matrix().reshape(F, J, 3, 3)
    R[:, 0] = Z_UP @ R[:, 0]  # the world turned z-up, as retarget turns a BVH's
    poses = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(F, 3 * J)
    np.savez(path, poses=poses, trans=root @ Z_UP.T - rest[0], betas=np.linspace(-1.0, 1.0, 16),
             mocap_framerate=np.array(30.0), gender=np.array("neutral"))
    return path


@pytest.fixture(scope="module")
def primate() -> mjkin.Tree:
    return mjkin.load("primate")


@dataclass(frozen=True)
class Same:
    """An SMPL-H clip (6 frames) with its body model, and the BVH of the same motion, read and as files."""

    clip: bvh.Clip
    ref: bvh.Clip
    npz: Path
    bvh: Path
    model: Path


@pytest.fixture
def same(tmp_path: Path) -> Same:
    model = write_body_model(tmp_path / "model.npz")
    rest = shaped_rest(model, np.linspace(-1.0, 1.0, 16), 16)
    _, names, parents = smpl.SKELETONS[52]
    angles, root = motion(52, 6)
    npz = write_clip(tmp_path / "walk.npz", angles, root, rest)
    offsets = rest - np.vstack([np.zeros(3), rest[list(parents[1:])]])
    (tmp_path / "walk.bvh").write_text(bvh_text(names, parents, offsets, angles, root, 1 / 30))
    return Same(smpl.read(npz, model), bvh.read(tmp_path / "walk.bvh"), npz, tmp_path / "walk.bvh", model)


def test_joint_positions_match_the_bvh_of_the_same_motion(same: Same) -> None:
    clip, ref = same.clip, same.ref
    assert clip.names == smpl.SKELETONS[52][1] and sorted(clip.names) == sorted(ref.names)
    order = [ref.index(n) for n in clip.names]  # the BVH lists its joints depth first
    assert [clip.names[p] if p >= 0 else None for p in clip.parents] == \
        [ref.names[ref.parents[j]] if ref.parents[j] >= 0 else None for j in order]
    assert clip.frames == 6 and clip.frame_time == pytest.approx(1 / 30, rel=1e-12)
    np.testing.assert_allclose(clip.positions(), ref.positions()[:, order], rtol=0, atol=SAME)
    np.testing.assert_allclose(clip.positions(rest=True), ref.positions(rest=True)[:, order], rtol=0, atol=SAME)


def test_retargeted_q_matches_the_bvh_of_the_same_motion(same: Same, primate: mjkin.Tree) -> None:
    from_npz = mjkin.retarget(same.npz, primate, body_model=same.model)
    from_bvh = mjkin.retarget(same.bvh, primate)
    assert from_npz.meta["retarget"]["metres_per_unit"] == 1.0  # metres, from the height
    np.testing.assert_allclose(from_npz.q, from_bvh.q, rtol=0, atol=1e-9)  # measured: 2e-13
    np.testing.assert_allclose(from_npz.times, from_bvh.times, rtol=0, atol=1e-12)


def test_an_amass_body_standing_in_its_z_up_world_stands_in_the_clip(tmp_path: Path, primate: mjkin.Tree) -> None:
    model = write_body_model(tmp_path / "model.npz", joints=55, shapes=20)
    poses = np.zeros((3, 165))
    poses[:, 0] = np.pi / 2  # AMASS's standing root: the model's y-up body turned +90 degrees about x
    np.savez(tmp_path / "stand.npz", poses=poses, trans=np.zeros((3, 3)), betas=np.zeros(16),
             mocap_frame_rate=np.array(60.0))
    clip = smpl.read(tmp_path / "stand.npz", model)
    p = clip.positions()[0]
    up = p[clip.index("Head")] - p[clip.index("LeftToeBase")]
    assert up[1] > 1.4 and np.hypot(up[0], up[2]) < 0.2  # up the clip's y
    assert clip.fps == 60.0 and clip.names[22:25] == ("Jaw", "LeftEye", "RightEye")
    traj = mjkin.retarget(tmp_path / "stand.npz", primate, body_model=model)
    head, feet = (primate.pose(traj.q[0], b, "body")[2, 3] for b in ("head", "left_foot"))
    assert head > feet + 1.0  # the figure stands up too


@pytest.mark.parametrize(("joints", "shapes", "used"), [(52, 10, 10), (52, 16, 16), (55, 20, 10), (55, 400, 16),
                                                       (24, 10, 10)])
def test_betas_shape_the_skeleton_as_far_as_the_model_has_shapes(tmp_path: Path, joints: int, shapes: int,
                                                                 used: int) -> None:
    # AMASS gives 16 betas; SMPL-X's shapedirs end in expression directions (from column 10 or 300), never used
    model = write_body_model(tmp_path / "model.npz", joints, shapes)
    rest = shaped_rest(model, np.linspace(-1.0, 1.0, 16), used)
    clip = smpl.read(write_clip(tmp_path / "c.npz", *motion(joints, 2), rest), model)
    np.testing.assert_allclose(clip.positions(rest=True)[0], rest, rtol=0, atol=1e-12)


def test_roles_found_by_name(same: Same) -> None:
    clip = same.clip
    roles = {r: clip.names[j] for r, j in source_mapping(clip).items()}
    assert roles == {"pelvis": "Hips", "head": "Head", "neck": "Neck", "left_hip": "LeftUpLeg", "left_knee": "LeftLeg",
                     "left_ankle": "LeftFoot", "left_toe": "LeftToeBase", "left_shoulder": "LeftArm",
                     "left_elbow": "LeftForeArm", "left_wrist": "LeftHand", "right_hip": "RightUpLeg",
                     "right_knee": "RightLeg", "right_ankle": "RightFoot", "right_toe": "RightToeBase",
                     "right_shoulder": "RightArm", "right_elbow": "RightForeArm", "right_wrist": "RightHand"}


def test_lafan1_names_are_found_by_role(primate: mjkin.Tree) -> None:
    # LAFAN1's 22 joints: Mixamo's body names with LeftToe for the toe, 6 channels on every joint, centimetres
    _, names, parents = smpl.SKELETONS[24]
    names, parents = names[:22], parents[:22]
    lafan = tuple(n.replace("ToeBase", "Toe") for n in names)
    rest = 100 * np.array([rest_joint(n) for n in names])
    offsets = rest - np.vstack([np.zeros(3), rest[list(parents[1:])]])
    angles, root = motion(22, 4)
    clip = bvh.parse(bvh_text(lafan, parents, offsets, angles, 100 * root, 1 / 30, six=True), "lafan.bvh")
    assert all(len(c) == 6 for c in clip.channels)
    roles = {r: clip.names[j] for r, j in source_mapping(clip).items()}
    assert roles["left_toe"] == "LeftToe" and roles["right_toe"] == "RightToe"
    assert roles["left_shoulder"] == "LeftArm" and roles["left_ankle"] == "LeftFoot" and roles["neck"] == "Neck"
    assert roles["left_knee"] == "LeftLeg" and roles["left_hip"] == "LeftUpLeg" and roles["pelvis"] == "Hips"
    assert mjkin.retarget(clip, primate).meta["retarget"]["metres_per_unit"] == 0.01


rotvecs = arrays(np.float64, 3, elements=st.floats(-7.0, 7.0, allow_nan=False))


@given(rotvecs)
@example(np.array([0.0, np.pi / 2, 0.0]))  # gimbal lock of ZYX: the middle (Y) angle at +-90 degrees
@example(np.array([0.0, -np.pi / 2, 0.0]))
@example(Rotation.from_euler("ZYX", [0.4, np.pi / 2, -0.7]).as_rotvec())
@example(Rotation.from_euler("ZYX", [-2.9, -np.pi / 2, 1.3]).as_rotvec())
@example(np.array([np.pi, 0.0, 0.0]))
@example(np.zeros(3))
def test_axis_angle_round_trips_through_the_euler_channels(r: np.ndarray) -> None:
    degrees = smpl.euler_channels(spatial.rotvec_to_quat(r))
    assert np.all(np.abs(degrees) <= 180.0)
    R = bvh.parse("HIERARCHY\nROOT A\n{\nOFFSET 0 0 0\nCHANNELS 3 Zrotation Yrotation Xrotation\n}\nMOTION\nFrames: 1\n"
                  "Frame Time: 1\n" + " ".join(f"{v:.17g}" for v in degrees)).local()[0, 0, :3, :3]
    np.testing.assert_allclose(R, spatial.rotvec_to_mat(r), rtol=0, atol=ROUND_TRIP)


def test_read_clip_dispatches_by_suffix(same: Same) -> None:
    assert CLIP_SUFFIXES == (".bvh", ".npz")
    np.testing.assert_array_equal(read_clip(same.bvh).values, same.ref.values)
    np.testing.assert_array_equal(read_clip(same.npz, same.model).values, same.clip.values)
    with pytest.raises(InputError, match=r"must be a \.bvh or \.npz file, got '\.c3d'"):
        read_clip(same.bvh.with_suffix(".c3d"))
    with pytest.raises(InputError, match="a body model is for .npz"):
        read_clip(same.bvh, same.model)


# AMASS's split form: each part's columns of the combined 'poses', in the model's joint order (root, 21 body joints,
# then SMPL-X's jaw and eyes, then both hands; SMPL's two hand joints have no part)
SPLIT = {24: {"root_orient": (0, 3), "pose_body": (3, 66)},
         52: {"root_orient": (0, 3), "pose_body": (3, 66), "pose_hand": (66, 156)},
         55: {"root_orient": (0, 3), "pose_body": (3, 66), "pose_jaw": (66, 69), "pose_eye": (69, 75),
              "pose_hand": (75, 165)}}


@pytest.mark.parametrize(("joints", "left_out"), [(52, ()), (55, ()), (55, ("pose_jaw", "pose_eye")),
                                                  (52, ("pose_hand",)), (24, ())])
def test_the_split_form_reads_as_the_same_clip_as_poses(tmp_path: Path, joints: int,
                                                        left_out: tuple[str, ...]) -> None:
    # AMASS's SMPL-X "stage-ii" files (and newer SMPL-H ones) hold the turns in parts, without 'poses'; a part
    # left out (SMPL's hands, which have none) is at rest
    model = write_body_model(tmp_path / "model.npz", joints, 16)
    rng = np.random.default_rng(3)
    poses, trans, betas = rng.uniform(-1.0, 1.0, (5, 3 * joints)), rng.normal(size=(5, 3)), rng.normal(size=16)
    parts = {k: poses[:, a:b].copy() for k, (a, b) in SPLIT[joints].items() if k not in left_out}
    held = np.zeros(3 * joints, dtype=np.bool_)
    for a, b in (SPLIT[joints][k] for k in parts):
        held[a:b] = True
    poses[:, ~held] = 0.0  # what the split file does not hold is at rest
    np.savez(tmp_path / "poses.npz", poses=poses, trans=trans, betas=betas, mocap_frame_rate=np.array(120.0))
    np.savez(tmp_path / "split.npz", **parts, trans=trans, betas=betas, mocap_frame_rate=np.array(120.0),
             gender=np.array("neutral"), surface_model_type=np.array("smplx"))
    combined, split = (smpl.read(tmp_path / f"{name}.npz", model) for name in ("poses", "split"))
    for field in fields(bvh.Clip):  # every field the same but the file it came from
        got, want = getattr(split, field.name), getattr(combined, field.name)
        if isinstance(want, np.ndarray):
            np.testing.assert_array_equal(got, want, field.name)
        elif field.name != "source":
            assert got == want, field.name
    assert split.fps == 120.0 and split.frames == 5


def bad_files(tmp: Path) -> list[tuple[str, Path | None, type[Exception], str]]:
    """(clip, body model, error, message pattern) of bad input, each made in ``tmp``."""
    model = write_body_model(tmp / "model.npz")
    rest = shaped_rest(model, np.linspace(-1.0, 1.0, 16), 16)
    angles, root = motion(52, 3)
    good = write_clip(tmp / "good.npz", angles, root, rest)
    data = dict(np.load(good))

    def variant(name: str, **change: object) -> str:
        d = {k: v for k, v in {**data, **change}.items() if v is not None}
        np.savez(tmp / f"{name}.npz", **d)  # type: ignore[arg-type]
        return str(tmp / f"{name}.npz")

    nan = data["poses"].copy()
    nan[1, 4] = np.nan
    m = dict(np.load(model))
    np.savez(tmp / "no_regressor.npz", **{k: v for k, v in m.items() if k != "J_regressor"})
    np.savez(tmp / "odd_tree.npz", **{**m, "kintree_table": m["kintree_table"][:, :40]})
    swapped = m["kintree_table"].copy()
    swapped[0, 23] = 5
    np.savez(tmp / "swapped.npz", **{**m, "kintree_table": swapped})
    (tmp / "model.pkl").write_bytes(b"\x80\x04N.")
    (tmp / "text.npz").write_text("not a zip")
    return [
        (str(good), None, InputError, "needs its body model: give body_model= \\(--body-model PATH\\)"),
        (variant("no_trans", trans=None), model, MjkinIOError, "has no 'trans'; expected \\(3, 3\\) root translations"),
        (variant("no_rate", mocap_framerate=None), model, MjkinIOError, "has no 'mocap_framerate'"),
        (variant("nan", poses=nan), model, MjkinIOError, "'poses' holds nan or inf"),
        (variant("short_trans", trans=data["trans"][:2]), model, MjkinIOError, "'trans' has shape \\(2, 3\\); expect"),
        (variant("smplx", poses=np.zeros((3, 165))), model, MjkinIOError,
         "'poses' has 165 values a frame \\(SMPL-X\\) but the SMPL-H body model .* has 52 joints \\(156 values\\)"),
        (variant("no_frames", poses=np.zeros((0, 156)), trans=np.zeros((0, 3))), model, MjkinIOError, "no frames"),
        (variant("rate", mocap_framerate=np.array(0.0)), model, MjkinIOError, "'mocap_framerate' must be one number"),
        (variant("names", poses=np.array(["a"] * 3)), model, MjkinIOError, "'poses' holds <U1 values"),
        (str(good), tmp / "no_regressor.npz", MjkinIOError, "has no 'J_regressor'; expected \\(52, vertices\\)"),
        (str(good), tmp / "odd_tree.npz", MjkinIOError, "has 40 joints; expected 24 \\(SMPL\\), 52 \\(SMPL-H\\)"),
        (str(good), tmp / "swapped.npz", MjkinIOError, "gives joint 23 the parent 5; SMPL-H's is 22"),
        (str(good), tmp / "model.pkl", MjkinIOError, "is a pickle, which mjkin does not load"),
        (str(good), tmp / "missing.npz", MjkinIOError, "body model not found"),
        (variant("no_poses", poses=None), model, smpl.SmplError, "has neither 'poses' nor its parts; expected "
         "'poses' \\(frames, 156\\) or 'root_orient' \\(frames, 3\\), 'pose_body' \\(frames, 63\\), "
         "'pose_hand' \\(frames, 90\\) \\(rotation vectors, rad; those after 'pose_body' optional\\)$"),
        (variant("root_only", poses=None, root_orient=data["poses"][:, :3]), model, smpl.SmplError,
         "has no 'pose_body'; expected \\(3, 63\\) rotation vectors"),
        (variant("smplx_parts", poses=None, root_orient=np.zeros((3, 3)), pose_body=np.zeros((3, 63)),
                 pose_jaw=np.zeros((3, 3)), pose_eye=np.zeros((3, 6))), model, smpl.SmplError,
         "has 'pose_jaw', 'pose_eye' but the SMPL-H body model .* has no such joints"),
        (variant("short_hand", poses=None, root_orient=np.zeros((3, 3)), pose_body=np.zeros((3, 63)),
                 pose_hand=np.zeros((2, 90))), model, smpl.SmplError,
         "'pose_hand' has shape \\(2, 90\\); expected \\(3, 90\\): one row per frame of 'root_orient'"),
        (str(tmp / "missing.npz"), model, MjkinIOError, "AMASS/SMPL clip not found"),
        (str(tmp / "text.npz"), model, MjkinIOError, "cannot read AMASS/SMPL clip .* as an .npz archive"),
    ]


def test_bad_files_are_one_line_errors(tmp_path: Path) -> None:
    for clip, model, error, message in bad_files(tmp_path):
        with pytest.raises(error, match=message) as e:
            smpl.read(clip, model)
        assert "\n" not in str(e.value), clip


def test_command_line(same: Same, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "walk.json"
    assert run(["retarget", str(same.npz), "--model", "primate", "--body-model", str(same.model), "-o", str(out)]) == 0
    assert "6 frames of" in capsys.readouterr().out and out.is_file()
    assert run(["retarget", str(same.npz), "--model", "primate"]) == 2
    err = capsys.readouterr().err
    assert "needs its body model" in err and "Traceback" not in err


# ------------------------------------------------------------------ hostile archives
def write_declared(path: Path, key: str, shape: tuple[int, ...], data_bytes: int, dtype: str = "<f8") -> Path:
    """An ``.npz`` whose ``key`` declares ``shape`` and holds ``data_bytes`` zeros (compressed: a zip bomb)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as z, \
            z.open(f"{key}.npy", "w", force_zip64=True) as m:
        np.lib.format.write_array_header_1_0(m, {"descr": dtype, "fortran_order": False, "shape": shape})
        chunk = bytes(1 << 24)
        for start in range(0, data_bytes, len(chunk)):
            m.write(chunk[: data_bytes - start])
    return path


def peak_of(call: Callable[[], object]) -> tuple[BaseException | None, int]:
    """What ``call`` raised, and the most memory (bytes, Python's and numpy's) it held at once."""
    tracemalloc.start()
    try:
        call()
        raised = None
    except Exception as e:  # noqa: BLE001 - the test looks at it
        raised = e
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return raised, peak


@pytest.mark.parametrize("case", ["bomb", "1e12", "object", "clip bomb"])
def test_a_crafted_archive_is_refused_on_its_headers(tmp_path: Path, case: str) -> None:
    """A 1.6 MB zip bomb reached 3.3 GB before the shape check; an array declaring 1e12 values raised a raw
    MemoryError. Each is refused on the array's header, nothing large read."""
    model = write_body_model(tmp_path / "model.npz")
    big = 300_000 * 156 * 8  # 374 MB of zeros in ~0.4 MB
    if case == "bomb":
        clip = write_declared(tmp_path / "bomb.npz", "poses", (300_000, 156), big)
        message = r"'poses' declares \(300000, 156\) float64 values \(357 MB\); mjkin reads arrays of at most 256 MB"
    elif case == "1e12":
        clip = write_declared(tmp_path / "huge.npz", "poses", (10**12 // 156, 156), 0)
        message = r"'poses' declares \(6410256410, 156\) float64 values \(7629395 MB\); mjkin reads arrays of at most"
    elif case == "object":
        clip = write_declared(tmp_path / "object.npz", "poses", (3, 156), 0, dtype="|O")
        message = r"'poses' holds object values; expected \(frames, 3 x joints\) rotation vectors"
    else:
        clip, model = tmp_path / "clip.npz", write_declared(tmp_path / "bomb_model.npz", "kintree_table",
                                                           (2, 300_000 * 78), big, dtype="<i8")
        message = r"'kintree_table' declares \(2, 23400000\) int64 values \(357 MB\); mjkin reads arrays of at most"
    raised, peak = peak_of(lambda: smpl.read(clip, model))
    assert isinstance(raised, smpl.SmplError), raised
    assert re.search(message, str(raised)), str(raised)
    assert peak < 32 * 2**20, f"{peak / 2**20:.0f} MB held"


def test_the_memory_cap_of_a_gigabyte_is_enough_to_refuse_a_bomb(tmp_path: Path) -> None:
    """The command line, under an address-space limit of 1 GB, says one line for a 3.3 GB bomb."""
    model = write_body_model(tmp_path / "model.npz")
    clip = write_declared(tmp_path / "bomb.npz", "poses", (2_700_000, 156), 0)  # declared only: the header is enough
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (2**30, 2**30)); "
            "from mjkin.apps.cli import main; sys.exit(main(sys.argv[1:]))")
    r = subprocess.run([sys.executable, "-c", code, "retarget", str(clip), "--model", "primate", "--body-model",
                        str(model), "-o", str(tmp_path / "out.json")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "'poses' declares (2700000, 156) float64 values (3214 MB); mjkin reads arrays of at most 256 MB" in r.stderr


@pytest.mark.parametrize("kind", ["fifo", "/dev/zero"])
@pytest.mark.parametrize("which", ["clip", "body model"])
def test_a_clip_or_body_model_that_is_no_regular_file_is_refused_unread(tmp_path: Path, kind: str,
                                                                         which: str) -> None:
    """``--body-model`` as a FIFO hung for ever."""
    model = write_body_model(tmp_path / "model.npz")
    clip = write_clip(tmp_path / "walk.npz", *motion(52, 3), shaped_rest(model, np.linspace(-1.0, 1.0, 16), 16))
    odd = tmp_path / "odd.npz"
    os.mkfifo(odd) if kind == "fifo" else odd.symlink_to("/dev/zero")
    with no_hang(), pytest.raises(smpl.SmplError) as e:
        smpl.read(odd, model) if which == "clip" else smpl.read(clip, odd)
    what = "AMASS/SMPL clip" if which == "clip" else "body model"
    told = "a FIFO (named pipe)" if kind == "fifo" else "a character device"
    assert str(e.value) == f"{what} {str(odd)!r} is {told}, not a regular file; give the file itself"
