"""``mjkin demo``: a short showcase in three scenes, each with captions.

1. ``seeds`` — the lecture notes' three-link arm (links 15, 10, 5, from [π/8, π/4, π/4]) side by side under
   pinv, DLS and CCD: every solver step is shown (eased between steps) while the
   tip walks onto (−20, 5), then toward the unreachable (−35, 5) from the start.
2. ``arm`` — the 7-DoF arm's effector follows a Cartesian path with rounded
   corners and minimum-jerk timing around two obstacles, solved frame by frame with the arm kept clear
   of the obstacles and of itself.
3. ``walk`` — the primate walks heel to toe, seen from the side by a tracking camera.

Every scene yields its frames one at a time (see :func:`mjkin.render.frames`), so
the showcase goes to the encoder without being held in memory.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator

import numpy as np
from numpy.typing import NDArray

from ... import motion, render
from ...errors import InputError
from ...goals import Rest
from ...kinematics.tree import Tree, bundled_models, load
from ...scene import Scene
from . import seeds

Array = NDArray[np.float64]
Images = Iterator[NDArray[np.uint8]]  # frames (height, width, 3), one at a time
SHARES = {"seeds": 0.34, "arm": 0.36, "walk": 0.3}  # parts of the showcase's length
SEED_METHODS = ("pinv", "dls", "ccd")
WALK_STEPS = 4
MAX_FRAMES = 100_000  # frames the showcase renders at most (55 min at 30 fps; each is rendered and kept in memory)
OBSTACLES = np.array([[0.52, 0.02, 0.3, 0.1], [0.2, 0.0, 1.07, 0.08]])  # x, y, z, radius (m)
ARM_STOPS = np.array([[0.45, 0.3, 0.45], [0.5, -0.25, 0.5], [0.3, -0.35, 0.9], [0.25, 0.35, 0.85],
                      [0.45, 0.3, 0.45]])


def _frames_of(share: float, seconds: float, fps: float) -> int:
    return max(2, int(round(share * seconds * fps)))


def _eased_steps(history: Array, steps: int, n: int) -> Array:
    """``n`` configurations showing solver steps ``0..steps`` of ``history (H, nq)``, eased between steps."""
    u = np.linspace(0.0, steps, n)
    k = np.minimum(np.floor(u).astype(int), max(steps - 1, 0))
    f = motion.min_jerk(u - k)[:, None] if steps else np.zeros((n, 1))
    nxt = np.minimum(k + 1, steps)
    return (1 - f) * history[k] + f * history[nxt]


def scene_seeds(width: int, height: int, n: int) -> Images:
    """Three panes (pinv, DLS, CCD, one above the other) of the seeds' arm: to (−20, 5), then toward (−35, 5).

    The three panes are rendered side by side, a frame of each at a time.
    """
    tree = load("planar_3link")
    half = max(1, n // 2)
    parts: dict[str, list[tuple[Array, Array, Array]]] = {m: [] for m in SEED_METHODS}
    for goal, count in ((seeds.REACHABLE, half), (seeds.UNREACHABLE, n - half)):
        for m in SEED_METHODS:
            res = seeds.three_link(m, goal)
            assert res.history is not None
            steps = int(res.iterations)
            q = _eased_steps(res.history.q, steps, count)
            err = res.history.error[np.minimum(np.round(np.linspace(0, steps, count)).astype(int), steps), 0]
            step = np.round(np.linspace(0, steps, count)).astype(int)
            parts[m].append((q, np.broadcast_to(goal, (count, 1, 3)), np.stack([step, err], -1)))
    heights = [height // 3, height // 3, height - 2 * (height // 3)]
    qs_all = np.concatenate([p[0] for m in SEED_METHODS for p in parts[m]])
    goals = np.array([seeds.REACHABLE, seeds.UNREACHABLE])
    panes = []
    for m, h in zip(SEED_METHODS, heights, strict=True):
        cam = render.default_camera(tree, qs_all, goals, aspect=width / h)
        clips = []
        for q, targets, info in parts[m]:  # one clip per goal: the trail starts again with the run

            def caption(t: int, m: str = m, info: Array = info, g: Array = targets[0, 0]) -> str:
                return f"{m} to ({g[0]:g}, {g[1]:g})\nstep {int(info[t, 0])} · error {info[t, 1]:.2g}"

            ov = render.Overlay(points=targets, point_size=1.0, trail="tip", caption=caption)
            clips.append(render.frames(tree, q, width, h, camera=cam, overlay=ov, desc=f"render {m}"))
        panes.append(itertools.chain.from_iterable(clips))
    return (np.concatenate(rows) for rows in zip(*panes, strict=True))


def arm_with_obstacles() -> Tree:
    """The bundled 7-DoF arm with :data:`OBSTACLES` as red spheres in its world."""
    xml = bundled_models()["arm7"].read_text()
    balls = "".join(f'<geom name="obstacle{i}" type="sphere" size="{r}" pos="{x} {y} {z}" rgba="0.8 0.25 0.25 1"/>'
                    for i, (x, y, z, r) in enumerate(OBSTACLES))
    return load(xml.replace("</worldbody>", balls + "</worldbody>"))


def arm_motion(n: int, fps: float) -> tuple[Tree, Array, motion.Trajectory]:
    """The arm scene's tree, effector path ``(n, 3)`` (world, m) and the trajectory that follows it.

    From the home key through :data:`ARM_STOPS` and back, corners rounded, eased; every frame
    keeps the arm clear of the obstacles and of itself (``avoid_collisions``).
    """
    tree = arm_with_obstacles()
    home = tree.model.key_qpos[0].copy()
    start = tree.pose(home, "ee")[:3, 3]
    stops = np.vstack([start, ARM_STOPS, start])
    path = motion.waypoints(stops, n, corner=0.12, ease=True)
    traj = motion.follow(tree, "ee", path, q0=home, fps=fps, extra=[Rest(q_rest=home, weight=0.3, priority=1)],
                         avoid_collisions=True)
    return tree, path, traj


def scene_arm(width: int, height: int, n: int, fps: float) -> Images:
    """The 7-DoF arm's effector along a rounded, eased path around two obstacles."""
    tree, path, traj = arm_motion(n, fps)
    scene = Scene(tree)
    contacts = np.array([len(scene.contacts(q)) for q in traj.q])
    err = np.linalg.norm(tree.pose(traj.q, "ee")[:, :3, 3] - path, axis=-1)
    cam = render.camera_path(tree, traj.q, np.vstack([path, OBSTACLES[:, :3]]), aspect=width / height,
                             follow=False, extra_radius=float(OBSTACLES[:, 3].max()))[0]

    def caption(t: int) -> str:
        return f"7-DoF arm: Cartesian path, eased, rounded\nerror {1000 * err[t]:.2f} mm · contacts {contacts[t]}"

    ov = render.Overlay(points=ARM_STOPS, trail="ee", caption=caption)
    return render.frames(tree, traj.q, width, height, camera=cam, overlay=ov, desc="render arm")


def walk_motion(n: int, fps: float) -> tuple[Tree, Array, Callable[[int], str]]:
    """The walk scene's primate, its poses ``(T, nq)`` (:data:`WALK_STEPS` whole steps of ``n`` frames) and captions."""
    tree = load("primate")
    steps, per = WALK_STEPS, max(2, n // WALK_STEPS)
    walk = motion.walk_cycle(tree, steps=steps, gait=motion.Gait(frames_per_step=per), fps=fps)

    def caption(t: int) -> str:
        return f"primate walk, heel to toe\nstep {t // per + 1} of {steps} · arms swing\nIK root: the planted foot"

    return tree, walk.q, caption


def scene_walk(width: int, height: int, n: int, fps: float) -> Images:
    """The primate walking four steps heel to toe, from the side, the camera following.

    The caption's lines are short: its band stays left of the figure, which the camera keeps in the middle.
    """
    tree, qs, caption = walk_motion(n, fps)
    return render.frames(tree, qs, width, height, overlay=render.Overlay(caption=caption), view=render.WALK_VIEW,
                         follow=True, desc="render walk")


SCENES: dict[str, Callable[[int, int, int, float], Images]] = {
    "seeds": lambda w, h, n, fps: scene_seeds(w, h, n),
    "arm": scene_arm,
    "walk": scene_walk,
}


def scene_frames(scene: str = "all", seconds: float = 15.0, fps: float = 30.0) -> dict[str, int]:
    """The frames each scene of ``scene`` (a name or "all") is asked for, and exactly renders."""
    names = list(SCENES) if scene == "all" else [scene]
    if any(s not in SCENES for s in names):
        raise InputError(f"unknown demo scene {scene!r}; choose one of: all, {', '.join(SCENES)}")
    if not (np.isfinite(seconds) and seconds > 0 and np.isfinite(fps) and fps > 0):
        raise InputError(f"--seconds and --fps must be positive, got {seconds!r}, {fps!r}")
    if seconds * fps > MAX_FRAMES:
        raise InputError(f"--seconds x --fps must give at most {MAX_FRAMES:,} frames, got {seconds * fps:,.0f}")
    total = sum(SHARES[s] for s in names)
    out = {s: _frames_of(SHARES[s] / total, seconds, fps) for s in names}
    if "walk" in out:  # whole steps
        out["walk"] = WALK_STEPS * max(2, out["walk"] // WALK_STEPS)
    return out


def showcase(scene: str = "all", seconds: float = 15.0, fps: float = 30.0, width: int = 640,
             height: int = 480) -> Images:
    """Frames ``(height, width, 3)`` of one scene or of all of them, one after another, made as they are taken.

    The scene names and lengths are checked at the call; each scene's solving starts when its first frame is taken.
    """
    counts = scene_frames(scene, seconds, fps)
    return itertools.chain.from_iterable(SCENES[s](width, height, n, fps) for s, n in counts.items())
