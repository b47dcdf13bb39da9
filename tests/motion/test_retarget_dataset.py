"""Retargeting a folder of clips: a file per clip and report.csv, failures as rows, resume, formats, a killed run,
workers, the command line."""

from __future__ import annotations

import csv
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_retarget import MOCAP, crouch_bvh
from test_smpl import motion, shaped_rest, write_body_model, write_clip

import mjkin
from conftest import ROOT, no_hang
from mjkin.apps.cli import run
from mjkin.distributed import ray
from mjkin.errors import InputError, MjkinError, MjkinIOError
from mjkin.motion import Trajectory, bvh, dataset, smpl
from mjkin.motion.dataset import REPORT, ReportFile, columns, qpos_names, read_report, retarget_many
from mjkin.motion.retarget import SELF_CLEARANCE, report
from mjkin.runtime.files import TEMP_MARK


def count_solves(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The names of the clips retargeted (solved) in this process from now on."""
    names: list[str] = []
    real = dataset.retarget

    def counted(clip: bvh.Clip, *args: object, **kwargs: object) -> Trajectory:
        names.append(Path(clip.source).name)
        return real(clip, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(dataset, "retarget", counted)
    return names


@pytest.fixture(scope="module")
def primate() -> mjkin.Tree:
    return mjkin.load("primate")


def crouches(folder: Path, names: list[str], frames: int = 12) -> Path:
    """Write a crouch clip (``frames`` frames) at each relative path of ``names`` under ``folder``."""
    for name in names:
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text(crouch_bvh(frames))
    return folder


def temps(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if TEMP_MARK in p.name]


def rows_of(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def test_a_folder_gives_a_file_per_clip_and_a_report(tmp_path: Path, primate: mjkin.Tree) -> None:
    src = crouches(tmp_path / "clips", ["crouch.bvh", "sub/crouch.bvh", "sub/deep/knees.bvh"], frames=10)
    (src / ".hidden.bvh").write_text("not read")  # hidden names are left out
    (src / "notes.txt").write_text("not a clip")
    if MOCAP.is_dir():
        shutil.copy(MOCAP / "mixamo_freebvh.bvh", src / "walk.bvh")
    out = tmp_path / "out"
    rows = retarget_many(src, "primate", out)
    names = ["crouch.bvh", "sub/crouch.bvh", "sub/deep/knees.bvh"] + (["walk.bvh"] if MOCAP.is_dir() else [])
    assert [r["clip"] for r in rows] == names and all(r["status"] == "ok" for r in rows)
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()) == sorted(
        [REPORT] + [n.replace(".bvh", ".npz") for n in names])  # same stems in sub-folders kept apart
    written = rows_of(out / REPORT)
    expected = list(report(primate, mjkin.retarget(src / "crouch.bvh", primate)))
    cols = list(written[0])
    assert cols[:4] == ["clip", "frames", "fps", "frames_per_second"] and cols[-1] == "status"
    assert cols[1:-1] == ["frames", "fps", *[k for k in expected if k != "frames"], *dataset.RECORD]
    assert [r["clip"] for r in written] == names and written[0]["limits"] == ""  # None: no joint outside
    for row, name in zip(written, names, strict=True):
        clip = bvh.read(src / name)
        assert int(row["frames"]) == clip.frames and float(row["fps"]) == clip.fps
        with np.load(out / name.replace(".bvh", ".npz")) as f:
            q = f["qpos"]
            assert q.dtype == np.float64 and q.shape == (clip.frames, primate.nq)
            assert np.array_equal(q, mjkin.retarget(src / name, primate).q)  # what mjkin.retarget gives, bit for bit
            assert f["fps"].shape == () and float(f["fps"]) == clip.fps
            assert list(f["qpos_names"]) == qpos_names(primate) and len(f["qpos_names"]) == primate.nq
            assert f["body_positions"].shape == (clip.frames, primate.nbody, 3)
            assert np.array_equal(f["body_positions"], primate.fk(q)[..., :3, 3])
            assert list(f["body_names"]) == primate.names("body")


def test_csv_and_json_files(tmp_path: Path, primate: mjkin.Tree) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "b.bvh"], frames=8)
    retarget_many(src, "primate", tmp_path / "npz")
    retarget_many(src, "primate", tmp_path / "csv", format="csv")
    retarget_many(src, "primate", tmp_path / "json", format="json")
    for name in ("a", "b"):
        q = np.load(tmp_path / "npz" / f"{name}.npz")["qpos"]
        path = tmp_path / "csv" / f"{name}.csv"
        assert np.array_equal(np.loadtxt(path, delimiter=","), q)  # exact: 17 significant digits
        header = [line[2:] for line in path.read_text().splitlines() if line.startswith("#")]
        assert header[-1].split(",") == qpos_names(primate) and len(header[-1].split(",")) == primate.nq
        assert any(line == f"fps: {bvh.read(src / f'{name}.bvh').fps!r}" for line in header)
        traj = Trajectory.load(tmp_path / "json" / f"{name}.json", primate)
        assert np.array_equal(traj.q, q) and traj.source == "primate"


def test_qpos_names_of_ball_free_and_unnamed_joints() -> None:
    tree = mjkin.load("""<mujoco model="m"><worldbody><body name="a"><freejoint name="root"/><geom size=".1"/>
        <body name="b"><joint name="neck" type="ball"/><geom size=".1"/><body name="c"><joint axis="0 0 1"/>
        <geom size=".1"/></body></body></body></worldbody></mujoco>""")
    assert qpos_names(tree) == ["root_x", "root_y", "root_z", "root_qw", "root_qx", "root_qy", "root_qz",
                                "neck_qw", "neck_qx", "neck_qy", "neck_qz", "joint2"]


def test_a_bad_clip_gets_a_row_and_the_others_finish(tmp_path: Path) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "c.bvh"], frames=8)
    (src / "b.bvh").write_text("HIERARCHY\nROOT Hips\n{\nOFFSET 0 0\n")  # broken
    (src / "d.bvh").write_text(crouch_bvh(6, names={"knee": "{S}Shin_Bone"}))  # no knee by name: unmappable
    np.savez(src / "e.npz", nothing=np.zeros(3))  # not an AMASS clip
    out = tmp_path / "out"
    rows = retarget_many(src, "primate", out)
    status = {r["clip"]: r["status"] for r in rows}
    assert status["a.bvh"] == status["c.bvh"] == "ok"
    for bad in ("b.bvh", "d.bvh", "e.npz"):
        assert status[bad] != "ok" and "\n" not in status[bad] and status[bad]
    assert "cannot map left_knee" in status["d.bvh"]
    assert [p.name for p in sorted(out.iterdir())] == ["a.npz", "c.npz", REPORT]
    assert {r["clip"]: r["status"] for r in rows_of(out / REPORT)} == status


def test_odd_files_in_a_dataset_get_a_row_each_and_the_others_finish(tmp_path: Path) -> None:
    """A FIFO named x.bvh hung the run for ever, a link to /dev/zero read until the memory ran out, a link to a
    private file put its first line into report.csv; a clip named in bytes that are not UTF-8 stopped the whole
    run when report.csv was written."""
    src = crouches(tmp_path / "clips", ["a.bvh", "c.bvh"], frames=6)
    os.mkfifo(src / "x.bvh")
    (src / "zero.bvh").symlink_to("/dev/zero")
    (tmp_path / "shadow").write_text("root:$6$s3cr3t:19000:0:99999:7:::\n")
    (src / "shadow.bvh").symlink_to(tmp_path / "shadow")
    bad = os.fsdecode(b"bad\xff\xfe.bvh")
    (src / bad).write_text(crouch_bvh(6))
    out = tmp_path / "out"
    with no_hang(120):  # a FIFO read waits for ever
        rows = retarget_many(src, "primate", out)
    status = {r["clip"]: r["status"] for r in rows}
    assert status == {
        "a.bvh": "ok", bad: "ok", "c.bvh": "ok",
        "shadow.bvh": f"BVH {str(src / 'shadow.bvh')!r} line 1: a BVH file starts with HIERARCHY; this one does not",
        "x.bvh": f"BVH file {str(src / 'x.bvh')!r} is a FIFO (named pipe), not a regular file; give the file itself",
        "zero.bvh": f"BVH file {str(src / 'zero.bvh')!r} is a character device, not a regular file; give the file "
                    "itself"}
    assert "s3cr3t" not in (out / REPORT).read_text(errors="replace")
    assert (out / os.fsdecode(b"bad\xff\xfe.npz")).is_file()
    again = retarget_many(src, "primate", out)  # the report, names in bytes and all, reads back: nothing redone
    assert {r["clip"]: r["status"] for r in again} == status


@pytest.mark.parametrize("case", ["fifo", "cell"])
def test_a_previous_report_that_is_odd_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                    case: str) -> None:
    """report.csv as a FIFO hung the run; a cell over 128 kB (csv's field limit) was a traceback."""
    src = crouches(tmp_path / "clips", ["a.bvh", "b.bvh"], frames=4)
    out = tmp_path / "out"
    out.mkdir()
    if case == "fifo":
        os.mkfifo(out / REPORT)
    else:
        (out / REPORT).write_text("clip,status\na.bvh," + "x" * 200_000 + "\n")
    with no_hang(120):
        assert run(["retarget", str(src), "--model", "primate", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"previous report {str(out / REPORT)!r}" in err, err
    assert ("is a FIFO (named pipe), not a regular file" if case == "fifo" else "a cell over 131072 characters") in err
    assert err.rstrip().endswith("delete it or give overwrite")


def test_one_clip_that_is_a_fifo_is_called_a_fifo(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """It was 'clip or folder not found'."""
    os.mkfifo(tmp_path / "x.bvh")
    with no_hang():
        assert run(["retarget", str(tmp_path / "x.bvh"), "--model", "primate", "-o", str(tmp_path / "x.npz")]) == 2
    err = capsys.readouterr().err
    assert err == (f"mjkin: error: clip {str(tmp_path / 'x.bvh')!r} is a FIFO (named pipe), not a regular file; give "
                   "the clip file itself\n")


def test_npz_clips_take_the_body_model(tmp_path: Path) -> None:
    model = write_body_model(tmp_path / "model.npz")  # outside the folder: it is no clip
    angles, root = motion(52, 6)
    src = crouches(tmp_path / "clips", ["crouch.bvh"], frames=6)
    write_clip(src / "walk.npz", angles, root, shaped_rest(model, np.linspace(-1.0, 1.0, 16), 16))
    without = {r["clip"]: r["status"] for r in retarget_many(src, "primate", tmp_path / "a")}
    assert without["crouch.bvh"] == "ok" and without["walk.npz"] != "ok"
    rows = retarget_many(src, "primate", tmp_path / "b", body_model=model)  # the BVH beside it is read without it
    assert [r["status"] for r in rows] == ["ok", "ok"]
    tree = mjkin.load("primate")
    q = np.load(tmp_path / "b" / "walk.npz")["qpos"]
    assert np.array_equal(q, mjkin.retarget(smpl.read(src / "walk.npz", model), tree).q)


def test_finished_clips_are_skipped_and_overwrite_redoes_them(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "b.bvh", "sub/c.bvh"], frames=8)
    (src / "bad.bvh").write_text("HIERARCHY\n")
    out = tmp_path / "out"
    first = retarget_many(src, "primate", out)
    files = {p: (p.stat().st_ino, p.stat().st_mtime_ns) for p in out.rglob("*.npz")}
    solved = count_solves(monkeypatch)
    again = retarget_many(src, "primate", out)
    assert solved == []  # bad.bvh fails at reading, before a solve; the others are done
    assert {p: (p.stat().st_ino, p.stat().st_mtime_ns) for p in out.rglob("*.npz")} == files  # not rewritten
    assert again == first  # the rows of the skipped clips come back from report.csv, values and all
    (out / "b.npz").unlink()  # a finished clip's file gone: it is done again
    retarget_many(src, "primate", out)
    assert solved == ["b.bvh"]
    solved.clear()
    retarget_many(src, "primate", out, overwrite=True)
    assert sorted(solved) == ["a.bvh", "b.bvh", "c.bvh"]
    assert all(p.stat().st_ino != files[p][0] for p in files)


def test_a_killed_run_loses_no_finished_clip(tmp_path: Path) -> None:
    n = 12
    src = crouches(tmp_path / "clips", [f"c{k:02d}.bvh" for k in range(n)], frames=100)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "mjkin.apps.cli", "retarget", str(src), "--model", "primate", "-o", str(out)]
    child = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        while child.poll() is None and len(read_report(out / REPORT) if (out / REPORT).is_file() else {}) < 2:
            time.sleep(0.005)
        child.send_signal(signal.SIGKILL)
    finally:
        child.wait()
    assert child.returncode == -signal.SIGKILL  # killed before it finished
    done = read_report(out / REPORT)
    assert 2 <= len(done) < n
    visible = sorted(p for p in out.iterdir() if not p.name.startswith("."))
    for p in visible:  # every file there is whole
        if p.suffix == ".npz":
            assert np.load(p)["qpos"].shape == (100, mjkin.load("primate").nq)
    assert {f"{c.removesuffix('.bvh')}.npz" for c in done} <= {p.name for p in visible}
    kept = {c: (out / f"{c.removesuffix('.bvh')}.npz").stat().st_mtime_ns for c in done}
    rows = retarget_many(src, "primate", out)  # resumed
    assert [r["status"] for r in rows] == ["ok"] * n and temps(out) == []
    assert {c: (out / f"{c.removesuffix('.bvh')}.npz").stat().st_mtime_ns for c in done} == kept


def test_two_workers_give_the_same_bits(tmp_path: Path) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "b.bvh", "sub/c.bvh", "d.bvh"], frames=10)
    (src / "bad.bvh").write_text("HIERARCHY\n")
    one = retarget_many(src, "primate", tmp_path / "one")
    two = retarget_many(src, "primate", tmp_path / "two", workers=2)
    for a, b in zip(one, two, strict=True):
        assert {k: v for k, v in a.items() if k != "frames_per_second"} == \
            {k: v for k, v in b.items() if k != "frames_per_second"}
    for p in (tmp_path / "one").rglob("*.npz"):
        with np.load(p) as f, np.load(tmp_path / "two" / p.relative_to(tmp_path / "one")) as g:
            assert np.array_equal(f["qpos"], g["qpos"]) and np.array_equal(f["body_positions"], g["body_positions"])


@pytest.mark.skipif(ray is not None, reason="checks the message shown without Ray")
def test_ray_without_ray_says_what_to_install(tmp_path: Path) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "b.bvh"], frames=6)
    with pytest.raises(MjkinError, match=r'pip install "mjkin\[ray\]"'):
        retarget_many(src, "primate", tmp_path / "out", ray=True)


@pytest.mark.skipif(ray is None, reason="needs the ray extra")
def test_ray_tasks_give_the_same_bits(tmp_path: Path) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "b.bvh", "bad.bvh"], frames=8)
    (src / "bad.bvh").write_text("HIERARCHY\n")
    one = retarget_many(src, "primate", tmp_path / "one")
    started = not ray.is_initialized()  # a session of another test in this process (test workers mix modules)
    try:
        on_ray = retarget_many(src, "primate", tmp_path / "ray", ray=True, workers=2)
    finally:
        if started:
            ray.shutdown()
    assert [r["status"] for r in on_ray] == [r["status"] for r in one]
    for name in ("a", "b"):
        assert np.array_equal(np.load(tmp_path / "one" / f"{name}.npz")["qpos"],
                              np.load(tmp_path / "ray" / f"{name}.npz")["qpos"])


def test_checked_before_any_work(tmp_path: Path) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh"], frames=6)
    with pytest.raises(InputError, match="format must be"):
        retarget_many(src, "primate", tmp_path / "out", format="parquet")
    with pytest.raises(InputError, match="workers must be"):
        retarget_many(src, "primate", tmp_path / "out", workers=0)
    with pytest.raises(InputError, match="unexpected keyword argument 'speed'"):
        retarget_many(src, "primate", tmp_path / "out", speed=3.0)
    with pytest.raises(MjkinIOError, match="mapping file not found"):
        retarget_many(src, "primate", tmp_path / "out", mapping=tmp_path / "nope.json")
    with pytest.raises(MjkinIOError, match="scene file not found"):
        retarget_many(src, "primate", tmp_path / "out", scene=tmp_path / "nope.xml")
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match="is a file"):
        retarget_many(src, "primate", tmp_path / "file")
    crouches(tmp_path / "other", ["a.bvh"])
    with pytest.raises(InputError, match="would both write"):
        retarget_many([src, tmp_path / "other"], "primate", tmp_path / "out")
    (src / "report.bvh").write_text(crouch_bvh(4))
    with pytest.raises(InputError, match="the report and clip"):
        retarget_many(src, "primate", tmp_path / "out", format="csv")
    assert not (tmp_path / "out").exists()


@given(st.lists(st.lists(st.sampled_from("abcdefg"), unique=True).map(sorted), min_size=1, max_size=6))
def test_columns_keep_every_rows_order_with_status_last(keys: list[list[str]]) -> None:
    rows = [{"clip": "x", **dict.fromkeys(k, 1), "status": "ok"} for k in keys]
    cols = columns(rows)
    assert sorted(cols) == sorted({"clip", "status"}.union(*keys)) and cols[0] == "clip" and cols[-1] == "status"
    for row in rows:
        assert sorted(row, key=cols.index) == list(row)  # each row's own order (report's), whatever its keys
    # a measure only some clips have (terrain) goes where report puts it, not at the end
    assert columns([{"clip": 1, "floor": 1, "speed": 1}, {"clip": 1, "floor": 1, "terrain": 1, "speed": 1}]) == \
        ["clip", "floor", "terrain", "speed", "status"]
    assert columns([{"clip": 1, "a": 1, "b": 1, "status": 1}, {"clip": 1, "b": 1, "a": 1}]) == \
        ["clip", "a", "b", "status"]  # rows that disagree: the order first seen


# report values: None, numbers, and texts that read as no number (a limits message)
values = st.one_of(st.none(), st.integers(-10**6, 10**6), st.floats(allow_nan=False),
                   st.text("abxyz ,\"\n", min_size=1))


@given(st.lists(st.fixed_dictionaries({"frames": values, "limits": values, "floor_min": values}), min_size=1,
                max_size=4))
def test_report_values_come_back_from_the_csv(tmp_path_factory: pytest.TempPathFactory, rows: list[dict]) -> None:
    path = tmp_path_factory.mktemp("report") / REPORT
    rows = [{"clip": f"c{k},\"{k}\".bvh", **row, "status": "ok"} for k, row in enumerate(rows)]
    written = ReportFile(path, [r["clip"] for r in rows])
    for row in rows:
        written.put(row)
    written.write()
    assert list(read_report(path).values()) == rows


def test_the_report_file_takes_a_new_column_where_report_puts_it(tmp_path: Path) -> None:
    written = ReportFile(tmp_path / REPORT, ["b", "a", "c"])
    written.put({"clip": "a", "floor": 0.5, "speed": 2, "status": "ok"})
    written.write()
    written.put({"clip": "b", "floor": -0.25, "terrain": 0.125, "speed": 3, "status": "ok"})
    written.put({"clip": "c", "status": "InputError: no"})
    written.write()
    assert (tmp_path / REPORT).read_text().splitlines() == [
        "clip,floor,terrain,speed,status", "b,-0.25,0.125,3,ok", "a,0.5,,2,ok", "c,,,,InputError: no"]


def test_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "sub/b.bvh"], frames=6)
    out = tmp_path / "out"
    assert run(["retarget", str(src), "--model", "primate", "-o", str(out), "--format", "csv", "--workers", "2"]) == 0
    said = capsys.readouterr()
    assert "2 of 2 clips on primate" in said.out and said.err == ""
    assert (out / "a.csv").is_file() and (out / "sub" / "b.csv").is_file() and (out / REPORT).is_file()
    (src / "bad.bvh").write_text("HIERARCHY\n")
    assert run(["retarget", str(src), "--model", "primate", "-o", str(out), "--format", "csv"]) == 3  # one failed
    said = capsys.readouterr()
    assert "2 of 3 clips" in said.out and said.err.startswith("mjkin: 1 clip not retargeted (the error in report")
    one = tmp_path / "one.npz"  # one clip: -o names the file
    assert run(["retarget", str(src / "a.bvh"), "--model", "primate", "-o", str(one)]) == 0
    assert "wrote" in capsys.readouterr().out
    assert np.array_equal(np.loadtxt(out / "a.csv", delimiter=","), np.load(one)["qpos"])


@pytest.mark.parametrize("value, held", [("off", None), ("none", None), ("0.004", 0.004), (None, SELF_CLEARANCE)])
def test_command_line_clearance_is_metres_or_off(tmp_path: Path, value: str | None, held: float | None) -> None:
    """``--clearance off`` turns the self-clearance off, as ``clearance=None`` does in Python; the file says which."""
    src = crouches(tmp_path / "clips", ["a.bvh"], frames=4) / "a.bvh"
    out = tmp_path / "a.json"
    assert run(["retarget", str(src), "--model", "primate", "-o", str(out),
                *([] if value is None else ["--clearance", value])]) == 0
    assert Trajectory.load(out, mjkin.load("primate")).meta["retarget"]["clearance"] == held


@pytest.mark.parametrize("value", ["-0.01", "nan", "inf", "two mm", ""])
def test_command_line_clearance_that_is_neither_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                            value: str) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh"], frames=4) / "a.bvh"
    assert run(["retarget", str(src), "--model", "primate", "-o", str(tmp_path / "a.json"), "--clearance", value]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--clearance: must be metres >= 0, or off" in err


@pytest.mark.parametrize("case", ["missing", "empty", "format", "retime", "no output", "not a clip", "same file",
                                  "retime npz", "format one"])
def test_command_line_mistakes_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "b.bvh"], frames=4)
    (tmp_path / "empty").mkdir()
    (tmp_path / "notes.txt").write_text("")
    crouches(tmp_path / "other", ["a.bvh"])
    out = str(tmp_path / "out")
    args = {"missing": [str(tmp_path / "nope"), "-o", out], "empty": [str(tmp_path / "empty"), "-o", out],
            "format": [str(src), "-o", out, "--format", "xlsx"], "retime": [str(src), "-o", out, "--retime"],
            "no output": [str(src)], "not a clip": [str(tmp_path / "notes.txt"), "-o", out],
            "same file": [str(src / "a.bvh"), str(tmp_path / "other" / "a.bvh"), "-o", out],
            "retime npz": [str(src / "a.bvh"), "-o", str(tmp_path / "a.npz"), "--retime"],
            "format one": [str(src / "a.bvh"), "-o", str(tmp_path / "a.json"), "--format", "csv"]}[case]
    assert run(["retarget", *args, "--model", "primate"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists() and not (tmp_path / "a.npz").exists()
