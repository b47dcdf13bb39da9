"""``mjkin bench retarget`` with GMR beside mjkin (issue 55): GMR in its own venv when it is found, else a note
saying how to point at it; both tools' rows scored by the one mjkin.motion.quality.score."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import mjkin
from mjkin.apps.bench import gmr
from mjkin.apps.bench.peers import Unavailable
from mjkin.apps.bench.report import shared_models_dir
from mjkin.apps.bench.retarget import bench_retarget, mocap_dir
from mjkin.motion import bvh

pytestmark = pytest.mark.slow  # GMR in a subprocess, mjkin on the meshed G1
MOCAP = mocap_dir() or Path("../shared/mocap")
WALK, CROUCH = MOCAP / "mixamo_freebvh.bvh", MOCAP / "mocapbank_19joint.bvh"
G1 = (shared_models_dir() or Path("../shared/models")) / "gmr_unitree_g1" / "g1_mocap_29dof.xml"


def gmr_or_reason() -> tuple[gmr.Gmr | None, str]:
    try:
        return gmr.find(), ""
    except Unavailable as e:
        return None, str(e)


GMR, WHY = gmr_or_reason()


def cut_clips(folder: Path, frames: int = 12) -> Path:
    """The two shared clips, ``frames`` frames each (the crouch from its deep part), in ``folder``."""
    for src, start, name in ((WALK, 0, "walk.bvh"), (CROUCH, 200, "crouch.bvh")):
        hierarchy, motion = src.read_text().split("MOTION", 1)
        lines = motion.strip().splitlines()
        frame_time = next(x for x in lines if x.lower().startswith("frame time"))
        rows = lines[lines.index(frame_time) + 1:][start:start + frames]
        (folder / name).write_text(f"{hierarchy}MOTION\nFrames: {len(rows)}\n{frame_time}\n" + "\n".join(rows) + "\n")
    return folder


@pytest.mark.skipif(not WALK.is_file(), reason=f"the shared clips are not here ({MOCAP})")
def test_each_shared_clip_gets_the_refit_of_its_rest_pose() -> None:
    assert gmr.rest_pose(bvh.read(WALK)) == "tpose"  # Mixamo: arms out
    assert gmr.rest_pose(bvh.read(CROUCH)) == "armsdown"  # the 19-joint rig: arms hanging


@pytest.mark.skipif(not G1.is_file(), reason=f"GMR's G1 is not here ({G1})")
def test_qpos_names_are_the_runners_in_the_models_order() -> None:
    tree = mjkin.load(G1)
    names = gmr.qpos_names(tree)
    assert len(names) == tree.nq and names[:7] == [f"pelvis_{c}" for c in ("x", "y", "z", "qw", "qx", "qy", "qz")]
    assert names[7] == tree.names("joint")[1]


def test_without_gmr_the_bench_keeps_mjkins_rows_and_says_how_to_point_at_it(tmp_path: Path,
                                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    if not (WALK.is_file() and G1.is_file()):
        pytest.skip(f"the shared clips and GMR's G1 are needed ({MOCAP}, {G1})")
    monkeypatch.setenv("MJKIN_GMR_PYTHON", str(tmp_path / "no-venv" / "bin" / "python"))
    rep = bench_retarget(repeat=1, clips=cut_clips(tmp_path), models=["gmr_unitree_g1"])
    beside = rep.extra["beside_gmr"]
    assert [r["tool"] for r in beside] == ["mjkin", "mjkin"] and {r["clip"] for r in beside} == {"walk.bvh",
                                                                                                 "crouch.bvh"}
    assert all(r["frames"] == 12 and r["frames_per_s"] > 0 and "mjkin_per_gmr" not in r for r in beside)
    (note,) = rep.notes
    assert "GMR was not found" in note and "MJKIN_GMR_PYTHON" in note and "README" in note
    assert rep.as_json()["notes"] == [note]


@pytest.mark.skipif(GMR is None, reason=f"GMR is not installed here: {WHY}")
def test_gmr_runs_beside_mjkin_on_the_same_clips_and_robot(tmp_path: Path) -> None:
    if not (WALK.is_file() and G1.is_file()):
        pytest.skip(f"the shared clips and GMR's G1 are needed ({MOCAP}, {G1})")
    rep = bench_retarget(repeat=1, clips=cut_clips(tmp_path), models=["gmr_unitree_g1"])
    beside = rep.extra["beside_gmr"]
    assert [(r["clip"], r["tool"]) for r in beside] == [("crouch.bvh", "mjkin"), ("crouch.bvh", "gmr"),
                                                        ("walk.bvh", "mjkin"), ("walk.bvh", "gmr")]
    assert not rep.notes and "gmr" in rep.settings
    for mine, theirs in (beside[:2], beside[2:]):
        assert theirs["frames"] == mine["frames"] == 12 and theirs["frames_per_s"] > 0
        assert mine["mjkin_per_gmr"] == pytest.approx(mine["frames_per_s"] / theirs["frames_per_s"], rel=0.02)
        assert set(mine) - {"mjkin_per_gmr"} == set(theirs) - {"gmr_config"}  # the same columns
    assert [r["gmr_config"] for r in beside[1::2]] == ["bvh_armsdown_to_g1.json", "bvh_tpose_to_g1.json"]


@pytest.mark.skipif(GMR is None, reason=f"GMR is not installed here: {WHY}")
def test_gmr_qpos_come_back_in_the_models_order_and_move(tmp_path: Path) -> None:
    if not (WALK.is_file() and G1.is_file()):
        pytest.skip(f"the shared clips and GMR's G1 are needed ({MOCAP}, {G1})")
    assert GMR is not None
    tree = mjkin.load(G1)
    q, timing = gmr.retarget(GMR, cut_clips(tmp_path, 8) / "walk.bvh", tree, workdir=tmp_path)
    assert q.shape == (8, tree.nq) and timing["frames"] == 8 and timing["frames_per_s_after_first"] > 0
    assert np.allclose(np.linalg.norm(q[:, 3:7], axis=1), 1.0, atol=1e-6)  # the root's quaternion where MuJoCo's is
    assert np.ptp(q[:, 0]) > 0.01  # the walk goes forward
    with pytest.raises(Unavailable, match="LAFAN1"):
        gmr.retarget(GMR, tmp_path / "walk.bvh", tree, robot="booster_t1")
