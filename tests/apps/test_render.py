"""Scene (contacts), offscreen frames, videos, motion and the CLI commands that use them."""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import imageio.v3 as imageio
import mujoco
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.ndimage import binary_erosion

import mjkin
import mjkin.envs  # noqa: F401  (registers the gymnasium environments)
from conftest import GYM_ASSETS, bundled, model_id, shared, tree_of
from mjkin import motion, render
from mjkin.apps.cli import main
from mjkin.kinematics import build
from mjkin.runtime.files import write_text
from mjkin.scene import Scene

SMALL = {"width": 160, "height": 120}


def clip(*args, **kwargs) -> np.ndarray:
    """The frames of :func:`mjkin.render.frames` as one array ``(T, H, W, 3)``."""
    return np.stack(list(render.frames(*args, **kwargs)))


TWO_BALLS = """<mujoco><worldbody><geom name="fixed" type="sphere" size="0.1"/>
<body name="mover" pos="1 0 0"><joint name="x" type="slide" axis="1 0 0" range="-1 0"/>
<geom name="ball" type="sphere" size="0.1"/></body></worldbody></mujoco>"""


def test_contacts_where_geoms_overlap_and_none_when_clear():
    scene = Scene(mjkin.load(TWO_BALLS))
    assert scene.contacts([0.0]) == [] and not scene.in_collision([0.0])
    (c,) = scene.contacts([-0.95])  # centres 0.05 apart: 0.15 overlap
    assert {c.geom1, c.geom2} == {"fixed", "ball"} and c.distance == pytest.approx(-0.15, abs=1e-9)
    assert scene.in_collision([-0.95])


def test_primate_self_contact(rng):
    tree = tree_of("primate")
    scene = Scene(tree)
    assert not scene.in_collision(tree.qpos0)
    q = tree.qpos0.copy()
    q[tree.jnt_qadr[tree.id("left_shoulder", "joint")]:][:4] = mjkin.spatial.quat_from_axis_angle([1, 0, 0], 1.2)
    contacts = scene.contacts(q)  # the arm swung into the head/torso region
    assert all(c.body1 != c.body2 for c in contacts)


def test_frames_are_not_blank_and_follow_q():
    tree = tree_of("arm7")
    q = np.stack([tree.qpos0, tree.model.key_qpos[0]])
    img = clip(tree, q, **SMALL)
    assert img.shape == (2, 120, 160, 3) and img.dtype == np.uint8
    assert img.std() > 10  # something is drawn
    assert np.abs(img[0].astype(int) - img[1].astype(int)).mean() > 1  # a different pose looks different


def test_overlay_markers_and_trail_are_drawn():
    tree = tree_of("arm7")
    q = tree.random_q(0, 5)
    plain = clip(tree, q, **SMALL)
    marked = clip(tree, q, camera=render.default_camera(tree, q), overlay=render.Overlay(
        points=tree.pose(q, "ee")[:, :3, 3], trail="ee"), **SMALL)
    assert (plain != marked).any(axis=-1).sum() > 50


def test_video_round_trip_and_atomic_writes(tmp_path):
    import imageio.v2 as imageio

    tree = tree_of("planar_2link")
    qs = motion.interpolate(tree, [0, 1], [[0, 0], [1.5, -1.0]], np.linspace(0, 1, 12))
    img = clip(tree, qs, **SMALL)
    for name in ("a.mp4", "a.gif"):
        render.write_video(img, tmp_path / name, fps=12)
        back = imageio.mimread(tmp_path / name)
        assert len(back) == 12 and back[0].shape[:2] == (120, 160)
    with pytest.raises(mjkin.MjkinIOError, match="does not exist"):
        render.write_video(img, tmp_path / "missing" / "v.mp4")
    with pytest.raises(mjkin.InputError, match=r"\.mp4 or \.gif"):
        render.write_video(img, tmp_path / "v.avi")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gif", "a.mp4"]  # no temporary left behind


def test_videos_are_written_at_the_size_asked_for(tmp_path, capfd):
    import imageio.v2 as imageio

    img = np.zeros((2, 78, 102, 3), np.uint8)  # even, but not a multiple of 16: imageio would scale it up
    for name in ("a.mp4", "a.gif"):
        render.write_video(img, tmp_path / name)
        assert imageio.mimread(tmp_path / name)[0].shape[:2] == (78, 102)
    assert "resizing" not in capfd.readouterr().err  # imageio's warning stays out of the user's terminal
    odd = np.zeros((2, 77, 101, 3), np.uint8)
    with pytest.raises(mjkin.InputError, match=r"frame size of an \.mp4 must be even \(H\.264 yuv420p\), got 101x77"):
        render.write_video(odd, tmp_path / "odd.mp4")
    render.write_video(odd, tmp_path / "odd.gif")  # a GIF holds any size
    assert imageio.mimread(tmp_path / "odd.gif")[0].shape[:2] == (77, 101)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gif", "a.mp4", "odd.gif"]


def test_frames_are_drawn_as_they_are_taken(monkeypatch):
    """A clip was drawn whole into one array before the first frame reached the encoder."""
    tree = tree_of("planar_2link")
    drawn = []
    draw = render.Painter.draw
    monkeypatch.setattr(render.Painter, "draw", lambda self, q, *a, **k: drawn.append(q) or draw(self, q, *a, **k))
    frames = render.frames(tree, np.zeros((50, 2)), 32, 24)
    assert drawn == []  # nothing drawn yet
    first = next(frames)
    assert first.shape == (24, 32, 3) and first.dtype == np.uint8 and len(drawn) == 1
    assert len(list(frames)) == 49 and len(drawn) == 50
    with pytest.raises(mjkin.InputError, match="needs"):  # the arguments are checked at the call
        render.frames(tree, np.zeros((3, 5)), 32, 24)


def video_frames(n, fail_at=None, other_size_at=None):
    """``n`` grey frames 48x64, a RuntimeError at frame ``fail_at``, a 50x64 frame at ``other_size_at``."""
    for k in range(n):
        if k == fail_at:
            raise RuntimeError("the renderer died")
        yield np.full((50 if k == other_size_at else 48, 64, 3), 20 * k, np.uint8)


def test_write_video_takes_frames_as_they_come_and_leaves_no_file_when_it_fails(tmp_path):
    for name in ("a.mp4", "a.gif"):
        render.write_video(video_frames(5), tmp_path / name, fps=10)  # a generator: no len(), no indexing
        back = imageio.imread(tmp_path / name, index=None)
        assert back.shape[:3] == (5, 48, 64) and back[..., :3].std() > 10
    with pytest.raises(RuntimeError, match="renderer died"):
        render.write_video(video_frames(5, fail_at=3), tmp_path / "b.mp4")
    for name in ("c.mp4", "c.gif"):
        with pytest.raises(mjkin.InputError, match=r"video frame 2 is \(50, 64, 3\) of uint8, the first \(48, 64, 3\)"):
            render.write_video(video_frames(5, other_size_at=2), tmp_path / name)
    with pytest.raises(mjkin.InputError, match="no frames"):
        render.write_video(iter(()), tmp_path / "d.mp4")
    with pytest.raises(mjkin.InputError, match="of uint8, got"):
        render.write_video([np.zeros((48, 64, 3))], tmp_path / "e.mp4")  # floats: not a picture's bytes
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gif", "a.mp4"]  # no half-written file, no temporary


PEAK_MEMORY = """import sys
from mjkin.apps.cli import main
code = main(sys.argv[1:])
print(next(line.split()[1] for line in open("/proc/self/status") if line.startswith("VmHWM:")))  # peak RSS, kB
sys.exit(code)
"""


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="peak memory is read from /proc (Linux)")
def test_replay_memory_does_not_grow_with_the_clip(tmp_path):
    """Every frame was held until the encoder ran (1000 frames of 160x120 took 46 MB more than 200). Here 60
    more frames of 640x480 would hold 55 MB; each takes ~60 ms to render in software, so a few large frames
    show it in half the time many small ones took (16 s against 33 s in the suite)."""
    tree = tree_of("planar_2link")
    peak = {}
    for n in (20, 80):
        q = np.stack([np.linspace(0.0, 6.0, n), np.sin(np.linspace(0.0, 20.0, n))], -1)
        script = motion.Trajectory(times=np.arange(n) / 30, q=q, fingerprint=motion.fingerprint(tree),
                                   model="planar_2link", frame="tip")  # the trail of the tip, no targets
        script.save(tmp_path / f"{n}.json")
        run = subprocess.run([sys.executable, "-c", PEAK_MEMORY, "replay", str(tmp_path / f"{n}.json"), "-o",
                              str(tmp_path / f"{n}.mp4"), "--width", "640", "--height", "480"],
                             capture_output=True, text=True)
        assert run.returncode == 0, run.stderr
        assert len(imageio.imread(tmp_path / f"{n}.mp4", index=None)) == n
        peak[n] = int(run.stdout.split()[-1]) / 1024  # MB
    assert abs(peak[80] - peak[20]) < 30, peak


def test_a_long_trail_is_framed_without_memory_quadratic_in_its_length():
    """The camera kept the whole trail in view of every frame with a (T, T, 3) array: 216 MB of float64 at
    3000 frames, and copies (linear: 2 MB). The cameras are made when :func:`render.frames` is called, before
    any frame is drawn."""
    import tracemalloc

    tree = tree_of("planar_2link")
    T = 3000
    qs = np.stack([np.linspace(0.0, 6.0, T), np.sin(np.linspace(0.0, 20.0, T))], -1)
    render.frames(tree, qs[:10], 160, 120, overlay=render.Overlay(trail="tip"))  # first use: imports, kernels
    tracemalloc.start()
    try:
        render.frames(tree, qs, 160, 120, overlay=render.Overlay(trail="tip"))
        peak = tracemalloc.get_traced_memory()[1] / 2**20
    finally:
        tracemalloc.stop()
    assert peak < 20, f"{peak:.0f} MB"


KILLED_WRITE = """import itertools, sys, time
import numpy as np
from mjkin import render

def frames():
    for k in itertools.count():
        if k == 3:
            print("writing", flush=True)
        if k >= 3:
            time.sleep(0.05)  # a long render, killed on the way
        yield np.zeros((48, 64, 3), np.uint8)

render.write_video(frames(), sys.argv[1])
"""


def test_a_killed_write_leaves_a_temporary_file_that_the_next_write_removes(tmp_path):
    target = tmp_path / "clip.mp4"
    writer = subprocess.Popen([sys.executable, "-c", KILLED_WRITE, str(target)], stdout=subprocess.PIPE, text=True)
    assert writer.stdout.readline() == "writing\n"
    (left,) = list(tmp_path.iterdir())  # the temporary file beside the target, ours by name
    assert left.name.startswith(".clip.mp4.mjkin-tmp-") and left.suffix == ".mp4"
    writer.kill()
    writer.wait()
    writer.stdout.close()
    old = time.time() - 3600
    live = tmp_path / f".clip.mp4.mjkin-tmp-{os.getpid()}-abcd_123.mp4"  # this process is writing it, an hour on
    foreign = [tmp_path / n for n in (".clip.mp4.abcd_123.mp4", ".clip.mp4.mjkin-tmp-abcd_123.mp4",  # similar names
                                      f"clip.mp4.mjkin-tmp-{writer.pid}-abcd_123.mp4",
                                      f".clip.mp4.mjkin-tmp-{writer.pid}-abcd_123.mp4x")]
    stale = tmp_path / f".notes.txt.mjkin-tmp-{writer.pid}-efgh_456.txt"  # the killed writer's, an hour old
    for p in (live, *foreign, stale):
        p.write_text("x")
        os.utime(p, (old, old))
    write_text(tmp_path / "a.txt", "a")  # this process started before the kill: the leftover is newer
    assert left.exists() and live.exists() and all(p.exists() for p in foreign) and not stale.exists()
    again = subprocess.run([sys.executable, "-c", "import sys; from mjkin.runtime.files import write_text; "
                            "write_text(sys.argv[1], 'b')", str(tmp_path / "b.txt")], capture_output=True, text=True)
    assert again.returncode == 0, again.stderr
    kept = ["a.txt", "b.txt", live.name, *(p.name for p in foreign)]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(kept)


def test_cli_says_the_size_it_wrote(tmp_path, capsys):
    import imageio.v2 as imageio

    out = tmp_path / "even.mp4"
    assert main(["render", "planar_2link", "-o", str(out), "--width", "102", "--height", "78"]) == 0
    assert "(1 frame, 102x78)" in capsys.readouterr().out
    assert imageio.mimread(out)[0].shape[:2] == (78, 102)


def test_interpolation_hits_keys_and_keeps_quaternions_unit(rng):
    tree = tree_of("primate")
    keys = tree.random_q(rng, 4)
    times = [0.0, 0.5, 1.5, 2.0]
    for smooth in (False, True):
        q = motion.interpolate(tree, times, keys, np.linspace(0, 2, 41), smooth=smooth)
        np.testing.assert_array_equal(motion.interpolate(tree, times, keys, times, smooth=smooth), keys)
        np.testing.assert_allclose(np.linalg.norm(q[:, tree.layout.quats], axis=-1), 1.0, atol=1e-12)
        assert np.isfinite(q).all()
    mid = motion.interpolate(tree, times, keys, [0.25])[0]  # halfway in time: halfway in angle
    a = mjkin.spatial.quat_distance(keys[0, 3:7], mid[3:7])
    assert a == pytest.approx(0.5 * mjkin.spatial.quat_distance(keys[0, 3:7], keys[1, 3:7]), abs=1e-9)


def test_follow_a_circle_and_replay_the_script(tmp_path):
    tree = tree_of("arm7")
    home = tree.model.key_qpos[0]
    c = tree.pose(home, "ee")[:3, 3] + [0.1, 0, -0.2]
    path = motion.circle(c, 0.1, 40, normal=[1, 0, 0])
    traj = motion.follow(tree, "ee", path, q0=home)
    assert traj.success.all() and len(traj.discontinuities(tree, threshold=0.5)) == 0
    np.testing.assert_allclose(tree.pose(traj.q, "ee")[:, :3, 3], path, atol=1e-4)
    traj.save(tmp_path / "t.json")
    back = motion.Trajectory.load(tmp_path / "t.json", tree)
    np.testing.assert_array_equal(back.q, traj.q)
    with pytest.raises(mjkin.InputError, match="recorded on model 'arm7'"):
        motion.Trajectory.load(tmp_path / "t.json", tree_of("ball_chain"))
    with pytest.raises(mjkin.MjkinIOError, match="not found"):
        motion.Trajectory.load(tmp_path / "nope.json")


def demo_trajectory(tree, frames, fps=30.0, smooth=0.3):
    """The old demo path on the bundled 7-DoF arm: its effector through five waypoints and home, and the stops."""
    home = tree.model.key_qpos[0].copy()
    start = tree.pose(home, "ee")[:3, 3]
    stops = np.array([start, [0.45, 0.3, 0.45], [0.5, -0.25, 0.5], [0.3, -0.35, 0.9], [0.25, 0.35, 0.85],
                      [0.45, 0.3, 0.45], start])
    traj = motion.follow(tree, "ee", motion.waypoints(stops, frames), q0=home, fps=fps, smooth=smooth,
                         extra=[mjkin.goals.Rest(q_rest=home, weight=0.3, priority=1)])  # keep a natural posture
    return traj, stops


def test_follow_smoothing_keeps_a_comfort_pose_from_swinging_the_arm():
    tree = tree_of("arm7")
    rough, _ = demo_trajectory(tree, 180, smooth=0.0)  # a comfort pose at priority 1 only
    smooth, stops = demo_trajectory(tree, 180)
    assert rough.success.all() and smooth.success.all()
    np.testing.assert_allclose(tree.pose(smooth.q, "ee")[:, :3, 3], smooth.targets[:, 0], atol=1e-4)
    assert smooth.jumps(tree).max() < 0.5 * rough.jumps(tree).max()
    np.testing.assert_allclose(smooth.targets[-1, 0], stops[-1])  # back home, and in a posture near home
    assert np.abs(smooth.q[-1] - tree.model.key_qpos[0]).max() < 0.05
    with pytest.raises(mjkin.InputError, match="smooth must be a finite number >= 0"):
        motion.follow(tree, "ee", stops, smooth=-1.0)


@pytest.mark.parametrize("call, text", [
    (lambda: motion.line([0, 0, 0], [1, 1, 1], 1), "at least 2 frames"),
    (lambda: motion.circle([0, 0, 0], -1, 10), "positive radius"),
    (lambda: motion.waypoints([[0, 0, 0]], 10), "at least two"),
    (lambda: motion.interpolate(tree_of("arm7"), [0, 0], np.zeros((2, 7)), [0]), "increasing"),
])
def test_motion_input_errors(call, text):
    with pytest.raises(mjkin.MjkinError, match=text):
        call()


def test_cli_demo_trajectory_render_replay(tmp_path, capsys):
    demo = tmp_path / "demo.mp4"
    assert main(["demo", "-o", str(demo), "--seconds", "0.5", "--width", "160", "--height", "120"]) == 0
    assert demo.stat().st_size > 1000 and "wrote" in capsys.readouterr().out
    script = tmp_path / "t.json"
    assert main(["trajectory", "arm7", "--site", "ee", "--path", "line", "--end", "0.4,0.2,0.6", "--frames", "10",
                 "-o", str(script)]) == 0
    out = tmp_path / "r.gif"
    assert main(["replay", str(script), "-o", str(out), "--width", "160", "--height", "120"]) == 0
    assert out.exists()
    stills = [tmp_path / f"frame{k}.png" for k in (0, 9, -1)]
    for k, path in zip((0, 9, -1), stills, strict=True):  # a still of one frame of the script
        small = ["--width", "160", "--height", "120"]
        assert main(["replay", str(script), "-o", str(path), "--frame", str(k), *small]) == 0
    first, ninth, last = (imageio.imread(p) for p in stills)
    assert np.array_equal(ninth, last) and not np.array_equal(first, last)
    png = tmp_path / "still.png"
    assert main(["render", "primate", "-o", str(png), "--width", "160", "--height", "120"]) == 0
    assert png.stat().st_size > 1000


@pytest.mark.parametrize("argv, text", [
    (["trajectory", "arm7", "--site", "hand", "--path", "circle", "-o", "{tmp}/t.json"], "unknown site or body 'hand'"),
    (["trajectory", "arm7", "--site", "ee", "--path", "line", "--end", "1,1,1", "--frames", "1", "-o", "{tmp}/t.json"],
     "at least 2 frames"),
    (["trajectory", "arm7", "--site", "ee", "--path", "waypoints", "-o", "{tmp}/t.json"], "needs --points"),
    (["render", "arm7", "-o", "{tmp}/no/such/dir/x.png"], "does not exist"),
    (["replay", "{tmp}/t.json", "--model", "arm7", "-o", "{tmp}/x.mp4"], "not found"),
    (["render", "arm7", "-o", "{tmp}/x.png", "--frame", "1"], "--frame must be in [-1, 0]"),
])
def test_cli_mistakes_exit_2_and_write_nothing(argv, text, tmp_path, capsys):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert text in err and err.count("\n") == 1
    assert list(tmp_path.rglob("*")) == []


def test_replay_refuses_a_script_from_another_model(tmp_path, capsys):
    tree = tree_of("arm7")
    traj = motion.Trajectory(times=np.zeros(1), q=tree.qpos0[None], fingerprint=motion.fingerprint(tree), model="arm7")
    traj.save(tmp_path / "t.json")
    assert main(["replay", str(tmp_path / "t.json"), "--model", "ball_chain", "-o", str(tmp_path / "x.mp4")]) == 2
    assert "recorded on model 'arm7'" in capsys.readouterr().err
    assert not (tmp_path / "x.mp4").exists()


def test_ik_can_avoid_collisions():
    """Two elbow solutions reach the target; an obstacle sits on one elbow; avoid_collisions picks the other."""
    from mjkin.ik.analytic import solutions
    from mjkin.kinematics import build

    xml = build.planar_chain([1.0, 0.7])
    free = mjkin.load(xml)
    (qa, qb), ok = solutions(free, np.array([1.2, 0.5, 0.0]), "ee")
    elbow = free.pose(qa, "link1_tip")[:3, 3]
    tree = mjkin.load(xml.replace("<worldbody>", f'<worldbody><geom name="post" type="sphere" size="0.08" '
                                                  f'pos="{elbow[0]} {elbow[1]} 0"/>', 1))
    goal = mjkin.goals.Position("ee", [1.2, 0.5, 0.0])
    scene = Scene(tree)
    plain = mjkin.solve(tree, goal, q0=qa, restarts=0)
    assert plain.success and scene.in_collision(plain.q)
    safe = mjkin.solve(tree, goal, q0=qa, avoid_collisions=True)
    assert safe.success and not scene.in_collision(safe.q)
    blocked = mjkin.solve(tree, mjkin.goals.Position("ee", elbow), q0=qa, avoid_collisions=True)
    assert not blocked.success and blocked.status == "constraint" and not scene.in_collision(blocked.q)


# ------------------------------------------------------------------ framing
FRAMED = bundled() + [GYM_ASSETS / f"{name}.xml" for name in ("humanoid", "ant", "pusher", "reacher")]
BAND = 0.05  # no figure pixel within this fraction of the image of any edge


def figure_mask(painter: render.Painter, q: np.ndarray, camera: mujoco.MjvCamera) -> np.ndarray:
    """Pixels ``(H, W)`` where MuJoCo's segmentation rendering shows a geom of the figure."""
    r = painter.renderer
    r.enable_segmentation_rendering()
    try:
        r.update_scene(painter.scene.set(q), camera)
        seg = r.render()
    finally:
        r.disable_segmentation_rendering()
    ids = render.figure_geoms(painter.tree.model)
    return (seg[..., 1] == mujoco.mjtObj.mjOBJ_GEOM) & np.isin(seg[..., 0], ids)


def assert_framed(mask: np.ndarray, what: str) -> None:
    h, w = mask.shape
    ys, xs = np.nonzero(mask)
    assert len(xs) > 0, f"{what}: the figure is not in the image"
    bx, by = int(np.ceil(BAND * w)), int(np.ceil(BAND * h))
    assert xs.min() >= bx and xs.max() < w - bx and ys.min() >= by and ys.max() < h - by, (
        f"{what}: figure pixels x {xs.min()}..{xs.max()} of {w}, y {ys.min()}..{ys.max()} of {h}")


@pytest.mark.parametrize("src", FRAMED, ids=model_id)
def test_default_camera_keeps_every_geom_inside_the_margin(src):
    tree = tree_of(src)
    qs = np.vstack([tree.qpos0, tree.random_q(np.random.default_rng(7), 3)])
    with render.Painter(tree, **SMALL) as painter:
        for k, q in enumerate(qs):  # a still of each pose
            assert_framed(figure_mask(painter, q, render.default_camera(tree, q[None])), f"pose {k}")
        video = render.default_camera(tree, qs)  # one shot for a video of all poses
        for k, q in enumerate(qs):
            assert_framed(figure_mask(painter, q, video), f"video frame {k}")
        look = render.default_camera(tree, qs[:1]).lookat
        corners = render.geom_corners(tree, qs[0]).reshape(-1, 3)
        assert np.all(look >= corners.min(0) - 1e-9) and np.all(look <= corners.max(0) + 1e-9)  # at the figure


def test_planar_chains_are_seen_along_their_joint_axis():
    for name in ("planar_2link", "planar_3link", "planar_prismatic"):
        tree = tree_of(name)
        np.testing.assert_allclose(np.abs(render.planar_axis(tree)), [0, 0, 1], atol=1e-12)
        cam = render.default_camera(tree, tree.qpos0[None])
        assert cam.elevation == -90.0  # looking down the z axes of the hinges
    for name in ("arm7", "ball_chain", "primate"):
        assert render.planar_axis(tree_of(name)) is None
    side = mjkin.load(build.planar_chain([1.0, 0.5]).replace('axis="0.0 0.0 1.0"', 'axis="0.0 1.0 0.0"'))
    np.testing.assert_allclose(np.abs(render.planar_axis(side)), [0, 1, 0], atol=1e-12)
    cam = render.default_camera(side, side.qpos0[None])  # hinged about y: seen from the side, world x to the right
    assert cam.elevation == 0.0 and render._basis(cam.azimuth, cam.elevation)[1] @ [1, 0, 0] > 0.99


def test_tracking_camera_follows_a_walker_smoothly():
    tree = tree_of("primate")
    T = 40
    qs = np.repeat(tree.qpos0[None], T, axis=0)
    qs[:, 0] = np.linspace(0.0, 4.0, T)  # the whole figure travels 4 m along x
    cams = render.camera_path(tree, qs, aspect=SMALL["width"] / SMALL["height"])
    looks = np.array([c.lookat for c in cams])
    assert looks[-1, 0] - looks[0, 0] > 2.0  # it follows
    assert len({c.distance for c in cams}) == 1  # at a fixed distance (no zoom pumping)
    assert np.abs(np.diff(looks, 2, axis=0)).max() < 0.05  # smoothly
    with render.Painter(tree, **SMALL) as painter:
        for k in (0, T // 2, T - 1):
            assert_framed(figure_mask(painter, qs[k], cams[k]), f"frame {k}")
    still = render.camera_path(tree, qs[:1].repeat(T, 0))
    assert len({tuple(c.lookat) for c in still}) == 1  # a figure that stays gets a still shot


# ------------------------------------------------------------------ overlays
@given(st.integers(0, 5000), st.integers(2, 300))
def test_trail_keeps_a_bounded_number_of_points(t, m):
    idx = render.trail_indices(t, m)
    assert idx[0] == 0 and idx[-1] == t and np.all(np.diff(idx) > 0)
    assert len(idx) <= m + 1
    assert len(idx) == t + 1 or len(idx) >= m // 2  # decimated only as much as needed


def test_overlay_geoms_per_frame_do_not_grow_with_the_video(monkeypatch):
    tree = tree_of("planar_2link")
    T = 160  # 20 times the trail's points (software GL draws a frame in ~15 ms, even at 32x24)
    qs = np.stack([np.linspace(0, 6, T), np.sin(np.linspace(0, 20, T))], -1)
    added = []
    draw = render.Painter.draw

    def counting(self, *args, **kwargs):
        image = draw(self, *args, **kwargs)
        added.append(self.added)
        return image

    monkeypatch.setattr(render.Painter, "draw", counting)
    overlay = render.Overlay(points=np.zeros((2, 3)), bones=np.array([[0, 1]]), trail="tip", trail_points=8)
    clip(tree, qs, 32, 24, overlay=overlay)  # every frame drawn
    assert len(added) == T and max(added) <= 2 + 1 + 8  # 2 markers, their bone + at most 8 trail segments
    assert added[-1] >= 2 + 1 + 4  # and the trail is still there at the end


def test_overlay_bones_must_index_its_points():
    tree = tree_of("planar_2link")
    with pytest.raises(mjkin.InputError, match="overlay bones must index the 2 points, got indices from 0 to 2"):
        render.frames(tree, tree.qpos0, overlay=render.Overlay(points=np.zeros((2, 3)), bones=np.array([[0, 2]])))


def test_side_by_side_draws_the_source_skeleton_with_bones(tmp_path, monkeypatch):
    """``mjkin retarget --side-by-side`` drew the source's joints as dots only: now a capsule of their colour joins
    each drawn joint to its nearest drawn ancestor.
    """  # noqa: D205
    from test_retarget import crouch_bvh

    from mjkin.motion import bvh
    from mjkin.motion.retarget import source_mapping

    text = crouch_bvh(12)
    write_text(tmp_path / "crouch.bvh", text)
    overlays = []
    draw = render.Painter.draw

    def keeping(self, *args, **kwargs):
        image = draw(self, *args, **kwargs)
        scene = self.renderer.scene
        overlays.append([(int(g.type), g.rgba.copy(), g.pos.copy()) for g in scene.geoms[scene.ngeom - self.added:
                                                                                             scene.ngeom]])
        return image

    monkeypatch.setattr(render.Painter, "draw", keeping)
    assert main(["retarget", str(tmp_path / "crouch.bvh"), "--model", "primate", "-o", str(tmp_path / "still.png"),
                 "--side-by-side", "--width", "160", "--height", "120"]) == 0
    (overlay,) = overlays
    dots = np.array([pos for kind, _, pos in overlay if kind == mujoco.mjtGeom.mjGEOM_SPHERE])
    bones = [(rgba, pos) for kind, rgba, pos in overlay if kind == mujoco.mjtGeom.mjGEOM_CAPSULE]
    source = bvh.parse(text)
    joints = sorted(source_mapping(source).values())
    assert len(dots) == len(joints) == 17
    at = {source.names[j]: i for i, j in enumerate(joints)}
    pairs = [("Hips", "Neck"), ("Neck", "Head")] + [(a.replace("*", s), b.replace("*", s)) for s in ("Left", "Right")
                                                     for a, b in [("Hips", "*Shoulder"), ("*Shoulder", "*Elbow"),
                                                                  ("*Elbow", "*Wrist"), ("Hips", "*Hip"),
                                                                  ("*Hip", "*Knee"), ("*Knee", "*Ankle"),
                                                                  ("*Ankle", "*Ankle_End")]]
    assert len(bones) == len(pairs) == len(joints) - 1  # one per drawn joint but the root
    middles = np.array([0.5 * (dots[at[a]] + dots[at[b]]) for a, b in pairs])
    centres = np.array([pos for _, pos in bones])
    assert np.abs(centres[:, None] - middles[None]).max(-1).min(0).max() < 1e-5  # each joins its joint to its parent
    dot_rgba = next(rgba for kind, rgba, _ in overlay if kind == mujoco.mjtGeom.mjGEOM_SPHERE)
    assert all(np.array_equal(rgba, dot_rgba) for rgba, _ in bones)  # in the dots' colour


def test_markers_and_trail_cast_no_shadow():
    tree = tree_of("arm7")
    q = tree.model.key_qpos[0]
    marker, trail = np.array([[0.3, 0.3, 0.9]]), np.array([[0.3, -0.3, 0.9], [0.3, 0.0, 1.0]])
    cam = render.default_camera(tree, q[None], marker)
    ov = render.Overlay(point_size=0.06, trail_width=8.0)
    with render.Painter(tree, 320, 240) as painter:
        plain, marked = painter.draw(q, cam).astype(int), painter.draw(q, cam, marker, trail, ov)
    fwd, _, up = render._basis(cam.azimuth, cam.elevation)
    rel = np.vstack([marker, trail]) - (cam.lookat - cam.distance * fwd)
    ndc_y = (rel @ up) / ((rel @ fwd) * np.tan(np.radians(tree.model.vis.global_.fovy) / 2))
    lowest = int((1 - ndc_y.min()) / 2 * 240) + 15  # the overlay's lowest image row, and the marker's radius
    changed = np.abs(marked.astype(int) - plain).sum(-1) > 12
    assert changed[:lowest].sum() > 100  # the markers are drawn
    assert not changed[lowest:].any()  # and nothing below them changed: no shadow on the floor or the arm


def unexplained_floor_shadow(tree: mjkin.Tree, q: np.ndarray, width: int = 640, height: int = 480) -> tuple[int, int]:
    """Floor pixels (the staged checker) in shadow with no geom straight above them, and all floor pixels in shadow.

    The bundled models light the scene from straight above, so a floor point can only be
    shadowed by a geom whose box covers it in x and y (boxes widened by 2 cm: a texel and a pixel).
    """
    data = mujoco.MjData(tree.model)
    data.qpos[:] = q
    mujoco.mj_kinematics(tree.model, data)
    m = tree.model
    casters = np.flatnonzero(m.geom_type != mujoco.mjtGeom.mjGEOM_PLANE)
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    corners = np.stack([data.geom_xpos[g] + (m.geom_aabb[g, :3] + signs * m.geom_aabb[g, 3:])
                        @ data.geom_xmat[g].reshape(3, 3).T for g in casters])  # (G, 8, 3)
    lo, hi = corners[..., :2].min(axis=1) - 0.02, corners[..., :2].max(axis=1) + 0.02
    with render.Painter(tree, width, height) as painter:
        cam = painter.camera(None, q[None])
        r = painter.renderer
        lit = painter.draw(q, cam).astype(int)
        r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        unshadowed = r.render().astype(int)
        r.enable_segmentation_rendering()
        seg = r.render().copy()
        r.disable_segmentation_rendering()
        floor_z = painter.floor.z
    fwd, right, up = render._basis(cam.azimuth, cam.elevation)
    ty = np.tan(np.radians(m.vis.global_.fovy) / 2)
    eye = np.asarray(cam.lookat) - cam.distance * fwd
    ys, xs = np.mgrid[:height, :width]
    nx, ny = (xs + 0.5) / width * 2 - 1, 1 - (ys + 0.5) / height * 2
    rays = fwd + (nx * ty * width / height)[..., None] * right + (ny * ty)[..., None] * up
    with np.errstate(divide="ignore"):
        t = (floor_z - eye[2]) / rays[..., 2]  # where each pixel's ray meets the staged floor
    floor = (seg[..., 0] == -1) & (t > 0)  # the staged checker: no model geom there, and below the horizon
    floor = binary_erosion(floor, iterations=2)  # not the antialiased pixels at the figure's outline
    shadow = floor & ((unshadowed - lit).sum(-1) > 30)
    points = eye + t[shadow][:, None] * rays[shadow]
    under = ((points[:, None, :2] >= lo) & (points[:, None, :2] <= hi)).all(-1).any(-1)
    return int((~under).sum()), int(shadow.sum())


@pytest.mark.parametrize("seed", [1, 5])
def test_no_shadow_specks_on_the_floor(seed):
    """Black specks dotted the floor where nothing stood above it: the floor shadowed itself in MuJoCo's shadow map.

    The primate in a random world pose (what ``mjkin render primate --q random`` drew) showed them.
    """
    tree = tree_of("primate")
    q = tree.random_q(np.random.default_rng(seed))
    specks, shadow = unexplained_floor_shadow(tree, q)
    assert shadow > 500  # the figure's own shadow is there
    assert specks == 0


def test_captions_are_drawn_in_the_corner():
    tree = tree_of("planar_2link")
    qs = np.zeros((3, 2))
    plain = clip(tree, qs, **SMALL)
    captioned = clip(tree, qs, overlay=render.Overlay(caption=lambda t: f"pinv · frame {t}"), **SMALL)
    diff = np.abs(captioned.astype(int) - plain).sum(-1) > 0
    assert diff[:, :30, :80].any(axis=(1, 2)).all()  # text top-left in every frame
    assert not diff[:, 60:, :].any()  # nothing in the lower half
    assert not np.array_equal(captioned[0], captioned[1])  # the frame number changes
    listed = clip(tree, qs, overlay=render.Overlay(caption=["a", "", "c"]), **SMALL)
    assert np.array_equal(listed[1], plain[1])


@pytest.mark.parametrize("src", bundled(), ids=model_id)
def test_no_coincident_caps_between_linked_geoms(src):
    """Two capsule/sphere caps with the same centre and radius in different bodies z-fight where they meet."""
    tree = tree_of(src)
    m = tree.model
    data = mujoco.MjData(m)
    mujoco.mj_kinematics(m, data)
    caps = []  # (geom, body, centre, radius)
    for g in range(m.ngeom):
        if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE:
            axis = data.geom_xmat[g].reshape(3, 3)[:, 2] * m.geom_size[g, 1]
            caps += [(g, m.geom_bodyid[g], data.geom_xpos[g] + s * axis, m.geom_size[g, 0]) for s in (-1, 1)]
        elif m.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE:
            caps.append((g, m.geom_bodyid[g], data.geom_xpos[g], m.geom_size[g, 0]))
    for i, (g1, b1, c1, r1) in enumerate(caps):
        for g2, b2, c2, r2 in caps[i + 1:]:
            if b1 != b2 and np.linalg.norm(c1 - c2) < 1e-9:
                assert abs(r1 - r2) > 1e-4 * max(r1, r2), f"geoms {m.geom(g1).name} and {m.geom(g2).name} z-fight"


def test_a_renderer_that_cannot_start_says_how_to_get_one(monkeypatch):
    """No GL context (MuJoCo's error): one line naming MUJOCO_GL=egl and when it must be set, and the model's
    offscreen settings put back."""
    def refuse(*args, **kwargs):
        raise mujoco.FatalError("gladLoadGL error\nno context")

    tree = tree_of("arm7")
    kept = tree.model.vis.global_.offwidth, tree.model.vis.quality.shadowsize
    monkeypatch.setattr(mujoco, "Renderer", refuse)
    with pytest.raises(mjkin.MjkinIOError, match="MUJOCO_GL=egl before mujoco is imported") as info:
        render.Painter(tree, 64, 48)
    assert "\n" not in str(info.value) and "gladLoadGL error no context" in str(info.value)
    assert (tree.model.vis.global_.offwidth, tree.model.vis.quality.shadowsize) == kept


# ------------------------------------------------------------------ stage
BARE_CHAIN = """<mujoco><worldbody>
<body name="base" pos="0 0 {z}"><joint name="x" type="slide" axis="1 0 0"/><joint name="yaw" axis="0 0 1"/>
<geom type="cylinder" size="0.05 0.02" group="3" rgba="0.2 0.7 0.3 1"/>
<body name="upper" pos="0 0 0.4"><joint name="shoulder" axis="0 1 0"/>
<geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" group="3" rgba="0.2 0.7 0.3 1"/>
<body name="lower" pos="0.3 0 0"><joint name="elbow" axis="0 1 0"/>
<body name="hand" pos="0.25 0 0"><geom type="sphere" size="0.02" rgba="0.9 0.2 0.2 1"/></body>
</body></body></body></worldbody></mujoco>"""  # no light, floor or sky; all geoms hidden (group 3, drawn green: their
# bodies show nothing else) but the hand's
NO_GEOMS = re.sub(r"<geom[^>]*/>", '<inertial pos="0 0 0" mass="0.1" diaginertia="1e-4 1e-4 1e-4"/>', BARE_CHAIN)
POSE = np.array([0.0, 0.4, -0.5, 1.0])  # x, yaw, shoulder, elbow


def bare_chain(z: float = 0.0, xml: str = BARE_CHAIN) -> mjkin.Tree:
    return tree_of(xml.format(z=z))


def grey(image: np.ndarray) -> np.ndarray:
    """``(H, W)``: pixels of the bones' grey, lit (the floor and sky are blue, the hand red)."""
    rgb = image.astype(int)
    return (np.abs(rgb[..., 0] - rgb[..., 2]) < 20) & (np.abs(rgb[..., 0] - rgb[..., 1]) < 20) & (rgb.mean(-1) > 60)


def pixels(cam: mujoco.MjvCamera, points: np.ndarray, fovy: float, width: int, height: int) -> np.ndarray:
    """Image (column, row) ``(n, 2)`` of world ``points (n, 3)`` seen by a free camera."""
    fwd, right, up = render._basis(cam.azimuth, cam.elevation)
    rel = points - (np.asarray(cam.lookat) - cam.distance * fwd)
    ty = np.tan(np.radians(fovy) / 2)
    x, y = (rel @ right) / (rel @ fwd * ty * width / height), (rel @ up) / (rel @ fwd * ty)
    return np.stack([(1 + x) / 2 * width, (1 - y) / 2 * height], axis=-1)


def test_a_model_without_light_floor_or_sky_is_lit_and_staged():
    """A mesh-free model with no light, floor or sky (unitree_g1 of the shared models) rendered black."""
    tree = bare_chain()
    stage = render.Stage.of(tree)
    assert stage.light and stage.backdrop and stage.bones.tolist() == [[1, 2], [2, 3], [3, 4]]
    with render.Painter(tree, **SMALL, stage=False) as painter:
        unstaged = painter.draw(POSE, painter.cameras(None, POSE[None], view=(120.0, -5.0))[0])
    assert unstaged.mean() < 3  # what the newcomer saw: a red dot on black
    staged = clip(tree, POSE, view=(120.0, -5.0), **SMALL)[0]
    assert staged.mean() > 40
    sky, ground = staged[:20, :40].astype(int), staged[-30:, 60:].astype(int)  # corners clear of the figure
    assert (sky[..., 2] - sky[..., 0] > 30).all()  # blue above
    assert ground.mean() > 40 and (ground[..., 2] - ground[..., 0] > 15).all()  # the blue checker below
    brightness = ground.sum(-1)
    dark, bright = (brightness < np.median(brightness)).mean(), (brightness > np.median(brightness)).mean()
    assert 0.2 < dark < 0.8 and 0.2 < bright < 0.8  # two colours of squares


def test_a_model_without_lights_gets_a_light_from_above_and_keeps_its_own_settings():
    floored = BARE_CHAIN.replace("<worldbody>", '<worldbody><geom type="plane" size="2 2 0.1" rgba="0.8 0.8 0.8 1"/>')
    tree = bare_chain(xml=floored)
    stage = render.Stage.of(tree)
    assert stage.light and stage.backdrop and stage.floor == 0.0 and stage.floors.tolist() == [0]
    light = tree.model.vis.headlight
    kept = light.active, light.ambient.copy(), light.diffuse.copy(), light.specular.copy()
    with render.Painter(tree, **SMALL) as painter:
        cam = painter.camera(None, POSE[None])
        lit = painter.draw(POSE, cam).astype(int)
        assert painter.renderer.scene.nlight == 2  # the headlight and the light from above
        painter.stage = dataclasses.replace(painter.stage, light=False)
        dim = painter.draw(POSE, cam).astype(int)
    assert lit.mean() > dim.mean() + 5 and lit.mean() > 60
    assert (light.active, *light.ambient, *light.diffuse, *light.specular) == (kept[0], *kept[1], *kept[2], *kept[3])


@pytest.mark.parametrize("name", ["arm7", "planar_2link", "primate", "panda"])
def test_models_with_their_own_scene_are_staged_in_the_one_look(name):
    """Each bundled model's own skybox, floor and light made its own look (black sky, white floors): the stage draws
    its sky and floor over them; ``stage=False`` draws the model as it is.
    """
    tree = tree_of(name)
    stage = render.Stage.of(tree)
    assert not stage.light and stage.backdrop and len(stage.bones) == 0 and len(stage.floors)  # its own light kept
    q = tree.random_q(np.random.default_rng(0))
    with render.Painter(tree, **SMALL) as staged, render.Painter(tree, **SMALL, stage=False) as plain:
        cam = staged.camera(None, q[None])
        assert not np.array_equal(staged.draw(q, cam), plain.draw(q, cam))
        assert plain.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX]


def test_panda_reach_env_renders_lit_with_a_sky(monkeypatch):
    def frame():
        env = gym.make("mjkin/PandaReach-v0", render_mode="rgb_array", width=160, height=120)
        env.reset(seed=3)
        image = env.render()
        env.close()
        return image

    staged = frame()
    monkeypatch.setattr(render.Stage, "of", classmethod(lambda cls, tree: cls()))  # nothing added
    black = (frame().max(-1) < 25).mean()
    assert staged.mean() > 40 and (staged.max(-1) < 25).mean() < 0.02 < black  # the model alone has a black sky


@pytest.mark.parametrize("xml", [BARE_CHAIN, NO_GEOMS], ids=["hidden-geoms", "no-geoms"])
def test_bare_links_are_drawn_as_bones_between_body_origins(xml):
    tree = bare_chain(xml=xml)
    stage = render.Stage.of(tree)
    assert stage.bones.tolist() == [[1, 2], [2, 3], [3, 4]] and 0 < stage.radius < 0.05
    with render.Painter(tree, **SMALL) as painter:
        cam = painter.camera(None, POSE[None])
        boned = grey(painter.draw(POSE, cam))
        painter.stage = dataclasses.replace(painter.stage, bones=np.zeros((0, 2), np.int64))
        bare = grey(painter.draw(POSE, cam))
    assert boned.sum() > bare.sum() + 150 and bare.sum() < 20
    origins = tree.fk(POSE)[1:, :3, 3]
    mids = pixels(cam, 0.5 * (origins[:-1] + origins[1:]), tree.model.vis.global_.fovy, **SMALL)
    for col, row in mids.astype(int):  # each bone crosses its midpoint's pixel (or one beside it)
        assert boned[row - 1:row + 2, col - 1:col + 2].any() and not bare[row - 1:row + 2, col - 1:col + 2].any()


def test_the_floor_is_under_the_figure_over_the_whole_video():
    standing = bare_chain()
    assert render.fit_floor(standing, POSE, render.Stage.of(standing)).z == 0.0  # the base stands at z = 0
    qs = np.stack([POSE, POSE + [0.0, 0.0, 1.2, 0.0]])
    raised = bare_chain(z=1.0)
    stage = render.Stage.of(raised)
    floor = render.fit_floor(raised, qs, stage)
    lowest = min(raised.fk(qs)[:, 1:, 2, 3].min() - stage.radius, render.geom_corners(raised, qs)[..., 2].min())
    assert floor.z == pytest.approx(lowest) and lowest < 0.95  # the arm swings down below its base: under the hand
    walk = np.repeat(POSE[None], 50, axis=0)
    walk[:, 0] = np.linspace(0.0, 100.0, 50)  # 100 m: larger squares, no more of them
    assert len(render.fit_floor(raised, walk, stage).centres) <= render.FLOOR_SQUARES
    with render.Painter(raised, 32, 24) as painter:
        painter.draw(walk[0], painter.camera(None, walk))
        n = painter.renderer.scene.ngeom
    assert n <= 1 + 1 + render.FLOOR_SQUARES + render.SKY_BANDS + 3  # the hand, the ground, 3 bones


def test_a_still_matches_its_frame_of_the_video():
    tree = bare_chain(z=1.0)
    qs = np.stack([POSE, POSE + [0.0, 0.0, 1.2, 0.0]])
    video = clip(tree, qs, **SMALL)
    with render.Painter(tree, **SMALL) as painter:  # as `mjkin render --frame 0` draws it
        still = painter.draw(qs[0], painter.camera(None, qs))
    assert np.array_equal(still, video[0])


G1 = [p for p in shared() if p.stem == "g1"]


@pytest.mark.skipif(not G1, reason="the shared mesh-free robot models are not here")
def test_cli_renders_the_mesh_free_g1_lit_on_a_floor_with_bones(tmp_path):
    out = tmp_path / "g1.png"
    assert main(["render", str(G1[0]), "-o", str(out), "--width", "160", "--height", "120"]) == 0
    image = imageio.imread(out)
    assert image.mean() > 35 and grey(image).sum() > 200  # was a few grey dots on black (mean 1)
