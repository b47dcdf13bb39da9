"""The mjkin command: output, and user mistakes as one line with exit status 2."""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import json
import os
import subprocess
import sys
from pathlib import Path

import imageio.v3 as imageio
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import mjkin
from conftest import no_hang
from mjkin import motion
from mjkin.apps.argtypes import nonnegative_int
from mjkin.apps.cli import build_parser, join_negative_vectors, main
from mjkin.runtime import files, progress


def test_info_outlines_the_tree(capsys):
    assert main(["info", "primate"]) == 0
    out = capsys.readouterr().out
    assert "nq=37 nv=30" in out
    assert "joint root: free" in out and "joint left_knee: hinge" in out and "site head" in out


def test_fk_json_equals_library(capsys):
    q = "0.1 0.2 0.3 -0.4 0.5 0.6 0.7"
    assert main(["fk", "arm7", "--q", q, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    tree = mjkin.load("arm7")
    T = tree.pose([float(v) for v in q.split()], "ee")
    ee = next(f for f in data["frames"] if f["name"] == "ee")
    np.testing.assert_allclose(ee["pos"], T[:3, 3], atol=1e-12)


def test_fk_degrees(capsys):
    assert main(["fk", "planar_2link", "--q", "90,0", "--deg", "--frame", "tip"]) == 0
    assert "pos  0.000000  1.700000  0.000000" in capsys.readouterr().out


@pytest.mark.parametrize("argv, text", [
    (["fk", "arm7", "--q", "1 2"], "needs (..., 7)"),
    (["fk", "arm7", "--q", "1 2 x 4 5 6 7"], "--q must be 7 numbers"),
    (["fk", "arm7", "--frame", "hand"], "unknown site or body 'hand'"),
    (["info", "no_such_model"], "model file not found"),
    (["fk", "arm7", "--q", "0 0 0 nan 0 0 0"], "NaN"),
    # a folder said "model file not found"
    (["info", str(mjkin.bundled_models()["arm7"].parent)], "is a folder, not a model file: give the MJCF/URDF file "),
])
def test_user_mistakes_exit_2_with_one_line(argv, text, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert text in err and err.count("\n") == 1 and "Traceback" not in err


def test_console_script_exits_2_without_traceback(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body>")
    r = subprocess.run([sys.executable, "-m", "mjkin.apps.cli", "info", str(bad)], capture_output=True, text=True)
    assert r.returncode == 2
    assert r.stderr.startswith("mjkin: error: cannot compile model") and "Traceback" not in r.stderr


# ------------------------------------------------------------------ checks before work
@pytest.fixture
def script(tmp_path):
    """A 5-frame script of the planar 2-link arm (no IK), written into the test's folder."""
    tree = mjkin.load("planar_2link")
    q = np.linspace([0.0, 0.0], [1.0, -1.0], 5)
    tips = tree.pose(q, "tip")[:, :3, 3]
    traj = motion.Trajectory(times=np.arange(5) / 30, q=q, fingerprint=motion.fingerprint(tree),
                             model="planar_2link", frame="tip", targets=tips[:, None, :])
    return traj.save(tmp_path / "five.json")


def bad_script(tmp_path, **change):
    doc = json.loads((tmp_path / "five.json").read_text())
    for key, value in change.items():
        if value is None:
            del doc[key]
        else:
            doc[key] = value
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    return str(tmp_path / "bad.json")


BEFORE_WORK = [  # argv (with {script}/{bad}), text in the one line
    (["demo", "--width", "-5"], "--width: must be a whole number > 0"),
    (["demo", "--width", "100000", "--height", "100000"], "--width must be at most 8192"),
    (["demo", "--height", "0"], "--height: must be a whole number > 0"),
    (["demo", "--width", "6.5"], "--width: must be a whole number"),
    (["demo", "--fps", "-5"], "--fps: must be a finite number > 0"),
    (["demo", "--fps", "0"], "--fps: must be a finite number > 0"),
    (["demo", "--fps", "inf"], "--fps: must be a finite number > 0"),
    (["demo", "--seconds", "0.01"], "at least 2 frames"),
    (["demo", "--seconds", "1e12"], "--seconds x --fps must give at most 100,000 frames, got 30,000,000,000,000"),
    (["reachability", "arm7", "--frame", "ee", "--orientations", "1000000000"],
     "orientations must be a whole number from 1 to 10,000, got 1000000000"),
    (["demo", "-o", "/proc/x.mp4"], "folder '/proc' is not writable"),
    (["demo", "-o", "missing/x.mp4"], "folder 'missing' does not exist"),
    (["demo", "-o", "d.avi"], "output must end in .mp4"),
    (["demo", "-o", "still.png", "--frame", "447"], "--frame must be in [-447, 446]"),  # 15 s, 30 fps
    (["replay", "{script}", "-o", "r.avi"], "output must end in .mp4"),
    (["replay", "{script}", "-o", "still.png", "--frame", "5"], "--frame must be in [-5, 4]"),
    (["replay", "{script}", "-o", "still.png", "--frame", "-6"], "--frame must be in [-5, 4]"),
    (["render", "planar_2link", "--script", "{script}", "-o", "r.gif", "--frame", "x"], "--frame: invalid int"),
    (["render", "planar_2link", "-o", "still.png", "--frame", "1"], "--frame must be in [-1, 0] (-1 = the last) for 1"),
    (["replay", "{script}", "-o", "."], "output must end in"),
    (["trajectory", "planar_2link", "--site", "tip", "--path", "line", "--end", "0,1,0", "-o", "t.txt"],
     "--output must end in .json"),
    (["trajectory", "planar_2link", "--site", "tip", "--path", "line", "--end", "0,1,0", "-o", "t.json",
      "--frames", "0"], "--frames: must be a whole number > 0"),
    (["ik", "arm7", "--frame", "ee", "--pos", "1,2"], "--pos must be 3 finite numbers x,y,z"),
    (["ik", "arm7", "--frame", "ee", "--pos", "1,2,nan"], "--pos must be 3 finite numbers"),
    (["ik", "arm7", "--frame", "ee", "--pos", "0.3,0,0.5", "--quat", "1,0,0"], "--quat must be 4 finite numbers"),
    (["ik", "arm7", "--frame", "ee", "--pos", "0.3,0,0.5", "--quat", "0,0,0,0"], "zero quaternion"),
    (["ik", "arm7", "--frame", "hand", "--pos", "0.3,0,0.5"], "unknown site or body 'hand'"),
    (["ik", "arm7", "--frame", "ee", "--pos", "0.3,0,0.5", "--tol", "-1"], "--tol: must be a finite number > 0"),
    (["ik", "arm7", "--frame", "ee", "--pos", "0.3,0,0.5", "--method", "magic"], "--method: invalid choice"),
    (["ik", "arm7", "--frame", "ee", "--pos", "0.3,0,0.5", "--q0", "hme"], "a keyframe name (home)"),
    (["fk", "planar_2link", "--q", "home"], "(the model has no named keyframes)"),
    # a negative --seed, on every command that takes one (numpy's generators refuse it with a traceback)
    (["fk", "arm7", "--q", "random", "--seed", "-1"], "--seed: must be a whole number >= 0, got -1"),
    (["ik", "arm7", "--frame", "ee", "--pos", "0.3,0.1,0.4", "--q0", "random", "--seed", "-5"],
     "--seed: must be a whole number >= 0, got -5"),
    (["render", "arm7", "--q", "random", "--seed", "-5", "-o", "r.png"], "--seed: must be a whole number >= 0"),
    (["trajectory", "arm7", "--site", "ee", "--path", "circle", "--q0", "random", "--seed", "-1", "-o", "t.json"],
     "--seed: must be a whole number >= 0"),
    (["bench", "ik", "--models", "arm7", "--targets", "5", "--seed", "-1"], "--seed: must be a whole number >= 0"),
    (["bench", "all", "--seed", "x"], "--seed: must be a whole number >= 0, got 'x'"),
    # workspace checks its output like the others
    (["workspace", "arm7", "-o", "ws.mp4"], "--output must end in .png"),
    (["workspace", "arm7", "-o", "/proc/ws.png"], "folder '/proc' is not writable"),
    (["workspace", "arm7", "-o", "missing/ws.png"], "folder 'missing' does not exist"),
    # bench seeds --out: an existing folder or a new one inside an existing folder
    (["bench", "seeds", "--out", "missing/figures"], "folder 'missing' does not exist"),
    (["bench", "seeds", "--out", "/proc/figures"], "folder '/proc' is not writable"),
    (["bench", "seeds", "--out", "{script}"], "is a file; give a folder"),
    (["bench", "all", "--out", "x"], "unrecognized arguments"),
    # videos are written at the size asked for: H.264 needs even sides
    (["render", "arm7", "--q", "home", "-o", "odd.mp4", "--width", "101", "--height", "77"],
     "--width/--height of an .mp4 must be even (H.264 yuv420p), got 101x77"),
    (["demo", "--width", "640", "--height", "481"], "must be even"),
    # --frame picks the frame of an image; a video has them all
    (["replay", "{script}", "-o", "x.mp4", "--frame", "5"], "--frame applies to .png/.jpg/.jpeg output"),
    (["render", "planar_2link", "--script", "{script}", "-o", "x.gif", "--frame", "0"], "--frame applies to"),
    # a single-valued option given twice
    (["ik", "arm7", "--frame", "ee", "--frame", "link3", "--pos", "0,0,0.5"],
     "argument --frame: given twice ('ee', then 'link3'); give it once"),
    (["fk", "arm7", "--q", "home", "--q", "random"], "argument --q: given twice"),
    # ik's --root/--joints/--base name bodies and joints the model has
    (["ik", "primate", "--frame", "left_hand", "--pos", "0.3,0.3,1.2", "--root", "torso"],
     "unknown body 'torso'; the model's body names: 'world', 'lower_torso', 'left_thigh'"),
    (["ik", "primate", "--frame", "left_hand", "--pos", "0.3,0.3,1.2", "--joints", "left_shoulder,wrist"],
     "unknown joint 'wrist'; the model's joint names: 'root', 'left_hip'"),
    (["ik", "primate", "--frame", "left_hand", "--pos", "0.3,0.3,1.2", "--base", "hips"], "unknown body 'hips'"),
]

BAD_SCRIPTS = [  # changes to a good script, text in the one line
    ({"times": None}, "has no 'times'"),
    ({"qpos": None}, "has no 'qpos'"),
    ({"fingerprint": None}, "'fingerprint' must be a string"),
    ({"times": "soon"}, "'times' must be a list of T times"),
    ({"qpos": [[0.0, 0.0], [1.0]]}, "'qpos' must be a list of T configurations"),
    ({"qpos": [[0.0, "a"]] * 5}, "'qpos' must be a list of T configurations"),
    ({"times": [0.0, 1.0]}, "'times' (2) and 'qpos' (5) must have the same number of frames"),
    ({"targets": [[[0.0, 0.0]]] * 5}, "'targets' must hold x,y,z points for each of the 5 frames"),
    ({"success": [True]}, "'success' must hold one true/false for each of the 5 frames"),
    ({"qpos": [[0.0, 0.0, 0.0]] * 5}, "this model needs (..., 2)"),
    # found by a probe: an integer beyond float range was an OverflowError, strings and numbers were booleans
    ({"times": [10**400, 0.1, 0.2, 0.3, 0.4]}, "'times' must be a list of T times in seconds (finite numbers)"),
    ({"qpos": [[10**400, 0.0]] * 5}, "'qpos' must be a list of T configurations"),
    ({"success": ["no"] * 5}, "'success' must be one true/false per frame"),
    ({"success": [1, 0, 1, 0, 1]}, "'success' must be one true/false per frame"),
    ({"qpos": [["0.5", "1"]] * 5}, "'qpos' must be a list of T configurations"),
    ({"times": [True, 0.1, 0.2, 0.3, 0.4]}, "'times' must be a list of T times"),
    ({"times": [0.4, 0.3, 0.2, 0.1, 0.0]}, "'times' must not decrease, but frame 1 is at 0.3 s after 0.4 s"),
    ({"times": [0.0] * 5}, "'times' are all 0 s; they must increase over the 5 frames"),
    ({"source": 5}, "'model', 'source' and 'site' must be strings"),
]


def one_line_exit_2(argv, text, capsys, folder, keep=()):
    """The CLI exits 2 with ``text`` in one stderr line, no traceback, and leaves no file behind."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert text in err, err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert sorted(p.name for p in folder.iterdir()) == sorted(keep)


@pytest.mark.parametrize("argv, text", BEFORE_WORK)
def test_bad_arguments_fail_before_any_work(argv, text, capsys, tmp_path, monkeypatch, script):
    monkeypatch.chdir(tmp_path)
    # IK and rendering must not start: make them fail loudly if they do
    monkeypatch.setattr("mjkin.apps.demo.showcase.showcase",
                        lambda *a, **k: pytest.fail("the demo ran before the checks"))
    monkeypatch.setattr("mjkin.motion.walk_cycle", lambda *a, **k: pytest.fail("the walk ran before the checks"))
    monkeypatch.setattr("mjkin.motion.follow", lambda *a, **k: pytest.fail("IK ran before the checks"))
    monkeypatch.setattr("mjkin.apps.cli.write_output", lambda *a, **k: pytest.fail("rendering ran before the checks"))
    monkeypatch.setattr(importlib.import_module("mjkin.explore.workspace"), "workspace",
                        lambda *a, **k: pytest.fail("sampling ran before the checks"))
    monkeypatch.setattr("mjkin.apps.bench.suite.bench_seeds",
                        lambda *a, **k: pytest.fail("the seeds ran before the checks"))
    argv = [a.format(script=script) for a in argv]
    one_line_exit_2(argv, text, capsys, tmp_path, keep=["five.json"])


@pytest.mark.parametrize("change, text", BAD_SCRIPTS)
@pytest.mark.parametrize("command", ["replay", "render"])
def test_bad_scripts_give_one_line(command, change, text, capsys, tmp_path, monkeypatch, script):
    monkeypatch.chdir(tmp_path)
    bad = bad_script(tmp_path, **change)
    argv = ["replay", bad, "--model", "planar_2link"] if command == "replay" else \
        ["render", "planar_2link", "--script", bad]
    one_line_exit_2(argv + ["-o", "out.mp4"], text, capsys, tmp_path, keep=["five.json", "bad.json"])


def clip_and_odd_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str, kind: str) -> tuple[Path, Path]:
    """A small clip ``a.bvh`` and a file ``name`` that is a FIFO, a link to /dev/zero or ("huge") over the JSON
    limit, in ``tmp_path``, the working folder."""
    from test_retarget import crouch_bvh

    monkeypatch.chdir(tmp_path)
    clip, odd = tmp_path / "a.bvh", tmp_path / name
    clip.write_text(crouch_bvh(4))
    if kind == "fifo":
        os.mkfifo(odd)
    elif kind == "/dev/zero":
        odd.symlink_to("/dev/zero")
    else:
        with odd.open("wb") as f:
            f.truncate(files.LIMITS["json"] + 1)
    return clip, odd


@pytest.mark.parametrize("kind", ["/dev/zero", "fifo", "huge"])
@pytest.mark.parametrize("command", ["mapping", "poses", "replay"])
def test_an_input_file_that_is_no_regular_file_is_one_line(command, kind, capsys, tmp_path, monkeypatch):
    """``--mapping``, ``--poses`` and ``replay`` given /dev/zero read until the memory ran out; a FIFO hung."""
    clip, odd = clip_and_odd_file(tmp_path, monkeypatch, "odd.json", kind)
    argv, what = {"mapping": (["retarget", str(clip), "--model", "primate", "--mapping", str(odd), "-o", "a.json"],
                              "mapping file"),
                  "poses": (["place-base", "arm7", "--frame", "ee", "--poses", str(odd), "--region", "-1,-1,1,1",
                             "-o", "p.png"], "--poses file"),
                  "replay": (["replay", str(odd), "--model", "planar_2link", "-o", "r.mp4"],
                             "trajectory file")}[command]
    limit = "1 MB" if command == "mapping" else "256 MB"
    told = {"/dev/zero": "is a character device, not a regular file; give the file itself",
            "fifo": "is a FIFO (named pipe), not a regular file; give the file itself",
            "huge": f"is over {limit}, the most mjkin reads of a {what}; is it the right file?"}[kind]
    if kind == "huge" and command == "mapping":
        told = "is over 1 MB, the most mjkin reads of a mapping file; is it the right file?"
    with no_hang(60):
        one_line_exit_2(argv, f"{what} {str(odd)!r} {told}", capsys, tmp_path, keep=["a.bvh", "odd.json"])


@pytest.mark.parametrize("kind", ["/dev/zero", "fifo"])
@pytest.mark.parametrize("given", ["ik model", "retarget --model", "retarget --scene"])
def test_a_model_or_scene_that_is_no_regular_file_is_one_line(given, kind, capsys, tmp_path, monkeypatch):
    """A FIFO as the model or the scene was said to be "not found" (MuJoCo, which reads it, would wait for ever)."""
    clip, odd = clip_and_odd_file(tmp_path, monkeypatch, "odd.xml", kind)
    argv, what, hint = {
        "ik model": (["ik", str(odd), "--frame", "ee", "--pos", "0.3,0,0.5"], "model file",
                     "give the MJCF/URDF file itself"),
        "retarget --model": (["retarget", str(clip), "--model", str(odd), "-o", "a.json"], "model file",
                             "give the MJCF/URDF file itself"),
        "retarget --scene": (["retarget", str(clip), "--model", "primate", "--scene", str(odd), "-o", "a.json"],
                             "scene file", "give an MJCF file whose world geoms are the ground")}[given]
    told = {"/dev/zero": "a character device", "fifo": "a FIFO (named pipe)"}[kind]
    with no_hang(60):
        one_line_exit_2(argv, f"{what} {str(odd)!r} is {told}, not a regular file; {hint}", capsys, tmp_path,
                        keep=["a.bvh", "odd.xml"])


@pytest.mark.parametrize("named", ["mesh", "include"])
@pytest.mark.parametrize("given", ["model", "scene"])
def test_a_file_a_model_names_that_is_a_fifo_is_one_line(given, named, capsys, tmp_path, monkeypatch):
    """MuJoCo reads a model's meshes and includes itself: a FIFO among them hung it for ever."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "parts").mkdir()
    os.mkfifo(tmp_path / "parts" / "odd")
    inside = ('<asset><mesh name="m" file="odd"/></asset><worldbody><geom type="mesh" mesh="m"/></worldbody>'
              if named == "mesh" else '<include file="parts/odd"/><worldbody/>')
    compiler = '<compiler meshdir="parts"/>' if named == "mesh" else ""
    (tmp_path / "m.xml").write_text(f"<mujoco>{compiler}{inside}</mujoco>")
    argv = ["info", "m.xml"] if given == "model" else \
        ["retarget", "a.bvh", "--model", "primate", "--scene", "m.xml", "-o", "a.json"]
    if given == "scene":
        from test_retarget import crouch_bvh

        (tmp_path / "a.bvh").write_text(crouch_bvh(4))
    name = "odd" if named == "mesh" else "parts/odd"
    with no_hang(60):
        one_line_exit_2(argv, f"{given} file 'm.xml' names {name!r} ({named}), which is a FIFO (named pipe), not a "
                        "regular file; give the file itself", capsys, tmp_path,
                        keep=["m.xml", "parts"] + (["a.bvh"] if given == "scene" else []))


def test_script_with_the_format_but_no_keys(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "t.json").write_text('{"format": "mjkin-trajectory"}')
    one_line_exit_2(["replay", "t.json", "-o", "r.mp4"], "has no 'times'", capsys, tmp_path, keep=["t.json"])


def test_version_comes_from_the_package(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"mjkin {importlib.metadata.version('mjkin')}"


def test_every_option_of_every_command_has_help():
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert {c.dest for c in sub._choices_actions} == set(sub.choices)  # every command has a help line
    assert all(c.help for c in sub._choices_actions)
    for name, command in sub.choices.items():
        for action in command._actions:
            assert action.help, f"mjkin {name} {'/'.join(action.option_strings) or action.dest} has no help"


# ------------------------------------------------------------------ ik, keyframes, random, limits
@pytest.mark.parametrize("model, frame", [("arm7", "world"), ("primate", "world")])
def test_ik_refuses_a_frame_no_joint_moves(model, frame, capsys, monkeypatch):
    monkeypatch.setattr("mjkin.apps.cli.solve", lambda *a, **k: pytest.fail("IK ran for a frame nothing moves"))
    assert main(["ik", model, "--frame", frame, "--pos", "0,0,0.5"]) == 2
    err = capsys.readouterr().err
    assert err == f"mjkin: error: no joint moves {frame!r}: choose a site or body below a joint\n"


@pytest.mark.filterwarnings("error::RuntimeWarning")  # found by a clean-clone run: the reason's distance overflowed
def test_ik_json_is_strict_json_even_for_absurd_targets(capsys):
    def refuse(name):
        raise ValueError(f"{name} is not JSON")

    tree = mjkin.load("arm7")
    far = tree.model.stat.center[0] + 999 * tree.model.stat.extent  # just inside the bound: a finite miss
    assert main(["ik", "arm7", "--frame", "ee", "--pos", f"{far},0,0", "--json", "--method", "dls"]) == 0
    out = json.loads(capsys.readouterr().out, parse_constant=refuse)
    assert out["success"] is False and out["error"][0] > 900 * tree.model.stat.extent


@pytest.mark.parametrize("pos", ["1e308,0.2,0.5", "2e3,0,0", "-1e200,0,0"])
def test_ik_refuses_targets_beyond_a_thousand_model_extents_in_one_line(pos, capsys):
    """``--pos 1e308,...`` searched 24 restarts and printed ``position error inf m``; now one line, exit 2."""
    assert main(["ik", "arm7", "--frame", "ee", "--pos", pos]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "more than 1000 model extents" in err and f"--pos {pos}" in err


def test_negative_numbers_in_vector_options(capsys):
    assert main(["ik", "planar_3link", "--frame", "tip", "--pos", "-20,5,0", "--json"]) == 0  # the seeds' target
    out = json.loads(capsys.readouterr().out)
    assert out["success"] is True
    np.testing.assert_allclose(mjkin.load("planar_3link").pose(out["q"], "tip")[:3, 3], [-20, 5, 0], atol=1e-5)
    args = build_parser().parse_args(join_negative_vectors(
        ["trajectory", "arm7", "--site", "ee", "--path", "line", "--start", "-.1,0,0", "--end", "-0.1,-0.2,0.3",
         "--q0", "-0.1 0 0 0 0 0 0", "--center", "-1,0,0", "--normal", "-1,0,0", "-o", "t.json"]))
    assert (args.start, args.end, args.q0, args.center, args.normal) == \
        ("-.1,0,0", "-0.1,-0.2,0.3", "-0.1 0 0 0 0 0 0", "-1,0,0", "-1,0,0")


@pytest.mark.parametrize("argv", [
    ["replay", "t.json", "-o", "x.png", "--frame", "-1"],  # not a vector option: argparse reads -1 itself
    ["ik", "arm7", "--frame", "ee", "--pos", "--quat"],  # not a number: a missing value stays an error
    ["ik", "arm7", "--", "--pos", "-1,0,0"],  # after --, nothing is an option
])
def test_negative_vectors_leave_other_arguments_alone(argv):
    assert join_negative_vectors(argv) == argv


@given(st.integers())
def test_seed_is_an_integer_at_least_zero(value):
    if value >= 0:
        assert nonnegative_int(str(value)) == value
    else:
        with pytest.raises(argparse.ArgumentTypeError, match=f"must be a whole number >= 0, got {value}$"):
            nonnegative_int(str(value))


def test_info_counts_bodies_without_world(capsys):
    assert main(["info", "arm7"]) == 0
    assert "bodies=7 (+ world) joints=7" in capsys.readouterr().out
    assert mjkin.load("arm7").fk(mjkin.load("arm7").qpos0).shape[0] == 8  # what fk returns: world too


def test_ik_json_reaches_the_target(capsys):
    pos, quat = [0.4, 0.2, 0.5], [0.0, 1.0, 0.0, 0.0]
    assert main(["ik", "arm7", "--frame", "ee", "--pos", ",".join(map(str, pos)), "--quat", "0,1,0,0",
                 "--q0", "home", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["success"] is True and out["status"] == "converged"
    assert set(out) >= {"q", "success", "error", "iterations", "status"} and out["iterations"] > 0
    T = mjkin.load("arm7").pose(out["q"], "ee")
    np.testing.assert_allclose(T[:3, 3], pos, atol=1e-6)
    assert mjkin.spatial.quat_distance(mjkin.spatial.mat_to_quat(T[:3, :3]), quat) < 1e-5
    assert max(out["error"]) < 1e-5


def test_ik_unreachable_is_not_an_error(capsys):
    assert main(["ik", "arm7", "--frame", "ee", "--pos", "3,0,0.5", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["success"] is False and out["status"] != "converged" and out["error"][0] > 1.0
    assert main(["ik", "arm7", "--frame", "ee", "--pos", "3,0,0.5", "--method", "dls"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("failed:") and "position error" in text


def test_q_accepts_keyframe_names_and_seeded_random(capsys):
    tree = mjkin.load("arm7")
    assert main(["fk", "arm7", "--q", "home", "--json"]) == 0
    np.testing.assert_array_equal(json.loads(capsys.readouterr().out)["q"], tree.model.key_qpos[0])
    qs = []
    for _ in range(2):
        assert main(["fk", "arm7", "--q", "random", "--seed", "7", "--json"]) == 0
        qs.append(json.loads(capsys.readouterr().out)["q"])
    assert qs[0] == qs[1]
    np.testing.assert_array_equal(tree.clip(qs[0]), qs[0])  # inside the limits
    assert main(["fk", "arm7", "--q", "random", "--seed", "8", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["q"] != qs[0]


def test_fk_outside_limits_warns_or_clips(capsys):
    q = "5 0 0 0 0 0 0"
    assert main(["fk", "arm7", "--q", q, "--json"]) == 0
    out, err = capsys.readouterr()
    assert err.count("\n") == 1 and "joint j1 = 5 is outside its range [-2.96, 2.96]" in err and "--clip" in err
    assert json.loads(out)["q"][0] == 5.0  # FK of q as given
    assert main(["fk", "arm7", "--q", q, "--json", "--clip"]) == 0
    out, err = capsys.readouterr()
    assert err == "" and json.loads(out)["q"][0] == pytest.approx(2.96)
    assert main(["fk", "arm7", "--q", "2 0 0 0 0 0 0"]) == 0
    assert capsys.readouterr().err == ""


def test_image_output_renders_only_the_frame_asked_for(tmp_path, monkeypatch, script, capsys):
    from mjkin import render

    drawn = []
    draw = render.Painter.draw
    monkeypatch.setattr(render.Painter, "draw", lambda self, q, *a, **k: drawn.append(q) or draw(self, q, *a, **k))
    out = tmp_path / "still.png"
    assert main(["replay", str(script), "-o", str(out), "--frame", "2", "--width", "64", "--height", "48"]) == 0
    assert len(drawn) == 1 and "(frame 2 of 5, 64x48)" in capsys.readouterr().out
    # the same image as frame 2 of the whole video (camera framed over all poses, trail up to frame 2)
    tree = mjkin.load("planar_2link")
    traj = motion.Trajectory.load(script)
    video = list(render.frames(tree, traj.q, 64, 48, overlay=render.Overlay(points=traj.targets, trail="tip")))
    import imageio.v2 as imageio

    np.testing.assert_array_equal(imageio.imread(out), video[2])


# ------------------------------------------------------------------ scripts: JSON a probe made, limits, models
def deep_script(tmp_path, depth=20_000):
    """A script whose 'times' is a list nested ``depth`` deep (json's decoder recursed until it failed)."""
    path = tmp_path / "deep.json"
    path.write_text('{"format": "mjkin-trajectory", "fingerprint": "x", "qpos": [[0, 0]], "times": '
                    + "[" * depth + "]" * depth + "}")
    return path


@pytest.mark.parametrize("command", ["replay", "render"])
def test_a_deeply_nested_script_gives_one_line(command, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    deep = deep_script(tmp_path)
    argv = ["replay", str(deep)] if command == "replay" else ["render", "planar_2link", "--script", str(deep)]
    one_line_exit_2(argv + ["-o", "out.mp4"], "its JSON is nested too deeply", capsys, tmp_path, keep=["deep.json"])


def arm_script(tmp_path, q):
    tree = mjkin.load("arm7")
    traj = motion.Trajectory(times=np.arange(len(q)) / 30, q=np.asarray(q, float), fingerprint=motion.fingerprint(tree),
                             model="arm7", source="arm7")
    return traj.save(tmp_path / "arm.json")


def test_replay_warns_about_joints_outside_their_limits_or_clips_them(tmp_path, capsys):
    home = mjkin.load("arm7").model.key_qpos[0]
    q = np.repeat(home[None], 4, axis=0)
    q[2, 0] = q[3, 0] = 5.0  # j1 beyond 2.96 from frame 2 on
    script = arm_script(tmp_path, q)
    out = ["-o", str(tmp_path / "r.png"), "--width", "64", "--height", "48"]
    assert main(["replay", str(script), *out, "--frame", "2"]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mjkin: warning: joint j1 = 5 is outside its range [-2.96, 2.96] "
                                                   "at frame 2 (and 1 more frame); rendered as recorded (--clip")
    as_recorded = imageio.imread(tmp_path / "r.png")
    assert main(["replay", str(script), *out, "--frame", "2", "--clip"]) == 0
    assert capsys.readouterr().err == ""
    assert not np.array_equal(imageio.imread(tmp_path / "r.png"), as_recorded)  # j1 at 2.96, not 5
    assert main(["render", "arm7", "--script", str(script), *out, "--frame", "0"]) == 0  # render --script warns too
    assert "joint j1 = 5" in capsys.readouterr().err


def test_a_script_remembers_where_its_model_came_from(tmp_path, capsys, monkeypatch):
    """'mjkin trajectory my.xml' then 'mjkin replay my.json' looked for a model named by the MJCF's name."""
    made, elsewhere = tmp_path / "made", tmp_path / "elsewhere"
    made.mkdir()
    elsewhere.mkdir()
    xml = mjkin.bundled_models()["arm7"].read_text().replace('model="arm7"', 'model="mine"')
    (made / "my.xml").write_text(xml)
    monkeypatch.chdir(made)
    assert main(["trajectory", "my.xml", "--site", "ee", "--path", "line", "--end", "0.4,0.2,0.6", "--frames", "3",
                 "-o", "my.json"]) == 0
    doc = json.loads((made / "my.json").read_text())
    assert doc["model"] == "mine" and doc["source"] == str(made / "my.xml")  # absolute: replay works from anywhere
    assert doc["fingerprint"] == motion.fingerprint(mjkin.load(made / "my.xml"))
    capsys.readouterr()
    monkeypatch.chdir(elsewhere)
    still = ["-o", "still.png", "--width", "64", "--height", "48"]
    assert main(["replay", str(made / "my.json"), *still]) == 0
    assert "wrote still.png (frame 2 of 3, 64x48)" in capsys.readouterr().out
    (made / "my.xml").rename(made / "moved.xml")  # the model is not where the script says
    one_line_exit_2(["replay", str(made / "my.json"), *still], f"the model of {str(made / 'my.json')!r} ('mine', "
                    f"from {str(made / 'my.xml')!r}) is not found; pass --model PATH", capsys, elsewhere,
                    keep=["still.png"])
    assert main(["replay", str(made / "my.json"), "--model", str(made / "moved.xml"), *still]) == 0
    capsys.readouterr()
    one_line_exit_2(["replay", str(made / "my.json"), "--model", "ball_chain", *still],  # another fingerprint
                    "was recorded on model 'mine'", capsys, elsewhere, keep=["still.png"])


def test_scripts_without_a_source_still_replay_by_model_name(tmp_path, capsys, script):
    doc = json.loads(script.read_text())
    del doc["source"]  # written before scripts recorded where their model came from
    script.write_text(json.dumps(doc))
    assert main(["replay", str(script), "-o", str(tmp_path / "old.png"), "--width", "64", "--height", "48"]) == 0
    assert "(frame 4 of 5, 64x48)" in capsys.readouterr().out


# ------------------------------------------------------------------ pipes
@pytest.mark.parametrize("argv, status", [
    (["info", "primate"], 141),  # as a Unix tool ended by SIGPIPE: 128 + 13
    (["fk", "primate", "--json"], 141),
    (["ik", "--help"], 0),  # argparse drops a failed write of the help itself
])
def test_a_closed_pipe_ends_quietly(argv, status):
    """'mjkin info primate | head -1' ended in a BrokenPipeError traceback and status 1."""
    command = subprocess.Popen([sys.executable, "-m", "mjkin.apps.cli", *argv], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    command.stdout.close()  # the reader is gone before anything is written: every write meets a closed pipe
    err = command.stderr.read().replace(f"mjkin: {progress.COMPILING}\n", "")  # a cold kernel cache says so
    command.stderr.close()
    assert command.wait() == status and err == ""


def test_piped_into_head(tmp_path):
    """The same through a shell pipe; the text head shows is the command's first line."""
    shell = f"{sys.executable} -m mjkin.apps.cli info primate | head -1; exit ${{PIPESTATUS[0]}}"
    run = subprocess.run(["bash", "-c", shell], capture_output=True, text=True)
    assert run.stdout.startswith("model primate: nq=37") and run.stdout.count("\n") == 1
    assert run.returncode in (0, 141)  # 0 when everything fit into the pipe before head left
    assert run.stderr.replace(f"mjkin: {progress.COMPILING}\n", "") == ""


# ------------------------------------------------------------------ ik: what may move
PRIMATE_IK = ["ik", "primate", "--frame", "left_hand", "--pos", "0.3,0.3,1.2", "--json"]


def test_ik_root_plants_a_body_instead_of_moving_the_free_root(capsys):
    tree = mjkin.load("primate")
    pelvis = tree.pose(tree.qpos0, "lower_torso", "body")
    assert main(PRIMATE_IK) == 0
    free = json.loads(capsys.readouterr().out)
    assert np.abs(tree.pose(free["q"], "lower_torso", "body")[:3, 3] - pelvis[:3, 3]).max() > 0.05  # it flew
    for body in ("lower_torso", "left_foot"):
        assert main(PRIMATE_IK + ["--root", body]) == 0
        rooted = json.loads(capsys.readouterr().out)
        assert rooted["success"] is True
        np.testing.assert_allclose(tree.pose(rooted["q"], body, "body"), tree.pose(tree.qpos0, body, "body"),
                                   atol=1e-6)
        np.testing.assert_allclose(tree.pose(rooted["q"], "left_hand")[:3, 3], [0.3, 0.3, 1.2], atol=1e-5)


@pytest.mark.parametrize("option, allowed", [
    (["--joints", "left_shoulder,left_elbow"], ["left_shoulder", "left_elbow"]),
    (["--base", "upper_torso"], ["left_shoulder", "left_elbow"]),  # the joints between it and the hand
])
def test_ik_joints_and_base_limit_the_joints_that_move(option, allowed, capsys):
    tree = mjkin.load("primate")
    assert main(PRIMATE_IK + option) == 0
    q = np.array(json.loads(capsys.readouterr().out)["q"])
    may = np.zeros(tree.nq, bool)
    for name in allowed:
        j = tree.id(name, "joint")
        may[tree.jnt_qadr[j]:tree.jnt_qadr[j] + {0: 7, 1: 4}.get(int(tree.jnt_type[j]), 1)] = True
    assert np.abs(q - tree.qpos0)[~may].max() == 0 and np.abs(q - tree.qpos0)[may].max() > 0.1


def test_ik_help_says_the_free_root_moves_unless_rooted(capsys):
    assert main(["ik", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "a free root joint" in text and "unless --root plants a body" in text
    assert "--root BODY" in text and "--joints J1,J2,..." in text and "--base BODY" in text


# ------------------------------------------------------------------ random, quaternions, output
def test_random_keeps_a_free_root_at_its_qpos0_pose(capsys):
    """'mjkin render primate --q random' drew a random world pose: the figure sank into the floor."""
    tree = mjkin.load("primate")
    root = tree.layout.free_q.ravel()
    for seed in range(3):
        assert main(["fk", "primate", "--q", "random", "--seed", str(seed), "--json"]) == 0
        q = np.array(json.loads(capsys.readouterr().out)["q"])
        np.testing.assert_array_equal(q[root], tree.qpos0[root])
        np.testing.assert_allclose(tree.clip(q), q, atol=1e-12)  # the rest: a random draw inside the limits
        assert np.abs(np.delete(q - tree.qpos0, root)).max() > 0.3
    assert main(["render", "--help"]) == 0
    assert "a free root joint keeps its qpos0 pose" in " ".join(capsys.readouterr().out.split())


FREE_BALL = """<mujoco model="loose"><compiler angle="radian"/><worldbody>
<body name="torso"><freejoint name="root"/><geom type="sphere" size="0.1"/>
  <body pos="0 0 0.2"><joint name="shoulder" type="ball"/><geom type="capsule" fromto="0 0 0 0 0 0.3" size="0.03"/>
    <site name="tip" pos="0 0 0.3"/></body>
  <body name="cone" pos="0.2 0 0"><joint name="wrist" type="ball" range="0 0.5"/><geom type="sphere" size="0.05"/>
  </body></body></worldbody></mujoco>"""


def test_quaternions_are_normalised_with_a_warning_and_unlimited_balls_have_no_cone(tmp_path, capsys):
    """A ball joint without a range warned 'turns beyond its 0 rad cone'; the real news was a non-unit quaternion."""
    xml = tmp_path / "loose.xml"
    xml.write_text(FREE_BALL)
    q = "0 0 1 2 0 0 0  2 0 0 0  1 0 0 0"  # the root's and the shoulder's quaternions have norm 2
    assert main(["fk", str(xml), "--q", q, "--json"]) == 0
    out, err = capsys.readouterr()
    assert err == ("mjkin: warning: --q: normalised the quaternions of joint root (norm 2), joint shoulder (norm 2) "
                   "to unit length\n")
    np.testing.assert_array_equal(json.loads(out)["q"], [0, 0, 1, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0])
    assert main(["fk", str(xml), "--q", "0 0 1 1 0 0 0  -1 0 0 0  -1 0 0 0"]) == 0  # -q is q: inside any cone
    assert capsys.readouterr().err == ""
    turned = "0 0 1 1 0 0 0  1 0 0 0  0.5403 0.8415 0 0"  # the wrist turned 2 rad in its 0.5 rad cone
    assert main(["fk", str(xml), "--q", turned]) == 0
    assert "joint wrist turns 2 rad, beyond its 0.5 rad cone; FK of --q as given" in capsys.readouterr().err
    assert main(["ik", "arm7", "--frame", "ee", "--pos", "0.4,0.2,0.5", "--quat", "0,2,0,0", "--json"]) == 0
    out, err = capsys.readouterr()
    assert err == "mjkin: warning: --quat: normalised '0,2,0,0' (norm 2) to unit length\n"
    assert json.loads(out)["success"] is True


def test_unnamed_bodies_are_named_by_their_id(tmp_path, capsys):
    xml = tmp_path / "loose.xml"
    xml.write_text(FREE_BALL)
    assert main(["info", str(xml)]) == 0
    assert "\n    body 2\n      joint shoulder: ball\n" in capsys.readouterr().out
    assert main(["fk", str(xml)]) == 0
    rows = capsys.readouterr().out.splitlines()
    assert rows[1].startswith("body 2                        pos ")


def test_no_negative_zeros_and_unlimited_hinges_wrapped(capsys):
    assert main(["fk", "planar_2link", "--q", "6.283185307179586,0"]) == 0  # sin(2 pi) = -2.4e-16
    out = capsys.readouterr().out
    assert "-0.000000" not in out and "site tip                      pos  1.700000  0.000000  0.000000" in out
    assert main(["fk", "planar_2link", "--q", "7,-7", "--json"]) == 0
    np.testing.assert_allclose(json.loads(capsys.readouterr().out)["q"], [7 - 2 * np.pi, 2 * np.pi - 7], atol=1e-12)
    tree = mjkin.load("planar_2link")
    assert main(["ik", "planar_2link", "--frame", "tip", "--pos", "0.5,1.2,0", "--q0", "9.5,-9", "--json"]) == 0
    q = json.loads(capsys.readouterr().out)["q"]
    assert all(-np.pi < v <= np.pi for v in q)  # unlimited hinges: shown in (-pi, pi]
    np.testing.assert_allclose(tree.pose(q, "tip")[:3, 3], [0.5, 1.2, 0], atol=1e-6)
    assert main(["ik", "planar_2link", "--frame", "tip", "--pos", "0.5,1.2,0", "--q0", "9.5,-9"]) == 0
    assert "-0.000000" not in capsys.readouterr().out


def test_a_still_is_called_a_still(tmp_path, capsys):
    assert main(["render", "planar_2link", "-o", str(tmp_path / "prim.png"), "--width", "64", "--height", "48"]) == 0
    assert capsys.readouterr().out == f"wrote {tmp_path / 'prim.png'} (still, 64x48)\n"


def test_ik_seed_help_says_what_each_default_is(capsys):
    """``ik --help`` said --seed "defaults to seed 0" and "a new draw each run" in one breath."""
    assert main(["ik", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "without it the restarts use seed 0, so a run repeats" in text
    assert "without it --q0 random is a new draw each run" in text and "default: a new draw" not in text


def test_ik_text_output_names_every_joint_with_its_values(capsys):
    """The primate's 37 numbers came without names: each joint now has its line, its values as in the q line."""
    assert main(["ik", "primate", "--frame", "left_hand", "--pos", "0.2,0.3,1.1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    q = [float(v) for v in lines[2].split()[1:]]
    tree = mjkin.load("primate")
    rows = lines[3:]
    assert len(rows) == tree.model.njnt and rows[0].split()[:2] == ["root", "free"]
    values = [float(v) for row in rows for v in row.split()[2:]]
    assert values == q and len(q) == tree.nq


# a target out of reach: every restart runs, so 10 000 of them take ~0.1 s without a limit, far more than 2 ms
FAR = ["ik", "arm7", "--frame", "ee", "--pos", "5,0,0", "--restarts", "10000", "--json"]


def test_ik_has_a_default_time_limit_per_target(capsys, monkeypatch):
    assert build_parser().parse_args(["ik", "arm7", "--frame", "ee", "--pos", "0,0,1"]).timeout == 10.0
    assert main(["ik", "--help"]) == 0
    assert "(default 10; none or 0: no limit)" in " ".join(capsys.readouterr().out.split())
    monkeypatch.setattr("mjkin.apps.cli.TIMEOUT", 0.002)  # the default, made short enough to bind here
    assert main(FAR) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["status"] == "timeout" and out["restarts"] < 10_000


@pytest.mark.parametrize("limit, status", [("none", "max_iterations"), ("0", "max_iterations"),
                                           ("0.002", "timeout"), ("600", "max_iterations")])
def test_ik_timeout_flag_lifts_or_sets_the_limit(limit, status, capsys, monkeypatch):
    monkeypatch.setattr("mjkin.apps.cli.TIMEOUT", 0.002)
    assert main([*FAR, "--timeout", limit]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["status"] == status and (out["restarts"] == 10_000) == (status != "timeout")


def test_ik_restarts_default_to_the_methods_own_under_the_limit(capsys):
    assert main(FAR[:-3] + ["--json"]) == 0
    assert json.loads(capsys.readouterr().out)["restarts"] == 24  # auto's, not its 1000 of a timed library call


@pytest.mark.parametrize("argv, text", [
    (["--timeout", "-1"], "--timeout: must be seconds > 0, or none (or 0) for no limit, got '-1'"),
    (["--timeout", "soon"], "--timeout: must be seconds > 0, or none (or 0) for no limit, got 'soon'"),
    (["--restarts", "20000"], "restarts must be"),
])
def test_bad_search_limits_are_one_line(argv, text, capsys):
    assert main(["ik", "arm7", "--frame", "ee", "--pos", "0.3,0,0.5", *argv]) == 2
    err = capsys.readouterr().err
    assert text in err and err.count("\n") == 1


def test_trajectory_names_the_frames_that_ran_out_of_time(tmp_path, capsys, monkeypatch):
    out = tmp_path / "far.json"
    argv = ["trajectory", "arm7", "--frame", "ee", "--path", "line", "--start", "5,0,0", "--end", "5,0,0.1",
            "--frames", "2", "--restarts", "10000", "-o", str(out)]
    monkeypatch.setattr("mjkin.apps.cli.TIMEOUT", 0.002)
    assert main(argv) == 0
    assert "frames [0, 1] ran out of the --timeout 0.002 s" in capsys.readouterr().out
    assert motion.Trajectory.load(out).meta["follow"]["timed_out"] == [0, 1]
    assert main([*argv, "--timeout", "none"]) == 0
    assert "ran out" not in capsys.readouterr().out
    assert motion.Trajectory.load(out).meta["follow"]["timed_out"] == []
