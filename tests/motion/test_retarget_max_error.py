"""Never a silent failure: a clip whose hands, feet and head miss their targets by more than a bound (95th
percentile over frames of each frame's worst) is failed, in Python, in report.csv and in the command's exit code."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from test_retarget import MOCAP, crouch_bvh, need_mocap
from test_retarget_dataset import crouches, rows_of
from test_retarget_resume import solved  # noqa: F401 - a fixture

import mjkin
from mjkin.apps.cli import run
from mjkin.errors import InputError
from mjkin.motion import Trajectory, bvh
from mjkin.motion.dataset import REPORT, retarget_many
from mjkin.motion.retarget import MAX_ERROR, report


@pytest.fixture(scope="module")
def primate() -> mjkin.Tree:
    return mjkin.load("primate")


def test_the_result_carries_each_frames_error_and_a_status(primate: mjkin.Tree) -> None:
    clip = bvh.parse(crouch_bvh(12), "crouch.bvh")
    traj = mjkin.retarget(clip, primate)
    info = traj.meta["retarget"]
    errors = np.asarray(info["errors"])
    assert errors.shape == (12,) and np.isfinite(errors).all() and (errors >= 0).all()
    assert info["status"] == "ok" and info["max_error"] == MAX_ERROR == 0.10
    measured = report(primate, traj)
    assert measured["frame_error_p95"] == pytest.approx(np.percentile(errors, 95), abs=1e-12)
    assert measured["frame_error_median"] == pytest.approx(np.median(errors), abs=1e-12)
    assert measured["frame_error_max"] == errors.max() == measured["keypoint_error_max"]  # each frame's worst point
    assert measured["worst_frame"] == int(np.argmax(errors))
    tight = mjkin.retarget(clip, primate, max_error=errors.min() / 2).meta["retarget"]
    assert tight["status"] == "failed" and np.array_equal(tight["errors"], errors)  # judged, the same solve
    for bad in (-0.1, 0.0, np.nan, np.inf, "10 cm", None):
        with pytest.raises(InputError, match="max_error"):
            mjkin.retarget(clip, primate, max_error=bad)  # type: ignore[arg-type]


def test_a_saved_result_keeps_its_errors(primate: mjkin.Tree, tmp_path: Path) -> None:
    traj = mjkin.retarget(bvh.parse(crouch_bvh(6), "crouch.bvh"), primate)
    back = Trajectory.load(traj.save(tmp_path / "c.json"), primate).meta["retarget"]
    assert back["errors"] == traj.meta["retarget"]["errors"] and back["status"] == "ok"


@need_mocap
def test_one_clip_over_the_bound_fails_with_exit_3(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    clip = str(MOCAP / "mixamo_freebvh.bvh")
    for out in (tmp_path / "walk.npz", tmp_path / "walk.json"):
        assert run(["retarget", clip, "--model", "primate", "-o", str(out), "--max-error", "0.001"]) == 3
        said = capsys.readouterr()
        assert said.err.count("\n") == 1 and "mixamo_freebvh.bvh" in said.err and "failed" in said.err
        assert "worst frame" in said.err and "--max-error 0.1 cm" in said.err
        assert out.is_file()  # the file is still written
        assert "95th percentile" in said.out and "median" in said.out and "max" in said.out
    assert run(["retarget", clip, "--model", "primate", "-o", str(tmp_path / "ok.npz")]) == 0  # within 10 cm
    said = capsys.readouterr()
    assert said.err == "" and "95th percentile" in said.out


def test_clips_over_the_bound_fail_in_the_report_with_exit_3(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                              solved: list[str]) -> None:  # noqa: F811
    src = crouches(tmp_path / "clips", ["a.bvh", "sub/b.bvh"], frames=8)
    if MOCAP.is_dir():
        shutil.copy(MOCAP / "mixamo_freebvh.bvh", src / "walk.bvh")
    names = ["a.bvh", "sub/b.bvh"] + (["walk.bvh"] if MOCAP.is_dir() else [])
    out = tmp_path / "out"
    tight = ["retarget", str(src), "--model", "primate", "-o", str(out), "--max-error", "0.000001"]
    assert run(tight) == 3
    said = capsys.readouterr()
    lines = said.err.splitlines()
    assert len(lines) == len(names) and all(any(n in line and "worst frame" in line for line in lines) for n in names)
    assert [r["status"] for r in rows_of(out / REPORT)] == ["failed"] * len(names)
    assert all((out / n).with_suffix(".npz").is_file() for n in names)  # the files are still written
    assert f"0 of {len(names)} clips" in said.out and "95th percentile" in said.out
    solved.clear()
    assert run(tight) == 3  # the same again: done, not redone, still failed
    assert solved == [] and capsys.readouterr().err.splitlines() == lines
    assert run([*tight[:-1], "1"]) == 0  # another bound judges the stored errors: nothing redone
    assert solved == [] and capsys.readouterr().err == ""
    assert [r["status"] for r in rows_of(out / REPORT)] == ["ok"] * len(names)
    rows = retarget_many(src, "primate", out, max_error=1e-6)
    assert solved == [] and [r["status"] for r in rows] == ["failed"] * len(names)


def test_a_clip_that_cannot_be_read_exits_3_too(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh"], frames=6)
    (src / "bad.bvh").write_text("HIERARCHY\n")
    assert run(["retarget", str(src), "--model", "primate", "-o", str(tmp_path / "out")]) == 3
    said = capsys.readouterr()
    assert "1 of 2 clips" in said.out and said.err.count("\n") == 1 and "bad.bvh" in said.err


@pytest.mark.parametrize("value", ["-0.01", "0", "nan", "inf", "ten cm", ""])
def test_a_bad_max_error_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], value: str) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh"], frames=4) / "a.bvh"
    assert run(["retarget", str(src), "--model", "primate", "-o", str(tmp_path / "a.json"),
                "--max-error", value]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--max-error: must be" in err
    assert not (tmp_path / "a.json").exists()


@need_mocap
def test_the_primates_crouch_fails_the_bound_only_by_its_hips_reach(primate: mjkin.Tree) -> None:
    """The shared 19-joint crouch onto the primate misses the default 10 cm bound (95th percentile 14 cm): in its
    deepest frames the pelvis stays 17 cm above its target with a hip at the end of its 1.8 rad cone (the source
    folds further at the hip). The same figure with 2.6 rad hips follows it within 5 cm: the bound is out of the
    primate's reach, not a fault of the roles or the scaling."""
    path = MOCAP / "mocapbank_19joint.bvh"
    traj = mjkin.retarget(path, primate)
    info = traj.meta["retarget"]
    errors = np.asarray(info["errors"])
    assert info["status"] == "failed" and np.percentile(errors, 95) > MAX_ERROR
    worst = int(np.argmax(errors))
    hips = []
    for side in ("left", "right"):
        j = primate.id(f"{side}_hip", "joint")
        w = traj.q[worst, primate.model.jnt_qposadr[j]]
        hips.append((2 * np.arccos(min(1.0, abs(w))), primate.model.jnt_range[j, 1]))
    assert any(angle >= limit - 1e-3 for angle, limit in hips), hips  # a hip at the end of its cone
    text = Path(mjkin.kinematics.tree.bundled_models()["primate"]).read_text()
    wide = text.replace('_hip" type="ball" range="0 1.8"', '_hip" type="ball" range="0 2.6"')
    assert wide.count('range="0 2.6"') == text.count('range="0 2.6"') + 2
    deep = mjkin.retarget(path, mjkin.load(wide)).meta["retarget"]
    assert deep["status"] == "ok" and np.percentile(deep["errors"], 95) < 0.06
