"""Retargeting quality (issue 39): no self-penetration on walks, also on harder synthetic ones (120 Hz, arms swung
wide and in against the hips, knees brushing), the G1's crouch close to its source with both knees bent, and the
bench's dataset-style table."""

from __future__ import annotations

import json
from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mjkin
from mjkin import spatial
from mjkin.apps.bench.report import shared_models_dir
from mjkin.apps.bench.retarget import bench_retarget, mocap_dir
from mjkin.apps.cli import main
from mjkin.motion import Trajectory, bvh
from mjkin.motion.retarget import report
from mjkin.motion.roles import source_mapping

MOCAP = mocap_dir() or Path("../shared/mocap")
WALK, CROUCH = MOCAP / "mixamo_freebvh.bvh", MOCAP / "mocapbank_19joint.bvh"
G1 = (shared_models_dir() or Path("../shared/models")) / "unitree_g1" / "g1.xml"
need_mocap = pytest.mark.skipif(not MOCAP.is_dir(), reason=f"the shared clips are not here ({MOCAP})")
need_g1 = pytest.mark.skipif(not G1.is_file(), reason=f"the G1 is not here ({G1})")
DEPTH = 1e-3  # m: the deepest self-penetration allowed in any frame
# the synthetic walks per figure: the primate's thighs nearly touch already (its legs cross at 120 Hz), the G1
# stands wide (its knees and feet only meet with the thighs turned 12 degrees in)
CLOSE = {"primate": {"arms_in": 8.0, "swing": 1.8, "legs_in": 0.0},
         "g1": {"arms_in": 12.0, "swing": 1.8, "legs_in": 12.0}}
FIGURES = [pytest.param("primate"), pytest.param("g1", marks=need_g1)]


@cache
def figure(name: str) -> mjkin.Tree:
    return mjkin.load("primate" if name == "primate" else G1)


# ------------------------------------------------------------------ synthetic clips
def with_local(clip: bvh.Clip, R: np.ndarray, p: np.ndarray, frame_time: float) -> bvh.Clip:
    """``clip`` with every frame's local rotations ``R (F, J, 3, 3)`` and translations ``p (F, J, 3)`` written into
    its channels (three rotation channels a joint)."""
    values = np.zeros((len(R), clip.values.shape[1]))
    for j, chans in enumerate(clip.channels):
        col = clip.columns[j]
        rot = [k for k, c in enumerate(chans) if c.endswith("rotation")]
        for k, c in enumerate(chans):
            if c.endswith("position"):
                values[:, col + k] = p[:, j, "xyz".index(c[0])]
        if rot:
            seq = "".join(chans[k][0] for k in rot).upper()
            values[:, col + np.array(rot)] = np.rad2deg(spatial.mat_to_euler(R[:, j], seq))
    return replace(clip, values=values, frame_time=frame_time)


def resample(clip: bvh.Clip, fps: float) -> bvh.Clip:
    """``clip`` at ``fps`` frames per second: joint turns slerped, translations interpolated linearly."""
    n = int((clip.frames - 1) * clip.frame_time * fps + 1e-3) + 1
    t = np.minimum(np.arange(n) / (fps * clip.frame_time), clip.frames - 1)
    i = np.minimum(t.astype(int), clip.frames - 2)
    w = (t - i)[:, None]
    L = clip.local()
    quat = spatial.mat_to_quat(L[..., :3, :3])
    R = spatial.quat_to_mat(spatial.slerp(quat[i], quat[i + 1], np.broadcast_to(w, quat[i].shape[:-1])))
    p = (1 - w[..., None]) * L[i, :, :3, 3] + w[..., None] * L[i + 1, :, :3, 3]
    return with_local(clip, R, p, 1.0 / fps)


def _turn(axis: int, angle: np.ndarray) -> np.ndarray:
    return spatial.axis_angle_to_mat(np.eye(3)[axis], angle)


def close_limbs_walk(clip: bvh.Clip, fps: float = 120.0, arms_in: float = 8.0, swing: float = 1.8,
                     legs_in: float = 4.0) -> bvh.Clip:
    """A walk made harder for self-contact: resampled to ``fps``, each upper arm turned ``arms_in`` degrees in
    toward the body and its fore-aft swing (about the hips' left axis) ``swing`` times as wide, each thigh turned
    ``legs_in`` degrees in toward the other (the feet keep their turn in the world).

    The hips' rest frame is taken as the rigs' (x left, y up, z forward).
    """
    clip = resample(clip, fps)
    roles = source_mapping(clip)
    L, W = clip.local(), clip.world()
    hips, parents = roles["pelvis"], clip.parents
    R = L[..., :3, :3].copy()
    Wh = W[:, hips, :3, :3]
    for side, inward in (("left", -1.0), ("right", 1.0)):
        sh, wr = roles[f"{side}_shoulder"], roles[f"{side}_wrist"]
        d = np.einsum("fji,fj->fi", Wh, W[:, wr, :3, 3] - W[:, sh, :3, 3])  # shoulder to wrist, hips frame
        pitch = np.arctan2(d[:, 2], -d[:, 1])  # forward of hanging down
        arm = _turn(2, inward * np.deg2rad(arms_in)) @ _turn(0, -(swing - 1) * (pitch - pitch.mean()))
        leg = _turn(2, np.full(len(R), inward * np.deg2rad(legs_in)))
        for joint, E in ((sh, arm), (roles[f"{side}_hip"], leg)):
            Wp = W[:, parents[joint], :3, :3]
            to_parent = np.swapaxes(Wp, -1, -2) @ Wh
            R[:, joint] = to_parent @ E @ np.swapaxes(to_parent, -1, -2) @ R[:, joint]
    turned = with_local(clip, R, L[..., :3, 3], clip.frame_time)
    W2 = turned.world()
    for side in ("left", "right"):  # the feet as they were in the world
        a = roles[f"{side}_ankle"]
        R[:, a] = np.swapaxes(W2[:, parents[a], :3, :3], -1, -2) @ W[:, a, :3, :3]
    return with_local(clip, R, L[..., :3, 3], clip.frame_time)


def cut(clip: bvh.Clip, start: int, stop: int) -> bvh.Clip:
    """Frames ``start:stop`` of ``clip``."""
    return replace(clip, values=clip.values[start:stop])


def bvh_text(path: Path, start: int, stop: int) -> str:
    """The BVH file at ``path`` with only its frames ``start:stop``."""
    hierarchy, motion = path.read_text().split("MOTION", 1)
    lines = motion.strip().splitlines()
    frame_time = next(x for x in lines if x.lower().startswith("frame time"))
    rows = lines[lines.index(frame_time) + 1:][start:stop]
    return f"{hierarchy}MOTION\nFrames: {len(rows)}\n{frame_time}\n" + "\n".join(rows) + "\n"


def knee_bends(tree: mjkin.Tree, traj: Trajectory) -> np.ndarray:
    """The figure's knee joints ``(F, 2)`` (left, right; rad, 0 straight): the hinge of each knee body."""
    bodies = traj.meta["retarget"]["bodies"]
    joints = [np.flatnonzero(tree.model.jnt_bodyid == tree.id(bodies[f"{s}_knee"], "body")) for s in ("left", "right")]
    assert all(len(j) == 1 for j in joints)
    return traj.q[:, [int(tree.model.jnt_qposadr[j[0]]) for j in joints]]


def source_knee_bends(clip: bvh.Clip) -> np.ndarray:
    """The source's knee bends ``(F, 2)`` (left, right; rad): the angle between thigh and shin."""
    roles, p = source_mapping(clip), clip.positions()
    out = []
    for s in ("left", "right"):
        thigh = p[:, roles[f"{s}_knee"]] - p[:, roles[f"{s}_hip"]]
        shin = p[:, roles[f"{s}_ankle"]] - p[:, roles[f"{s}_knee"]]
        cos = np.sum(thigh * shin, -1) / np.linalg.norm(thigh, axis=-1) / np.linalg.norm(shin, axis=-1)
        out.append(np.arccos(np.clip(cos, -1.0, 1.0)))
    return np.stack(out, -1)


# ------------------------------------------------------------------ self-contact
@need_mocap
def test_resampling_at_the_clip_rate_gives_the_clip_back() -> None:
    clip = bvh.read(WALK)
    same, fast = resample(clip, clip.fps), resample(clip, 4 * clip.fps)
    assert same.frames == clip.frames and fast.frames == 4 * (clip.frames - 1) + 1
    assert np.abs(same.positions() - clip.positions()).max() < 1e-2  # cm: the file's 0.0333333 s against 1/30
    assert np.abs(fast.positions()[::4] - clip.positions()).max() < 1e-2


@need_mocap
@pytest.mark.parametrize("name", FIGURES)
@pytest.mark.parametrize("close", [False, True], ids=["walk", "close-limbs-120Hz"])
def test_walks_keep_the_figure_off_itself(name: str, close: bool) -> None:
    tree, clip = figure(name), bvh.read(WALK)
    rep = report(tree, mjkin.retarget(close_limbs_walk(clip, **CLOSE[name]) if close else clip, tree))
    assert rep["self_contact_deepest"] >= -DEPTH, rep
    assert rep["limits"] is None and rep["speed_limit_ratio"] <= 1 + 1e-9


@need_mocap
@pytest.mark.parametrize("name", FIGURES)
def test_the_close_limbs_walks_go_through_the_figure_without_clearance(name: str) -> None:
    tree = figure(name)
    rep = report(tree, mjkin.retarget(close_limbs_walk(bvh.read(WALK), **CLOSE[name]), tree, clearance=None))
    assert rep["self_contact_deepest"] < -DEPTH  # the walks above are hard: their limbs meet in the source


@need_mocap
@settings(max_examples=6)
@given(arms_in=st.floats(0.0, 12.0), swing=st.floats(1.0, 2.2))
def test_hands_swung_against_the_hips_stay_out(arms_in: float, swing: float) -> None:
    tree = figure("primate")
    clip = cut(close_limbs_walk(bvh.read(WALK), arms_in=arms_in, swing=swing, legs_in=0.0), 180, 273)
    rep = report(tree, mjkin.retarget(clip, tree))
    assert rep["self_contact_deepest"] >= -DEPTH, rep


# ------------------------------------------------------------------ the G1's crouch
@pytest.fixture(scope="module")
def g1_crouch() -> tuple[mjkin.Tree, Trajectory]:
    tree = figure("g1")
    return tree, mjkin.retarget(CROUCH, tree)


@need_mocap
@need_g1
def test_g1_crouch_follows_its_source(g1_crouch: tuple[mjkin.Tree, Trajectory]) -> None:
    tree, traj = g1_crouch
    rep = report(tree, traj)
    assert rep["keypoint_error_median"] <= 0.025  # 3.97 cm before issue 39
    assert rep["self_contact_deepest"] >= -DEPTH and rep["limits"] is None


@need_mocap
@need_g1
def test_g1_crouch_holds_with_the_clip_moved_by_rounding() -> None:
    """Found in CI on another CPU: at 6 iterations a frame the crouch's rise lagged on a straight leg (3.0 cm at the
    median), as it does here with the clip's channels moved by 1e-6; the answer must not hang on the last bits."""
    clip = bvh.read(CROUCH)
    moved = replace(clip, values=clip.values + np.random.default_rng(0).normal(0.0, 1e-6, clip.values.shape))
    tree = figure("g1")
    assert report(tree, mjkin.retarget(moved, tree))["keypoint_error_median"] <= 0.025


@need_mocap
@need_g1
def test_g1_bends_both_knees_in_the_deep_crouch(g1_crouch: tuple[mjkin.Tree, Trajectory]) -> None:
    tree, traj = g1_crouch
    deep = np.argsort(traj.targets[:, 0, 2])[:100]  # the 100 frames of the lowest pelvis target
    fig = np.median(knee_bends(tree, traj)[deep], axis=0)
    src = np.median(source_knee_bends(bvh.read(CROUCH))[deep], axis=0)  # the source kneels: 1.9 and 2.6 rad
    assert fig.min() > 0.5  # before: the left knee straight at its limit (-0.33 rad), the right at 1.75
    assert abs((fig[0] - fig[1]) - (src[0] - src[1])) < 0.4


# ------------------------------------------------------------------ the bench
@need_mocap
def test_bench_table_has_frames_per_second_median_and_iqr_over_the_clips(tmp_path: Path) -> None:
    (tmp_path / "walk.bvh").write_text(bvh_text(WALK, 0, 16))
    (tmp_path / "more").mkdir()
    (tmp_path / "more" / "crouch.bvh").write_text(bvh_text(CROUCH, 200, 216))
    (tmp_path / "notes.txt").write_text("not a clip")
    rep = bench_retarget(repeat=1, clips=tmp_path, models=["primate"])
    per_clip, (row,) = rep.tables.values()
    assert sorted(r["clip"] for r in per_clip) == ["crouch.bvh", "walk.bvh"]
    fps = sorted(r["frames_per_s"] for r in per_clip)
    assert row["model"] == "primate" and row["clips"] == 2 and row["frames"] == 32
    assert row["frames_per_s_median"] == round(float(np.median(fps)))
    assert row["frames_per_s_q25"] <= row["frames_per_s_median"] <= row["frames_per_s_q75"]
    assert row["frames_per_s_iqr"] == pytest.approx(row["frames_per_s_q75"] - row["frames_per_s_q25"], abs=1)
    assert {"keypoint_median_cm", "skate_mm_per_frame", "skate_max_cm", "floor_min_mm", "clips_in_limits",
            "speed_ratio", "self_contact_frames", "deepest_mm"} <= set(row)
    doc = rep.as_json()
    assert len(doc["rows"]) == 2 and doc["dataset"] == [row]


@need_mocap
def test_bench_command_takes_clips_and_models_and_writes_json(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    clips = tmp_path / "clips"
    clips.mkdir()
    (clips / "walk.bvh").write_text(bvh_text(WALK, 0, 12))
    out = tmp_path / "retarget.json"
    assert main(["bench", "retarget", "--clips", str(clips), "--models", "primate", "--repeat", "1",
                 "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert [r["model"] for r in doc["dataset"]] == ["primate"] and doc["rows"][0]["clip"] == "walk.bvh"
    assert "frames_per_s_iqr" in capsys.readouterr().out
    for bad in (["--clips", str(tmp_path / "none")], ["--clips", str(clips), "--models", "no_such_figure"]):
        assert main(["bench", "retarget", *bad]) == 2
        assert "Traceback" not in capsys.readouterr().err
