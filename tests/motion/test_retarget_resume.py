"""Resuming a dataset run: report.csv records what each file was made from (model digest, options, mjkin version),
and a rerun redoes a clip whose record differs or whose file does not load; the output folder may be the input's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_retarget import G1
from test_retarget_dataset import count_solves, crouches, rows_of
from test_smpl import motion, shaped_rest, write_body_model, write_clip

import mjkin
from mjkin.apps.cli import run
from mjkin.errors import InputError
from mjkin.motion import Trajectory, dataset
from mjkin.motion.dataset import REPORT, retarget_many


@pytest.fixture
def solved(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The names of the clips retargeted (solved) in this process from now on."""
    return count_solves(monkeypatch)


def qpos_of(path: Path) -> np.ndarray:
    """The qpos a clip's file holds, whatever its format."""
    if path.suffix == ".npz":
        with np.load(path) as f:
            return f["qpos"]
    return np.loadtxt(path, delimiter=",", ndmin=2) if path.suffix == ".csv" else Trajectory.load(path).q


def test_the_report_records_what_each_file_was_made_from(tmp_path: Path) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "b.bvh"], frames=6)
    (src / "bad.bvh").write_text("HIERARCHY\n")
    rows = retarget_many(src, "primate", tmp_path / "out")
    written = rows_of(tmp_path / "out" / REPORT)
    assert list(written[0])[:3] == ["clip", "frames", "fps"] and list(written[0])[-1] == "status"
    for row in written:
        assert len(row["model_sha256"]) == 64 and row["mjkin_version"] == mjkin.__version__
        assert '"scale": null' in row["options"] and '"clearance": 0.002' in row["options"]
    assert {r["model_sha256"] for r in written} == {r["model_sha256"] for r in rows}  # the rows say the same
    other = retarget_many(src, "primate", tmp_path / "again", overwrite=True)
    assert [r["model_sha256"] for r in other] == [r["model_sha256"] for r in rows]  # stable from run to run


def test_a_rerun_with_other_options_redoes_every_clip(tmp_path: Path, solved: list[str]) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "b.bvh"], frames=6)
    out = tmp_path / "out"
    retarget_many(src, "primate", out)
    for options in ({"scale": 0.011}, {"max_speed": 8.0}, {"clearance": None}, {"clearance": 0.004}):
        solved.clear()
        retarget_many(src, "primate", out, **options)
        assert sorted(solved) == ["a.bvh", "b.bvh"], options
        solved.clear()
        retarget_many(src, "primate", out, **options)  # the same again: done
        assert solved == [], options
    retarget_many(src, "primate", out, clearance=0.004, max_error=0.5)  # the bound only judges: nothing to redo
    assert solved == []


def test_a_rerun_onto_another_model_redoes_every_clip(tmp_path: Path, solved: list[str]) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "b.bvh"], frames=6)
    out = tmp_path / "out"
    retarget_many(src, "primate", out)
    solved.clear()
    text = mjkin.bundled_models()["primate"].read_text()
    changed = tmp_path / "primate_site.xml"  # the same figure with one more site: another model
    changed.write_text(text.replace("</worldbody>", '<site name="extra_marker" pos="3 3 3"/></worldbody>', 1))
    retarget_many(src, changed, out)
    assert sorted(solved) == ["a.bvh", "b.bvh"]


@pytest.mark.skipif(not G1.is_file(), reason=f"the shared G1 is not here ({G1})")
def test_the_command_line_onto_the_g1_after_the_primate(tmp_path: Path) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "b.bvh"], frames=6)
    out = tmp_path / "out"
    assert run(["retarget", str(src), "--model", "primate", "-o", str(out)]) == 0
    assert run(["retarget", str(src), "--model", str(G1), "-o", str(out)]) == 0
    g1 = mjkin.load(G1)
    for name in ("a", "b"):
        with np.load(out / f"{name}.npz") as f:
            assert f["qpos"].shape == (6, g1.nq)
    assert {r["model_sha256"] for r in rows_of(out / REPORT)} == {dataset.model_digest(g1.model)}


@pytest.mark.parametrize("fmt", ["npz", "csv", "json"])
def test_a_file_that_does_not_load_is_redone(tmp_path: Path, solved: list[str], fmt: str) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "b.bvh", "c.bvh"], frames=6)
    out = tmp_path / "out"
    retarget_many(src, "primate", out, format=fmt)
    solved.clear()
    q = qpos_of(out / f"a.{fmt}")
    whole = (out / f"a.{fmt}").read_bytes()
    (out / f"a.{fmt}").write_bytes(whole[:len(whole) // 2])  # cut in half
    (out / f"b.{fmt}").write_bytes(b"")  # emptied
    rows = retarget_many(src, "primate", out, format=fmt)
    assert sorted(solved) == ["a.bvh", "b.bvh"] and [r["status"] for r in rows] == ["ok"] * 3
    assert np.array_equal(qpos_of(out / f"a.{fmt}"), q)


def test_a_file_of_another_shape_is_redone(tmp_path: Path, solved: list[str]) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "b.bvh"], frames=6)
    out = tmp_path / "out"
    retarget_many(src, "primate", out)
    solved.clear()
    with np.load(out / "a.npz") as f:
        arrays = dict(f)
    np.savez(out / "a.npz", **{**arrays, "qpos": arrays["qpos"][:, :-1]})  # a column short
    retarget_many(src, "primate", out)
    assert solved == ["a.bvh"]


def test_an_old_report_without_the_record_is_redone(tmp_path: Path, solved: list[str]) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "b.bvh"], frames=6)
    out = tmp_path / "out"
    retarget_many(src, "primate", out)
    solved.clear()
    (out / REPORT).write_text("clip,frames,fps,status\na.bvh,6,30.0,ok\nb.bvh,6,30.0,ok\n")  # an older mjkin's
    retarget_many(src, "primate", out)
    assert sorted(solved) == ["a.bvh", "b.bvh"]
    assert all(r["model_sha256"] for r in rows_of(out / REPORT))


def test_the_output_folder_may_be_the_input_folder(tmp_path: Path, solved: list[str]) -> None:
    src = crouches(tmp_path / "clips", ["a.bvh", "sub/b.bvh"], frames=6)
    first = retarget_many(src, "primate", src)
    assert [r["status"] for r in first] == ["ok", "ok"] and (src / "sub" / "b.npz").is_file()
    solved.clear()
    again = retarget_many(src, "primate", src)  # its .npz files are outputs, not clips
    assert solved == [] and again == first
    q = qpos_of(src / "a.npz")
    whole = (src / "a.npz").read_bytes()
    (src / "a.npz").write_bytes(whole[:len(whole) // 2])  # a damaged output there: listed in report.csv, redone
    retarget_many(src, "primate", src)
    assert solved == ["a.bvh"] and np.array_equal(qpos_of(src / "a.npz"), q)
    assert run(["retarget", str(src), "--model", "primate", "-o", str(src)]) == 0
    assert solved == ["a.bvh"]


def test_an_amass_clip_in_the_output_folder_is_a_clip_never_overwritten(tmp_path: Path) -> None:
    model = write_body_model(tmp_path / "model.npz")
    angles, root = motion(52, 6)
    src = crouches(tmp_path / "clips", ["crouch.bvh"], frames=6)
    write_clip(src / "walk.npz", angles, root, shaped_rest(model, np.linspace(-1.0, 1.0, 16), 16))
    amass = (src / "walk.npz").read_bytes()
    with pytest.raises(InputError, match="would overwrite clip"):
        retarget_many(src, "primate", src, body_model=model)  # walk.npz would be its own output
    rows = retarget_many(src, "primate", src, body_model=model, format="csv")
    assert [r["status"] for r in rows] == ["ok", "ok"] and (src / "walk.csv").is_file()
    assert (src / "walk.npz").read_bytes() == amass
    assert [r["clip"] for r in retarget_many(src, "primate", src, body_model=model, format="csv")] == \
        ["crouch.bvh", "walk.npz"]
