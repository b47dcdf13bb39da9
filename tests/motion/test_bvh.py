"""BVH reading: FK of small files written here against hand-computed positions, channel orders, End Sites,
units, one-line errors; the two shared clips."""

from __future__ import annotations

import os
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from conftest import no_hang
from mjkin.apps.bench.retarget import mocap_dir
from mjkin.errors import InputError, MjkinError
from mjkin.motion import bvh
from mjkin.runtime import files

MOCAP = mocap_dir() or Path("../shared/mocap")  # found as the benchmarks find them (also from a worktree)
need_mocap = pytest.mark.skipif(not MOCAP.is_dir(), reason=f"the shared clips are not here ({MOCAP})")

# root at (1, 2, 3) turned 90 deg about z; child offset (0, 10, 0) turned 90 deg about x; an End Site (0, 0, 5)
SMALL = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Left Knee
  {
    OFFSET 0 10 0
    CHANNELS 3 {order}
    End Site
    {
      OFFSET 0 0 5
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0083333
1 2 3 0 0 0 0 0 0
1 2 3 90 0 0 {angles}
"""


def small(order: str = "Xrotation Yrotation Zrotation", angles: str = "90 0 0") -> str:
    return SMALL.replace("{order}", order).replace("{angles}", angles)


def test_fk_by_hand() -> None:
    clip = bvh.parse(small())
    assert clip.names == ("Hips", "Left Knee", "Left Knee_End")  # names may hold spaces
    assert clip.ends.tolist() == [False, False, True]
    assert clip.frames == 2 and clip.fps == pytest.approx(120, rel=1e-4)
    p = clip.positions()
    np.testing.assert_allclose(p[0], [[1, 2, 3], [1, 12, 3], [1, 12, 8]], atol=1e-12)
    # frame 1: Rz(90) maps y to -x; the knee's Rx(90) maps its z to -y, then Rz(90): -y -> +x
    np.testing.assert_allclose(p[1], [[1, 2, 3], [-9, 2, 3], [-4, 2, 3]], atol=1e-12)


@pytest.mark.parametrize("order", ["Zrotation Xrotation Yrotation", "Yrotation Xrotation Zrotation",
                                   "Xrotation Zrotation Yrotation"])
def test_channel_order_is_the_product_in_listed_order(order: str) -> None:
    angles = {"X": 30.0, "Y": -50.0, "Z": 70.0}
    axes = [w[0] for w in order.split()]
    clip = bvh.parse(small(order, " ".join(str(angles[a]) for a in axes)))

    def rot(axis: str, deg: float) -> np.ndarray:
        c, s = np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))
        i, j = [(1, 2), (2, 0), (0, 1)]["XYZ".index(axis)]
        R = np.eye(3)
        R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
        return R

    R_knee = rot(axes[0], angles[axes[0]]) @ rot(axes[1], angles[axes[1]]) @ rot(axes[2], angles[axes[2]])
    R_root = rot("Z", 90)
    end = np.array([1, 2, 3]) + R_root @ (np.array([0, 10, 0]) + R_knee @ [0, 0, 5])
    np.testing.assert_allclose(clip.positions()[1, 2], end, atol=1e-12)


def test_six_channels_on_a_child_replace_its_offset() -> None:
    text = small().replace("CHANNELS 3 Xrotation Yrotation Zrotation",
                           "CHANNELS 6 Xposition Yposition Zposition Xrotation Yrotation Zrotation")
    text = text.replace("1 2 3 0 0 0 0 0 0", "1 2 3 0 0 0 0 10 0 0 0 0").replace("1 2 3 90 0 0 90 0 0",
                                                                               "1 2 3 0 0 0 0 20 0 0 0 0")
    p = bvh.parse(text).positions()
    np.testing.assert_allclose(p[:, 1], [[1, 12, 3], [1, 22, 3]], atol=1e-12)


def test_units_from_height() -> None:
    tall = small().replace("OFFSET 0 10 0", "OFFSET 0 170 0").replace("OFFSET 0 0 5", "OFFSET 0 0 0")
    assert bvh.unit_scale(bvh.parse(tall)) == (0.01, "cm")
    assert bvh.unit_scale(bvh.parse(tall.replace("OFFSET 0 170 0", "OFFSET 0 1.7 0"))) == (1.0, "m")
    assert bvh.unit_scale(bvh.parse(tall.replace("OFFSET 0 170 0", "OFFSET 0 67 0"))) == (0.0254, "in")
    with pytest.raises(InputError, match="--scale"):
        bvh.unit_scale(bvh.parse(tall.replace("OFFSET 0 170 0", "OFFSET 0 0.1 0")))


@pytest.mark.parametrize(("edit", "message"), [
    (("HIERARCHY", "HIERARCHI"), "line 1: a BVH file starts with HIERARCHY; this one does not"),
    (("OFFSET 0 10 0", "OFFSET 0 ten 0"), "line 8: expected a number"),
    (("Zrotation Xrotation Yrotation", "Zrotation Xrotation Wrotation"), "unknown channel 'wrotation'"),
    (("Frames: 2", "Frames: 3"), "needs 27 numbers, found 18"),
    (("Frame Time: 0.0083333", "Frame Time: 0"), "Frame Time: must be a finite number of seconds"),
    (("1 2 3 90 0 0 90 0 0", "1 2 3 90 0 0 90 x 0"), "expected a channel value"),
    (("  }\n}\nMOTION", "  }\nMOTION"), "expected JOINT, End Site or '}'"),
    (("MOTION", "MOTIONS"), "expected 'MOTION'"),
    (("JOINT Left Knee", "JOINT Hips"), "joint name 'Hips' appears twice"),
])
def test_malformed_files_are_one_line_errors(edit: tuple[str, str], message: str) -> None:
    with pytest.raises(bvh.BvhError, match=message) as e:
        bvh.parse(small().replace(*edit), "bad.bvh")
    assert "\n" not in str(e.value) and "bad.bvh" in str(e.value)
    assert isinstance(e.value, MjkinError)


def test_a_bad_channel_value_names_its_line() -> None:
    text = small().replace("1 2 3 90 0 0 90 0 0", "1 2 3 90 0 0 90 1.5.5 0")
    with pytest.raises(bvh.BvhError) as e:
        bvh.parse(text, "bad.bvh")
    assert str(e.value) == "BVH 'bad.bvh' line 20: expected a channel value (a number), got '1.5.5'"


def test_odd_spaces_line_ends_and_words_after_the_last_frame_read_as_before() -> None:
    """The values are read in bulk, and again a line at a time when the bulk read stops: the same numbers."""
    text = small().replace("1 2 3 90 0 0 90 0 0", "1\u00a02 3 90 0 0\r\n90\u20030 0").rstrip() + " end of clip\n"
    clip = bvh.parse(text)
    np.testing.assert_array_equal(clip.values, [[1, 2, 3, 0, 0, 0, 0, 0, 0], [1, 2, 3, 90, 0, 0, 90, 0, 0]])


def test_parsing_takes_a_few_times_the_files_size(tmp_path: Path) -> None:
    """Each value was a Python float in a list of tokens: ~30x the file's size in memory; now they are read in bulk."""
    values = np.round(np.random.default_rng(0).uniform(-180, 180, (20_000, 9)), 4)
    path = tmp_path / "long.bvh"
    path.write_text(small().split("MOTION")[0] + "MOTION\nFrames: 20000\nFrame Time: 0.01\n"
                    + "\n".join(" ".join(f"{v:.4f}" for v in row) for row in values) + "\n")
    tracemalloc.start()
    try:
        clip = bvh.read(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(clip.values, values)
    assert peak < 5 * path.stat().st_size  # the text, its motion block, the values (main: 27x)


def test_positions_of_a_long_clip_take_little_more_room_than_themselves(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every frame's (J, 4, 4) transforms were made at once: 15x the room of the positions (1.3 GB for 160k frames)."""
    monkeypatch.setattr(bvh, "CHUNK", 256, raising=False)  # this clip is as long as 80 of them
    F = 80 * 256 + 5
    angles = np.random.default_rng(1).uniform(-90, 90, (F, 9))
    clip = bvh.parse(small().split("MOTION")[0] + f"MOTION\nFrames: {F}\nFrame Time: 0.01\n"
                     + "\n".join(" ".join(map(str, row)) for row in angles))
    tracemalloc.start()
    try:
        p = clip.positions()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2 * p.nbytes
    np.testing.assert_array_equal(p, clip.world()[..., :3, 3])
    np.testing.assert_array_equal(clip.positions(np.array([7, 3])), p[[7, 3]])


@pytest.mark.parametrize("bad", ["0", "-0.0083333", "nan", "inf", "1e-320", "11"])
def test_frame_time_outside_1e_4_to_10_seconds_is_a_one_line_error(bad: str) -> None:
    with pytest.raises(bvh.BvhError) as e:
        bvh.parse(small().replace("Frame Time: 0.0083333", f"Frame Time: {bad}"), "bad.bvh")
    assert str(e.value) == (f"BVH 'bad.bvh' line 18: Frame Time: must be a finite number of seconds from 0.0001 "
                            f"to 10, got {bad!r}")
    assert isinstance(e.value, MjkinError)


@pytest.mark.parametrize("good", [repr(1 / 120), "0.0001", "10"])
def test_frame_times_in_range_are_kept(good: str) -> None:
    clip = bvh.parse(small().replace("Frame Time: 0.0083333", f"Frame Time: {good}"))
    assert clip.frame_time == float(good)


def chain(depth: int) -> str:
    """A BVH chain of ``depth`` joints, each nested in the one before and 1 unit above it, ending in an End Site."""
    opening = "".join(f"{'ROOT' if k == 0 else 'JOINT'} J{k}\n{{\n  OFFSET 0 1 0\n  CHANNELS 3 Zrotation Xrotation "
                      "Yrotation\n" for k in range(depth))
    closing = "}\n" * depth
    return (f"HIERARCHY\n{opening}End Site\n{{\n  OFFSET 0 1 0\n}}\n{closing}MOTION\nFrames: 1\n"
            f"Frame Time: 0.0083333\n{'0 ' * (3 * depth)}\n")


def test_a_1000_deep_chain_loads() -> None:
    clip = bvh.parse(chain(1000))
    assert clip.names[-2:] == ("J999", "J999_End") and len(clip.names) == 1001
    assert clip.parents.tolist() == list(range(-1, 1000))
    np.testing.assert_allclose(clip.positions()[0, :, 1], np.arange(1, 1002))


def test_an_unclosed_chain_names_the_missing_brace() -> None:
    with pytest.raises(bvh.BvhError, match=r"line 19: file ends early; expected }$"):
        bvh.parse(chain(3).split("MOTION")[0][:-2])  # the root left open


def test_truncated_and_missing_files(tmp_path: Path) -> None:
    with pytest.raises(bvh.BvhError, match="file ends early"):
        bvh.parse(small()[:60])
    with pytest.raises(bvh.BvhError, match="not found"):
        bvh.read(tmp_path / "none.bvh")


@need_mocap
@pytest.mark.parametrize(("name", "frames", "joints", "root"), [
    ("mixamo_freebvh", 69, 55, "mixamorig:Hips"), ("mocapbank_19joint", 455, 19, "Hips")])
def test_shared_clips(name: str, frames: int, joints: int, root: str) -> None:
    clip = bvh.read(MOCAP / f"{name}.bvh")
    assert clip.frames == frames and clip.fps == pytest.approx(30, rel=1e-4) and clip.names[0] == root
    assert int((~clip.ends).sum()) == joints
    assert bvh.unit_scale(clip) == (0.01, "cm")
    p = clip.positions()
    height = p[0, :, 1].max() - p[0, :, 1].min()
    assert 140 < height < 200 and np.isfinite(p).all()  # a person in centimetres, upright along y


def test_the_cli_on_a_1000_deep_chain_says_one_short_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """It printed a RecursionError traceback; then a line listing all 1001 joints: now the first 40 and a count."""
    from mjkin.apps.cli import main

    clip = tmp_path / "deep.bvh"
    clip.write_text(chain(1000))
    assert main(["retarget", str(clip), "--model", "primate", "-o", str(tmp_path / "out.json")]) == 2
    err = "".join(line for line in capsys.readouterr().err.splitlines(True)  # not a compile's notices
                  if line.startswith("mjkin: error: ") or not line.startswith("mjkin: "))
    assert err.count("\n") == 1 and "cannot map" in err and "(961 more)" in err and len(err) < 1500


# ------------------------------------------------------------------ hostile and odd files
def odd_file(tmp_path: Path, kind: str, name: str = "x.bvh") -> Path:
    """A file called ``name`` that is no regular BVH file: a FIFO, a link to /dev/zero, a folder, a huge sparse file."""
    path = tmp_path / name
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "/dev/zero":
        path.symlink_to("/dev/zero")
    elif kind == "folder":
        path.mkdir()
    elif kind == "huge":
        with path.open("wb") as f:
            f.truncate(files.LIMITS["bvh"] + 1)  # sparse: no disk used
    return path


@pytest.mark.parametrize("kind, message", [
    ("fifo", "is a FIFO (named pipe), not a regular file"), ("/dev/zero", "is a character device, not a regular file"),
    ("folder", "is a folder, not a regular file"),
    ("huge", "is over 64 MB, the most mjkin reads of a BVH file; is it the right file?")])
def test_a_file_that_is_no_regular_bvh_is_refused_unread(tmp_path: Path, kind: str, message: str) -> None:
    """A FIFO hung for ever, /dev/zero read until the memory ran out; a FIFO alone was said to be 'not found'."""
    path = odd_file(tmp_path, kind)
    with no_hang(), pytest.raises(bvh.BvhError) as e:
        bvh.read(path)
    assert str(e.value) == f"BVH file {str(path)!r} {message}" + ("; give the file itself" if kind != "huge" else "")


def test_a_file_that_grows_past_the_limit_is_cut_off(monkeypatch: pytest.MonkeyPatch) -> None:
    """/proc files say they are empty; read no more than the limit and one byte."""
    monkeypatch.setitem(files.LIMITS, "bvh", 1000)
    with pytest.raises(bvh.BvhError, match=r"'/proc/self/maps' is over 1000 bytes, the most mjkin reads of a BVH file"):
        bvh.read("/proc/self/maps")


def test_what_a_file_holds_is_never_echoed(tmp_path: Path) -> None:
    """A clip linked to a private file (/etc/shadow) put its first line into the error (and report.csv)."""
    secret = tmp_path / "shadow"
    secret.write_text("root:$6$s3cr3t:19000:0:99999:7:::\ndaemon:*:19000:0:99999:7:::\n")
    clip = tmp_path / "clip.bvh"
    clip.symlink_to(secret)
    with pytest.raises(bvh.BvhError) as e:
        bvh.read(clip)
    assert "s3cr3t" not in str(e.value) and "root:" not in str(e.value)
    assert str(e.value) == f"BVH {str(clip)!r} line 1: a BVH file starts with HIERARCHY; this one does not"


def test_a_long_token_is_echoed_shortened() -> None:
    with pytest.raises(bvh.BvhError) as e:
        bvh.parse(small().replace("MOTION", "M" * 100_000))
    assert len(str(e.value)) < 200 and "..." in str(e.value)
